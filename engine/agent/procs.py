"""Broker processes the agent runs: its own children, and ones it re-adopts after a restart.

Every broker runs in a process group of its own (:func:`engine.process.spawn`), so it survives the
agent. The agent writes ``pid.json`` beside it: the pid, the process start time in clock ticks
since boot (``/proc/<pid>/stat`` field 22) and the argv. After an agent restart a pid is adopted
only if ``/proc/<pid>`` still has that start time (a recycled pid has another) and its command line
names the broker folder; anything else found running from that folder is a stray and is stopped.
Linux-only (``/proc``), like the agent.
"""

from __future__ import annotations

import functools
import logging
import os
import signal
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from engine import process

_CLK_TCK = os.sysconf("SC_CLK_TCK")


@dataclass(frozen=True)
class ProcInfo:
    """What /proc says of a live (not zombie) process."""

    pid: int
    start_ticks: int
    pgid: int
    argv: tuple[str, ...]


def proc_info(pid: int) -> ProcInfo | None:
    """The process ``pid`` if it exists and is not a zombie, else None."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        raw = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return None
    # "pid (comm) state ppid pgrp session tty_nr tpgid flags minflt cminflt majflt cmajflt utime
    # stime cutime cstime priority nice num_threads itrealvalue starttime ...": comm may hold
    # blanks and parentheses, so split after the last ")".
    rest = stat.rsplit(")", 1)[1].split()
    if rest[0] in ("Z", "X"):
        return None
    argv = tuple(a.decode("utf-8", "replace") for a in raw.split(b"\0") if a)
    return ProcInfo(pid=pid, start_ticks=int(rest[19]), pgid=int(rest[2]), argv=argv)


@functools.cache
def _boot_time() -> float:
    """When the machine booted (it does not change while the agent runs: read once; every GET
    /v1/brokers asked it for every broker)."""
    for line in Path("/proc/stat").read_text().splitlines():
        if line.startswith("btime "):
            return float(line.split()[1])
    return 0.0


def started_at(start_ticks: int) -> float:
    """Seconds since the epoch when a process with ``start_ticks`` started."""
    return _boot_time() + start_ticks / _CLK_TCK


def mentions(info: ProcInfo, folder: Path, program: str) -> bool:
    """True if ``info`` runs ``program`` (argv[0]) with an argument inside ``folder``."""
    prefix = f"{folder}/"
    return bool(info.argv) and info.argv[0] == program and any(
        prefix in arg for arg in info.argv[1:]
    )


def processes_mentioning(folder: Path) -> list[ProcInfo]:
    """Live processes with an argument inside ``folder`` (tests use it to find leftovers)."""
    prefix = f"{folder}/"
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            info = proc_info(int(entry.name))
            if info is not None and any(prefix in arg for arg in info.argv[1:]):
                found.append(info)
    return found


def processes_of(folder: Path, program: str) -> list[ProcInfo]:
    """Live processes running ``program`` with an argument inside ``folder``."""
    return [info for info in processes_mentioning(folder) if mentions(info, folder, program)]


class BrokerProcess(Protocol):
    pid: int
    start_ticks: int

    def alive(self) -> bool: ...
    def exit_code(self) -> int | None: ...
    def stop(self, grace: float) -> None: ...
    def log_tail(self, max_bytes: int = 2000) -> str: ...


def log_end(proc: BrokerProcess, count: int = 12) -> str:
    """The last ``count`` lines of a broker's log, for an error message."""
    return "\n".join(proc.log_tail().strip().splitlines()[-count:])


class SpawnedProcess:
    """A broker this agent started (its Popen reaps it and knows its exit code)."""

    def __init__(self, child: process.Child) -> None:
        self.child = child
        self.pid = child.pid
        info = proc_info(child.pid)
        self.start_ticks = info.start_ticks if info else 0

    def alive(self) -> bool:
        return self.child.running()

    def exit_code(self) -> int | None:
        return self.child.popen.returncode

    def stop(self, grace: float) -> None:
        process.stop(self.child, grace=grace)

    def log_tail(self, max_bytes: int = 2000) -> str:
        return self.child.log_tail(max_bytes)


class AdoptedProcess:
    """A broker started by an earlier agent; alive while /proc shows the same start time."""

    def __init__(self, info: ProcInfo, log_path: Path) -> None:
        self.pid = info.pid
        self.start_ticks = info.start_ticks
        self.log_path = log_path

    def alive(self) -> bool:
        info = proc_info(self.pid)
        return info is not None and info.start_ticks == self.start_ticks

    def exit_code(self) -> int | None:
        return None  # not our child: its parent (init) collected the status

    def stop(self, grace: float) -> None:
        stop_foreign(ProcInfo(self.pid, self.start_ticks, self.pid, ()), grace)

    def log_tail(self, max_bytes: int = 2000) -> str:
        return process.read_tail(self.log_path, max_bytes)


def stop_together(procs: Sequence[BrokerProcess], graces: Sequence[float],
                  after_signal: Callable[[], None] | None = None) -> list[Exception | None]:
    """Stop many brokers at once, each with its grace: the agent's own children are all sent
    SIGTERM, then waited for (:func:`engine.process.stop_each`, which runs ``after_signal``
    between the two); adopted ones are stopped from a thread each meanwhile. Each one's error
    (None: stopped), in order."""
    errors: list[Exception | None] = [None] * len(procs)
    own = [i for i, p in enumerate(procs) if isinstance(p, SpawnedProcess)]
    other = [i for i in range(len(procs)) if i not in set(own)]

    def stop_other(i: int) -> None:
        try:
            procs[i].stop(graces[i])
        except Exception as exc:  # noqa: BLE001 - this broker's own error
            errors[i] = exc

    threads = [threading.Thread(target=stop_other, args=(i,), daemon=True) for i in other]
    for thread in threads:
        thread.start()
    outcomes = process.stop_each([procs[i].child for i in own], [graces[i] for i in own],  # type: ignore[attr-defined]
                                 after_signal)
    for i, outcome in zip(own, outcomes):
        errors[i] = outcome if isinstance(outcome, Exception) else None  # else: its exit code
    for thread in threads:
        thread.join()
    return errors


def raise_first(errors: Mapping[str, Exception], what: str, logger: logging.Logger) -> None:
    """After stopping many things together: log each one's failure (``what`` and its name), then
    raise the first by name, so a caller learns of it once all were tried."""
    for name, error in sorted(errors.items()):
        logger.error("%s %s could not be stopped: %s", what, name, error)
    if errors:
        raise errors[min(errors)]


def stop_foreign(info: ProcInfo, grace: float) -> None:
    """SIGTERM a process that is not our child (its group if it leads one), SIGKILL after
    ``grace`` s; return once it is gone (or a zombie its parent will reap)."""
    def same() -> bool:
        now = proc_info(info.pid)
        return now is not None and now.start_ticks == info.start_ticks

    def send(sig: signal.Signals) -> None:
        if not same():
            return
        try:
            if os.getpgid(info.pid) == info.pid:
                os.killpg(info.pid, sig)
            else:
                os.kill(info.pid, sig)
        except ProcessLookupError:
            pass

    send(signal.SIGTERM)
    if not same() or process.wait_exit(info.pid, grace) or not same():
        return
    send(signal.SIGKILL)
    process.wait_until(lambda: not same(), 10.0, 0.02, what=f"pid {info.pid} to die")

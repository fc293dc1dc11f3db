"""Run real broker processes: spawn, poll until ready, stop, with nothing left behind.

- :func:`spawn` starts an argv (no shell) in a session and process group of its own, stdin from
  /dev/null, stdout and stderr appended to ``<log_dir>/<name>.log``.
- :func:`wait_until` polls a predicate until it returns something truthy or a deadline passes; it
  fails fast, with the log's tail, if the watched child exits meanwhile. No bare sleeps elsewhere.
- :func:`stop` sends SIGTERM to the whole group, SIGKILL after a grace period, and reaps the child,
  so a JVM and anything it forked are gone when it returns. :func:`stop_each` does that for many
  children at once (every group is signalled first, then all are waited for together), each with
  its own outcome; :func:`stop_all` is the same for a caller that treats any failure as fatal.
- :func:`wait_exit` waits for a process to exit and wakes the moment it does (a pidfd, Linux 5.3+),
  where ``Popen.wait(timeout)`` polls with sleeps growing to 50 ms, which a stop would pay.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

from engine.errors import ProcessError, WaitTimeoutError

T = TypeVar("T")


@dataclass
class Child:
    """A spawned process; its pid is also its process-group id."""

    name: str
    argv: tuple[str, ...]
    log_path: Path
    popen: subprocess.Popen[bytes]

    @property
    def pid(self) -> int:
        return self.popen.pid

    def running(self) -> bool:
        """True while the leader has not exited (polls, so it also reaps an exited leader)."""
        return self.popen.poll() is None

    def group_alive(self) -> bool:
        """True while a live process (not a zombie awaiting its reaper) is in the child's group."""
        try:
            os.killpg(self.pid, 0)
        except ProcessLookupError:
            return False
        except PermissionError:  # exists, owned by someone else (should not happen)
            return True
        return bool(_live_group_members(self.pid))

    def log_tail(self, max_bytes: int = 4000) -> str:
        """The end of the child's log, for error messages."""
        return read_tail(self.log_path, max_bytes)


def read_tail(path: Path, max_bytes: int = 4000) -> str:
    """The last ``max_bytes`` of a log file as text ("" if it cannot be read)."""
    try:
        with path.open("rb") as fh:
            fh.seek(max(0, path.stat().st_size - max_bytes))
            return fh.read().decode("utf-8", "replace")
    except OSError:
        return ""


def spawn(
    argv: Sequence[str | os.PathLike[str]],
    *,
    log_dir: Path,
    name: str,
    cwd: Path | None = None,
    extra_env: Mapping[str, str] | None = None,
) -> Child:
    """Start ``argv`` in its own process group; output goes to ``log_dir/<name>.log``."""
    args = tuple(os.fspath(a) for a in argv)
    if not args:
        raise ProcessError("cannot spawn an empty command")
    log_dir.mkdir(parents=True, exist_ok=True)
    log_path = log_dir / f"{name}.log"
    env = {**os.environ, **extra_env} if extra_env else None
    with log_path.open("ab") as log:
        try:
            popen = subprocess.Popen(  # noqa: S603 - argv list, no shell
                args,
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
                cwd=cwd,
                env=env,
                start_new_session=True,
                close_fds=True,
            )
        except OSError as exc:
            raise ProcessError(f"cannot start {name} ({args[0]}): {exc}") from exc
    return Child(name=name, argv=args, log_path=log_path, popen=popen)


def wait_until(
    predicate: Callable[[], T],
    deadline: float,
    interval: float | Callable[[], float] = 0.05,
    *,
    what: str | None = None,
    child: Child | None = None,
    ignore: tuple[type[BaseException], ...] = (),
) -> T:
    """Call ``predicate`` every ``interval`` s until it returns a truthy value, and return it.
    ``interval`` may be a function, asked before each pause (a poll that speeds up or slows down).

    ``deadline`` is a budget in seconds from now. Exceptions listed in ``ignore`` count as "not
    yet" (the last one is quoted on timeout). If ``child`` exits first, raise :class:`ProcessError`
    at once with its log tail; on timeout raise :class:`WaitTimeoutError` naming ``what``.
    """
    label = what or getattr(predicate, "__name__", repr(predicate))
    end = time.monotonic() + deadline
    last_error: BaseException | None = None
    while True:
        try:
            result = predicate()
        except ignore as exc:
            last_error = exc
        else:
            if result:
                return result
        if child is not None and not child.running():
            raise ProcessError(
                f"{child.name} exited with code {child.popen.returncode} while waiting for {label}"
                f"; log {child.log_path}:\n{child.log_tail()}"
            )
        remaining = end - time.monotonic()
        if remaining <= 0:
            detail = f"last error: {last_error}" if last_error else ""
            if child is not None:
                detail += f"\nlog {child.log_path}:\n{child.log_tail()}"
            raise WaitTimeoutError(label, deadline, detail.strip())
        time.sleep(min(interval() if callable(interval) else interval, remaining))


def stop(child: Child, grace: float = 10.0) -> int:
    """SIGTERM the child's group, SIGKILL it after ``grace`` s, reap; return the leader's exit code.

    Returns once no live process is left in the group (members the leader left behind are
    killed too)."""
    _signal_group(child, signal.SIGTERM)
    return _finish_stop(child, grace, time.monotonic() + grace)


def stop_each(children: Sequence[Child], graces: Sequence[float],
              after_signal: Callable[[], None] | None = None) -> list[int | Exception]:
    """:func:`stop` for many children at once, each with its grace: SIGTERM every group first,
    then wait for them all (each until its grace after the signals, then SIGKILL), so stopping N
    brokers takes about as long as the slowest one, not the sum. Each child's outcome, in order:
    its leader's exit code, or the error that kept it from being stopped (the others are still
    waited for: one child that will not stop leaves none of the others running).
    ``after_signal`` runs once every group was signalled, before the wait (e.g. to wake children
    that act on a signal only when their loop wakes up)."""
    for child in children:
        _signal_group(child, signal.SIGTERM)
    if after_signal is not None:
        after_signal()
    now = time.monotonic()
    outcomes: list[int | Exception] = []
    for child, grace in zip(children, graces, strict=True):
        try:
            outcomes.append(_finish_stop(child, grace, now + grace))
        except Exception as exc:  # noqa: BLE001 - this child's own error
            outcomes.append(exc)
    return outcomes


def stop_all(children: Sequence[Child], grace: float = 10.0) -> list[int]:
    """:func:`stop_each` with one grace for all, for a caller that wants the exit codes and has no
    use for a partial stop: once every child was waited for, the first error is raised."""
    outcomes = stop_each(children, [grace] * len(children))
    for outcome in outcomes:
        if isinstance(outcome, Exception):
            raise outcome
    return outcomes  # type: ignore[return-value] - no error among them


def _finish_stop(child: Child, grace: float, end: float) -> int:
    """Wait for a signalled child until ``end`` (SIGKILL then), reap it, then its group."""
    if not wait_exit(child.popen, max(0.0, end - time.monotonic())):
        _signal_group(child, signal.SIGKILL)
    child.popen.wait()
    if child.group_alive():
        try:
            wait_until(lambda: not child.group_alive(), grace, 0.01, what="the group to exit")
        except WaitTimeoutError:
            _signal_group(child, signal.SIGKILL)
            wait_until(lambda: not child.group_alive(), 5.0, 0.01,
                       what=f"process group {child.pid} to die after SIGKILL")
    return child.popen.returncode


def wait_exit(target: subprocess.Popen[bytes] | int, timeout: float) -> bool:
    """Wait up to ``timeout`` s for a process (our child's Popen, or any pid) to exit; True once
    it has. Wakes when it exits (pidfd); where pidfds are missing, a child is waited for with
    ``Popen.wait`` and another pid is polled every 10 ms. A child is not reaped here."""
    pid = target.pid if isinstance(target, subprocess.Popen) else target
    if isinstance(target, subprocess.Popen) and target.returncode is not None:
        return True
    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        return True
    except (AttributeError, OSError):  # no pidfd here: the portable, slower ways
        if isinstance(target, subprocess.Popen):
            try:
                target.wait(timeout=timeout)
                return True
            except subprocess.TimeoutExpired:
                return False
        try:
            wait_until(lambda: not _exists(pid), timeout, 0.01, what=f"pid {pid} to exit")
            return True
        except WaitTimeoutError:
            return False
    try:
        poller = select.poll()
        poller.register(fd, select.POLLIN)
        end = time.monotonic() + timeout
        while True:  # poll() may return early on a signal (EINTR is retried with the rest)
            if poller.poll(max(0.0, end - time.monotonic()) * 1000):
                return True
            if time.monotonic() >= end:
                return False
    finally:
        os.close(fd)


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _signal_group(child: Child, sig: signal.Signals) -> None:
    try:
        os.killpg(child.pid, sig)
    except ProcessLookupError:
        pass


def _live_group_members(pgid: int) -> list[int]:
    """Pids in process group ``pgid`` that are not zombies (Linux /proc)."""
    members = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # "pid (comm) state ppid pgrp ...": comm may contain blanks and parentheses.
        state, _ppid, pgrp = stat.rsplit(")", 1)[1].split()[:3]
        if int(pgrp) == pgid and state not in ("Z", "X"):
            members.append(int(entry.name))
    return members

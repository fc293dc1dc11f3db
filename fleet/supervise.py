"""Keep a fleet process running: restart it when it crashes, stop it with the supervisor.

``python -m fleet.supervise [--name NAME] [--status-file F] -- COMMAND...`` runs COMMAND (no
shell) and, like the agents do for brokers:

- restarts it when it dies of a signal (kill -9, a segfault) or exits with a code other than 0
  and 2, after a backoff of 0.5 s doubling to 30 s (back to 0.5 s once a run lasted 60 s);
- does not restart it after exit code 2, the fleet's "fix the command line or the input" code
  (a bad LoTLan file, a data directory in use): restarting cannot help, so the supervisor exits 2
  too, and after exit 0 (a clean stop) it exits 0;
- on SIGTERM or SIGINT stops it (SIGTERM to its process group, SIGKILL after 10 s) and exits 0;
- if the supervisor itself is killed (even with kill -9), the child gets SIGTERM from the kernel
  (``PR_SET_PDEATHSIG``), so no unsupervised copy is left running beside the next supervisor;
- writes ``--status-file`` (JSON: child pid, restarts, last exit) at each change, atomically.

The task planner and the fleet manager keep their state on disk (journal, data directory), so a
restart resumes where the killed process stopped. ``plantkg fleet planner`` runs the planner
this way.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

log = logging.getLogger("fleet.supervise")
BACKOFF_BASE = 0.5
BACKOFF_CAP = 30.0
STABLE_AFTER = 60.0
STOP_GRACE = 10.0
NO_RESTART = (0, 2)
PR_SET_PDEATHSIG = 1


@dataclass(frozen=True)
class Status:
    name: str
    pid: int | None
    restarts: int
    last_exit: str | None
    since: float


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM when the supervisor dies (Linux)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):
        pass


def describe_exit(code: int) -> str:
    if code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit code {code}"


def backoff(attempt: int) -> float:
    return min(BACKOFF_CAP, BACKOFF_BASE * 2 ** max(0, attempt - 1))


class Supervisor:
    def __init__(self, argv: Sequence[str], *, name: str, status_file: Path | None = None,
                 delay: Callable[[int], float] = backoff) -> None:
        self.argv = list(argv)
        self.name = name
        self.status_file = status_file
        self.delay = delay
        self.stopping = threading.Event()
        self.child: subprocess.Popen[bytes] | None = None
        self.restarts = 0
        self.last_exit: str | None = None

    def _write_status(self) -> None:
        if self.status_file is None:
            return
        status = Status(self.name, self.child.pid if self.child and self.child.poll() is None else None,
                        self.restarts, self.last_exit, time.time())
        tmp = self.status_file.with_name(self.status_file.name + ".tmp")
        tmp.write_text(json.dumps(asdict(status)), encoding="utf-8")
        os.replace(tmp, self.status_file)

    def _spawn(self) -> subprocess.Popen[bytes]:
        return subprocess.Popen(self.argv, stdin=subprocess.DEVNULL, start_new_session=True,  # noqa: S603
                                preexec_fn=_die_with_parent)

    def stop(self) -> None:
        self.stopping.set()

    def _stop_child(self) -> None:
        child = self.child
        if child is None or child.poll() is not None:
            return
        try:
            os.killpg(child.pid, signal.SIGTERM)
            child.wait(STOP_GRACE)
        except subprocess.TimeoutExpired:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
        except ProcessLookupError:
            child.wait()

    def run(self) -> int:
        """Run until stopped (0), or until the child exits 0 or 2 (that code)."""
        attempt = 0
        try:
            while not self.stopping.is_set():
                try:
                    self.child = self._spawn()
                except OSError as err:
                    log.error("%s: cannot start %s: %s", self.name, self.argv[0], err)
                    return 2
                started = time.monotonic()
                self._write_status()
                log.info("%s: started, pid %d", self.name, self.child.pid)
                while (code := self.child.poll()) is None:
                    if self.stopping.wait(0.2):
                        self._stop_child()
                        self.last_exit = "stopped by the supervisor"
                        return 0
                self.last_exit = describe_exit(code)
                if code in NO_RESTART:
                    log.info("%s: %s, not restarted", self.name, self.last_exit)
                    return code
                attempt = 1 if time.monotonic() - started >= STABLE_AFTER else attempt + 1
                wait = self.delay(attempt)
                self.restarts += 1
                self._write_status()
                log.warning("%s: %s; restart %d in %.1f s", self.name, self.last_exit, self.restarts, wait)
                if self.stopping.wait(wait):
                    return 0
            return 0
        finally:
            self._stop_child()
            self._write_status()


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m fleet.supervise",
                                     description="run a fleet process, restart it when it crashes")
    parser.add_argument("--name", default="child")
    parser.add_argument("--status-file", type=Path)
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARGS...]")
    args = parser.parse_args(argv)
    if args.command and args.command[0] == "--":
        args.command = args.command[1:]
    if not args.command:
        parser.error("give the command to run after --, e.g. -- python -m fleet.planner ...")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(list(sys.argv[1:] if argv is None else argv))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.status_file is not None and not args.status_file.parent.is_dir():
        print(f"error: --status-file {args.status_file}: its folder does not exist", file=sys.stderr)
        return 2
    supervisor = Supervisor(args.command, name=args.name, status_file=args.status_file)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda _s, _f: supervisor.stop())
    return supervisor.run()


if __name__ == "__main__":
    sys.exit(main())

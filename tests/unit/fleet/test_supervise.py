"""fleet.supervise with real child processes: a child killed -9 is started again (a new pid),
exit code 2 and 0 are not restarted, SIGTERM stops supervisor and child, and a supervisor killed
-9 takes its child with it (no unsupervised copy left)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from engine import process
from fleet.supervise import Supervisor, backoff, describe_exit

CHILD = ("import os, sys, time, pathlib\n"
         "pathlib.Path(sys.argv[1]).write_text(str(os.getpid()))\n"
         "code = int(sys.argv[2])\n"
         "if code >= 0: sys.exit(code)\n"
         "while True: time.sleep(0.05)\n")


def child_argv(pid_file: Path, exit_code: int = -1) -> list[str]:
    return [sys.executable, "-c", CHILD, str(pid_file), str(exit_code)]


def read_pid(pid_file: Path, not_this: int | None = None) -> int:
    def fresh() -> int | None:
        try:
            pid = int(pid_file.read_text())
        except (OSError, ValueError):
            return None
        return pid if pid != not_this else None
    return process.wait_until(fresh, 15.0, 0.02, what="the child's pid")


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as f:
        return f.read().split()[2] != "Z"


def test_backoff_and_exit_texts() -> None:
    assert [backoff(n) for n in (1, 2, 3, 10)] == [0.5, 1.0, 2.0, 30.0]
    assert describe_exit(-9) == "killed by SIGKILL" and describe_exit(3) == "exit code 3"


def test_a_child_killed_9_is_started_again_and_stopped_with_the_supervisor(tmp_path: Path) -> None:
    pid_file, status = tmp_path / "pid", tmp_path / "status.json"
    sup = Supervisor(child_argv(pid_file), name="t", status_file=status, delay=lambda _n: 0.05)
    result: list[int] = []
    thread = threading.Thread(target=lambda: result.append(sup.run()))
    thread.start()
    try:
        first = read_pid(pid_file)
        os.kill(first, signal.SIGKILL)
        second = read_pid(pid_file, not_this=first)
        process.wait_until(lambda: json.loads(status.read_text())["pid"] == second, 10, 0.02,
                           what="the status file naming the new child")
        shown = json.loads(status.read_text())
        assert shown["restarts"] == 1 and shown["last_exit"] == "killed by SIGKILL"
    finally:
        sup.stop()
        thread.join(20)
    assert result == [0] and not alive(second)


@pytest.mark.parametrize("code", [0, 2])
def test_exit_0_and_2_are_not_restarted(tmp_path: Path, code: int) -> None:
    sup = Supervisor(child_argv(tmp_path / "pid", code), name="t", delay=lambda _n: 0.05)
    assert sup.run() == code and sup.restarts == 0


def test_other_exit_codes_are_restarted(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    script = ("import pathlib, sys\n"
              f"p = pathlib.Path({str(runs)!r}); n = int(p.read_text()) if p.exists() else 0\n"
              "p.write_text(str(n + 1)); sys.exit(3 if n < 2 else 2)\n")
    sup = Supervisor([sys.executable, "-c", script], name="t", delay=lambda _n: 0.01)
    assert sup.run() == 2 and sup.restarts == 2 and runs.read_text() == "3"


def test_sigterm_and_kill_9_of_the_supervisor_process(tmp_path: Path) -> None:
    for how in (signal.SIGTERM, signal.SIGKILL):
        pid_file = tmp_path / f"pid-{how.name}"
        sup = subprocess.Popen([sys.executable, "-m", "fleet.supervise", "--name", "t", "--",
                                *child_argv(pid_file)], stderr=subprocess.PIPE)
        try:
            child = read_pid(pid_file)
            sup.send_signal(how)
            code = sup.wait(20)
            assert code == (0 if how is signal.SIGTERM else -9)
            process.wait_until(lambda: not alive(child), 15, 0.02, what=f"the child gone after {how.name}")
        finally:
            if sup.poll() is None:
                sup.kill()
                sup.wait()


def test_bad_command_lines_exit_2(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "fleet.supervise", "--name", "t"], capture_output=True,
                          text=True, timeout=30)
    assert done.returncode == 2 and "after --" in done.stderr
    done = subprocess.run([sys.executable, "-m", "fleet.supervise", "--", str(tmp_path / "nothing")],
                          capture_output=True, text=True, timeout=30)
    assert done.returncode == 2 and "cannot start" in done.stderr


def test_plantkg_fleet_planner_runs_it_supervised(tmp_path: Path) -> None:
    """A command line the planner refuses (exit 2) is not restarted: the command exits 2 at once
    with the planner's own message."""
    done = subprocess.run([sys.executable, "-m", "engine.cli", "fleet", "planner", "--lotlan",
                           str(tmp_path / "none.tl")], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2, done.stderr
    assert "--plant" in done.stderr and "not restarted" in done.stderr

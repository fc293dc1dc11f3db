"""When the agent tells a broker to save (engine.agent.save_tick), with child processes standing
in for brokers: one that catches SIGUSR1 and reports each, one that does not catch it."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator

import pytest

from engine.agent.save_tick import SaveTicker, catches, chars_read

CATCHER = """
import signal, sys
signal.signal(signal.SIGUSR1, lambda *_: (sys.stdout.write("saved\\n"), sys.stdout.flush()))
signal.signal(signal.SIGINT, signal.default_int_handler)  # its own, even where SIGINT came ignored
print("ready", flush=True)
for line in sys.stdin:
    print("read", flush=True)
"""
IGNORANT = "import sys\nprint('ready', flush=True)\nsys.stdin.read()\n"


@pytest.fixture
def children() -> Iterator[list[subprocess.Popen[str]]]:
    started: list[subprocess.Popen[str]] = []
    yield started
    for child in started:
        child.kill()
        child.wait(10)


def start(children: list[subprocess.Popen[str]], code: str) -> subprocess.Popen[str]:
    child = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             text=True)
    children.append(child)
    assert child.stdout is not None and child.stdout.readline() == "ready\n"
    return child


def test_catches_reads_the_handlers_of_a_process(children: list[subprocess.Popen[str]]) -> None:
    catcher, ignorant = start(children, CATCHER), start(children, IGNORANT)
    assert catches(catcher.pid, signal.SIGUSR1) and not catches(ignorant.pid, signal.SIGUSR1)
    assert catches(catcher.pid, signal.SIGINT)  # a second handler it installed (KeyboardInterrupt)
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait(10)
    assert not catches(gone.pid, signal.SIGUSR1) and chars_read(gone.pid) is None


def test_a_save_is_sent_when_due_and_only_after_the_process_read_something(
        children: list[subprocess.Popen[str]]) -> None:
    child = start(children, CATCHER)
    assert child.stdin is not None and child.stdout is not None
    ticker = SaveTicker(every=0.25)
    assert ticker.step(child.pid, signal.SIGUSR1, now=100.0)       # the first: nothing known yet
    assert child.stdout.readline() == "saved\n"
    assert not ticker.step(child.pid, signal.SIGUSR1, now=100.1)   # not due
    assert not ticker.step(child.pid, signal.SIGUSR1, now=100.3)   # due, but it read nothing since
    before = chars_read(child.pid)
    child.stdin.write("a message\n")
    child.stdin.flush()
    assert child.stdout.readline() == "read\n"
    assert chars_read(child.pid) != before
    assert not ticker.step(child.pid, signal.SIGUSR1, now=100.4)   # read, but not due (0.3 + 0.25)
    assert ticker.step(child.pid, signal.SIGUSR1, now=100.6)
    assert child.stdout.readline() == "saved\n" and ticker.sent == 2


def test_a_process_without_a_handler_is_never_signalled(children: list[subprocess.Popen[str]]) -> None:
    # SIGUSR1's default action ends a process: a broker spawned a moment ago, before it installed
    # its handlers, would be killed by the save meant to protect its data.
    child = start(children, IGNORANT)
    ticker = SaveTicker(every=0.25)
    assert not ticker.step(child.pid, signal.SIGUSR1, now=1.0)
    assert not ticker.step(child.pid, signal.SIGUSR1, now=2.0)
    assert child.poll() is None and ticker.sent == 0


def test_a_new_process_is_saved_afresh(children: list[subprocess.Popen[str]]) -> None:
    one, two = start(children, CATCHER), start(children, CATCHER)
    ticker = SaveTicker(every=0.25)
    assert ticker.step(one.pid, signal.SIGUSR1, now=1.0)
    assert ticker.step(two.pid, signal.SIGUSR1, now=2.0)  # the broker restarted: a new pid
    assert two.stdout is not None and two.stdout.readline() == "saved\n"
    assert one.poll() is None and two.poll() is None

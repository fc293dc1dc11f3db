"""engine.agent.supervision: the loop that supervises brokers and bridge workers."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import pytest

from engine import process
from engine.agent.supervision import backoff, start_supervisor


@dataclass(eq=False)
class Unit:
    name: str
    op: threading.Lock = field(default_factory=threading.Lock)
    steps: int = 0


def test_backoff_doubles_up_to_its_cap() -> None:
    assert [backoff(1.0, 30.0, n) for n in (1, 2, 3, 5, 6, 10)] == [1.0, 2.0, 4.0, 16.0, 30.0, 30.0]
    assert backoff(0.5, 30.0, 0) == 0.5


def test_each_unit_is_stepped_a_busy_one_skipped_a_failing_one_logged(
        caplog: pytest.LogCaptureFixture) -> None:
    calm, busy, broken = Unit("calm"), Unit("busy"), Unit("broken")
    busy.op.acquire()  # a PUT in progress: the loop must not wait for it

    def step(unit: Unit) -> None:
        unit.steps += 1
        if unit is broken:
            raise RuntimeError("boom")

    stop = threading.Event()
    thread = start_supervisor("test-supervisor", stop, 0.001, lambda: [calm, busy, broken], step,
                              lambda u: f"unit {u.name}")
    try:
        process.wait_until(lambda: calm.steps >= 3 and broken.steps >= 3, 10, 0.001,
                           what="three rounds")
    finally:
        stop.set()
        thread.join(5)
    assert not thread.is_alive()
    assert busy.steps == 0 and not broken.op.locked() and not calm.op.locked()
    assert "supervising unit broken" in caplog.text and "boom" in caplog.text

"""The Kafka -> MQTT half's flow: consume, wait for PUBACKs while the window is full, pause only
when it stays full or MQTT is down."""

from __future__ import annotations

import pytest

from engine.bridge_worker.consume_window import ConsumeWindow, Flow


def window() -> ConsumeWindow:
    return ConsumeWindow(high=100, low=80, hold_limit=1.0)


def test_consumes_below_the_window() -> None:
    w = window()
    assert [w.decide(True, n, 0.0) for n in (0, 50, 99)] == [Flow.CONSUME] * 3


def test_a_full_window_waits_for_acks_and_reopens_only_at_low() -> None:
    w = window()
    steps = [(100, 0.0, Flow.AWAIT_ACKS), (99, 0.1, Flow.AWAIT_ACKS), (81, 0.2, Flow.AWAIT_ACKS),
             (80, 0.3, Flow.CONSUME), (95, 0.4, Flow.CONSUME), (120, 0.5, Flow.AWAIT_ACKS)]
    assert [w.decide(True, n, t) for n, t, _ in steps] == [flow for _, _, flow in steps]


def test_a_window_full_past_the_hold_limit_pauses_until_it_reopens() -> None:
    w = window()
    assert w.decide(True, 100, 10.0) is Flow.AWAIT_ACKS
    assert w.decide(True, 100, 10.99) is Flow.AWAIT_ACKS
    assert w.decide(True, 100, 11.0) is Flow.PAUSE
    assert w.decide(True, 90, 30.0) is Flow.PAUSE
    assert w.decide(True, 80, 31.0) is Flow.CONSUME
    assert w.decide(True, 100, 31.5) is Flow.AWAIT_ACKS   # a new full spell: the limit counts anew


def test_disconnected_pauses_and_forgets_the_full_spell() -> None:
    w = window()
    assert w.decide(True, 100, 0.0) is Flow.AWAIT_ACKS
    assert w.decide(False, 100, 0.5) is Flow.PAUSE
    assert w.decide(False, 0, 5.0) is Flow.PAUSE
    assert w.decide(True, 0, 6.0) is Flow.CONSUME   # after a reconnect (the rewind empties the window)


@pytest.mark.parametrize(("high", "low"), [(100, 100), (100, 120), (100, -1)])
def test_a_low_mark_not_below_high_is_refused(high: int, low: int) -> None:
    with pytest.raises(ValueError, match="low"):
        ConsumeWindow(high=high, low=low, hold_limit=1.0)

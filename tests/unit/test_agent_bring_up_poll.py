"""How often the agent polls a starting broker (engine.agent.bring_up.poll_interval): fast while a
quick broker would come up, then less often as the wait grows, never slower than its health
checks."""

from __future__ import annotations

import pytest

from engine.agent.bring_up import READY_BACKOFF, READY_POLL, poll_interval

MOSQUITTO_SLOW = 10.0 / 5000   # its start deadline / 5000, as wait_all_healthy sets it
KAFKA_SLOW = 90.0 / 5000


@pytest.mark.parametrize("elapsed", [0.0, 0.001, 0.006, READY_POLL * READY_BACKOFF])
def test_the_first_moments_poll_the_port_at_the_fastest_rate(elapsed: float) -> None:
    assert poll_interval(elapsed, False, MOSQUITTO_SLOW) == READY_POLL
    assert poll_interval(elapsed, False, KAFKA_SLOW) == READY_POLL


def test_a_long_wait_polls_in_proportion_to_its_length() -> None:
    assert poll_interval(0.5, False, KAFKA_SLOW) == pytest.approx(0.5 / READY_BACKOFF)
    assert poll_interval(0.1, False, KAFKA_SLOW) == pytest.approx(0.1 / READY_BACKOFF)


@pytest.mark.parametrize(("elapsed", "slow"), [(5.0, KAFKA_SLOW), (0.5, MOSQUITTO_SLOW), (60.0, MOSQUITTO_SLOW)])
def test_the_port_is_never_polled_less_often_than_the_health_check(elapsed: float, slow: float) -> None:
    assert poll_interval(elapsed, False, slow) == slow


@pytest.mark.parametrize("elapsed", [0.0, 0.01, 3.0])
def test_a_listening_broker_gets_its_health_check_at_its_own_interval(elapsed: float) -> None:
    assert poll_interval(elapsed, True, KAFKA_SLOW) == KAFKA_SLOW
    assert poll_interval(elapsed, True, MOSQUITTO_SLOW) == MOSQUITTO_SLOW


def test_a_kafka_boot_of_seconds_is_polled_tens_of_times_a_second_not_thousands() -> None:
    """Count the polls of a 5 s wait (the loop of wait_all_healthy, without the broker): about
    50 * ln(cap / first) while the interval grows, then 1 per health interval; a fixed
    READY_POLL would make 20,000."""
    elapsed, polls = 0.0, 0
    while elapsed < 5.0:
        elapsed += poll_interval(elapsed, False, KAFKA_SLOW)
        polls += 1
    assert 5.0 / KAFKA_SLOW < polls < 600

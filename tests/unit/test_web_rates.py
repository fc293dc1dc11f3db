"""The dashboard's rate counting without a broker: the ring of one-second buckets, the book of
watched (broker, topic) pairs with a clock the test moves, which taps the plant asks for, and
``/api/rates`` of a server that watches nothing. Real brokers: tests/web/test_rates.py."""

from __future__ import annotations

import pytest

from engine.check.watch import Endpoint
from engine.model import BrokerSpec, BrokerStatus, DesiredState, ObservedBroker, ObservedState, TopicSpec
from engine.web.rates import RateBook, RateMonitor, RateRing, RateTarget, rate_targets

# (what is added as (second, n), the last second asked for, per second expected, total expected)
RING_CASES = [
    pytest.param([], 10, [0, 0, 0, 0], 0, id="empty"),
    pytest.param([(10, 1), (10, 2), (9, 5)], 10, [0, 0, 5, 3], 8, id="two-seconds"),
    pytest.param([(7, 1), (8, 2), (9, 3), (10, 4)], 10, [1, 2, 3, 4], 10, id="full-window"),
    pytest.param([(5, 9), (10, 4)], 10, [0, 0, 0, 4], 13, id="old-second-left-the-window"),
    pytest.param([(6, 9), (10, 4)], 10, [0, 0, 0, 4], 13, id="same-slot-reused-by-a-newer-second"),
    pytest.param([(10, 4), (6, 9)], 10, [0, 0, 0, 4], 13, id="late-second-older-than-the-slot-dropped"),
    pytest.param([(10, 4)], 12, [0, 4, 0, 0], 4, id="quiet-seconds-after-are-zero"),
    pytest.param([(10, 4)], 20, [0, 0, 0, 0], 4, id="all-out-of-the-window"),
    pytest.param([(11, 4)], 10, [0, 0, 0, 0], 4, id="a-future-second-is-not-shown-yet"),
]


@pytest.mark.parametrize(("adds", "last", "expected", "total"), RING_CASES)
def test_ring(adds: list[tuple[int, int]], last: int, expected: list[int], total: int) -> None:
    ring = RateRing(window=4)
    for second, n in adds:
        ring.add(second, n)
    assert ring.series(last) == expected
    assert ring.total == total


def test_ring_memory_is_the_window_whatever_the_traffic() -> None:
    ring = RateRing(window=60)
    for second in range(100_000):
        ring.add(second, 3)
    assert ring.series(99_999) == [3] * 60
    assert len(ring._counts) == len(ring._seconds) == 60
    assert ring.total == 300_000


def test_ring_refuses_an_empty_window() -> None:
    with pytest.raises(ValueError, match="window must be at least 1 second, not 0"):
        RateRing(window=0)


class Clock:
    def __init__(self, now: float) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


def test_book_counts_only_watched_pairs_and_keeps_history_across_retargets() -> None:
    clock = Clock(100.2)
    book = RateBook(window=3, clock=clock)
    book.keep([("a", "t1"), ("a", "t2")])
    book.count("a", "t1")
    book.count("a", "t1")
    book.count("a", "unwatched")          # not kept: memory only for the watched pairs
    book.count("b", "t1")
    clock.now = 101.7
    book.count("a", "t2", 5)
    clock.now = 102.0                       # 101 is complete, 102 has just begun
    assert book.rows() == [("a", "t1", [0, 2, 0], 2), ("a", "t2", [0, 0, 5], 5)]
    book.keep([("a", "t2"), ("b", "t3")])  # t1 went; t2's history stays; t3 starts empty
    assert book.rows() == [("a", "t2", [0, 0, 5], 5), ("b", "t3", [0, 0, 0], 0)]


def _plant(kinds: dict[str, str], topics: list[tuple[str, str]]) -> DesiredState:
    brokers = tuple(BrokerSpec(b, f"urn:{b}", b, kind, "127.0.0.2", 1000 + i)
                    for i, (b, kind) in enumerate(sorted(kinds.items())))
    return DesiredState(brokers=brokers, topics=tuple(TopicSpec(b, t, f"urn:{b}:{t}") for b, t in topics))


def _running(desired: DesiredState, status: dict[str, BrokerStatus], pid: int = 42) -> ObservedState:
    return ObservedState(brokers=tuple(ObservedBroker(desired.broker(b), s, pid=pid)  # type: ignore[arg-type]
                                       for b, s in status.items()))


PLANT = _plant({"mq": "mosquitto", "kf": "kafka", "cb": "ngsi-v2", "down": "mosquitto"},
               [("mq", "b"), ("mq", "a"), ("kf", "k"), ("cb", "e"), ("down", "x")])
RUNNING = BrokerStatus.RUNNING


def test_targets_are_the_running_mosquitto_and_kafka_brokers_with_their_topics() -> None:
    observed = _running(PLANT, {"mq": RUNNING, "kf": RUNNING, "cb": RUNNING, "down": BrokerStatus.CRASHED})
    assert rate_targets(PLANT, observed) == (
        RateTarget(Endpoint("kf", "kafka", "127.0.0.2", 1002), ("k",), 42),
        RateTarget(Endpoint("mq", "mosquitto", "127.0.0.2", 1003), ("a", "b"), 42),
    )


@pytest.mark.parametrize(("desired", "observed"), [
    pytest.param(None, None, id="no-plant"),
    pytest.param(PLANT, None, id="agents-not-asked"),
    pytest.param(PLANT, ObservedState(), id="nothing-runs"),
    pytest.param(PLANT, _running(PLANT, {"mq": BrokerStatus.STARTING, "down": BrokerStatus.STOPPED}), id="not-running-yet"),
    pytest.param(PLANT, _running(PLANT, {"cb": RUNNING}), id="only-a-context-broker"),
])
def test_no_targets(desired: DesiredState | None, observed: ObservedState | None) -> None:
    assert rate_targets(desired, observed) == ()


def test_targets_are_bounded_and_a_restarted_broker_is_a_new_target() -> None:
    observed = _running(PLANT, {"mq": RUNNING, "kf": RUNNING})
    limited = rate_targets(PLANT, observed, limit=2)
    assert [(t.endpoint.broker, t.topics) for t in limited] == [("mq", ("a", "b"))]  # the plant's first two
    again = rate_targets(PLANT, _running(PLANT, {"mq": RUNNING, "kf": RUNNING}, pid=43))
    assert set(again).isdisjoint(rate_targets(PLANT, observed))


def test_monitor_without_running_brokers_starts_no_tap_and_stops_its_thread() -> None:
    monitor = RateMonitor(lambda: (PLANT, ObservedState()), interval=0.05).start()
    try:
        monitor.retarget()
        doc = monitor.document()
        assert doc == {"window_s": 60, "enabled": True, "topics": []}
        assert [t.name for t in monitor.threads()] == ["plantkg-web-rates"]
    finally:
        monitor.stop()
    assert monitor.threads() == []


def test_api_rates_of_a_server_that_watches_nothing() -> None:
    from tests.web.conftest import closed_directory, make_app
    from engine.web.plant_state import PlantState
    from tests.web.conftest import ROOT

    state = PlantState([str(ROOT / "ontology" / "examples" / "robot-cell.ttl")], None,
                       directory_loader=lambda _p: closed_directory())
    response = make_app(state).test_client().get("/api/rates")
    assert response.status_code == 200
    assert response.get_json() == {"window_s": 60, "enabled": False, "topics": []}
    assert response.headers["Cache-Control"] == "no-cache"

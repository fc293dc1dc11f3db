"""apply(): orchestration against an in-test double of the agents (tests/unit/fake_agents.py).

The double enforces what real agents enforce (topics need their broker, calls go to the broker's
host, one broker per address), so these tests check order, parallelism, retries, failure
isolation, the check after apply and convergence. Time is faked: no test sleeps.
"""

from __future__ import annotations

import random
import threading
from dataclasses import replace

import pytest

from engine.apply import (
    ApplyEvent,
    EventKind,
    OutcomeStatus,
    PlanNotApplicableError,
    RetryPolicy,
    apply,
    lanes,
    operations,
)
from engine.errors import PermanentDispatchError, TemporaryDispatchError
from engine.model import Action, BrokerSpec, DesiredState, ObservedState
from engine.plan import destroy_plan, plan
from tests.unit.fake_agents import FakeFleet
from tests.unit.plan_data import load_case


class FakeTime:
    """A clock that only moves when someone sleeps."""

    def __init__(self) -> None:
        self.now = 0.0
        self.sleeps: list[float] = []
        self.lock = threading.Lock()

    def clock(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        with self.lock:
            self.sleeps.append(seconds)
            self.now += seconds


def run(fleet: FakeFleet, desired: DesiredState, *, destroy: bool = False, **kw):  # type: ignore[no-untyped-def]
    t = kw.pop("time", FakeTime())
    directory = fleet.directory()
    observed = observe_fleet(fleet, desired)
    the_plan = destroy_plan(desired, observed) if destroy else plan(desired, observed)
    events: list[ApplyEvent] = []
    result = apply(the_plan, desired, directory, on_event=events.append, destroy=destroy,
                   observe_fn=lambda _d, hosts: observe_fleet(fleet, desired, hosts),
                   clock=t.clock, sleep=t.sleep, rng=random.Random(7), **kw)
    return result, events


def observe_fleet(fleet: FakeFleet, desired: DesiredState, hosts=None) -> ObservedState:  # type: ignore[no-untyped-def]
    from engine.observed import observe

    asked = set(hosts or ()) | {b.host for b in desired.brokers} | {b.spec.host for b in fleet.brokers.values()}
    return observe(fleet.directory(), asked)


def robot_cell() -> DesiredState:
    desired, _, _ = load_case("empty-all-create")
    return desired


def index(fleet: FakeFleet, verb: str, key: str) -> int:
    return fleet.verbs().index((verb, key))


def test_apply_creates_everything_in_order_and_converges() -> None:
    fleet = FakeFleet()
    result, events = run(fleet, robot_cell())
    assert result.ok and result.converged and not result.failed
    assert len(result.changed) == 6
    for broker in ("kafka", "mosquitto"):
        put = index(fleet, "put_broker", broker)
        topics = [i for i, (v, k) in enumerate(fleet.verbs()) if v == "put_topic" and k.startswith(broker + "/")]
        assert topics and all(i > put for i in topics)
    # the bridge goes to the agent of its local (MQTT) broker, after that broker and its topics
    bridge = index(fleet, "put_bridge", "bridge.mosquitto.kafka")
    assert bridge > max(i for i, (v, k) in enumerate(fleet.verbs()) if k.startswith("mosquitto"))
    assert fleet.calls[bridge][0] == "127.0.0.2"
    starts = [e.address for e in events if e.kind is EventKind.START]
    dones = [e.address for e in events if e.kind is EventKind.DONE]
    assert sorted(starts) == sorted(dones) == sorted(c.address for c in result.plan.pending)
    # a second run has nothing to do
    again, _ = run(fleet, robot_cell())
    assert again.plan.empty and again.outcomes == () and again.ok


def test_lanes_run_in_parallel() -> None:
    """Both brokers' PUTs wait for each other: only parallel lanes can pass the barrier."""
    fleet = FakeFleet()
    barrier = threading.Barrier(2, timeout=10)
    fleet.hooks[("put_broker", "kafka")] = barrier.wait
    fleet.hooks[("put_broker", "mosquitto")] = barrier.wait
    result, _ = run(fleet, robot_cell(), parallelism=2)
    assert result.ok


def test_temporary_errors_are_retried_with_growing_backoff() -> None:
    fleet = FakeFleet()
    fleet.fail[("put_broker", "kafka")] = [TemporaryDispatchError("503 starting")] * 3
    t = FakeTime()
    result, events = run(fleet, robot_cell(), time=t,
                         retries=RetryPolicy(attempts=5, base=1.0, cap=30.0, deadline=100.0))
    assert result.ok
    kafka = next(o for o in result.outcomes if o.change.address == "broker.kafka")
    assert kafka.attempts == 4
    assert len(t.sleeps) == 3
    for n, delay in enumerate(t.sleeps, start=1):  # half-jittered exponential: [0.5, 1] * 2**(n-1)
        assert 2 ** (n - 1) * 0.5 <= delay <= 2 ** (n - 1)
    assert [e.attempt for e in events if e.kind is EventKind.RETRY] == [1, 2, 3]


def test_retries_stop_at_the_deadline_and_skip_the_lane() -> None:
    fleet = FakeFleet()
    fleet.fail[("put_broker", "kafka")] = [TemporaryDispatchError("connection refused")] * 100
    t = FakeTime()
    result, events = run(fleet, robot_cell(), time=t,
                         retries=RetryPolicy(attempts=100, base=1.0, cap=4.0, deadline=20.0))
    failed = {o.change.address: o for o in result.failed}
    assert set(failed) == {"broker.kafka"}
    assert "gave up after" in (failed["broker.kafka"].error or "")
    assert t.now <= 20.0
    assert {o.change.address for o in result.skipped} == {
        "topic.kafka.robot.abb-irb120.energy", "topic.kafka.robot.abb-irb120.position"}
    assert all(("put_topic", k) not in fleet.verbs() for k in ("kafka/robot.abb-irb120.energy",))
    # the other broker went ahead, and its bridge to Kafka (which connects once Kafka runs)
    assert {o.change.address for o in result.changed} == {
        "broker.mosquitto", "topic.mosquitto.robot.abb-irb120.position", "bridge.mosquitto.kafka"}
    assert not result.ok and not result.unexpected  # a failure explains what is left
    assert [e.kind for e in events].count(EventKind.SKIPPED) == 2


def test_permanent_error_stops_only_its_broker_and_a_rerun_converges() -> None:
    fleet = FakeFleet()
    fleet.fail[("put_broker", "kafka")] = [PermanentDispatchError("422: driver failed", hint="see the log")]
    result, _ = run(fleet, robot_cell())
    assert [o.change.address for o in result.failed] == ["broker.kafka"]
    assert result.failed[0].attempts == 1 and "see the log" in (result.failed[0].error or "")
    assert len(result.skipped) == 2 and len(result.changed) == 3
    assert result.after is not None and not result.after.empty
    rerun, _ = run(fleet, robot_cell())
    assert rerun.ok and {o.change.address for o in rerun.changed} == {
        "broker.kafka", "topic.kafka.robot.abb-irb120.energy", "topic.kafka.robot.abb-irb120.position"}


def test_a_driver_that_does_not_do_what_it_said_is_reported() -> None:
    fleet = FakeFleet()
    desired = robot_cell()
    run(fleet, desired)
    changed = replace(desired, topics=tuple(
        replace(t, retention_ms=1000) if t.broker_id == "kafka" and "energy" in t.name else t
        for t in desired.topics))
    original = fleet.client

    def lying_client(url: str, token: str):  # type: ignore[no-untyped-def]
        client = original(url, token)
        client.put_topic = lambda spec: None  # answers OK, changes nothing
        return client

    fleet.client = lying_client  # type: ignore[method-assign]
    result, _ = run(fleet, changed)
    assert [o.change.address for o in result.changed] == ["topic.kafka.robot.abb-irb120.energy"]
    assert [u.address for u in result.unexpected] == ["topic.kafka.robot.abb-irb120.energy"]
    assert "reported the topic done" in result.unexpected[0].detail
    assert not result.ok


def test_plan_that_cannot_be_applied_dispatches_nothing() -> None:
    desired, observed, _ = load_case("partitions-down-refused")
    fleet = FakeFleet.from_observed(observed)
    with pytest.raises(PlanNotApplicableError, match="Kafka cannot remove partitions"):
        apply(plan(desired, observed), desired, fleet.directory())
    assert fleet.calls == []


REMOVED_TOPICS = ("topic.kafka.robot.abb-irb120.energy", "topic.kafka.robot.abb-irb120.position")


def test_a_removed_brokers_topics_go_with_its_delete_on_its_old_host() -> None:
    """The broker's DELETE removes its folder, topics and all: the topic deletes the plan shows
    take no call of their own and are done when the broker's DELETE is."""
    desired, observed, _ = load_case("broker-removed-delete")
    fleet = FakeFleet.from_observed(observed)
    the_plan = plan(desired, observe_fleet(fleet, desired))
    assert {c.address for c in the_plan.pending} >= {*REMOVED_TOPICS, "broker.kafka"}
    ops = {op.change.address: op for op in operations(the_plan, desired)}
    assert all(ops[t].calls == () and ops[t].carried_by == "broker.kafka" for t in REMOVED_TOPICS)
    result, events = run(fleet, desired)
    assert result.ok
    deletes = [(h, v, k) for h, v, k in fleet.calls if v.startswith("delete")]
    assert deletes == [("127.0.0.3", "delete_broker", "kafka")]
    done = {o.change.address: o for o in result.changed}
    assert set(REMOVED_TOPICS) <= set(done) and all(done[t].attempts == 1 for t in REMOVED_TOPICS)
    started = [e.address for e in events if e.kind is EventKind.START]
    finished = [e.address for e in events if e.kind is EventKind.DONE]
    for topic in REMOVED_TOPICS:  # announced with the broker's delete, ended before it
        assert started.index(topic) < started.index("broker.kafka")
        assert finished.index(topic) < finished.index("broker.kafka")


def test_a_failed_broker_delete_leaves_its_topics_not_attempted() -> None:
    desired, observed, _ = load_case("broker-removed-delete")
    fleet = FakeFleet.from_observed(observed)
    fleet.fail[("delete_broker", "kafka")] = [PermanentDispatchError("refused")]
    result, events = run(fleet, desired)
    assert not result.ok
    failed = {o.change.address for o in result.failed}
    skipped = {o.change.address: o.error for o in result.skipped}
    assert failed == {"broker.kafka"}
    assert {t: skipped.get(t) for t in REMOVED_TOPICS} == {t: "not attempted: broker.kafka failed" for t in REMOVED_TOPICS}
    assert [e.address for e in events if e.kind is EventKind.SKIPPED].count(REMOVED_TOPICS[0]) == 1
    assert fleet.brokers["kafka"].topics  # nothing was deleted


def test_a_topic_delete_of_a_broker_that_stays_keeps_its_call() -> None:
    desired, observed, _ = load_case("broker-removed-delete")
    fleet = FakeFleet.from_observed(observed)
    topic = next(t for t in desired.topics if t.broker_id == "mosquitto")
    fewer = replace(desired, topics=tuple(t for t in desired.topics if t != topic))
    the_plan = plan(fewer, observe_fleet(fleet, fewer))
    ops = {op.change.address: op for op in operations(the_plan, fewer)}
    assert ops[topic.address].calls and ops[topic.address].carried_by is None
    result, _ = run(fleet, fewer)
    assert result.ok
    assert ("delete_topic", f"mosquitto/{topic.name}") in fleet.verbs()


def test_broker_moving_host_is_stopped_there_first() -> None:
    desired, observed, _ = load_case("host-change-replace")
    fleet = FakeFleet.from_observed(observed)
    result, _ = run(fleet, desired)
    assert result.ok
    kafka = [(h, v) for h, v, k in fleet.calls if k.startswith("kafka") and v != "list_brokers"]
    assert kafka[:2] == [("127.0.0.3", "delete_broker"), ("127.0.0.4", "put_broker")]
    assert fleet.brokers["kafka"].spec.host == "127.0.0.4" and len(fleet.brokers["kafka"].topics) == 2


def test_new_broker_on_the_address_of_a_removed_one_waits_for_it() -> None:
    desired, observed, _ = load_case("no-change")
    fleet = FakeFleet.from_observed(observed)
    old = fleet.brokers["mosquitto"].spec
    newcomer = BrokerSpec("mosquitto-2", "urn:x:m2", "m2", "mosquitto", old.host, old.port)
    target = DesiredState(
        brokers=tuple(sorted([b for b in desired.brokers if b.id != "mosquitto"] + [newcomer],
                             key=lambda b: b.id)),
        topics=tuple(t for t in desired.topics if t.broker_id != "mosquitto"))
    work = lanes(operations(plan(target, observe_fleet(fleet, target)), target))
    assert any({op.change.address for op in lane} >= {"broker.mosquitto", "broker.mosquitto-2"} for lane in work)
    result, _ = run(fleet, target)
    assert result.ok, [o.error for o in result.failed]
    assert index(fleet, "delete_broker", "mosquitto") < index(fleet, "put_broker", "mosquitto-2")


def test_destroy_removes_the_plants_brokers_only() -> None:
    desired, observed, _ = load_case("stray-broker-delete")
    fleet = FakeFleet.from_observed(observed)
    result, _ = run(fleet, desired, destroy=True)
    assert result.ok
    assert set(fleet.brokers) == {"legacy"}
    assert result.plan.pending[-1].action is Action.DELETE


def test_events_carry_timing() -> None:
    fleet = FakeFleet()
    fleet.fail[("put_broker", "kafka")] = [TemporaryDispatchError("503")]
    _, events = run(fleet, robot_cell(), retries=RetryPolicy(base=2.0))
    done = next(e for e in events if e.kind is EventKind.DONE and e.address == "broker.kafka")
    assert 1.0 <= done.elapsed <= 2.0 and done.attempt == 2
    assert events[-1].kind is EventKind.VERIFY


def test_agent_down_during_apply_fails_its_changes_and_is_reported() -> None:
    fleet = FakeFleet()
    desired = robot_cell()
    original = fleet.client

    def flaky(url: str, token: str):  # type: ignore[no-untyped-def]
        client = original(url, token)
        if client.host == "127.0.0.3":
            def refuse(*_a, **_k):  # type: ignore[no-untyped-def]
                raise TemporaryDispatchError("connection refused")
            client.put_broker = refuse
        return client

    fleet.client = flaky  # type: ignore[method-assign]
    result, _ = run(fleet, desired, retries=RetryPolicy(attempts=3))
    assert {o.change.address for o in result.failed} == {"broker.kafka"}
    assert {o.status for o in result.outcomes} == {OutcomeStatus.DONE, OutcomeStatus.FAILED, OutcomeStatus.SKIPPED}


def test_only_the_settings_of_the_brokers_kind_are_sent() -> None:
    """robot-position carries Kafka and MQTT settings; each broker gets its own kind's only."""
    desired = robot_cell()
    mixed = replace(desired, topics=tuple(
        replace(t, partitions=3, replication_factor=1, qos=1, retain=False) for t in desired.topics))
    fleet = FakeFleet()
    result, _ = run(fleet, mixed)
    assert result.ok, [o.error for o in result.failed]
    (topic,) = fleet.brokers["mosquitto"].topics
    assert (topic.qos, topic.partitions) == (1, None)


def test_a_failing_check_is_reported_not_raised() -> None:
    from engine.observed import ObserveError

    fleet = FakeFleet()
    desired = robot_cell()
    the_plan = plan(desired, observe_fleet(fleet, desired))

    def broken_observe(_d, _h):  # type: ignore[no-untyped-def]
        raise ObserveError("agent at http://127.0.0.3:7300 answered 500")

    result = apply(the_plan, desired, fleet.directory(), observe_fn=broken_observe)
    assert len(result.changed) == 6 and result.after is None and not result.ok
    assert [u.address for u in result.unexpected] == ["check"]


def test_the_check_waits_for_a_change_that_shows_late() -> None:
    """A Kafka cluster's brokers learn a new topic a moment apart: the first look after apply
    may miss it. The check asks again (time is faked) and finds nothing unexpected."""
    fleet = FakeFleet()
    desired = robot_cell()
    looks = []

    def late_observe(_d, hosts):  # type: ignore[no-untyped-def]
        seen = observe_fleet(fleet, desired, hosts)
        looks.append(seen)
        if len(looks) == 1:  # the first look misses every topic
            return replace(seen, brokers=tuple(replace(b, topics=()) for b in seen.brokers))
        return seen

    t = FakeTime()
    the_plan = plan(desired, observe_fleet(fleet, desired))
    result = apply(the_plan, desired, fleet.directory(), observe_fn=late_observe,
                   hosts={b.host for b in desired.brokers}, clock=t.clock, sleep=t.sleep,
                   rng=random.Random(7))
    assert len(looks) >= 2 and t.sleeps, "the check did not ask again"
    assert result.unexpected == () and result.after is not None


def test_the_check_gives_up_after_settle_seconds() -> None:
    fleet = FakeFleet()
    desired = robot_cell()

    def never(_d, hosts):  # type: ignore[no-untyped-def]
        seen = observe_fleet(fleet, desired, hosts)
        return replace(seen, brokers=tuple(replace(b, topics=()) for b in seen.brokers))

    t = FakeTime()
    the_plan = plan(desired, observe_fleet(fleet, desired))
    result = apply(the_plan, desired, fleet.directory(), observe_fn=never,
                   hosts={b.host for b in desired.brokers}, clock=t.clock, sleep=t.sleep,
                   rng=random.Random(7), settle=5.0)
    assert 5.0 <= t.now < 8.0
    assert result.unexpected and all("reported the topic done" in u.detail for u in result.unexpected)

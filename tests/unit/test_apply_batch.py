"""apply() in waves of batches against the in-test double of the agents: one request per agent per
wave, a lane that moves host continuing in the next wave, the check after apply using the state
the agents answered with instead of asking again (and asking where that state is not known)."""

from __future__ import annotations

import random
import threading
from collections import Counter
from dataclasses import dataclass, replace

from engine.agent.calls import AgentCall, BatchAnswer, run_calls
from engine.apply import apply
from engine.model import BrokerSpec, DesiredState
from engine.plan import plan
from tests.unit.fake_agents import FakeClient, FakeFleet
from tests.unit.plan_data import load_case
from tests.unit.test_apply import FakeTime, observe_fleet, robot_cell


@dataclass
class AnsweringClient(FakeClient):
    """A double whose batch answers, as the agent does with ``observe``, what its host runs."""

    batches: Counter[str] | None = None

    def batch(self, lanes: list[list[AgentCall]], observe: bool = False) -> BatchAnswer:
        assert self.batches is not None
        with self.fleet.lock:
            self.batches[self.host] += 1
        answer = run_calls(self, lanes)
        if not observe:
            return answer
        with self.fleet.lock:
            brokers = tuple(sorted((b for b in self.fleet.brokers.values() if b.spec.host == self.host),
                                   key=lambda b: b.spec.id))
            bridges = tuple(sorted((b for b in self.fleet.bridges.values() if b.spec.local.host == self.host),
                                   key=lambda b: b.spec.address))
        return BatchAnswer(answer.lanes, brokers, bridges)


def answering(fleet: FakeFleet) -> Counter[str]:
    """Make ``fleet``'s clients answer with their state; count the batches per host."""
    counts: Counter[str] = Counter()
    fleet.client = lambda url, token: AnsweringClient(  # type: ignore[method-assign]
        fleet, url.split("//")[1].split(":")[0], counts)
    return counts


def run(fleet: FakeFleet, desired: DesiredState, asked: list[set[str]], **kw):  # type: ignore[no-untyped-def]
    t = FakeTime()

    def observe_fn(directory, hosts):  # type: ignore[no-untyped-def]
        asked.append(set(hosts))
        return observe_fleet(fleet, desired, hosts)

    the_plan = plan(desired, observe_fleet(fleet, desired))
    return apply(the_plan, desired, fleet.directory(), observe_fn=observe_fn, clock=t.clock, sleep=t.sleep,
                 rng=random.Random(3), hosts={b.host for b in desired.brokers}, **kw)


def test_one_request_per_agent_and_no_second_look_at_agents_that_answered() -> None:
    fleet = FakeFleet()
    counts = answering(fleet)
    asked: list[set[str]] = []
    result = run(fleet, robot_cell(), asked)
    assert result.ok and len(result.changed) == 6
    assert counts == Counter({"127.0.0.2": 1, "127.0.0.3": 1})  # broker, topics and bridge together
    assert asked == []  # both agents answered with what they run: the check needed no request


def test_a_broker_moving_host_continues_on_the_new_agent_in_the_next_wave() -> None:
    desired, observed, _ = load_case("host-change-replace")
    fleet = FakeFleet.from_observed(observed)
    counts = answering(fleet)
    asked: list[set[str]] = []
    result = run(fleet, desired, asked)
    assert result.ok, [o.error for o in result.failed]
    kafka = [(h, v) for h, v, k in fleet.calls if k.startswith("kafka")]
    assert kafka[:2] == [("127.0.0.3", "delete_broker"), ("127.0.0.4", "put_broker")]
    assert counts["127.0.0.3"] == 1 and counts["127.0.0.4"] == 1
    assert asked == []  # every agent asked again answered a batch


def test_an_agent_whose_requests_overlapped_is_asked_again() -> None:
    """Kafka moves to 127.0.0.4 while a new broker starts there slowly: the second request to
    127.0.0.4 (kafka's put) is sent while the first (the slow start) is in flight, so neither
    answer is the agent's state after both; the check asks that agent."""
    desired, observed, _ = load_case("host-change-replace")
    extra = BrokerSpec("extra", "urn:x:extra", "extra", "mosquitto", "127.0.0.4", 1999)
    desired = replace(desired, brokers=tuple(sorted((*desired.brokers, extra), key=lambda b: b.id)))
    fleet = FakeFleet.from_observed(observed)
    counts = answering(fleet)
    kafka_sent = threading.Event()
    fleet.hooks[("put_broker", "extra")] = lambda: kafka_sent.wait(10)
    fleet.hooks[("put_broker", "kafka")] = kafka_sent.set
    asked: list[set[str]] = []
    result = run(fleet, desired, asked, parallelism=4)
    assert result.ok, [o.error for o in result.failed]
    assert kafka_sent.is_set() and counts["127.0.0.4"] == 2
    assert asked == [{"127.0.0.4"}]


def test_without_state_in_the_answers_every_host_is_asked() -> None:
    fleet = FakeFleet()  # the plain double answers no state
    asked: list[set[str]] = []
    result = run(fleet, robot_cell(), asked)
    assert result.ok and asked == [{"127.0.0.2", "127.0.0.3"}]


def test_the_checks_merge_of_answered_and_asked_agents_finds_what_is_left() -> None:
    """One agent answers its state, the other is asked; a broker missing on the asked one
    (its PUT 'succeeds' but does nothing) is found by the check."""
    fleet = FakeFleet()
    counts = answering(fleet)
    original = fleet.client

    def mixed(url: str, token: str):  # type: ignore[no-untyped-def]
        client = original(url, token)
        if client.host == "127.0.0.3":  # the Kafka agent: a plain double, and a lying PUT
            plain = FakeClient(fleet, client.host)
            plain.put_broker = lambda spec, owner=None: None  # type: ignore[method-assign]
            return plain
        return client

    fleet.client = mixed  # type: ignore[method-assign]
    asked: list[set[str]] = []
    result = run(fleet, robot_cell(), asked)
    # the first check asks the unanswered agent only; while the lie shows, it asks all again
    assert asked[0] == {"127.0.0.3"} and counts["127.0.0.2"] == 1
    assert len(asked) > 1 and all(a == {"127.0.0.2", "127.0.0.3"} for a in asked[1:])
    assert not result.ok and "broker.kafka" in [u.address for u in result.unexpected]
    assert result.after is not None and not result.after.empty


def test_an_agent_skipping_a_lane_without_a_failure_fails_its_change_instead_of_looping() -> None:
    from engine.agent.calls import SKIPPED

    fleet = FakeFleet()
    original = fleet.client

    def odd(url: str, token: str):  # type: ignore[no-untyped-def]
        client = original(url, token)
        if client.host == "127.0.0.3":
            client.batch = lambda lanes, observe=False: BatchAnswer(  # type: ignore[method-assign]
                tuple(tuple(SKIPPED for _ in lane) for lane in lanes))
        return client

    fleet.client = odd  # type: ignore[method-assign]
    asked: list[set[str]] = []
    result = run(fleet, robot_cell(), asked)
    failed = {o.change.address: o.error for o in result.failed}
    assert list(failed) == ["broker.kafka"] and "skipped the call without a failure" in failed["broker.kafka"]
    assert {o.change.address for o in result.skipped} == {
        "topic.kafka.robot.abb-irb120.energy", "topic.kafka.robot.abb-irb120.position"}

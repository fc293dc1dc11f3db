"""An in-test double of the agents (AgentClient's verbs), for unit tests of orchestration only.

It keeps brokers per host in memory and enforces what the real agents and brokers enforce, so an
orchestration mistake fails loudly: a topic call before its broker exists, a call sent to the
agent of the wrong host, two brokers on one address, fewer Kafka partitions. Every call is logged
(``calls``) so tests can check order; failures can be scripted per call (``fail``); a host can be
``down`` (connection refused). Like the agent, it records the ``owner`` a call names and refuses
(409) another owner's things. Integration tests never use this: they run the real agent.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from urllib.parse import urlsplit

from engine.agent.calls import AgentCall, BatchAnswer, run_calls
from engine.agents_config import AgentDirectory
from engine.apply import operations
from engine.errors import PermanentDispatchError, TemporaryDispatchError
from engine.model import (
    BridgeSpec,
    BridgeStatus,
    BrokerSpec,
    BrokerStatus,
    ObservedBridge,
    ObservedBroker,
    ObservedState,
    ObservedTopic,
    Plan,
    TopicSpec,
)
from engine.plan import ALL_TOPIC_SETTINGS, REPLACE_FIELDS, topic_settings


@dataclass
class FakeFleet:
    """All agents of a test plant; ``client_for``-compatible through :meth:`directory`."""

    brokers: dict[str, ObservedBroker] = field(default_factory=dict)
    bridges: dict[str, ObservedBridge] = field(default_factory=dict)  # by address
    calls: list[tuple[str, str, str]] = field(default_factory=list)  # (host, verb, key)
    fail: dict[tuple[str, str], list[Exception]] = field(default_factory=dict)  # (verb, key) -> errors
    down: set[str] = field(default_factory=set)
    hooks: dict[tuple[str, str], Callable[[], None]] = field(default_factory=dict)
    next_pid: int = 1000
    lock: threading.RLock = field(default_factory=threading.RLock)

    @classmethod
    def from_observed(cls, observed: ObservedState) -> FakeFleet:
        return cls(brokers={b.spec.id: b for b in observed.brokers},
                   bridges={b.spec.address: b for b in observed.bridges})

    def directory(self) -> AgentDirectory:
        return AgentDirectory(default_token="test-token", client_factory=self.client)

    def client(self, url: str, token: str) -> FakeClient:
        assert token == "test-token"
        host = urlsplit(url).hostname
        assert host is not None
        return FakeClient(self, host)

    def observed(self, hosts: set[str] | None = None) -> ObservedState:
        with self.lock:
            brokers = tuple(sorted(self.brokers.values(), key=lambda b: b.spec.id))
            bridges = tuple(sorted(self.bridges.values(), key=lambda b: b.spec.address))
        return ObservedState(brokers=brokers, bridges=bridges)

    def verbs(self) -> list[tuple[str, str]]:
        return [(verb, key) for _host, verb, key in self.calls]

    def apply_directly(self, plan: Plan, desired) -> None:  # type: ignore[no-untyped-def]
        """Run the plan's agent calls one after another (no retries, no threads)."""
        for op in operations(plan, desired):
            for call in op.calls:
                extra = {} if call.owner is None else {"owner": call.owner}
                getattr(self.client(f"http://{call.host}:7300", "test-token"), call.verb)(*call.args, **extra)


def _claim(current: str | None, given: str | None, what: str) -> str | None:
    """As engine.agent.owners.claim: another owner's thing is refused."""
    if given is not None and current is not None and current != given:
        raise PermanentDispatchError(f"409: {what} is owned by plant {current!r}")
    return given if given is not None else current


@dataclass
class FakeClient:
    """AgentClient's verbs over a :class:`FakeFleet`, for the agent of ``host``."""

    fleet: FakeFleet
    host: str

    def _enter(self, verb: str, key: str) -> None:
        fleet = self.fleet
        with fleet.lock:
            fleet.calls.append((self.host, verb, key))
            if self.host in fleet.down:
                raise TemporaryDispatchError(f"connection refused by {self.host}", host=self.host)
            scripted = fleet.fail.get((verb, key))
            error = scripted.pop(0) if scripted else None
        hook = fleet.hooks.get((verb, key))
        if hook is not None:
            hook()
        if error is not None:
            raise error

    def _mine(self, broker_id: str) -> ObservedBroker:
        broker = self.fleet.brokers.get(broker_id)
        if broker is None or broker.spec.host != self.host:
            raise PermanentDispatchError(f"404: broker {broker_id} is not on the agent of {self.host}",
                                         host=self.host)
        return broker

    def batch(self, lanes: list[list[AgentCall]], observe: bool = False) -> BatchAnswer:
        """The agent's batch as its single calls, one lane after another (``observe`` is not
        honoured: the answer carries no state, so apply asks the fleet afterwards)."""
        return run_calls(self, lanes)

    def health(self) -> dict:
        self._enter("health", "")
        return {"status": "ok"}

    def list_brokers(self) -> list[ObservedBroker]:
        self._enter("list_brokers", "")
        with self.fleet.lock:
            return [b for b in self.fleet.brokers.values() if b.spec.host == self.host]

    def get_broker(self, broker_id: str) -> ObservedBroker | None:
        self._enter("get_broker", broker_id)
        with self.fleet.lock:
            b = self.fleet.brokers.get(broker_id)
            return b if b is not None and b.spec.host == self.host else None

    def put_broker(self, spec: BrokerSpec, owner: str | None = None) -> ObservedBroker:
        self._enter("put_broker", spec.id)
        fleet = self.fleet
        with fleet.lock:
            if spec.host != self.host:
                raise PermanentDispatchError(f"400: broker {spec.id} is for {spec.host}, sent to {self.host}")
            old = fleet.brokers.get(spec.id)
            owner = _claim(old.owner if old is not None else None, owner, spec.address)
            if old is not None and old.spec.host != self.host:
                raise PermanentDispatchError(f"409: {spec.id} still runs on {old.spec.host}")
            for other in fleet.brokers.values():
                if other.spec.id != spec.id and (other.spec.host, other.spec.port) == (spec.host, spec.port):
                    raise PermanentDispatchError(f"409: {spec.host}:{spec.port} is used by {other.spec.id}")
            restart = old is None or old.status is not BrokerStatus.RUNNING or any(
                getattr(old.spec, f) != getattr(spec, f) for f in REPLACE_FIELDS)
            topics = () if old is None or old.spec.kind != spec.kind else old.topics
            if old is not None and old.spec.kind != spec.kind:  # its folder (and bridges) go
                self._drop_bridges_of(spec.id)
            if restart:
                fleet.next_pid += 1
            new = ObservedBroker(spec=spec, status=BrokerStatus.RUNNING, topics=topics,
                                 pid=fleet.next_pid if restart else old.pid,  # type: ignore[union-attr]
                                 started_at=1.0, restarts=0 if old is None else old.restarts,
                                 owner=owner)
            fleet.brokers[spec.id] = new
            return new

    def delete_broker(self, broker_id: str, owner: str | None = None) -> None:
        self._enter("delete_broker", broker_id)
        with self.fleet.lock:
            broker = self.fleet.brokers.get(broker_id)
            if broker is not None and broker.spec.host == self.host:
                _claim(broker.owner, owner, broker.spec.address)
                del self.fleet.brokers[broker_id]
                self._drop_bridges_of(broker_id)

    def _drop_bridges_of(self, broker_id: str) -> None:
        for address in [a for a, b in self.fleet.bridges.items() if b.spec.local.id == broker_id]:
            del self.fleet.bridges[address]

    def list_bridges(self) -> list[ObservedBridge]:
        self._enter("list_bridges", "")
        with self.fleet.lock:
            return [b for b in self.fleet.bridges.values() if b.spec.local.host == self.host]

    def put_bridge(self, spec: BridgeSpec, owner: str | None = None,
                   remote_token: str | None = None) -> ObservedBridge:
        """As the agent: the local broker must run here; the remote may be anywhere, or down.
        ``remote_token`` (an mqtt-ngsi bridge, or a worker into a closed Kafka) is taken and not kept."""
        self._enter("put_bridge", spec.address)
        with self.fleet.lock:
            local = self._mine(spec.local.id)
            old = self.fleet.bridges.get(spec.address)
            owner = _claim(old.owner if old is not None else None, owner, spec.address)
            if (local.spec.host, local.spec.port) != (spec.local.host, spec.local.port):
                raise PermanentDispatchError(f"409: {spec.address}: local end is not the broker here")
            new = ObservedBridge(spec=spec, status=BridgeStatus.RUNNING, forwarded=0, retried=0,
                                 owner=owner, forwarded_per_s=0.0)
            self.fleet.bridges[spec.address] = new
            return new

    def delete_bridge(self, local_id: str, remote_id: str, owner: str | None = None) -> None:
        self._enter("delete_bridge", f"bridge.{local_id}.{remote_id}")
        with self.fleet.lock:
            bridge = self.fleet.bridges.get(f"bridge.{local_id}.{remote_id}")
            if bridge is not None and bridge.spec.local.host == self.host:
                _claim(bridge.owner, owner, bridge.spec.address)
                del self.fleet.bridges[bridge.spec.address]

    def put_topic(self, spec: TopicSpec, owner: str | None = None) -> ObservedTopic:
        self._enter("put_topic", f"{spec.broker_id}/{spec.name}")
        with self.fleet.lock:
            broker = self._mine(spec.broker_id)
            settings = topic_settings(broker.spec.kind)
            foreign = [f for f in ALL_TOPIC_SETTINGS if f not in settings and getattr(spec, f) is not None]
            if foreign:  # as the drivers' check_topic_fields
                raise PermanentDispatchError(f"400: {foreign[0]} does not apply to a {broker.spec.kind} broker")
            old = next((t for t in broker.topics if t.name == spec.name), None)
            owner = _claim(old.owner if old is not None else None, owner, spec.address)
            values = {k: getattr(spec, k) for k in settings}
            if old is not None:
                if old.partitions and values.get("partitions") and values["partitions"] < old.partitions:
                    raise PermanentDispatchError("422: Kafka cannot remove partitions")
                values = {k: (v if v is not None else getattr(old, k)) for k, v in values.items()}
            topic = ObservedTopic(name=spec.name, **values, owner=owner)
            others = tuple(t for t in broker.topics if t.name != spec.name)
            self.fleet.brokers[spec.broker_id] = replace(
                broker, topics=tuple(sorted(others + (topic,), key=lambda t: t.name)))
            return topic

    def delete_topic(self, broker_id: str, name: str, owner: str | None = None) -> None:
        self._enter("delete_topic", f"{broker_id}/{name}")
        with self.fleet.lock:
            broker = self._mine(broker_id)
            old = next((t for t in broker.topics if t.name == name), None)
            _claim(old.owner if old is not None else None, owner, f"topic.{broker_id}.{name}")
            self.fleet.brokers[broker_id] = replace(
                broker, topics=tuple(t for t in broker.topics if t.name != name))

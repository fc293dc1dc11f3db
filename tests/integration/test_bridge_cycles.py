"""Bridge cycles through real agents and Mosquitto brokers (issue 15).

Three "machines" (127.0.0.2, .3, .4), one agent each. A plant whose brokers bridge in a ring
A -> B -> C -> A (and one of four, and one through a Kafka broker) is refused by ``plantkg apply``
(exit 2, the cycle named in order) and nothing is started; a chain of two-way bridges A <-> B <-> C, which the same check allows, is applied and one
QoS-1 publish reaches each broker exactly once, counted for 10 s (the ring delivered ~36,000 copies
per broker in 5 s before the check existed).
"""

from __future__ import annotations

import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.cli import main
from engine.model import BridgeStatus
from tests.integration.agents import AgentFleet, start_agents

pytestmark = pytest.mark.integration

HOSTS = {"a": "127.0.0.2", "b": "127.0.0.3", "c": "127.0.0.4"}
#: Brokers of the refused rings only (nothing is started for them): a fourth Mosquitto, a Kafka.
MORE = {"d": ("127.0.0.2", "mosquitto"), "k": ("127.0.0.3", "kafka")}
TOPIC = "line.t"
COUNT_FOR = 10.0

HEADER = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/bridge-cycle-test#> .
:t a pk:Topic ; pk:id "t" ; pk:name "line.t" ; pk:qos 1 ; pk:partitions 1 ; pk:replicationFactor 1 .
:sensor a pk:Resource ; pk:id "sensor" ; pk:name "sensor" ; pk:sendsTo :a ; pk:publishes :t .
"""
BROKER = """:{id} a pk:Broker ; pk:id "{id}" ; pk:name "{id}" ; pk:brokerType "{kind}" ;
    pk:ip "{host}" ; pk:port {port} ; pk:hasTopic :t ; pk:bridgesTo {to} {open}.
"""
#: The counting clients below connect anonymously: the ring's Mosquittos are open labs (closed is
#: the default, docs/security.md); Kafka is open while it has no users.
OPEN_LAB = "; pk:allowAnonymous true "


@dataclass
class Machines:
    fleet: AgentFleet
    ports: dict[str, int]
    tmp: Path

    def plant(self, name: str, bridges: dict[str, list[str]]) -> Path:
        path = self.tmp / f"{name}.ttl"
        path.write_text(HEADER + "".join(
            BROKER.format(id=b, host=HOSTS[b] if b in HOSTS else MORE[b][0],
                          kind="mosquitto" if b in HOSTS else MORE[b][1], port=self.ports[b],
                          to=" , ".join(f":{t}" for t in to), open=OPEN_LAB if b in HOSTS or MORE[b][1] == "mosquitto" else "")
            for b, to in bridges.items()))
        return path

    def run(self, capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return code, out + err


@pytest.fixture(scope="module")
def machines(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Machines]:
    tmp = tmp_path_factory.mktemp("bridge-cycles")
    fleet = start_agents(list(HOSTS.values()), tmp / "agents")
    try:
        hosts = {**HOSTS, **{b: h for b, (h, _) in MORE.items()}}
        yield Machines(fleet, {b: netutil.free_port(h) for b, h in hosts.items()}, tmp)
    finally:
        fleet.stop()  # also fails the module if a broker was left deployed or a process survived


class Counting:
    """A QoS-1 subscriber to TOPIC on one broker, counting each payload it receives."""

    def __init__(self, host: str, port: int) -> None:
        self.got: Counter[str] = Counter()
        self._lock = threading.Lock()
        subscribed = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-cyc-{uuid.uuid4().hex[:8]}")
        self.client.on_connect = lambda c, *_: c.subscribe(TOPIC, 1)
        self.client.on_subscribe = lambda *_: subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect(host, port)
        self.client.loop_start()
        assert subscribed.wait(10), f"no SUBACK from {host}:{port}"

    def _on_message(self, _c: object, _u: object, msg: mqtt.MQTTMessage) -> None:
        with self._lock:
            self.got[msg.payload.decode()] += 1

    def counts(self) -> Counter[str]:
        with self._lock:
            return Counter(self.got)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def publish_one(host: str, port: int, payload: str) -> None:
    pub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-cyc-pub-{uuid.uuid4().hex[:8]}")
    pub.connect(host, port)
    pub.loop_start()
    try:
        pub.publish(TOPIC, payload.encode(), qos=1).wait_for_publish(timeout=10)
    finally:
        pub.loop_stop()
        pub.disconnect()


RINGS = {
    "three-mosquitto": ({"a": ["b"], "b": ["c"], "c": ["a"]}, "a -> b -> c -> a"),
    "four-mosquitto": ({"a": ["b"], "b": ["c"], "c": ["d"], "d": ["a"]}, "a -> b -> c -> d -> a"),
    "through-kafka": ({"a": ["k"], "k": ["b"], "b": ["a"]}, "a -> k -> b -> a"),
}


@pytest.mark.parametrize("ring_name", sorted(RINGS))
def test_a_ring_is_refused_and_nothing_starts(machines: Machines, capsys: pytest.CaptureFixture[str],
                                              ring_name: str) -> None:
    bridges, cycle = RINGS[ring_name]
    ring = machines.plant(ring_name, bridges)
    code, out = machines.run(capsys, "validate", ring)
    assert code == 0, out  # each bridge alone is valid: the loop is the ring as a whole
    code, out = machines.run(capsys, "apply", ring, "--agents", machines.fleet.agents_file, "--yes")
    assert code == 2, out
    assert "bridge cycle" in out and f"{cycle} forwards line.t" in out, out
    assert "remove one pk:bridgesTo" in out and "Traceback" not in out
    assert machines.fleet.brokers() == {}, "a refused plant must start no broker"
    assert all(not m.client().list_bridges() for m in machines.fleet.agents.values())


def test_a_chain_of_two_way_bridges_delivers_each_message_once(machines: Machines,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    chain = machines.plant("chain", {"a": ["b"], "b": ["a", "c"], "c": ["b"]})
    code, out = machines.run(capsys, "apply", chain, "--agents", machines.fleet.agents_file, "--yes")
    assert code == 0, out
    try:
        def all_running() -> bool:
            bridges = [b for m in machines.fleet.agents.values() for b in m.client().list_bridges()]
            return len(bridges) == 2 and all(b.status is BridgeStatus.RUNNING for b in bridges)
        process.wait_until(all_running, 30, 0.1, what="both two-way bridges to run")
        sinks = {b: Counting(HOSTS[b], machines.ports[b]) for b in HOSTS}
        try:
            def probes_everywhere() -> bool:  # the bridges' remote subscriptions are in place
                n = f"probe-{uuid.uuid4().hex[:6]}"
                publish_one(HOSTS["a"], machines.ports["a"], n)
                publish_one(HOSTS["c"], machines.ports["c"], n + "-c")
                time.sleep(0.2)
                return all(s.counts()[n] and s.counts()[n + "-c"] for s in sinks.values())
            process.wait_until(probes_everywhere, 30, 0.1, what="probes to cross both bridges")
            publish_one(HOSTS["a"], machines.ports["a"], "the-one")
            publish_one(HOSTS["c"], machines.ports["c"], "from-c")
            started = time.monotonic()
            while time.monotonic() - started < COUNT_FOR:  # any copy beyond the first fails at once
                counts = {b: s.counts() for b, s in sinks.items()}
                assert all(max(c.values()) <= 1 for c in counts.values()), counts
                time.sleep(0.1)
            counts = {b: s.counts() for b, s in sinks.items()}
            assert {b: (c["the-one"], c["from-c"]) for b, c in counts.items()} == \
                {b: (1, 1) for b in HOSTS}, counts
            with capsys.disabled():
                print(f"\nchain a<->b<->c, {COUNT_FOR:.0f} s: " + ", ".join(
                    f"{b}: the-one x{c['the-one']}, from-c x{c['from-c']}" for b, c in counts.items()))
        finally:
            for s in sinks.values():
                s.close()
    finally:
        code, out = machines.run(capsys, "destroy", chain, "--agents", machines.fleet.agents_file, "--yes")
        assert code == 0, out

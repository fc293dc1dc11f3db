"""``plantkg agent`` as a real subprocess managing real Mosquitto and Kafka brokers.

Each test starts its agents on free loopback ports with a state dir under its tmp_path and talks
to them with AgentClient and the brokers' own clients (paho, confluent-kafka). After each test no
process may mention its tmp_path (agent, mosquitto, java); anything found is stopped and the test
fails. Kafka starts twice in this file (first start, then a restart after kill -9).
"""

from __future__ import annotations

import os
import queue
import signal
import sys
import urllib.error
import urllib.request
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from confluent_kafka import Consumer, KafkaException, Producer, TopicPartition
from confluent_kafka.admin import AdminClient, ConfigResource, ResourceType
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, parts, process
from engine.agent.client import AgentClient
from engine.agent.procs import proc_info, processes_mentioning, processes_of, stop_foreign
from engine.errors import AgentAuthError, DispatchError, PermanentDispatchError
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker, TopicSpec

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
PLANTKG = Path(sys.executable).parent / "plantkg"


@dataclass
class AgentProcess:
    state_dir: Path
    port: int
    child: process.Child

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}"

    def client(self, token: str | None = None) -> AgentClient:
        token = token or (self.state_dir / "token").read_text(encoding="utf-8").strip()
        return AgentClient(self.url, token, timeout=30.0)

    def kill9(self) -> None:
        os.kill(self.child.pid, signal.SIGKILL)
        self.child.popen.wait(10)

    def terminate(self) -> int:
        self.child.popen.send_signal(signal.SIGTERM)
        return self.child.popen.wait(60)


@dataclass
class Agents:
    tmp_path: Path
    started: list[AgentProcess] = field(default_factory=list)

    def start(self, state_dir: Path, *options: str, port: int | None = None) -> AgentProcess:
        port = port or netutil.free_port(HOST)
        child = process.spawn(
            [PLANTKG, "agent", "--listen", f"{HOST}:{port}", "--state-dir", state_dir, *options],
            log_dir=self.tmp_path / "logs", name=f"agent-{len(self.started)}",
        )
        agent = AgentProcess(state_dir, port, child)
        self.started.append(agent)
        process.wait_until(lambda: (state_dir / "token").is_file() and agent.client().health(),
                           30.0, 0.05, what=f"the agent on port {port}", child=child,
                           ignore=(DispatchError, OSError))
        return agent

    def stop_all(self) -> None:
        for agent in self.started:
            if agent.child.running():
                process.stop(agent.child, grace=60.0)


@pytest.fixture
def agents(tmp_path: Path) -> Iterator[Agents]:
    fleet = Agents(tmp_path)
    try:
        yield fleet
    finally:
        fleet.stop_all()
        left = processes_mentioning(tmp_path)
        for info in left:  # leave nothing behind, even after a failure
            stop_foreign(info, 30.0)
        assert not left, "left running:\n" + "\n".join(" ".join(i.argv)[:200] for i in left)


def mqtt_spec(broker_id: str = "m1", port: int | None = None) -> BrokerSpec:
    return BrokerSpec(id=broker_id, iri=f"https://example.org/plant#{broker_id}", name="Cell MQTT",
                      kind="mosquitto", host=HOST, port=port or netutil.free_port(HOST))


def mqtt_roundtrip(port: int) -> None:
    """Subscribe, publish one QoS-1 message, receive it."""
    received: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
    subscribed: queue.Queue[object] = queue.Queue()
    topic = f"plantkg/agent-test/{uuid.uuid4().hex}"
    sub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"sub-{uuid.uuid4().hex[:8]}")
    pub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"pub-{uuid.uuid4().hex[:8]}")
    sub.on_message = lambda _c, _u, msg: received.put(msg)
    sub.on_subscribe = lambda *_args: subscribed.put(True)
    clients = []
    try:
        for client in (sub, pub):
            client.connect(HOST, port, keepalive=10)
            clients.append(client)
            client.loop_start()
            process.wait_until(client.is_connected, 10.0, 0.005, what="CONNACK")
        sub.subscribe(topic, qos=1)
        subscribed.get(timeout=10)
        info = pub.publish(topic, b"from the agent test", qos=1)
        info.wait_for_publish(timeout=10)
        message = received.get(timeout=10)
        assert (message.topic, message.payload) == (topic, b"from the agent test")
    finally:
        for client in clients:
            client.disconnect()
            client.loop_stop()


def mosquitto_processes(state_dir: Path, broker_id: str) -> list[int]:
    folder = state_dir / "brokers" / broker_id
    return [p.pid for p in processes_of(folder, str(parts.mosquitto_binary()))]


def wait_broker(client: AgentClient, broker_id: str, predicate, what: str,
                deadline: float = 30.0) -> ObservedBroker:
    def check() -> ObservedBroker | None:
        broker = client.get_broker(broker_id)
        return broker if broker is not None and predicate(broker) else None
    return process.wait_until(check, deadline, 0.02, what=what)


# --- Mosquitto -----------------------------------------------------------------------------

def test_mosquitto_through_the_agent(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state, "--stop-brokers-on-exit")
    client = agent.client()

    # The token is required (and created 0600 on first start).
    assert (state / "token").stat().st_mode & 0o777 == 0o600
    with pytest.raises(urllib.error.HTTPError) as info:
        urllib.request.urlopen(f"{agent.url}/v1/brokers", timeout=10)
    assert info.value.code == 401
    with pytest.raises(AgentAuthError):
        agent.client("wrong-token-0123456789").list_brokers()

    # PUT -> a real broker that carries MQTT messages.
    spec = mqtt_spec()
    first = client.put_broker(spec)
    assert first.status is BrokerStatus.RUNNING and first.restarts == 0
    mqtt_roundtrip(spec.port)

    # PUT again -> same process.
    assert client.put_broker(spec).pid == first.pid
    assert mosquitto_processes(state, "m1") == [first.pid]

    # Another port -> restarted there; the old port is closed.
    moved_spec = mqtt_spec(port=netutil.free_port(HOST))
    moved = client.put_broker(moved_spec)
    assert moved.pid != first.pid and moved.spec.port == moved_spec.port
    mqtt_roundtrip(moved_spec.port)
    assert not netutil.port_open(HOST, spec.port)
    assert proc_info(first.pid) is None

    # kill -9 the broker -> CRASHED, then restarted by the agent (restarts=1).
    os.kill(moved.pid, signal.SIGKILL)
    crashed = wait_broker(client, "m1", lambda b: b.status is BrokerStatus.CRASHED, "CRASHED")
    assert "exited unexpectedly" in (crashed.last_error or "")
    restarted = wait_broker(client, "m1", lambda b: b.status is BrokerStatus.RUNNING, "restart")
    assert restarted.restarts == 1 and restarted.pid != moved.pid
    mqtt_roundtrip(moved_spec.port)
    assert mosquitto_processes(state, "m1") == [restarted.pid]

    # DELETE -> the process is gone.
    client.delete_broker("m1")
    assert proc_info(restarted.pid) is None and not netutil.port_open(HOST, moved_spec.port)
    assert client.list_brokers() == []

    assert agent.terminate() == 0


def test_an_agent_restart_re_adopts_its_brokers(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state)  # default: brokers outlive the agent
    spec = mqtt_spec()
    first = agent.client().put_broker(spec)

    # kill -9 the agent: the broker keeps running and serving.
    agent.kill9()
    assert proc_info(first.pid) is not None
    mqtt_roundtrip(spec.port)

    # A new agent on the same state dir adopts it: same pid, no second mosquitto.
    again = agents.start(state, port=agent.port)
    adopted = again.client().get_broker("m1")
    assert adopted.pid == first.pid and adopted.restarts == 0
    # RUNNING once its health check passes: at adoption if it answers within 1 s, else the
    # supervisor's next check (a loaded machine: CI saw STARTING at the first GET).
    process.wait_until(lambda: again.client().get_broker("m1").status is BrokerStatus.RUNNING, 30.0,
                       what="the adopted broker to be RUNNING")
    assert again.client().get_broker("m1").pid == first.pid
    assert mosquitto_processes(state, "m1") == [first.pid]
    assert again.client().put_broker(spec).pid == first.pid  # no restart either

    # SIGTERM: the agent exits cleanly and leaves the broker running (it is the plant's).
    assert again.terminate() == 0
    assert proc_info(first.pid) is not None
    third = agents.start(state, "--stop-brokers-on-exit")
    assert third.client().get_broker("m1").pid == first.pid
    assert third.terminate() == 0  # with --stop-brokers-on-exit: stopped
    assert proc_info(first.pid) is None and not netutil.port_open(HOST, spec.port)


# --- Kafka ---------------------------------------------------------------------------------

def kafka_topic(name: str, **settings) -> TopicSpec:
    return TopicSpec(broker_id="k1", name=name, iri=f"https://example.org/plant#{name}", **settings)


def described(bootstrap: str, name: str) -> tuple[int, str]:
    """(partitions, retention.ms) of a topic as an independent AdminClient sees them."""
    admin = AdminClient({"bootstrap.servers": bootstrap})
    topics = admin.list_topics(timeout=10).topics
    resource = ConfigResource(ResourceType.TOPIC, name)
    configs = admin.describe_configs([resource])[resource].result(timeout=10)
    return len(topics[name].partitions), configs["retention.ms"].value


def librdkafka_threads(pid: int) -> list[str]:
    names = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            names.append((task / "comm").read_text().strip())
        except OSError:
            continue
    return [n for n in names if n.startswith("rdk:")]


def test_kafka_through_the_agent(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state, "--stop-brokers-on-exit")
    client = agent.client()
    spec = BrokerSpec(id="k1", iri="https://example.org/plant#k1", name="Cell Kafka", kind="kafka",
                      host=HOST, port=netutil.free_port(HOST))
    bootstrap = f"{HOST}:{spec.port}"

    broker = client.put_broker(spec)
    assert broker.status is BrokerStatus.RUNNING and broker.pid
    folder = state / "brokers" / "k1"
    controller_port = (folder / "controller.port").read_text().strip()

    # A topic with 3 partitions and a retention: the broker itself reports them.
    name = "robot.position"
    observed = client.put_topic(kafka_topic(name, partitions=3, retention_ms=3_600_000))
    assert (observed.partitions, observed.replication_factor, observed.retention_ms) == (3, 1, 3_600_000)
    assert described(bootstrap, name) == (3, "3600000")
    assert client.put_topic(kafka_topic(name, partitions=3)).partitions == 3  # idempotent

    # Up is fine; down is refused with a clear message and changes nothing.
    assert client.put_topic(kafka_topic(name, partitions=4, retention_ms=60_000)).partitions == 4
    with pytest.raises(PermanentDispatchError) as info:
        client.put_topic(kafka_topic(name, partitions=2))
    assert "409" in info.value.message and "4 partitions" in info.value.message
    assert "cannot lower them to 2" in info.value.message and "pk:partitions" in (info.value.hint or "")
    assert described(bootstrap, name) == (4, "60000")
    listed = client.get_broker("k1").topics
    assert [(t.name, t.partitions, t.retention_ms) for t in listed] == [(name, 4, 60_000)]

    # Messages go through.
    producer = Producer({"bootstrap.servers": bootstrap, "acks": "all"})
    producer.produce(name, key=b"k", value=b"v", partition=3)
    assert producer.flush(30) == 0
    producer.close()  # else it reconnects to the killed broker below and logs about it

    # The agent keeps no AdminClient (librdkafka threads) once the requests are answered.
    process.wait_until(lambda: not librdkafka_threads(agent.child.pid), 10.0, 0.05,
                       what="the agent's librdkafka threads to end")

    # kill -9 the JVM: restarted on the same data and controller port; the topic is still there.
    os.kill(broker.pid, signal.SIGKILL)
    restarted = wait_broker(client, "k1", lambda b: b.status is BrokerStatus.RUNNING
                            and b.restarts == 1, "Kafka to be restarted", deadline=120.0)
    assert restarted.pid != broker.pid
    assert (folder / "controller.port").read_text().strip() == controller_port
    assert [(t.name, t.partitions) for t in restarted.topics] == [(name, 4)]
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": uuid.uuid4().hex,
                         "enable.auto.commit": False})
    try:
        consumer.assign([TopicPartition(name, 3, 0)])

        def poll_one():
            message = consumer.poll(0.5)
            if message is not None and message.error():
                raise KafkaException(message.error())
            return message
        message = process.wait_until(poll_one, 30.0, 0.0, what="the message after the restart")
        assert (message.key(), message.value()) == (b"k", b"v")
    finally:
        consumer.close()

    # DELETE: the JVM is gone, the port closed.
    client.delete_topic("k1", name)
    assert client.get_broker("k1").topics == ()
    client.delete_broker("k1")
    assert proc_info(restarted.pid) is None and not netutil.port_open(HOST, spec.port)
    assert agent.terminate() == 0

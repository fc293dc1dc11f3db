"""plan / apply / destroy against real agents and real brokers: the paper's robot cell.

Two ``plantkg agent`` processes serve 127.0.0.2 (Mosquitto) and 127.0.0.3 (Kafka); the plant is a
copy of ontology/examples/robot-cell.ttl with free ports. The tests run in file order on one
deployment (Kafka's start is the expensive part): apply → messages flow through both brokers
with the partitions the ontology asks for → plan is empty → an invalid plant, a plant asking for
fewer partitions and an unconfirmed apply change nothing → a port change replaces Mosquitto →
removing Kafka from the plant stops it → destroy stops the rest. The module fixture then checks
that no broker process is left and stops the agents.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import re
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import rdflib
from confluent_kafka import Consumer, KafkaException, Producer, TopicPartition
from confluent_kafka.admin import AdminClient
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.cli import main
from engine.model import BridgeStatus
from engine.security import kafka_client, principal_key, principals
from kg.namespaces import PK
from tests.integration.agents import AgentFleet, plant_copy, set_port, start_agents

pytestmark = pytest.mark.integration

MQTT_HOST, KAFKA_HOST = "127.0.0.2", "127.0.0.3"
POSITION, ENERGY = "robot.abb-irb120.position", "robot.abb-irb120.energy"


@dataclass
class Cell:
    fleet: AgentFleet
    plant: Path
    ports: dict[str, int]
    tmp: Path

    def run(self, capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str, str]:
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out, out.err

    def snapshot(self) -> dict[str, tuple[object, ...]]:
        """What runs, including the volatile facts that show a restart."""
        return {i: (b.status, b.pid, b.started_at, b.spec.port, tuple(t.name for t in b.topics))  # type: ignore[attr-defined]
                for i, b in self.fleet.brokers().items()}


#: The robot cell's Mosquitto is closed: the ROS machine logs in with the password its
#: pk:secretRef names (env:PLANTKG_ROS_MACHINE_PASSWORD: tests/conftest.py made a throwaway one,
#: which the agents inherit).
ROS_ENV = "PLANTKG_ROS_MACHINE_PASSWORD"
ROS_PASSWORD = os.environ[ROS_ENV]  # tests/conftest.py made it
#: The cell's Kafka is closed (closed by default): the test's Kafka clients log in as plantkg's own
#: principal, whose password the test run's principal key gives (engine.security.kafka_client).
AS_PLANTKG = kafka_client.client_settings(closed=True)


def as_ros_machine(client: mqtt.Client) -> mqtt.Client:
    """The ROS machine publishes the position (its write right)."""
    client.username_pw_set("ros-machine", ROS_PASSWORD)
    return client


def as_observer(client: mqtt.Client) -> mqtt.Client:
    """plantkg's observer principal reads every topic (nobody of the plant reads the position on
    Mosquitto: only the bridge worker and plantkg's taps do)."""
    client.username_pw_set(principals.OBSERVER, principal_key.password_for(principals.OBSERVER))
    return client


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    tmp = tmp_path_factory.mktemp("robot-cell")
    fleet = start_agents([MQTT_HOST, KAFKA_HOST], tmp)
    try:
        plant, ports = plant_copy("robot-cell.ttl", tmp)
        yield Cell(fleet, plant, ports, tmp)
    finally:
        fleet.stop()


# ------------------------------------------------------------------------------------ clients

def as_prober(client: mqtt.Client) -> mqtt.Client:
    """plantkg's check principal writes every topic (as ``plantkg check --probe`` does)."""
    client.username_pw_set(principals.CHECK, principal_key.password_for(principals.CHECK))
    return client


def mqtt_roundtrip(host: str, port: int, topic: str,
                   publisher: Callable[[mqtt.Client], mqtt.Client] = as_ros_machine) -> None:
    """Subscribe (as plantkg's observer), publish one QoS-1 message (as ``publisher``: the ROS
    machine by default), receive it (paho)."""
    received: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
    subscribed: queue.Queue[object] = queue.Queue()
    clients = []
    try:
        sub = as_observer(mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"plantkg-it-sub-{uuid.uuid4().hex[:6]}"))
        sub.on_message = lambda _c, _u, msg: received.put(msg)
        sub.on_subscribe = lambda _c, _u, _mid, codes, _p: subscribed.put(codes)
        pub = publisher(mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"plantkg-it-pub-{uuid.uuid4().hex[:6]}"))
        for client in (sub, pub):
            clients.append(client)
            client.connect(host, port, keepalive=10)
            client.loop_start()
            process.wait_until(client.is_connected, 10.0, 0.01, what="MQTT CONNACK")
        sub.subscribe(topic, qos=1)
        subscribed.get(timeout=10)
        payload = uuid.uuid4().hex.encode()
        info = pub.publish(topic, payload, qos=1)
        info.wait_for_publish(timeout=10)
        msg = received.get(timeout=10)
        assert (msg.topic, msg.payload) == (topic, payload)
    finally:
        for client in clients:
            client.disconnect()
            client.loop_stop()


def kafka_partitions(bootstrap: str, topic: str) -> int:
    admin = AdminClient({**AS_PLANTKG, "bootstrap.servers": bootstrap})
    meta = process.wait_until(lambda: admin.list_topics(topic, timeout=5).topics.get(topic),
                              30.0, 0.2, what=f"metadata of {topic}", ignore=(KafkaException,))
    return len(meta.partitions)


def kafka_roundtrip(bootstrap: str, topic: str) -> None:
    """Produce one message and consume it back from partition 0 (confluent-kafka)."""
    value = uuid.uuid4().hex.encode()
    delivered: list = []
    producer = Producer({**AS_PLANTKG, "bootstrap.servers": bootstrap, "acks": "all"})
    producer.produce(topic, key=b"k", value=value, partition=0,
                     on_delivery=lambda err, msg: delivered.append((err, msg)))
    assert producer.flush(30) == 0 and delivered and delivered[0][0] is None, delivered
    offset = delivered[0][1].offset()
    consumer = Consumer({**AS_PLANTKG, "bootstrap.servers": bootstrap, "group.id": f"it-{uuid.uuid4().hex[:8]}",
                         "enable.auto.commit": False})
    try:
        consumer.assign([TopicPartition(topic, 0, offset)])

        def poll_one():  # type: ignore[no-untyped-def]
            msg = consumer.poll(0.5)
            if msg is not None and msg.error():
                raise KafkaException(msg.error())
            return msg

        msg = process.wait_until(poll_one, 30.0, 0.0, what=f"a message on {topic}")
        assert msg.value() == value
    finally:
        consumer.close()


def assert_bridged(mqtt_host: str, mqtt_port: int, bootstrap: str, topic: str) -> None:
    """A QoS-1 message published on Mosquitto arrives on Kafka, payload untouched, with the MQTT
    topic as key and in a header (the bridge worker may still be connecting: poll until it is)."""
    payload = json.dumps({"probe": uuid.uuid4().hex}).encode()
    pub = as_ros_machine(mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-pub-{uuid.uuid4().hex[:8]}"))
    pub.connect(mqtt_host, mqtt_port)
    pub.loop_start()
    consumer = Consumer({**AS_PLANTKG, "bootstrap.servers": bootstrap, "group.id": f"it-{uuid.uuid4().hex[:8]}",
                         "auto.offset.reset": "earliest", "enable.auto.commit": False})
    consumer.subscribe([topic])
    try:
        def arrived():  # type: ignore[no-untyped-def]
            pub.publish(topic, payload, qos=1).wait_for_publish(timeout=10)
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                msg = consumer.poll(0.2)
                if msg is not None and msg.error() is None and msg.value() == payload:
                    return msg
            return None

        msg = process.wait_until(arrived, 60.0, 0.0, what=f"{topic} bridged into Kafka")
        assert msg.key() == topic.encode()
        assert dict(msg.headers() or [])["mqtt.topic"] == topic.encode()
    finally:
        consumer.close()
        pub.loop_stop()
        pub.disconnect()


# -------------------------------------------------------------------------------- the tests

def test_apply_deploys_the_robot_cell(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = cell.run(capsys, "apply", cell.plant, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 0, out + err
    assert "Plan: 6 to create, 0 to update, 0 to replace, 0 to destroy." in out
    assert "broker.kafka: Created after" in out and "Apply complete: 6 changed" in out
    mqtt_roundtrip(MQTT_HOST, cell.ports["mosquitto"], POSITION)
    bootstrap = f"{KAFKA_HOST}:{cell.ports['kafka']}"
    assert kafka_partitions(bootstrap, ENERGY) == 3
    assert kafka_partitions(bootstrap, POSITION) == 3
    kafka_roundtrip(bootstrap, ENERGY)
    # the bridge carries the robot's position from Mosquitto into Kafka
    assert_bridged(MQTT_HOST, cell.ports["mosquitto"], bootstrap, POSITION)


def test_plan_after_apply_has_no_changes(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = cell.run(capsys, "plan", cell.plant, "--agents", cell.fleet.agents_file,
                              "--detailed-exitcode")
    assert code == 0, out + err
    assert out.rstrip().endswith("No changes. The plant matches its description.")
    code, out, _ = cell.run(capsys, "status", cell.plant, "--agents", cell.fleet.agents_file)
    assert code == 0
    brokers, bridges = out.split("\n\n")
    rows = {line.split()[0]: line.split() for line in brokers.splitlines()[1:]}
    assert rows["kafka"][3] == rows["mosquitto"][3] == "running"
    assert bridges.splitlines()[1].split()[:3] == ["bridge.mosquitto.kafka", "mqtt-kafka", "running"]
    assert rows["kafka"][2] == f"{KAFKA_HOST}:{cell.ports['kafka']}"
    assert rows["kafka"][7] == "2/2" and rows["mosquitto"][7] == "1/1"


def test_a_killed_bridge_worker_is_restarted_by_its_agent_and_loses_nothing(cell: Cell) -> None:
    """SIGKILL the worker the Mosquitto agent runs while 3,000 messages flow: the agent restarts
    it, Mosquitto redelivers what it had not acknowledged, Kafka ends up with every message."""
    agent = cell.fleet.client(MQTT_HOST)
    (bridge,) = agent.list_bridges()
    assert bridge.status is BridgeStatus.RUNNING and bridge.pid
    run_id, count = uuid.uuid4().hex[:8], 3000
    consumer = Consumer({**AS_PLANTKG, "bootstrap.servers": f"{KAFKA_HOST}:{cell.ports['kafka']}",
                         "group.id": f"it-{run_id}", "auto.offset.reset": "earliest"})
    consumer.subscribe([POSITION])
    pub = as_ros_machine(mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-pub-{run_id}"))
    pub.max_inflight_messages_set(100)
    pub.max_queued_messages_set(0)
    pub.connect(MQTT_HOST, cell.ports["mosquitto"])
    pub.loop_start()
    got: set[int] = set()
    try:
        infos = []
        for n in range(count):
            infos.append(pub.publish(POSITION, f"{run_id}:{n}".encode(), qos=1))
            if n == count // 3:
                os.kill(bridge.pid, signal.SIGKILL)
        for info in infos:
            info.wait_for_publish(timeout=60)

        def restarted() -> bool:
            (now,) = agent.list_bridges()
            return now.pid not in (None, bridge.pid) and now.restarts == bridge.restarts + 1 \
                and now.status is BridgeStatus.RUNNING

        process.wait_until(restarted, 60, 0.2, what="the agent to restart the killed worker")

        def all_in_kafka() -> bool:
            msg = consumer.poll(0.5)
            if msg is not None and msg.error() is None:
                tag, _, n = msg.value().decode().partition(":")
                if tag == run_id:
                    got.add(int(n))
            return len(got) == count

        process.wait_until(all_in_kafka, 120, 0.0, what=f"all {count} messages in Kafka")
    finally:
        consumer.close()
        pub.loop_stop()
        pub.disconnect()
    assert got == set(range(count))


def test_apply_without_terminal_or_yes_refuses(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    before = cell.snapshot()
    changed = cell.tmp / "changed-port.ttl"
    changed.write_text(cell.plant.read_text())
    set_port(changed, "mosquitto", netutil.free_port(MQTT_HOST))
    code, out, err = cell.run(capsys, "apply", changed, "--agents", cell.fleet.agents_file)
    assert code == 2, out + err
    assert "standard input is not a terminal" in err and "--yes" in err
    assert cell.snapshot() == before


def test_invalid_plant_changes_nothing(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    before = cell.snapshot()
    broken = cell.tmp / "broken.ttl"
    text = cell.plant.read_text()
    broken.write_text(re.sub(r'pk:ip "127\.0\.0\.3"', 'pk:ip "kafka-host"', text))
    code, out, err = cell.run(capsys, "apply", broken, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 1, out + err
    assert "Violation" in out and "nothing was planned, started or stopped" in err
    assert cell.snapshot() == before


def test_fewer_partitions_are_refused(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    before = cell.snapshot()
    fewer = cell.tmp / "fewer-partitions.ttl"
    text = cell.plant.read_text()
    energy = text.index("rc:robot-energy\n    a owl:NamedIndividual")
    fewer.write_text(text[:energy] + text[energy:].replace("pk:partitions 3", "pk:partitions 2", 1))
    code, out, err = cell.run(capsys, "plan", fewer, "--agents", cell.fleet.agents_file)
    assert code == 2, out + err
    assert f"! topic.kafka.{ENERGY}: partitions 3 → 2: Kafka cannot remove partitions" in out
    code, out, err = cell.run(capsys, "apply", fewer, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 2 and "the plan cannot be applied" in err
    assert cell.snapshot() == before
    assert kafka_partitions(f"{KAFKA_HOST}:{cell.ports['kafka']}", ENERGY) == 3


def test_port_change_replaces_the_broker(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    old_port, new_port = cell.ports["mosquitto"], netutil.free_port(MQTT_HOST)
    kafka_before = cell.snapshot()["kafka"]
    set_port(cell.plant, "mosquitto", new_port)
    cell.ports["mosquitto"] = new_port
    code, out, err = cell.run(capsys, "plan", cell.plant, "--agents", cell.fleet.agents_file,
                              "--detailed-exitcode")
    assert code == 2, out + err
    assert "-/+ broker.mosquitto must be replaced" in out
    assert f"~ port: {old_port} → {new_port}   # forces replacement" in out
    # the bridge worker follows its broker to the new port
    assert "Plan: 0 to create, 1 to update, 1 to replace, 0 to destroy." in out
    assert "~ bridge.mosquitto.kafka will be updated" in out
    code, out, err = cell.run(capsys, "apply", cell.plant, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 0, out + err
    mqtt_roundtrip(MQTT_HOST, new_port, POSITION)
    assert_bridged(MQTT_HOST, new_port, f"{KAFKA_HOST}:{cell.ports['kafka']}", POSITION)
    assert not netutil.port_open(MQTT_HOST, old_port)
    assert cell.snapshot()["kafka"] == kafka_before  # the other broker was not touched
    code, out, _ = cell.run(capsys, "plan", cell.plant, "--agents", cell.fleet.agents_file,
                            "--detailed-exitcode")
    assert code == 0, out


def without_broker(path: Path, broker: str, out: Path) -> None:
    """The plant without ``broker``: its links, the topics only it carried, and their uses."""
    g = rdflib.Graph().parse(path)
    node = next(s for s, o in g.subject_objects(PK.id) if str(o) == broker)
    g.remove((node, None, None))
    g.remove((None, None, node))
    carried = set(g.objects(None, PK.hasTopic))
    for topic in set(g.subjects(rdflib.RDF.type, PK.Topic)) - carried:
        g.remove((topic, None, None))
        g.remove((None, None, topic))
    for link in (PK.publishes, PK.subscribes):  # uses no broker of the resource carries any more
        for resource, topic in list(g.subject_objects(link)):
            if not any((b, PK.hasTopic, topic) in g for b in g.objects(resource, PK.sendsTo)):
                g.remove((resource, link, topic))
    g.serialize(out, format="turtle")


def test_removing_a_broker_stops_it(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    kafka_pid = cell.snapshot()["kafka"][1]
    smaller = cell.tmp / "without-kafka.ttl"
    without_broker(cell.plant, "kafka", smaller)
    code, out, err = cell.run(capsys, "plan", smaller, "--agents", cell.fleet.agents_file)
    assert code == 0, out + err
    # the bridge worker's principal leaves Mosquitto's users: its ACL changes, it restarts
    assert "Plan: 0 to create, 0 to update, 1 to replace, 4 to destroy." in out
    assert "-/+ broker.mosquitto must be replaced" in out
    assert out.index(f"- topic.kafka.{ENERGY}") < out.index("- broker.kafka")
    assert "- bridge.mosquitto.kafka will be destroyed" in out
    code, out, err = cell.run(capsys, "apply", smaller, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 0, out + err
    assert "kafka" not in cell.fleet.brokers()
    assert not netutil.port_open(KAFKA_HOST, cell.ports["kafka"])
    assert not Path(f"/proc/{kafka_pid}").exists()
    mqtt_roundtrip(MQTT_HOST, cell.ports["mosquitto"], POSITION)


def test_destroy_stops_everything(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    pids = [s[1] for s in cell.snapshot().values()]
    code, out, err = cell.run(capsys, "destroy", cell.plant, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 0, out + err
    assert "Destroy complete" in out
    assert cell.fleet.brokers() == {}
    assert not netutil.port_open(MQTT_HOST, cell.ports["mosquitto"])
    assert all(not Path(f"/proc/{pid}").exists() for pid in pids)
    code, out, _ = cell.run(capsys, "destroy", cell.plant, "--agents", cell.fleet.agents_file, "--yes")
    assert code == 0 and "Nothing to destroy" in out

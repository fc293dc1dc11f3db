"""A Kafka broker plantkg deploys creates no topic the plant did not declare (issue 13).

One agent deploys one Kafka (KRaft) with one declared topic through its HTTP API, as apply does.
Then, against that real broker:

- a producer to an undeclared topic gets ``UNKNOWN_TOPIC_OR_PART`` (delivery report, or librdkafka's
  own ``_UNKNOWN_TOPIC`` once it knows), and a metadata request naming an unknown topic is answered
  with that error; neither creates the topic: the broker's topic list and the agent's observation
  stay the declared topic only;
- the declared topic takes and gives back records;
- a bridge worker (MQTT -> Kafka) started before its Kafka topic exists — what apply does, since
  the bridge runs in its Mosquitto's lane in parallel with the Kafka lane — keeps every message
  unacknowledged and retries; once the topic is created through the agent, every message arrives,
  in order, once.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from confluent_kafka import OFFSET_BEGINNING, Consumer, KafkaError, KafkaException, Producer, TopicPartition
from confluent_kafka.admin import AdminClient
from paho.mqtt import client as mqtt

from benchmarks import bridge_rig as rig
from engine import netutil, process
from engine.agent.client import AgentClient
from engine.bridge_worker.config import Direction, Route, WorkerConfig
from engine.bridge_worker.stats import read_stats
from engine.model import BrokerSpec, BrokerStatus, TopicSpec
from tests.integration.agents import AgentFleet, start_agents

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
DECLARED = "cell.declared"
UNKNOWN = (KafkaError.UNKNOWN_TOPIC_OR_PART, KafkaError._UNKNOWN_TOPIC)


class Deployed:
    """One agent, one Kafka it deployed, one declared topic."""

    def __init__(self, fleet: AgentFleet) -> None:
        self.fleet = fleet
        self.client: AgentClient = fleet.client(HOST)
        self.spec = BrokerSpec(id="k1", iri="https://example.org/plant#k1", name="Cell Kafka",
                               kind="kafka", host=HOST, port=netutil.free_port(HOST))
        self.bootstrap = f"{HOST}:{self.spec.port}"

    def topic(self, name: str) -> TopicSpec:
        return TopicSpec(broker_id="k1", name=name, iri=f"https://example.org/plant#{name}")

    def broker_topics(self) -> list[str]:
        """The topics the broker itself lists (Kafka's internal ones left out)."""
        admin = AdminClient({"bootstrap.servers": self.bootstrap})
        return sorted(n for n in admin.list_topics(timeout=10).topics if not n.startswith("__"))


@pytest.fixture(scope="module")
def kafka(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployed]:
    fleet = start_agents([HOST], tmp_path_factory.mktemp("no-autocreate"))
    try:
        deployed = Deployed(fleet)
        broker = deployed.client.put_broker(deployed.spec)
        assert broker.status is BrokerStatus.RUNNING, broker
        fleet.brokers()  # remember the JVM's pid: the teardown checks it is gone
        deployed.client.put_topic(deployed.topic(DECLARED))
        yield deployed
        deployed.client.delete_broker("k1")  # as destroy does; the fleet's stop checks nothing is left
    finally:
        fleet.stop()


def delivery(producer: Producer, topic: str, value: bytes, deadline: float) -> KafkaError | None:
    """Produce one record and return its delivery error (None: acknowledged); a produce that
    librdkafka refuses at once returns that error."""
    outcome: list[KafkaError | None] = []
    try:
        producer.produce(topic, value, on_delivery=lambda err, _msg: outcome.append(err))
    except KafkaException as exc:
        return exc.args[0]
    producer.flush(deadline)
    assert outcome, f"no delivery report for {topic!r} within {deadline} s"
    return outcome[0]


def read_values(bootstrap: str, topic: str, count: int, deadline: float) -> list[bytes]:
    """The values of partition 0 of ``topic`` from the start, until ``count`` were read."""
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"t-{uuid.uuid4().hex[:8]}",
                         "enable.auto.commit": False})
    values: list[bytes] = []
    try:
        consumer.assign([TopicPartition(topic, 0, OFFSET_BEGINNING)])

        def enough() -> bool:
            msg = consumer.poll(0.2)
            if msg is not None and not msg.error():
                values.append(msg.value())
            return len(values) >= count

        process.wait_until(enough, deadline, 0.0, what=f"{count} records on {topic}")
        while (msg := consumer.poll(0.5)) is not None:  # and nothing more (no duplicate)
            if not msg.error():
                values.append(msg.value())
    finally:
        consumer.close()
    return values


def test_the_rendered_broker_says_so(kafka: Deployed) -> None:
    folder = kafka.fleet.agents[HOST].state_dir / "brokers" / "k1"
    lines = (folder / "server.properties").read_text(encoding="utf-8").splitlines()
    assert "auto.create.topics.enable=false" in lines


def test_undeclared_topic_is_refused_and_never_created(kafka: Deployed) -> None:
    undeclared = f"cell.undeclared-{uuid.uuid4().hex[:6]}"
    # topic.metadata.propagation.max.ms: how long librdkafka waits for a topic it does not know
    # (30 s by default) before failing the record with the broker's UNKNOWN_TOPIC_OR_PART
    producer = Producer({"bootstrap.servers": kafka.bootstrap, "acks": "all", "log_level": 0,
                         "topic.metadata.propagation.max.ms": 2000, "message.timeout.ms": 30000})
    err = delivery(producer, undeclared, b"nobody declared me", 30.0)
    assert err is not None and err.code() in UNKNOWN, err
    again = delivery(producer, undeclared, b"still nobody", 30.0)
    assert again is not None and again.code() in UNKNOWN, again

    # A metadata request naming one unknown topic (what librdkafka clients send) creates nothing.
    asked = f"cell.asked-{uuid.uuid4().hex[:6]}"
    meta = AdminClient({"bootstrap.servers": kafka.bootstrap}).list_topics(asked, timeout=10)
    assert meta.topics[asked].error is not None
    assert meta.topics[asked].error.code() == KafkaError.UNKNOWN_TOPIC_OR_PART

    assert kafka.broker_topics() == [DECLARED]
    observed = kafka.client.get_broker("k1")
    assert observed is not None and [t.name for t in observed.topics] == [DECLARED]

    # The declared topic works: acknowledged and read back.
    value = f"hello {uuid.uuid4().hex}".encode()
    assert delivery(producer, DECLARED, value, 30.0) is None
    assert value in read_values(kafka.bootstrap, DECLARED, 1, 30.0)


def test_bridge_worker_retries_until_its_topic_exists(kafka: Deployed, tmp_path: Path) -> None:
    late = f"cell.late-{uuid.uuid4().hex[:6]}"
    mosquitto = rig.Mosquitto(tmp_path / "mosquitto").start()
    cfg = WorkerConfig("late-bridge", HOST, mosquitto.port, kafka.bootstrap,
                       (Route("cell/late", late, Direction.MQTT_TO_KAFKA),), tmp_path / "worker",
                       stats_interval=0.1)
    worker = rig.start_worker(cfg)
    publisher = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="late-publisher")
    try:
        rig.wait_ready(cfg, worker)
        publisher.connect(HOST, mosquitto.port)
        publisher.loop_start()
        sent = [f"m{i:03d}".encode() for i in range(40)]
        infos = []
        for value in sent[:20]:  # before the topic exists
            infos.append(publisher.publish("cell/late", value, qos=1))
        # librdkafka gives up on the unknown topic after topic.metadata.propagation.max.ms (30 s)
        process.wait_until(lambda: (s := read_stats(cfg.state_dir)) is not None and s.retried > 0,
                           90.0, 0.2, what="the worker to retry the records of the missing topic",
                           child=worker)
        stats = read_stats(cfg.state_dir)
        assert stats is not None and stats.forwarded_mqtt_to_kafka == 0
        assert "Unknown topic" in (stats.last_error or ""), stats.last_error
        assert late not in kafka.broker_topics()  # the worker's produce created nothing

        for value in sent[20:30]:  # while it retries
            infos.append(publisher.publish("cell/late", value, qos=1))
        kafka.client.put_topic(kafka.topic(late))  # what apply's Kafka lane does
        for value in sent[30:]:
            infos.append(publisher.publish("cell/late", value, qos=1))

        got = read_values(kafka.bootstrap, late, len(sent), 60.0)
        assert got == sent  # nothing lost, nothing twice, in order
        end = time.monotonic() + 10.0
        for info in infos:
            info.wait_for_publish(max(end - time.monotonic(), 0.1))
            assert info.is_published()
        final = process.wait_until(
            lambda: (s := read_stats(cfg.state_dir)) is not None
            and s.forwarded_mqtt_to_kafka == len(sent) and s, 10.0, 0.1,
            what="the worker's stats to count every record")
        assert final.retried >= 1
    finally:
        publisher.loop_stop()
        publisher.disconnect()
        code = process.stop(worker)
        mosquitto.stop()
        kafka.client.delete_topic("k1", late)
    assert code == 0, worker.log_tail()
    assert not worker.group_alive()

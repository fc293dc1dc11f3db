"""The MQTT <-> Kafka bridge worker against real Mosquitto and Kafka: 10,000 messages each way,
nothing missing (duplicates counted and printed), order kept per MQTT topic / Kafka partition —
also while the target broker or the worker itself is SIGKILLed mid-stream and started again, and
when the remote is down at the worker's start."""

from __future__ import annotations

import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from confluent_kafka import OFFSET_BEGINNING, Consumer, Producer, TopicPartition
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from benchmarks import bridge_rig as rig
from engine import process
from engine.errors import WaitTimeoutError
from engine.bridge_worker.config import Direction, Route, WorkerConfig
from engine.bridge_worker.mqtt_to_kafka import IN_FLIGHT
from engine.bridge_worker.stats import WorkerStats, read_stats
from tests.integration.conftest import KafkaBroker, start_kafka

pytestmark = pytest.mark.integration

N = 10_000
MQTT_TOPICS = ("cell/a", "cell/b", "cell/c", "cell/d")
PARTITIONS = 4
RATE = 2500           # messages/s of the paced senders (the stream lasts ~4 s: kills land mid-stream)
DELIVERY_DEADLINE = 60.0


# --- what was sent, what arrived ---------------------------------------------------------------

def payload(stream: object, seq: int) -> bytes:
    return f"{stream}|{seq:06d}".encode()


def check_delivery(label: str, streams: list[object], received: list[bytes], count: int = N) -> int:
    """received == sent (``count`` messages over ``streams``) as sets, first occurrences in order
    per stream; returns the duplicates."""
    sent = {payload(s, i) for s in streams for i in range(count // len(streams))}
    got = set(received)
    missing = sorted(sent - got)
    assert not missing, f"{label}: {len(missing)} missing: {missing[:3]}...{missing[-3:]}"
    assert got <= sent, f"{label}: unexpected {sorted(got - sent)[:5]}"
    firsts: dict[str, list[int]] = {}
    seen: set[bytes] = set()
    for item in received:
        if item not in seen:
            seen.add(item)
            stream, seq = item.decode().split("|")
            firsts.setdefault(stream, []).append(int(seq))
    for stream, seqs in firsts.items():
        assert seqs == sorted(seqs), f"{label}: order broken on {stream}"
    duplicates = len(received) - len(got)
    print(f"{label}: {len(sent)} sent, {len(got)} received, {duplicates} duplicates")
    return duplicates


def paced(total: int, send: Callable[[int], None]) -> threading.Thread:
    """Call ``send(i)`` for i in 0..total-1 at about RATE per second, in a thread."""
    pause = threading.Event()

    def run() -> None:
        start = time.monotonic()
        for i in range(total):
            ahead = start + i / RATE - time.monotonic()
            if ahead > 0.005:
                pause.wait(ahead)  # pacing the sender, not waiting for a condition
            send(i)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def mqtt_client(port: int, client_id: str, persistent: bool = False) -> mqtt.Client:
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5)
    client.max_inflight_messages_set(100)
    client.reconnect_delay_set(1, 1)
    props = Properties(PacketTypes.CONNECT)
    if persistent:
        props.SessionExpiryInterval = 3600
    client.connect("127.0.0.1", port, clean_start=not persistent, properties=props)
    client.loop_start()
    return client


def publish_mqtt(port: int) -> threading.Thread:
    """N QoS-1 messages spread over MQTT_TOPICS, paced; the thread ends when all are PUBACKed."""
    client = mqtt_client(port, "test-publisher")
    per_topic = N // len(MQTT_TOPICS)
    infos: list[mqtt.MQTTMessageInfo] = []

    def send(i: int) -> None:
        topic = MQTT_TOPICS[i % len(MQTT_TOPICS)]
        infos.append(client.publish(topic, payload(topic, i // len(MQTT_TOPICS)), qos=1))
        if i == per_topic * len(MQTT_TOPICS) - 1:
            for info in infos:
                info.wait_for_publish(60)
            client.disconnect()
            client.loop_stop()

    return paced(per_topic * len(MQTT_TOPICS), send)


def read_kafka(bootstrap: str, topic: str, count: int, deadline: float = DELIVERY_DEADLINE) -> list[bytes]:
    """Values of ``topic`` from the beginning, partition by partition in offset order, until at
    least ``count`` distinct values arrived."""
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": "test-reader", "enable.auto.commit": False})
    consumer.assign([TopicPartition(topic, p, OFFSET_BEGINNING) for p in range(PARTITIONS)])
    values: list[bytes] = []
    distinct: set[bytes] = set()

    def all_read() -> bool:
        for msg in consumer.consume(1000, timeout=0.2):
            if not msg.error():
                values.append(msg.value())
                distinct.add(msg.value())
        return len(distinct) >= count

    try:
        process.wait_until(all_read, deadline, 0.0, what=f"{count} records on {topic}")
    finally:
        consumer.close()
    return values


def produce_kafka(bootstrap: str, topic: str) -> threading.Thread:
    """N records spread over the partitions (payload "<partition>|<seq>"), paced, all confirmed."""
    producer = Producer({"bootstrap.servers": bootstrap, "enable.idempotence": True, "acks": "all",
                         "linger.ms": 2})
    per_partition = N // PARTITIONS

    def send(i: int) -> None:
        partition = i % PARTITIONS
        producer.produce(topic, payload(partition, i // PARTITIONS), partition=partition)
        producer.poll(0)
        if i == per_partition * PARTITIONS - 1:
            assert producer.flush(60) == 0

    return paced(per_partition * PARTITIONS, send)


@dataclass
class Subscriber:
    """A persistent-session QoS-1 subscriber that reconnects by itself."""

    client: mqtt.Client
    received: list[bytes]

    @classmethod
    def start(cls, port: int, topic: str) -> Subscriber:
        received: list[bytes] = []
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="test-subscriber", protocol=mqtt.MQTTv5)
        client.reconnect_delay_set(1, 1)
        client.on_message = lambda _c, _u, msg: received.append(msg.payload)
        granted = threading.Event()
        client.on_subscribe = lambda *_: granted.set()
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = 3600
        client.connect("127.0.0.1", port, clean_start=False, properties=props)
        client.subscribe(topic, qos=1)
        client.loop_start()
        process.wait_until(granted.is_set, 10.0, what="the test subscription")
        return cls(client, received)

    def wait_for(self, count: int) -> list[bytes]:
        """What arrived once ``count`` distinct messages did, or at the deadline (the caller's
        check then says what is missing)."""
        try:
            process.wait_until(lambda: len(set(self.received)) >= count, DELIVERY_DEADLINE,
                               what=f"{count} distinct MQTT messages")
        except WaitTimeoutError:
            pass
        return list(self.received)

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


# --- fixtures ----------------------------------------------------------------------------------

@pytest.fixture
def cleanup() -> Iterator[list[Callable[[], object]]]:
    """Stop functions, run in reverse order at the end of the test even when it fails."""
    todo: list[Callable[[], object]] = []
    yield todo
    for stop in reversed(todo):
        stop()


@pytest.fixture
def mosquitto(tmp_path: Path, cleanup: list) -> rig.Mosquitto:
    broker = rig.Mosquitto(tmp_path / "mosquitto").start()
    cleanup.append(broker.stop)
    return broker


@dataclass
class OwnKafka:
    """A Kafka node for the tests that kill or stop it: can be started again (same ports, data)."""

    broker: KafkaBroker
    child: process.Child | None

    @property
    def bootstrap(self) -> str:
        return self.broker.bootstrap_servers

    def down(self, kill: bool) -> None:
        assert self.child is not None
        rig.kill_group(self.child) if kill else process.stop(self.child)
        self.child = None

    def up(self) -> None:
        self.child = rig.respawn_kafka(self.broker.config, self.broker.broker_dir)


@pytest.fixture
def own_kafka(tmp_path: Path) -> Iterator[OwnKafka]:
    broker = start_kafka(tmp_path / "own-kafka")
    own = OwnKafka(broker, broker.child)
    yield own
    if own.child is not None:
        process.stop(own.child, grace=30.0)


class Workers:
    """Starts a bridge worker for the test and stops it (checking exit code 0) at the end."""

    def __init__(self, cleanup: list) -> None:
        self.child: process.Child | None = None
        cleanup.append(self.stop_clean)

    def start(self, cfg: WorkerConfig, wait: bool = True) -> process.Child:
        self.cfg = cfg
        self.child = rig.start_worker(cfg)
        if wait:
            rig.wait_ready(cfg, self.child)
        return self.child

    def stats(self) -> WorkerStats | None:
        return read_stats(self.cfg.state_dir)

    def stats_reaching(self, condition: Callable[[WorkerStats], bool], deadline: float = 10.0) -> WorkerStats:
        """The worker's stats once ``condition`` holds: stats.json is rewritten every
        stats_interval, so one read may lag the messages already delivered."""
        return process.wait_until(lambda: (s := self.stats()) is not None and condition(s) and s,
                                  deadline, 0.1, what="the worker's stats to catch up")

    def kill_when(self, predicate: Callable[[WorkerStats], bool]) -> None:
        assert self.child is not None
        process.wait_until(lambda: (s := self.stats()) is not None and predicate(s), 60.0,
                           what="the worker to be mid-stream", child=self.child)
        rig.kill_group(self.child)
        self.child = None

    def stop_clean(self) -> None:
        if self.child is not None:
            child, self.child = self.child, None
            assert process.stop(child) == 0, f"worker exit code {child.popen.returncode}: {child.log_tail()}"
            assert not child.group_alive()


@pytest.fixture
def workers(cleanup: list) -> Workers:
    return Workers(cleanup)


def worker_config(tmp_path: Path, bridge_id: str, mqtt_port: int, bootstrap: str, direction: Direction,
                  kafka_topic: str) -> WorkerConfig:
    routes = (tuple(Route(t, kafka_topic, direction) for t in MQTT_TOPICS)
              if direction is Direction.MQTT_TO_KAFKA else (Route("cell/out", kafka_topic, direction),))
    return WorkerConfig(bridge_id, "127.0.0.1", mqtt_port, bootstrap, routes, tmp_path / "worker",
                        stats_interval=0.1)


def mqtt_to_kafka(tmp_path: Path, mosquitto: rig.Mosquitto, bootstrap: str, workers: Workers,
                  name: str, disturb: Callable[[], None] | None = None) -> int:
    """10,000 MQTT messages through a worker into Kafka; ``disturb`` runs mid-stream."""
    rig.create_topics(bootstrap, [name], PARTITIONS)
    workers.start(worker_config(tmp_path, name, mosquitto.port, bootstrap, Direction.MQTT_TO_KAFKA, name))
    sender = publish_mqtt(mosquitto.port)
    if disturb is not None:
        disturb()
    values = read_kafka(bootstrap, name, N)
    sender.join(60)
    return check_delivery(name, list(MQTT_TOPICS), values)


def kafka_to_mqtt(tmp_path: Path, mosquitto: rig.Mosquitto, bootstrap: str, workers: Workers,
                  name: str, disturb: Callable[[Subscriber], None] | None = None) -> int:
    """10,000 Kafka records through a worker to an MQTT subscriber; ``disturb`` runs mid-stream."""
    rig.create_topics(bootstrap, [name], PARTITIONS)
    subscriber = Subscriber.start(mosquitto.port, "cell/out")
    try:
        workers.start(worker_config(tmp_path, name, mosquitto.port, bootstrap, Direction.KAFKA_TO_MQTT, name))
        sender = produce_kafka(bootstrap, name)
        if disturb is not None:
            disturb(subscriber)
        received = subscriber.wait_for(N)
        sender.join(60)
    finally:
        subscriber.stop()
    return check_delivery(name, list(range(PARTITIONS)), received)


def test_mqtt_to_kafka_10k(tmp_path: Path, mosquitto: rig.Mosquitto, kafka_broker: KafkaBroker,
                           workers: Workers) -> None:
    mqtt_to_kafka(tmp_path, mosquitto, kafka_broker.bootstrap_servers, workers, "m2k-plain")
    assert workers.stats_reaching(lambda s: s.forwarded_mqtt_to_kafka >= N).ready
    workers.stop_clean()  # SIGTERM: exit code 0, no process left
    assert not read_stats(workers.cfg.state_dir).ready  # type: ignore[union-attr]


def test_kafka_to_mqtt_10k(tmp_path: Path, mosquitto: rig.Mosquitto, kafka_broker: KafkaBroker,
                           workers: Workers) -> None:
    kafka_to_mqtt(tmp_path, mosquitto, kafka_broker.bootstrap_servers, workers, "k2m-plain")
    assert workers.stats_reaching(lambda s: s.forwarded_kafka_to_mqtt >= N).ready


def test_mqtt_to_kafka_worker_killed(tmp_path: Path, mosquitto: rig.Mosquitto, kafka_broker: KafkaBroker,
                                     workers: Workers) -> None:
    def kill_and_restart() -> None:
        workers.kill_when(lambda s: s.forwarded_mqtt_to_kafka >= N // 4)
        workers.start(workers.cfg)

    mqtt_to_kafka(tmp_path, mosquitto, kafka_broker.bootstrap_servers, workers, "m2k-worker-killed",
                  kill_and_restart)


def test_mqtt_to_kafka_at_full_speed_worker_killed(tmp_path: Path, mosquitto: rig.Mosquitto,
                                                   kafka_broker: KafkaBroker, workers: Workers) -> None:
    """Many messages in flight: mosquitto_pub (C, 1000 in flight) sends 4 x IN_FLIGHT messages on one topic
    as fast as it can while the worker is SIGKILLed and started again. Nothing is missing, the
    order holds, and the duplicates are bounded: the worker takes at most IN_FLIGHT messages
    it has not confirmed (Mosquitto 2.0.11 sends past the Receive Maximum, the worker stops
    reading), and Mosquitto may not have read the PUBACKs of up to about as many more: it reads one
    packet per connection per pass of its event loop. (With several publishers at full speed that
    lag grows without bound, which is why this test has one.)"""
    bootstrap = kafka_broker.bootstrap_servers
    topic = MQTT_TOPICS[0]
    rig.create_topics(bootstrap, ["m2k-full-speed"], PARTITIONS)
    cfg = worker_config(tmp_path, "m2k-full-speed", mosquitto.port, bootstrap, Direction.MQTT_TO_KAFKA,
                        "m2k-full-speed")
    workers.start(cfg)
    n = 4 * IN_FLIGHT  # more than the duplicates' bound, or the bound would hold whatever happens
    lines = tmp_path / "lines"
    lines.write_bytes(b"".join(payload(topic, i) + b"\n" for i in range(n)))
    with open(lines, "rb") as stdin:
        sender = subprocess.Popen([shutil.which("mosquitto_pub") or "mosquitto_pub", "-h", "127.0.0.1",
                                   "-p", str(mosquitto.port), "-t", topic, "-q", "1", "-M", "1000",
                                   "-i", "full-speed", "-l"], stdin=stdin)
    try:
        workers.kill_when(lambda s: s.forwarded_mqtt_to_kafka >= n // 4)
        workers.start(workers.cfg)
        values = read_kafka(bootstrap, "m2k-full-speed", n)
        assert sender.wait(60) == 0
    finally:
        if sender.poll() is None:
            sender.kill()
            sender.wait()
    duplicates = check_delivery("m2k-full-speed", [topic], values, n)
    assert duplicates <= 2 * IN_FLIGHT, duplicates


def test_kafka_to_mqtt_worker_killed(tmp_path: Path, mosquitto: rig.Mosquitto, kafka_broker: KafkaBroker,
                                     workers: Workers) -> None:
    def kill_and_restart(_subscriber: Subscriber) -> None:
        workers.kill_when(lambda s: s.forwarded_kafka_to_mqtt >= N // 4)
        workers.start(workers.cfg)

    kafka_to_mqtt(tmp_path, mosquitto, kafka_broker.bootstrap_servers, workers, "k2m-worker-killed",
                  kill_and_restart)


def test_kafka_to_mqtt_mosquitto_killed(tmp_path: Path, mosquitto: rig.Mosquitto, kafka_broker: KafkaBroker,
                                        workers: Workers) -> None:
    """Mosquitto loses what it held in memory; the worker replays from its last commit. The test
    subscriber's session must be on disk to outlive the kill: Mosquitto is told to save it."""
    def kill_and_restart(subscriber: Subscriber) -> None:
        mosquitto.save()
        process.wait_until(lambda: len(subscriber.received) >= N // 4, 60.0, what="a quarter delivered")
        mosquitto.kill()
        mosquitto.start()

    kafka_to_mqtt(tmp_path, mosquitto, kafka_broker.bootstrap_servers, workers, "k2m-mosquitto-killed",
                  kill_and_restart)
    # the loss is recorded; a reconnect attempt during the restart may have written the last word
    stats = workers.stats()
    assert stats is not None and any(word in (stats.last_error or "") for word in ("connection lost",
                                                                                 "unreachable"))
    assert f":{mosquitto.port} " in (stats.last_error or "")


def test_mqtt_to_kafka_kafka_killed(tmp_path: Path, mosquitto: rig.Mosquitto, own_kafka: OwnKafka,
                                    workers: Workers) -> None:
    def kill_and_restart() -> None:
        process.wait_until(lambda: (s := workers.stats()) is not None and s.forwarded_mqtt_to_kafka >= N // 4,
                           60.0, what="a quarter forwarded")
        own_kafka.down(kill=True)
        process.wait_until(lambda: (s := workers.stats()) is not None and not s.ready, 30.0,
                           what="the worker to notice Kafka is gone")
        own_kafka.up()

    mqtt_to_kafka(tmp_path, mosquitto, own_kafka.bootstrap, workers, "m2k-kafka-killed", kill_and_restart)


def test_worker_comes_up_when_its_remote_does(tmp_path: Path, mosquitto: rig.Mosquitto, own_kafka: OwnKafka,
                                              workers: Workers) -> None:
    rig.create_topics(own_kafka.bootstrap, ["late"], PARTITIONS)
    own_kafka.down(kill=False)
    cfg = worker_config(tmp_path, "late", mosquitto.port, own_kafka.bootstrap, Direction.MQTT_TO_KAFKA, "late")
    child = workers.start(cfg, wait=False)
    stats = process.wait_until(lambda: (s := workers.stats()) is not None and s.kafka_connected is False and s,
                               30.0, what="the worker to find Kafka down", child=child)
    # the last error is the probe's ("unreachable") or the producer's ("Connect to ... failed"),
    # whichever came last: both name the Kafka address
    assert not stats.ready and stats.mqtt_connected
    assert own_kafka.bootstrap.rsplit(":", 1)[1] in (stats.last_error or ""), stats.last_error
    own_kafka.up()
    rig.wait_ready(cfg, child, deadline=60.0)
    client = mqtt_client(mosquitto.port, "late-publisher")
    client.publish("cell/a", payload("cell/a", 0), qos=1).wait_for_publish(10)
    client.disconnect()
    client.loop_stop()
    assert read_kafka(own_kafka.bootstrap, "late", 1) == [payload("cell/a", 0)]


def test_counters_go_on_after_a_restart(tmp_path: Path, mosquitto: rig.Mosquitto, kafka_broker: KafkaBroker,
                                        workers: Workers) -> None:
    """A worker stopped and started again (as its agent does after a crash or a changed route)
    counts on from its last run: status shows what the bridge forwarded, not what this process did."""
    rig.create_topics(kafka_broker.bootstrap_servers, ["counted"], PARTITIONS)
    cfg = worker_config(tmp_path, "counted", mosquitto.port, kafka_broker.bootstrap_servers,
                        Direction.MQTT_TO_KAFKA, "counted")

    def send(first: int, count: int) -> None:
        client = mqtt_client(mosquitto.port, f"counted-publisher-{first}")
        for seq in range(first, first + count):
            client.publish("cell/a", payload("cell/a", seq), qos=1).wait_for_publish(10)
        client.disconnect()
        client.loop_stop()

    workers.start(cfg)
    send(0, 30)
    assert len(set(read_kafka(kafka_broker.bootstrap_servers, "counted", 30))) == 30
    workers.stats_reaching(lambda s: s.forwarded_mqtt_to_kafka == 30)
    workers.stop_clean()  # a clean stop: every message acknowledged, none sent again
    again = workers.start(cfg)
    stats = workers.stats()
    assert stats is not None and stats.pid == again.pid and stats.forwarded_mqtt_to_kafka == 30
    send(30, 20)
    assert len(set(read_kafka(kafka_broker.bootstrap_servers, "counted", 50))) == 50
    assert workers.stats_reaching(lambda s: s.forwarded_mqtt_to_kafka >= 50).forwarded_mqtt_to_kafka == 50


def test_the_mqtt_client_pumps_its_owner_on_its_io_thread_as_often_as_asked(mosquitto: rig.Mosquitto) -> None:
    """The MQTT -> Kafka half serves Kafka's delivery reports through the client's ``pump``: it
    runs on the client's I/O thread, and the wait it returns bounds that thread's wait for the
    socket (an idle connection would otherwise pass once per TICK, and PUBACKs would wait)."""
    from engine.bridge_worker.mqtt_client import TICK, MqttClient  # noqa: PLC0415 - this test only

    client = MqttClient("127.0.0.1", mosquitto.port, "pump-test", keepalive=10, session_expiry=0,
                        receive_maximum=10, clean_start=True)
    calls: list[tuple[str, float]] = []

    def pump() -> float:
        calls.append((threading.current_thread().name, time.monotonic()))
        return 0.01

    client.pump = pump
    client.start()
    try:
        process.wait_until(lambda: len(calls) >= 20, 30.0, 0.01, what="20 passes of the MQTT client")
    finally:
        client.stop()
    assert {name for name, _ in calls} == {"mqtt-pump-test"}
    assert calls[19][1] - calls[0][1] < 19 * TICK / 2, "the pump's wait did not bound the I/O thread's"

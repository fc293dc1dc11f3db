"""Taps and probes: what ``check`` subscribes to and publishes at real brokers.

A tap subscribes to some topics on one broker and counts what arrives from the moment it is ready:
MQTT with a v5 client (subscribed once the SUBACK came; retained messages, old news, are not sent),
Kafka with a consumer assigned to every partition at its high-water mark read before the watch
starts — "from latest", without the race of a group subscription whose position is resolved after
a message was already written.

A probe is one message marked as a check: the MQTT v5 user property / Kafka header ``plantkg-check``
holds a unique id, and so does the JSON payload, because bridges do not carry the mark over
(Mosquitto bridges speak MQTT 3.1.1, the MQTT <-> Kafka worker writes its own headers): a tap
recognises a probe by either. Real consumers of the topic see it too.

The demo's :class:`engine.demo.simulate.Tap` is not reused: it reads Kafka from the earliest offset
(old messages would pass a flow) and keeps only the last payload per topic, not each probe.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from abc import ABC, abstractmethod
from collections import Counter
from dataclasses import dataclass

import paho.mqtt.client as mqtt
from confluent_kafka import Consumer, KafkaException, Producer, TopicPartition
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from engine.errors import EngineError
from engine.security import kafka_client, principals
from engine.security.mqtt_client import secure
from engine.values import host_in_url

PROBE_MARK = "plantkg-check"
PROBE_NOTE = "plantkg check probe: a test message, not plant data"


class BrokerUnreachableError(EngineError):
    """A broker of a flow could not be connected to, subscribed at or published to in time."""


@dataclass(frozen=True)
class Endpoint:
    """Where a tap or a probe goes: one broker of the plant."""

    broker: str
    kind: str
    host: str
    port: int
    tls: bool = False   # a listener that speaks TLS (verified against the plant CA)
    closed: bool = False  # a Kafka that admits only its users: log in as plantkg (engine.security.kafka_client)

    def kafka_settings(self) -> dict[str, object]:
        """librdkafka settings that log a tap or a probe in at this Kafka (none: open and plain)."""
        return kafka_client.client_settings(self.closed, self.tls)

    @property
    def address(self) -> str:
        return f"{host_in_url(self.host)}:{self.port}"

    @property
    def where(self) -> str:
        return f"{self.broker} ({self.kind} at {self.address})"


def probe_payload(probe_id: str, resource: str, topic: str) -> bytes:
    """A probe's body: says what it is, names the flow, carries the id."""
    return json.dumps({PROBE_MARK: probe_id, "note": PROBE_NOTE, "resource": resource,
                       "topic": topic, "ts": time.time()}).encode()


def probe_id_of(data: bytes, mark: str | None = None) -> str | None:
    """The probe id of a message (its mark, else its JSON payload), None for plant data."""
    if mark:
        return mark
    if not data.startswith(b"{") or PROBE_MARK.encode() not in data:
        return None
    try:
        body = json.loads(data)
    except ValueError:
        return None
    found = body.get(PROBE_MARK) if isinstance(body, dict) else None
    return found if isinstance(found, str) else None


class Tap(ABC):
    """Counts messages per topic and arrivals per probe id at one broker (thread-safe)."""

    def __init__(self, endpoint: Endpoint, topics: tuple[str, ...]) -> None:
        self.endpoint, self.topics = endpoint, topics
        self._lock = threading.Lock()
        self._messages: Counter[str] = Counter()
        self._probes: Counter[str] = Counter()

    def record(self, topic: str, data: bytes, mark: str | None = None) -> None:
        probe = probe_id_of(data, mark)
        with self._lock:
            if probe is None:
                self._messages[topic] += 1
            else:
                self._probes[probe] += 1

    def messages(self, topic: str) -> int:
        """Plant messages seen on ``topic`` (probes not counted)."""
        with self._lock:
            return self._messages[topic]

    def probe_arrivals(self, probe_id: str) -> int:
        with self._lock:
            return self._probes[probe_id]

    @abstractmethod
    def start(self, timeout: float) -> None:
        """Connect and subscribe within ``timeout`` s, or raise BrokerUnreachableError."""

    @abstractmethod
    def close(self) -> None:
        """Disconnect; safe after a failed start."""


def _wait(event: threading.Event, timeout: float, endpoint: Endpoint, what: str) -> None:
    if not event.wait(max(timeout, 0.0)):
        raise BrokerUnreachableError(f"{endpoint.where}: no {what} within {timeout:.1f} s",
                                     hint="is the broker running? `plantkg status` shows it")


class MqttTap(Tap):
    """An MQTT v5 subscriber to the tap's topics (QoS 1)."""

    def __init__(self, endpoint: Endpoint, topics: tuple[str, ...]) -> None:
        super().__init__(endpoint, topics)
        self._client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5,
                                   client_id=f"plantkg-check-{uuid.uuid4().hex[:12]}")
        secure(self._client, endpoint.kind, principals.OBSERVER, endpoint.tls)
        self._connected, self._subscribed = threading.Event(), threading.Event()
        self._refused: list[str] = []
        self._client.on_connect = self._on_connect
        self._client.on_subscribe = self._on_subscribe
        self._client.on_message = lambda _c, _u, msg: self.record(msg.topic, msg.payload, _mark(msg))

    def _on_connect(self, _c: object, _u: object, _f: object, reason: object, _p: object) -> None:
        if getattr(reason, "is_failure", False):
            self._refused.append(f"connection refused: {reason}")
        self._connected.set()

    def _on_subscribe(self, _c: object, _u: object, _mid: object, codes: list, _p: object) -> None:
        self._refused += [f"subscription refused: {c}" for c in codes if getattr(c, "is_failure", False)]
        self._subscribed.set()

    def start(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        try:
            self._client.connect(self.endpoint.host, self.endpoint.port, keepalive=30)
        except OSError as exc:
            raise BrokerUnreachableError(f"{self.endpoint.where}: cannot connect: {exc}",
                                         hint="is the broker running? `plantkg status` shows it") from None
        self._client.loop_start()
        _wait(self._connected, end - time.monotonic(), self.endpoint, "CONNACK")
        # retained messages are old news: not sent at subscribe time, so they never pass a flow
        options = SubscribeOptions(qos=1, retainHandling=SubscribeOptions.RETAIN_DO_NOT_SEND)
        self._client.subscribe([(t, options) for t in self.topics])
        _wait(self._subscribed, end - time.monotonic(), self.endpoint, "SUBACK")
        if self._refused:
            raise BrokerUnreachableError(f"{self.endpoint.where}: {'; '.join(self._refused)}")

    def close(self) -> None:
        self._client.disconnect()
        self._client.loop_stop()


def _mark(msg: mqtt.MQTTMessage) -> str | None:
    props = getattr(msg, "properties", None)
    for key, value in getattr(props, "UserProperty", None) or ():
        if key == PROBE_MARK:
            return str(value)
    return None


class KafkaTap(Tap):
    """A consumer assigned to every partition of the tap's topics at their high-water marks."""

    def __init__(self, endpoint: Endpoint, topics: tuple[str, ...]) -> None:
        super().__init__(endpoint, topics)
        self._consumer = Consumer({"bootstrap.servers": endpoint.address,
                                   "group.id": f"plantkg-check-{uuid.uuid4().hex}",
                                   "enable.auto.commit": False, "log_level": 0, **endpoint.kafka_settings()})
        self._stop, self._sleep = threading.Event(), threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"check-tap-{endpoint.broker}", daemon=True)

    def start(self, timeout: float) -> None:
        end = time.monotonic() + timeout
        while True:  # a leader still being elected answers with an error: ask again until the end
            try:
                assignment = self._positions(end)
                break
            except KafkaException as exc:
                if time.monotonic() + 0.2 < end:
                    self._sleep.wait(0.2)
                    continue
                self._consumer.close()
                raise BrokerUnreachableError(f"{self.endpoint.where}: {exc.args[0]}",
                                             hint="is the broker running? `plantkg status` shows it") from None
            except BrokerUnreachableError:
                self._consumer.close()
                raise
        self._consumer.assign(assignment)
        self._thread.start()

    def _positions(self, end: float) -> list[TopicPartition]:
        """Every partition of the tap's topics at its high-water mark (the next offset written)."""
        assignment = []
        meta = self._consumer.list_topics(timeout=max(end - time.monotonic(), 0.1))
        for topic in self.topics:
            found = meta.topics.get(topic)
            if found is None or not found.partitions:
                raise BrokerUnreachableError(
                    f"{self.endpoint.where}: topic {topic!r} does not exist",
                    hint="apply the plant first (`plantkg apply`); `plantkg plan` shows what is missing")
            if found.error is not None:
                raise KafkaException(found.error)
            for partition in sorted(found.partitions):
                _, high = self._consumer.get_watermark_offsets(
                    TopicPartition(topic, partition), timeout=max(end - time.monotonic(), 0.1), cached=False)
                assignment.append(TopicPartition(topic, partition, high))
        return assignment

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                msg = self._consumer.poll(0.1)
                if msg is None or msg.error() is not None:
                    continue
                mark = dict(msg.headers() or ()).get(PROBE_MARK)
                self.record(msg.topic(), msg.value() or b"", mark.decode("utf-8", "replace") if mark else None)
        finally:
            self._consumer.close()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(10)


def make_tap(endpoint: Endpoint, topics: tuple[str, ...]) -> Tap:
    return KafkaTap(endpoint, topics) if endpoint.kind == "kafka" else MqttTap(endpoint, topics)


def publish_probe(endpoint: Endpoint, topic: str, probe_id: str, payload: bytes, timeout: float) -> None:
    """Publish one probe at ``endpoint`` and wait for the broker to take it (PUBACK / ack=all)."""
    if endpoint.kind == "kafka":
        _publish_kafka(endpoint, topic, probe_id, payload, timeout)
    else:
        _publish_mqtt(endpoint, topic, probe_id, payload, timeout)


def _publish_kafka(endpoint: Endpoint, topic: str, probe_id: str, payload: bytes, timeout: float) -> None:
    outcome: list[object] = []
    producer = Producer({"bootstrap.servers": endpoint.address, "acks": "all",
                         "log_level": 0, "message.timeout.ms": max(int(timeout * 1000), 1000),
                         **endpoint.kafka_settings()})
    producer.produce(topic, payload, headers=[(PROBE_MARK, probe_id.encode())],
                     on_delivery=lambda err, _msg: outcome.append(err))
    producer.flush(timeout)
    if not outcome or outcome[0] is not None:
        problem = outcome[0] if outcome else f"not acknowledged within {timeout:.1f} s"
        raise BrokerUnreachableError(f"{endpoint.where}: the probe on {topic!r} was not taken: {problem}")


def _publish_mqtt(endpoint: Endpoint, topic: str, probe_id: str, payload: bytes, timeout: float) -> None:
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5,
                         client_id=f"plantkg-check-probe-{uuid.uuid4().hex[:12]}")
    secure(client, endpoint.kind, principals.CHECK, endpoint.tls)
    props = Properties(PacketTypes.PUBLISH)
    props.UserProperty = (PROBE_MARK, probe_id)
    connected = threading.Event()
    client.on_connect = lambda *_: connected.set()
    end = time.monotonic() + timeout
    try:
        client.connect(endpoint.host, endpoint.port, keepalive=30)
    except OSError as exc:
        raise BrokerUnreachableError(f"{endpoint.where}: cannot connect: {exc}") from None
    client.loop_start()
    try:
        _wait(connected, end - time.monotonic(), endpoint, "CONNACK")
        info = client.publish(topic, payload, qos=1, properties=props)
        info.wait_for_publish(max(end - time.monotonic(), 0.1))
        if not info.is_published():
            raise BrokerUnreachableError(
                f"{endpoint.where}: the probe on {topic!r} was not acknowledged within {timeout:.1f} s")
    except (RuntimeError, ValueError) as exc:
        raise BrokerUnreachableError(f"{endpoint.where}: the probe on {topic!r} failed: {exc}") from None
    finally:
        client.disconnect()
        client.loop_stop()

"""Simulated data sources for the demo: what a plant's resources would publish.

Each publishing resource of the plant gets a source that writes JSON payloads to the broker it
sends to, on the topic it publishes: a robot pose (six joint angles and a TCP position, as a ROS
node would publish it) for a topic whose ``pk:valueTopic`` is ``position``; a power reading
(watts, accumulated watt-hours) for ``energy`` or ``power``; a counter for anything else. MQTT
sources publish at 10 Hz with the topic's QoS, Kafka sources at 1 Hz with ``acks=all``.

A :class:`Tap` subscribes to every such topic on its broker and counts what arrives, so the demo
shows data that really went through the brokers.
"""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import paho.mqtt.client as mqtt
from confluent_kafka import Consumer, Producer

from engine.model import BrokerSpec
from engine.security import kafka_client, principals
from engine.security.mqtt_client import MqttLogin, apply_login, apply_tls, secure
from engine.security.secrets import read_secret


@dataclass(frozen=True)
class Feed:
    """One resource publishing one topic to one broker."""

    resource: str
    topic: str
    value: str           # pk:valueTopic: what the payload is
    broker: BrokerSpec
    qos: int = 1
    user: str | None = None        # the resource's pk:id: its user name where it has a secret
    secret_ref: str | None = None  # its pk:secretRef (env:NAME or file:/path), read here

    @property
    def rate_hz(self) -> float:
        return 10.0 if self.broker.kind == "mosquitto" else 1.0

    def login(self) -> MqttLogin | None:
        """The resource's login (its pk:id and the secret its reference points to), if it has one."""
        if self.secret_ref is None or self.user is None:
            return None
        return MqttLogin(self.user, read_secret(f"{self.user}.secretRef", self.secret_ref))


def kafka_login(feed: Feed) -> dict[str, object]:
    """librdkafka settings of a resource publishing to a Kafka: at a closed Kafka it logs in as
    itself (SCRAM-SHA-512, its pk:id and the secret its reference points to), like the plant's
    real client would; TLS where the Kafka speaks it; nothing for an open, plain Kafka (a resource
    without a pk:secretRef at a closed Kafka connects without a login, and the broker refuses it)."""
    out = kafka_client.client_settings(False, feed.broker.tls)
    login = feed.login()
    if login is not None and kafka_client.is_closed(feed.broker):
        out |= {"security.protocol": "sasl_ssl" if feed.broker.tls else "sasl_plaintext",
                "sasl.mechanism": "SCRAM-SHA-512", "sasl.username": login.username,
                "sasl.password": login.password}
    return out


def payload(feed: Feed, n: int, t: float) -> bytes:
    """The n-th message of ``feed`` at time ``t`` (seconds since the demo started)."""
    if feed.value == "position":
        joints = [round(30 * math.sin(t * 0.5 + k), 3) for k in range(6)]
        tcp = {"x": round(0.35 + 0.1 * math.cos(t * 0.5), 4), "y": round(0.1 * math.sin(t * 0.5), 4), "z": 0.42}
        body: dict[str, object] = {"joints_deg": joints, "tcp_m": tcp}
    elif feed.value in ("energy", "power"):
        watts = round(180 + 40 * math.sin(t * 0.3), 1)
        body = {"power_w": watts, "energy_wh": round(180 * t / 3600, 4)}
    elif feed.value in AGV_PAYLOADS:
        body = AGV_PAYLOADS[feed.value](n, t)
    else:
        body = {"count": n}
    return json.dumps({"seq": n, "ts": time.time(), "source": feed.resource, **body}).encode()


# The AGV channels of the second paper (ontology/examples/agv-middleware.ttl), by pk:valueTopic:
# machine state, kinematics, capabilities (from the vehicle), motion and action commands (to it).
_STATES = ("driving", "loading", "driving", "unloading", "idle")
AGV_PAYLOADS: dict[str, Callable[[int, float], dict[str, object]]] = {
    "status": lambda n, t: {"state": _STATES[(n // 20) % len(_STATES)],
                            "battery_pct": round(100 - (t / 36) % 100, 1)},
    "movement": lambda n, t: {"x_m": round(5 + 4 * math.cos(t * 0.2), 3), "y_m": round(3 + 2 * math.sin(t * 0.2), 3),
                              "theta_rad": round((t * 0.2) % (2 * math.pi), 3), "speed_mps": round(0.8 + 0.2 * math.sin(t), 3)},
    "description": lambda n, t: {"payload_kg": 100, "max_speed_mps": 1.2, "actions": ["load", "unload", "idle"]},
    "motion": lambda n, t: {"task_id": f"task-{n // 5}", "point": [round(2.0 + n % 5, 1), 3.0],
                            "max_velocity": [1.0, 0.5], "sequence": n % 5},
    "action": lambda n, t: {"task_id": f"task-{n // 5}", "action": ("loading", "unloading", "idle")[n % 3]},
}


class Source(threading.Thread):
    """Publishes ``feed`` at its rate until stopped."""

    def __init__(self, feed: Feed, stop: threading.Event) -> None:
        super().__init__(name=f"source-{feed.resource}", daemon=True)
        self.feed, self.stop_event, self.sent = feed, stop, 0

    def run(self) -> None:
        b = self.feed.broker
        if b.kind == "kafka":
            producer = Producer({"bootstrap.servers": f"{b.host}:{b.port}", "acks": "all", "log_level": 3,
                                 "enable.idempotence": True, **kafka_login(self.feed)})
            publish: Callable[[bytes], None] = lambda data: producer.produce(self.feed.topic, data)
            close: Callable[[], object] = lambda: producer.flush(10)
        else:
            # one client per feed: a resource publishing several topics must not reuse one client
            # id, or the broker drops each connection when the next one with that id arrives
            client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2,
                                 client_id=f"demo-{self.feed.resource}-{self.feed.topic}")
            apply_tls(client, b.tls)
            apply_login(client, self.feed.login())
            client.connect(b.host, b.port)
            client.loop_start()
            publish = lambda data: client.publish(self.feed.topic, data, qos=self.feed.qos).wait_for_publish(5)
            close = lambda: (client.loop_stop(), client.disconnect())
        start = time.monotonic()
        try:
            while not self.stop_event.is_set():
                publish(payload(self.feed, self.sent, time.monotonic() - start))
                self.sent += 1
                if b.kind == "kafka":
                    producer.poll(0)
                self.stop_event.wait(1.0 / self.feed.rate_hz)
        finally:
            close()


@dataclass
class Seen:
    """What a tap received on one topic."""

    count: int = 0
    last: dict[str, object] = field(default_factory=dict)


class Tap(threading.Thread):
    """Subscribes to ``topics`` on ``broker`` and records what arrives."""

    def __init__(self, broker: BrokerSpec, topics: list[str], stop: threading.Event) -> None:
        super().__init__(name=f"tap-{broker.id}", daemon=True)
        self.broker, self.topics, self.stop_event = broker, topics, stop
        self.seen: dict[str, Seen] = {t: Seen() for t in topics}
        self.ready = threading.Event()
        self._lock = threading.Lock()

    def _record(self, topic: str, data: bytes) -> None:
        with self._lock:
            entry = self.seen.setdefault(topic, Seen())
            entry.count += 1
            try:
                entry.last = json.loads(data)
            except ValueError:
                entry.last = {"raw": data[:60].decode("utf-8", "replace")}

    def run(self) -> None:
        b = self.broker
        if b.kind == "kafka":
            consumer = Consumer({"bootstrap.servers": f"{b.host}:{b.port}", "group.id": f"plantkg-demo-{time.time_ns()}",
                                 "auto.offset.reset": "earliest", "log_level": 3,
                                 **kafka_client.client_settings(kafka_client.is_closed(b), b.tls)})
            consumer.subscribe(self.topics, on_assign=lambda *_: self.ready.set())
            try:
                while not self.stop_event.is_set():
                    msg = consumer.poll(0.2)
                    if msg is not None and msg.error() is None:
                        self._record(msg.topic(), msg.value())
            finally:
                consumer.close()
            return
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"demo-tap-{b.id}")
        secure(client, b.kind, principals.OBSERVER, b.tls)
        client.on_message = lambda _c, _u, m: self._record(m.topic, m.payload)
        client.on_subscribe = lambda *_: self.ready.set()
        client.connect(b.host, b.port)
        client.subscribe([(t, 1) for t in self.topics])
        client.loop_start()
        self.stop_event.wait()
        client.loop_stop()
        client.disconnect()

    def snapshot(self) -> dict[str, Seen]:
        with self._lock:
            return {t: Seen(s.count, dict(s.last)) for t, s in self.seen.items()}

"""The load test's burst through an MQTT -> Kafka bridge: M QoS-1 messages published at once on
Mosquitto, each timed publish -> PUBACK (Mosquitto has it) and publish -> consumed from Kafka (the
bridge worker forwarded it and Kafka confirmed it). The bridge counterpart of
``benchmarks.mqtt_burst`` and ``benchmarks.kafka_burst``: the burst is handed to the client in one
loop first; payloads carry a burst number and an index, so late records of an earlier burst are
not counted.
"""

from __future__ import annotations

import time
import uuid

import paho.mqtt.client as mqtt
from confluent_kafka import OFFSET_END, Consumer, KafkaException, TopicPartition

from benchmarks.mqtt_burst import BurstResult


class BridgeBurstRig:
    """A paho publisher on ``mqtt_host:mqtt_port`` and a consumer of ``topic`` (one partition) on
    ``bootstrap``; the bridge between them is the system under test. Use as a context manager."""

    def __init__(self, mqtt_host: str, mqtt_port: int, bootstrap: str, topic: str,
                 ready_s: float = 60.0) -> None:
        self.topic = topic
        self._sent: dict[int, float] = {}
        self._ack_at: dict[int, float] = {}   # PUBACK time by MQTT message id (paho's thread)
        self._consumed: dict[int, float] = {}
        self._mid: dict[int, int] = {}        # message id -> index in the burst
        self._number = 0
        self.consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"bench-{uuid.uuid4().hex[:8]}",
                                  "enable.auto.commit": False, "fetch.wait.max.ms": 1, "log_level": 0})
        self.consumer.assign([TopicPartition(topic, 0, OFFSET_END)])
        self.publisher = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-{uuid.uuid4().hex[:8]}")
        self.publisher.max_inflight_messages_set(1000)
        self.publisher.max_queued_messages_set(0)
        self.publisher.on_publish = self._on_publish
        self.publisher.connect(mqtt_host, mqtt_port)
        self.publisher.loop_start()
        end = time.monotonic() + ready_s  # until the bridge forwards: a probe comes back through Kafka
        while not self.burst(1, 16, deadline=1.0).delivery_s:
            if time.monotonic() > end:
                self.__exit__()
                raise TimeoutError(f"no message came through the bridge to {topic} within {ready_s} s")

    def __enter__(self) -> BridgeBurstRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.publisher.loop_stop()
        self.publisher.disconnect()
        self.consumer.close()

    def _on_publish(self, _c: object, _u: object, mid: int, *rest: object) -> None:
        # No lock of ours here: paho calls this holding its own, which publish() also takes.
        self._ack_at[mid] = time.perf_counter()

    def _index(self, value: bytes) -> int | None:
        number, index = divmod(int.from_bytes(value[:8], "big"), 1 << 32)
        return index if number == self._number else None

    def burst(self, messages: int, size: int, deadline: float = 60.0) -> BurstResult:
        """Publish ``messages`` payloads of ``size`` bytes (>= 8) at once; wait for the PUBACKs and
        for every record in Kafka (at most ``deadline`` s)."""
        filler = b"x" * max(0, size - 8)
        self._number += 1
        payloads = [((self._number << 32) + i).to_bytes(8, "big") + filler for i in range(messages)]
        self._sent, self._ack_at, self._consumed, self._mid = {}, {}, {}, {}
        began = time.perf_counter()
        for i, payload in enumerate(payloads):
            self._sent[i] = time.perf_counter()
            self._mid[self.publisher.publish(self.topic, payload, qos=1).mid] = i
        send_s = time.perf_counter() - began
        end = time.monotonic() + deadline
        while (len(self._ack_at) < messages or len(self._consumed) < messages) and time.monotonic() < end:
            for msg in self.consumer.consume(num_messages=1000, timeout=0.001):
                if msg.error() is not None:
                    raise KafkaException(msg.error())
                index = self._index(msg.value())
                if index is not None:
                    self._consumed.setdefault(index, time.perf_counter())
        acked = {self._mid[mid]: at for mid, at in list(self._ack_at.items()) if mid in self._mid}
        return BurstResult(messages, 1, size, "bridge", send_s,
                           tuple(acked[i] - self._sent[i] for i in sorted(acked)),
                           tuple(self._consumed[i] - self._sent[i] for i in sorted(self._consumed)))

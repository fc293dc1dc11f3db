"""The load test's burst against a Kafka broker: M messages produced at once (acks=all, no
linger), each timed produce → acknowledged (delivery report) and produce → consumed (a consumer
assigned to the topic's end before the burst). The Kafka counterpart of
``benchmarks.mqtt_burst``: one thread, the burst handed to the client in one loop first.
"""

from __future__ import annotations

import time
import uuid

from confluent_kafka import OFFSET_END, Consumer, KafkaException, Producer, TopicPartition

from benchmarks.mqtt_burst import BurstResult


class KafkaRig:
    """A producer and a consumer of ``topic`` on ``bootstrap``; use as a context manager."""

    def __init__(self, bootstrap: str, topic: str, ready_s: float = 60.0):
        self.topic = topic
        self.producer = Producer({"bootstrap.servers": bootstrap, "acks": "all", "linger.ms": 0,
                                  "queue.buffering.max.messages": 1_000_000, "log_level": 0})
        self.consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"bench-{uuid.uuid4().hex[:8]}",
                                  "enable.auto.commit": False, "fetch.wait.max.ms": 1, "log_level": 0})
        self._sent: dict[int, float] = {}
        self._acked: dict[int, float] = {}
        self._consumed: dict[int, float] = {}
        self._number = 0
        self.consumer.assign([TopicPartition(topic, 0, OFFSET_END)])
        end = time.monotonic() + ready_s  # until the assignment is live: a message sent before it is never seen
        while not self.burst(1, 16, deadline=1.0).delivery_s:
            if time.monotonic() > end:
                raise TimeoutError(f"no message on {topic} came back within {ready_s} s")

    def __enter__(self) -> KafkaRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.consumer.close()
        self.producer.flush(10)

    def _index(self, value: bytes) -> int | None:
        """The message's index in the current burst (None: from an earlier burst)."""
        number, index = divmod(int.from_bytes(value[:8], "big"), 1 << 32)
        return index if number == self._number else None

    def _on_delivery(self, err: object, msg: object) -> None:
        index = self._index(msg.value())  # type: ignore[attr-defined]
        if err is None and index is not None:
            self._acked[index] = time.perf_counter()

    def burst(self, messages: int, size: int, deadline: float = 60.0) -> BurstResult:
        """Produce ``messages`` payloads of ``size`` bytes (>= 8) at once; wait for acks and consumption."""
        filler = b"x" * max(0, size - 8)
        self._number += 1
        payloads = [((self._number << 32) + i).to_bytes(8, "big") + filler for i in range(messages)]
        self._sent, self._acked, self._consumed = {}, {}, {}
        began = time.perf_counter()
        for i, payload in enumerate(payloads):
            self._sent[i] = time.perf_counter()
            self.producer.produce(self.topic, payload, partition=0, on_delivery=self._on_delivery)
        send_s = time.perf_counter() - began
        end = time.monotonic() + deadline
        while (len(self._acked) < messages or len(self._consumed) < messages) and time.monotonic() < end:
            self.producer.poll(0)
            for msg in self.consumer.consume(num_messages=1000, timeout=0.001):
                if msg.error() is not None:
                    raise KafkaException(msg.error())
                index = self._index(msg.value())
                if index is not None:
                    self._consumed.setdefault(index, time.perf_counter())
        return BurstResult(messages, 1, size, "kafka", send_s,
                           tuple(self._acked[i] - self._sent[i] for i in sorted(self._acked) if i in self._sent),
                           tuple(self._consumed[i] - self._sent[i] for i in sorted(self._consumed) if i in self._sent))

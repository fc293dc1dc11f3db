"""Kafka notifications (confluent-kafka): the notification JSON as the record value.

One idempotent producer (``acks=all``, ``enable.idempotence``) per bootstrap list. The record key
is ``notification.kafka.key`` when given, else the entity id, so one entity's notifications stay
in one partition and in order (Orion sends a null key; plantkg's default is a documented
difference). Headers as Orion's: ``Fiware-Service``, ``Fiware-ServicePath``,
``Fiware-Correlator``, ``Ngsiv2-AttrsFormat``. A notification counts as sent when the broker
acknowledged the record; an error or no answer within :data:`DELIVERY_TIMEOUT` is a temporary
failure (the lane retries).
"""

from __future__ import annotations

import threading
import time

from confluent_kafka import KafkaError, KafkaException, Producer

from engine.context_broker.subscriptions.model import KafkaTarget
from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.subscriptions.result import Result

DELIVERY_TIMEOUT = 10.0


class KafkaSender:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._producers: dict[str, Producer] = {}

    def _producer(self, bootstrap: str) -> Producer:
        with self._lock:
            producer = self._producers.get(bootstrap)
            if producer is None:
                producer = Producer({
                    "bootstrap.servers": bootstrap,
                    "acks": "all",
                    "enable.idempotence": True,
                    "message.timeout.ms": int(DELIVERY_TIMEOUT * 1000),
                    "client.id": "plantkg-context-broker",
                })
                self._producers[bootstrap] = producer
            return producer

    def _forget(self, bootstrap: str) -> None:
        with self._lock:
            self._producers.pop(bootstrap, None)

    def send(self, target: KafkaTarget, msg: Outgoing) -> Result:
        producer = self._producer(target.bootstrap)
        done = threading.Event()
        outcome: list[KafkaError | None] = []

        def delivered(err: KafkaError | None, _record: object) -> None:
            outcome.append(err)
            done.set()

        headers = [("Fiware-ServicePath", msg.service_path), ("Fiware-Correlator", msg.correlator),
                   ("Ngsiv2-AttrsFormat", msg.attrs_format)]
        if msg.service:
            headers.insert(0, ("Fiware-Service", msg.service))
        try:
            producer.produce(target.topic, value=msg.body,
                             key=(target.key if target.key is not None else msg.entity_id),
                             headers=headers, on_delivery=delivered)
        except (BufferError, KafkaException) as err:
            return Result.temporary(f"Kafka produce failed: {err}")
        deadline = time.monotonic() + DELIVERY_TIMEOUT + 2.0
        while not done.is_set() and time.monotonic() < deadline:
            producer.poll(0.05)
        if not done.is_set():
            return Result.temporary(f"no acknowledgement from Kafka {target.bootstrap} within "
                                    f"{DELIVERY_TIMEOUT:g} s")
        err = outcome[0]
        if err is None:
            return Result.success()
        if err.fatal():
            self._forget(target.bootstrap)
        return Result.temporary(f"Kafka delivery failed: {err.str()}")

    def close(self) -> None:
        with self._lock:
            producers, self._producers = list(self._producers.values()), {}
        for producer in producers:
            producer.flush(5.0)

"""Kafka notifications (confluent-kafka): the notification JSON as the record value.

One idempotent producer (``acks=all``, ``enable.idempotence``) per bootstrap list. The record key
is ``notification.kafka.key`` when given, else the entity id, so one entity's notifications stay
in one partition and in order (Orion sends a null key; plantkg's default is a documented
difference). Headers as Orion's: ``Fiware-Service``, ``Fiware-ServicePath``,
``Fiware-Correlator``, ``Ngsiv2-AttrsFormat``. A notification counts as sent when the broker
acknowledged the record; an error or no answer within :data:`DELIVERY_TIMEOUT` is a temporary
failure (the lane retries).

A Kafka of the plant that is closed (engine.derived.access: no ``pk:allowAnonymous true``) admits
only SASL clients. The context broker is told those brokers (``--closed-kafka``, rendered by the
NGSI driver from the plant) and logs in there as plantkg's own Kafka principal, SASL/PLAIN with
the password derived from the principal key its agent exports
(:mod:`engine.security.kafka_client`), when any address of a target's bootstrap list is one of
them. Any other Kafka a subscription names gets no credentials: plantkg's password (sent in clear
by PLAIN) goes only where the plant deployed a closed Kafka. A key that cannot be read makes each
notification a temporary failure, named in ``lastFailureReason``.

A Kafka of the plant that speaks TLS (``pk:tls true``: ``--tls-kafka``) is reached over TLS
(SASL_SSL where it is also closed, SSL otherwise), trusting only the plant CA (the agent exports
``$PLANTKG_CA_DIR``) and checking the broker's address against its certificate. A CA that cannot
be read is a temporary failure too.
"""

from __future__ import annotations

import ipaddress
import threading
import time
from typing import Any

from confluent_kafka import KafkaError, KafkaException, Producer

from engine.context_broker.subscriptions.model import KafkaTarget, PlantKafkas
from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.subscriptions.result import Result
from engine.errors import EngineError
from engine.security import kafka_client

DELIVERY_TIMEOUT = 10.0


def bootstrap_addresses(bootstrap: str) -> frozenset[tuple[str, int]]:
    """The (address, port) pairs of a ``host:port[,host:port...]`` list, an IP address
    normalised as :func:`engine.values.check_host` does (a name kept, lower case)."""
    out = set()
    for item in bootstrap.split(","):
        host, _, port = item.rpartition(":")
        host = host.strip("[]").lower()
        try:
            host = str(ipaddress.ip_address(host))
        except ValueError:
            pass
        if port.isdigit():
            out.add((host, int(port)))
    return frozenset(out)


class KafkaSender:
    def __init__(self, kafkas: PlantKafkas = PlantKafkas()) -> None:
        """``kafkas``: the plant's closed Kafka brokers (a target naming one of them is sent to
        logged in as plantkg's own principal) and those that speak TLS (sent to over TLS)."""
        self._lock = threading.Lock()
        self._producers: dict[str, Producer] = {}
        self._kafkas = kafkas

    def logs_in(self, bootstrap: str) -> bool:
        """True when ``bootstrap`` names one of the plant's closed Kafka brokers."""
        return bool(bootstrap_addresses(bootstrap) & self._kafkas.closed)

    def speaks_tls(self, bootstrap: str) -> bool:
        """True when ``bootstrap`` names one of the plant's Kafka brokers that speak TLS."""
        return bool(bootstrap_addresses(bootstrap) & self._kafkas.tls)

    def _producer(self, bootstrap: str) -> Producer:
        """The producer of ``bootstrap``; raises EngineError when plantkg's password cannot be
        derived (the principal key unreadable) or the plant CA cannot be read."""
        with self._lock:
            producer = self._producers.get(bootstrap)
            if producer is None:
                config: dict[str, Any] = {
                    "bootstrap.servers": bootstrap,
                    "acks": "all",
                    "enable.idempotence": True,
                    "message.timeout.ms": int(DELIVERY_TIMEOUT * 1000),
                    "client.id": "plantkg-context-broker",
                }
                login = kafka_client.client_settings(self.logs_in(bootstrap), tls=self.speaks_tls(bootstrap))
                producer = Producer(config | login)
                self._producers[bootstrap] = producer
            return producer

    def _forget(self, bootstrap: str) -> None:
        with self._lock:
            self._producers.pop(bootstrap, None)

    def send(self, target: KafkaTarget, msg: Outgoing) -> Result:
        try:
            producer = self._producer(target.bootstrap)
        except EngineError as err:  # the principal key (a closed Kafka), the plant CA (a TLS one)
            return Result.temporary(f"Kafka {target.bootstrap}: cannot connect as plantkg: {err}")
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

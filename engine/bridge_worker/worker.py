"""One bridge worker: its MQTT connection, the forwarding halves its routes need, a Kafka health
probe and the stats file, run until asked to stop.

Threads: the MQTT client's I/O thread (MQTT in and out), the producer's polling thread (Kafka delivery
reports -> PUBACKs), a probe thread (is the Kafka cluster reachable?) and the main thread, which
runs the Kafka -> MQTT half and writes ``stats.json``. A stop (SIGTERM, SIGINT) ends consuming
first, then waits, bounded, for the writes and PUBACKs in flight, then disconnects: the MQTT session
stays on the broker, so what arrives meanwhile waits there for the next start.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.bridge_worker.config import Direction, WorkerConfig
from engine.bridge_worker.health import Health
from engine.bridge_worker.kafka_to_mqtt import KafkaToMqtt
from engine.bridge_worker.loop import TICK, BridgeLoop, Half
from engine.bridge_worker.mqtt_link import MqttLink
from engine.bridge_worker.mqtt_to_kafka import IN_FLIGHT, MqttToKafka
from engine.bridge_worker.stats import WorkerStats

log = logging.getLogger("plantkg.bridge")

PROBE_EVERY = 1.0      # seconds between probes of the Kafka cluster
PROBE_TIMEOUT = 2.0


class Worker(BridgeLoop):
    def __init__(self, cfg: WorkerConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.health = Health(cfg.bridge_id)
        self.link = MqttLink(cfg, self.health, receive_maximum=IN_FLIGHT)
        self.m2k = MqttToKafka(cfg, self.link, self.health) if cfg.routes_of(Direction.MQTT_TO_KAFKA) else None
        self.k2m = KafkaToMqtt(cfg, self.link, self.health) if cfg.routes_of(Direction.KAFKA_TO_MQTT) else None

    def halves(self) -> Sequence[Half]:
        return [h for h in (self.m2k, self.k2m) if h is not None]

    def step(self) -> None:
        """Kafka -> MQTT polls Kafka on the main thread."""
        if self.k2m:
            self.k2m.step(TICK)
        else:
            super().step()

    def snapshot(self) -> WorkerStats:
        return self.health.snapshot(needs_subscription=self.m2k is not None,
                                    needs_assignment=self.k2m is not None,
                                    stopping=self.stopping.is_set())

    def stopped_line(self) -> str:
        return (f"stopped: {self.health.forwarded_mqtt_to_kafka} forwarded MQTT -> Kafka, "
                f"{self.health.forwarded_kafka_to_mqtt} Kafka -> MQTT")

    def probe(self) -> None:
        admin = AdminClient({"bootstrap.servers": self.cfg.kafka_bootstrap,
                             "client.id": f"{self.cfg.client_id}-probe",
                             "reconnect.backoff.max.ms": 2000,
                             "error_cb": lambda err: None,  # the producer/consumer report errors
                             **self.cfg.kafka_auth()})
        while not self.stopping.is_set():
            try:
                admin.list_topics(timeout=PROBE_TIMEOUT)
                self.health.set(kafka_connected=True)
            except KafkaException as exc:
                self.health.set(kafka_connected=False)
                self.health.error(f"Kafka {self.cfg.kafka_bootstrap} unreachable: {exc.args[0].str()}")
            self.stopping.wait(PROBE_EVERY)

"""One bridge worker: its MQTT connection, the forwarding halves its routes need, a Kafka health
probe and the stats file, run until asked to stop.

Threads: paho's network thread (MQTT in and out), the producer's polling thread (Kafka delivery
reports -> PUBACKs), a probe thread (is the Kafka cluster reachable?) and the main thread, which
runs the Kafka -> MQTT half and writes ``stats.json``. A stop (SIGTERM, SIGINT) ends consuming
first, then waits, bounded, for the writes and PUBACKs in flight, then disconnects: the MQTT session
stays on the broker, so what arrives meanwhile waits there for the next start.
"""

from __future__ import annotations

import logging
import threading
import time

from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.bridge_worker.config import Direction, WorkerConfig
from engine.bridge_worker.health import Health
from engine.bridge_worker.kafka_to_mqtt import KafkaToMqtt
from engine.bridge_worker.mqtt_link import MqttLink
from engine.bridge_worker.mqtt_to_kafka import MqttToKafka
from engine.bridge_worker.stats import write_stats

log = logging.getLogger("plantkg.bridge")

STOP_GRACE = 10.0      # seconds a stop waits for writes and PUBACKs in flight
PROBE_EVERY = 1.0      # seconds between probes of the Kafka cluster
PROBE_TIMEOUT = 2.0


class Worker:
    def __init__(self, cfg: WorkerConfig) -> None:
        self.cfg = cfg
        self.health = Health(cfg.bridge_id)
        self.stopping = threading.Event()
        self.link = MqttLink(cfg, self.health)
        self.m2k = MqttToKafka(cfg, self.link, self.health) if cfg.routes_of(Direction.MQTT_TO_KAFKA) else None
        self.k2m = KafkaToMqtt(cfg, self.link, self.health) if cfg.routes_of(Direction.KAFKA_TO_MQTT) else None
        self._probe = threading.Thread(target=self._probe_kafka, name="kafka-probe", daemon=True)

    def run(self) -> None:
        """Forward until :attr:`stopping` is set, then stop cleanly."""
        self.cfg.state_dir.mkdir(parents=True, exist_ok=True)
        self._write_stats()
        if self.m2k:
            self.m2k.start()
        if self.k2m:
            self.k2m.start()
        self.link.start()
        self._probe.start()
        next_stats = 0.0
        while not self.stopping.is_set():
            if self.k2m:
                self.k2m.step(0.05)
            else:
                self.stopping.wait(0.05)
            now = time.monotonic()
            if now >= next_stats or self.health.changed.is_set():
                self.health.changed.clear()
                self._write_stats()
                next_stats = now + self.cfg.stats_interval
        self._shutdown()

    def _shutdown(self) -> None:
        log.info("stopping")
        self._write_stats()
        deadline = time.monotonic() + STOP_GRACE
        if self.m2k:
            self.m2k.stop(deadline)
        if self.k2m:
            self.k2m.stop(deadline)
        self.link.stop()
        self._write_stats()
        log.info("stopped: %d forwarded MQTT -> Kafka, %d Kafka -> MQTT",
                 self.health.forwarded_mqtt_to_kafka, self.health.forwarded_kafka_to_mqtt)

    def _write_stats(self) -> None:
        snapshot = self.health.snapshot(needs_subscription=self.m2k is not None,
                                        needs_assignment=self.k2m is not None,
                                        stopping=self.stopping.is_set())
        try:
            write_stats(self.cfg.state_dir, snapshot)
        except OSError as exc:
            log.warning("cannot write stats: %s", exc)

    def _probe_kafka(self) -> None:
        admin = AdminClient({"bootstrap.servers": self.cfg.kafka_bootstrap,
                             "client.id": f"{self.cfg.client_id}-probe",
                             "reconnect.backoff.max.ms": 2000,
                             "error_cb": lambda err: None})  # the producer/consumer report errors
        while not self.stopping.is_set():
            try:
                admin.list_topics(timeout=PROBE_TIMEOUT)
                self.health.set(kafka_connected=True)
            except KafkaException as exc:
                self.health.set(kafka_connected=False)
                self.health.error(f"Kafka {self.cfg.kafka_bootstrap} unreachable: {exc.args[0].str()}")
            self.stopping.wait(PROBE_EVERY)

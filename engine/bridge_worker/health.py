"""The worker's live state, shared by its threads, turned into :class:`WorkerStats` snapshots.

Connection flags and counters are set by the MQTT thread, the Kafka threads and the main loop;
every change of a connection flag sets :attr:`Health.changed`, so the main loop writes the stats
file at once instead of at the next interval.
"""

from __future__ import annotations

import logging
import os
import threading
import time

from engine.bridge_worker.stats import WorkerStats

log = logging.getLogger("plantkg.bridge")

# the counters of WorkerStats that add up over the bridge's life (connection flags do not)
CUMULATIVE = ("forwarded_mqtt_to_kafka", "forwarded_kafka_to_mqtt", "forwarded_mqtt_to_ngsi",
              "retried", "refused", "skipped")


class Health:
    def __init__(self, bridge_id: str) -> None:
        self.bridge_id = bridge_id
        self.changed = threading.Event()
        self._lock = threading.Lock()
        self.mqtt_connected = False
        self.subscribed = False            # MQTT -> Kafka subscriptions granted
        self.kafka_connected: bool | None = None
        self.assigned = False              # Kafka -> MQTT partitions assigned, positions committed
        self.forwarded_mqtt_to_kafka = 0
        self.forwarded_kafka_to_mqtt = 0
        self.retried = 0
        self.last_error: str | None = None

    def set(self, **flags: object) -> None:
        """Set connection flags; a real change wakes the stats writer."""
        with self._lock:
            moved = {k: v for k, v in flags.items() if getattr(self, k) != v}
            for key, value in moved.items():
                setattr(self, key, value)
        if moved:
            log.info("state: %s", ", ".join(f"{k}={v}" for k, v in moved.items()))
            self.changed.set()

    def carry_on_from(self, previous: WorkerStats | None) -> None:
        """Start the counters where the previous run of this bridge left them, so they count
        since the bridge was created, not since this process started (a worker restarted by its
        agent, after a crash, a kill -9 or a changed route, keeps counting). Only a snapshot of
        the same bridge counts; what a killed worker forwarded after its last snapshot (at most
        ``stats_interval`` s of traffic) is not in it."""
        if previous is None or previous.bridge_id != self.bridge_id:
            return
        with self._lock:
            for name in CUMULATIVE:
                if hasattr(self, name):
                    setattr(self, name, getattr(previous, name))

    def count(self, counter: str, n: int = 1) -> None:
        with self._lock:
            setattr(self, counter, getattr(self, counter) + n)

    def error(self, text: str) -> None:
        with self._lock:
            repeated = self.last_error == text
            self.last_error = text
        if not repeated:
            log.warning("%s", text)

    def snapshot(self, *, needs_subscription: bool, needs_assignment: bool, stopping: bool) -> WorkerStats:
        with self._lock:
            ready = (not stopping and self.mqtt_connected and self.kafka_connected is True
                     and (self.subscribed or not needs_subscription)
                     and (self.assigned or not needs_assignment))
            return WorkerStats(
                bridge_id=self.bridge_id, pid=os.getpid(), ready=ready,
                mqtt_connected=self.mqtt_connected, kafka_connected=self.kafka_connected,
                forwarded_mqtt_to_kafka=self.forwarded_mqtt_to_kafka,
                forwarded_kafka_to_mqtt=self.forwarded_kafka_to_mqtt,
                retried=self.retried, last_error=self.last_error, updated_at=time.time(),
            )

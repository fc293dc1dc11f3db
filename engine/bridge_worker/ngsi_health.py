"""The NGSI worker's live state: :class:`engine.bridge_worker.health.Health` with the flags and
counters of an MQTT <-> NGSI bridge, and its readiness rule, turned into
:class:`engine.bridge_worker.stats.WorkerStats` snapshots (``mechanism`` "mqtt-ngsi").

Ready means: MQTT connected with its subscriptions granted (if it forwards MQTT -> NGSI), the
context broker answering ``GET /version``, its last write not refused for the token (401/403),
and (if it forwards NGSI -> MQTT) its subscriptions made on the context broker.
"""

from __future__ import annotations

import os
import time

from engine.bridge_worker.health import Health
from engine.bridge_worker.ngsi_config import MECHANISM
from engine.bridge_worker.stats import WorkerStats


class NgsiHealth(Health):
    """:class:`Health` with the NGSI worker's flags and counters."""

    def __init__(self, bridge_id: str) -> None:
        super().__init__(bridge_id)
        self.ngsi_connected: bool | None = None
        self.subscriptions_made = False
        self.token_refused = False         # the last write was answered 401/403
        self.forwarded_mqtt_to_ngsi = 0
        self.refused = 0
        self.skipped = 0

    def ngsi_snapshot(self, *, needs_subscription: bool, needs_ngsi_subscriptions: bool,
                      stopping: bool) -> WorkerStats:
        with self._lock:
            ready = (not stopping and self.mqtt_connected and self.ngsi_connected is True
                     and not self.token_refused
                     and (self.subscribed or not needs_subscription)
                     and (self.subscriptions_made or not needs_ngsi_subscriptions))
            return WorkerStats(
                bridge_id=self.bridge_id, pid=os.getpid(), ready=ready,
                mqtt_connected=self.mqtt_connected, kafka_connected=None,
                forwarded_mqtt_to_kafka=0, forwarded_kafka_to_mqtt=0,
                retried=self.retried, last_error=self.last_error, updated_at=time.time(),
                mechanism=MECHANISM, ngsi_connected=self.ngsi_connected,
                forwarded_mqtt_to_ngsi=self.forwarded_mqtt_to_ngsi, refused=self.refused,
                skipped=self.skipped,
            )

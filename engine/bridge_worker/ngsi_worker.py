"""One MQTT <-> NGSI-v2 bridge worker (the paper's FIROS role): its MQTT connection, the MQTT ->
NGSI lanes, the keeper of its context broker subscriptions (NGSI -> MQTT), a ``GET /version``
probe of the context broker and the stats file, run until asked to stop.

Ready (the agent reports RUNNING): see :mod:`engine.bridge_worker.ngsi_health`. A stop (SIGTERM,
SIGINT) takes no new message, waits (bounded) for the requests in flight and their PUBACKs,
disconnects, and leaves the subscriptions in place: the bridge still exists. ``python -m engine.bridge_worker --remove
worker.json`` deletes them when the bridge is deleted (:func:`remove_subscriptions`).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

from engine.bridge_worker.loop import BridgeLoop, Half, Startable
from engine.bridge_worker.mqtt_link import MqttLink
from engine.bridge_worker.mqtt_to_ngsi import MqttToNgsi
from engine.bridge_worker.ngsi_client import NgsiClient, NgsiError
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiWorkerConfig
from engine.bridge_worker.ngsi_health import NgsiHealth
from engine.bridge_worker.ngsi_subscriptions import SubscriptionKeeper, apply_plan
from engine.bridge_worker.stats import WorkerStats

log = logging.getLogger("plantkg.bridge")

PROBE_EVERY = 1.0


class NgsiWorker(BridgeLoop):
    def __init__(self, cfg: NgsiWorkerConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.health = NgsiHealth(cfg.bridge_id)
        inbound = cfg.routes_of(NgsiDirection.MQTT_TO_NGSI)
        self.link = MqttLink(cfg, self.health, topics=[(r.mqtt_topic, r.qos) for r in inbound])
        self.m2n = MqttToNgsi(cfg, self.link, self.health, self.stopping) if inbound else None
        self.keeper = (SubscriptionKeeper(cfg, self.health, self.stopping)
                       if cfg.routes_of(NgsiDirection.NGSI_TO_MQTT) else None)

    def halves(self) -> Sequence[Half]:
        return [self.m2n] if self.m2n else []

    def watchers(self) -> Sequence[Startable]:
        return [self.keeper] if self.keeper else []

    def snapshot(self) -> WorkerStats:
        return self.health.ngsi_snapshot(needs_subscription=self.m2n is not None,
                                         needs_ngsi_subscriptions=self.keeper is not None,
                                         stopping=self.stopping.is_set())

    def stopped_line(self) -> str:
        return (f"stopped: {self.health.forwarded_mqtt_to_ngsi} forwarded MQTT -> NGSI, "
                f"{self.health.refused} refused, {self.health.skipped} notifications skipped")

    def probe(self) -> None:
        client = NgsiClient(self.cfg.ngsi_url, self.cfg.token_file, timeout=2.0,
                            ca_file=self.cfg.ngsi_ca_file)
        try:
            while not self.stopping.is_set():
                try:
                    client.version()
                    self.health.set(ngsi_connected=True)
                except NgsiError as exc:
                    self.health.set(ngsi_connected=False)
                    self.health.error(f"context broker {self.cfg.ngsi_url} does not answer: {exc.text}")
                self.stopping.wait(PROBE_EVERY)
        finally:
            client.close()


def remove_subscriptions(cfg: NgsiWorkerConfig) -> int:
    """Delete every subscription this bridge owns on the context broker (the bridge is being
    deleted); returns how many. Raises :class:`NgsiError` if the context broker does not answer."""
    client = NgsiClient(cfg.ngsi_url, cfg.token_file, ca_file=cfg.ngsi_ca_file)
    try:
        return len(apply_plan(client, cfg, remove_all=True).delete)
    finally:
        client.close()

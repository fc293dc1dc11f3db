"""MQTT -> NGSI: every message of a subscribed topic becomes one upsert of the topic's entity; the
MQTT message is acknowledged only after the context broker answered 2xx.

Messages arrive on the MQTT client's thread and are queued on a *lane*: a thread with its own keep-alive
connection that sends one request at a time. A topic always goes to the same lane, so its
messages reach the context broker in arrival order; PUBACKs leave in arrival order across lanes
(:class:`engine.bridge_worker.ledgers.InOrderAcks`). What the answer means
(:mod:`engine.bridge_worker.ngsi_client`):

- 2xx: ``forwarded``; the message is acknowledged;
- the context broker away, 5xx, 429, a token it does not take: the same request again after a
  backoff (0.1 s doubling to 2 s), counted in ``retried``; the lane waits, so order is kept;
- another 4xx, or a payload :mod:`engine.bridge_worker.ngsi_mapping` refuses: counted in
  ``refused``, logged with the reason, acknowledged — a poison message must not block its topic.

A message that is a context broker notification (the loop rule) is acknowledged and counted in
``skipped``. Messages of a connection that dropped are not sent: the broker sends them again on
the next connection of the persistent session.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import zlib
from dataclasses import dataclass


from engine.bridge_worker.ledgers import InOrderAcks, PendingAck
from engine.bridge_worker.mqtt_link import RECEIVE_MAXIMUM, MqttLink
from engine.bridge_worker.mqtt_wire import Publish
from engine.bridge_worker.ngsi_client import NgsiClient, NgsiRefused, NgsiUnavailable
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiRoute, NgsiWorkerConfig
from engine.bridge_worker.ngsi_health import NgsiHealth
from engine.bridge_worker.ngsi_mapping import Refused, is_notification, upsert_body

log = logging.getLogger("plantkg.bridge.mqtt-to-ngsi")

LANES = 4                  # at most this many requests in flight (one per lane)
BACKOFF = (0.1, 2.0)       # seconds before a failed request is sent again: first, cap


@dataclass(frozen=True)
class _Job:
    route: NgsiRoute
    payload: bytes
    received_at: float
    generation: int
    entry: PendingAck | None


class MqttToNgsi:
    def __init__(self, cfg: NgsiWorkerConfig, link: MqttLink, health: NgsiHealth,
                 stopping: threading.Event) -> None:
        self.cfg = cfg
        self.link = link
        self.health = health
        self.stopping = stopping           # the worker's: set on SIGTERM
        self.routes = {r.mqtt_topic: r for r in cfg.routes_of(NgsiDirection.MQTT_TO_NGSI)}
        self.acks = InOrderAcks(link.ack)
        self.generation = 0
        self._gen_lock = threading.Lock()
        lanes = max(1, min(LANES, len(self.routes)))
        self._queues: list[queue.Queue[_Job | None]] = [queue.Queue() for _ in range(lanes)]
        self._threads = [threading.Thread(target=self._lane, args=(q,), name=f"ngsi-lane-{i}", daemon=True)
                         for i, q in enumerate(self._queues)]
        self._taking = True
        link.on_message = self.on_message
        link.on_connection.append(self._connection_changed)
        link.hold_reading_while(lambda: len(self.acks) >= RECEIVE_MAXIMUM)

    def start(self) -> None:
        for thread in self._threads:
            thread.start()

    # --- the MQTT client's thread ------------------------------------------------------------

    def on_message(self, msg: Publish) -> None:
        if not self._taking:
            return  # not acknowledged: the broker sends it again to the next session
        route = self.routes.get(msg.topic)
        if route is None:  # a subscription left in the session by an earlier configuration
            log.warning("dropping a message on %r: no route (unsubscribing)", msg.topic)
            self.link.unsubscribe(msg.topic)
            self.link.ack(msg.mid, msg.qos)
            return
        entry = self.acks.add(msg.mid, msg.qos) if msg.qos > 0 else None
        payload = bytes(msg.payload)
        if is_notification(payload):  # the loop rule: never write a notification back
            self.health.count("skipped")
            if entry is not None:
                self.acks.confirm(entry)
            return
        lane = zlib.crc32(msg.topic.encode("utf-8")) % len(self._queues)
        self._queues[lane].put(_Job(route, payload, time.time(), self.generation, entry))

    def _connection_changed(self, up: bool, generation: int) -> None:
        with self._gen_lock:
            self.generation = generation
        if not up:
            dropped = self.acks.connection_lost()
            if dropped:
                log.info("%d messages unacknowledged at disconnect; the broker will send them again", dropped)

    # --- the lanes ---------------------------------------------------------------------------

    def _lane(self, jobs: queue.Queue[_Job | None]) -> None:
        client = NgsiClient(self.cfg.ngsi_url, self.cfg.token_file, ca_file=self.cfg.ngsi_ca_file)
        try:
            while True:
                job = jobs.get()
                if job is None:
                    return
                self._forward(client, job)
        finally:
            client.close()

    def _stale(self, job: _Job) -> bool:
        return job.generation != self.generation

    def _forward(self, client: NgsiClient, job: _Job) -> None:
        if self._stale(job):
            return  # its connection dropped: the broker sends it again
        try:
            body = upsert_body(job.route.entity_id, job.route.entity_type, job.payload, job.received_at)
        except Refused as exc:
            self._refused(job, exc.reason)
            return
        delay = BACKOFF[0]
        while True:
            try:
                client.upsert(body)
            except NgsiRefused as exc:
                self._refused(job, exc.text)
                return
            except NgsiUnavailable as exc:
                self.health.count("retried")
                if exc.status in (401, 403):
                    self.health.set(token_refused=True)
                self.health.error(f"{exc.text}; retrying")
                if self._stale(job) or self.stopping.wait(delay):
                    return  # not acknowledged: sent again by the broker
                delay = min(delay * 2, BACKOFF[1])
                continue
            self.health.count("forwarded_mqtt_to_ngsi")
            self.health.set(token_refused=False)
            if job.entry is not None:
                self.acks.confirm(job.entry)
            return

    def _refused(self, job: _Job, reason: str) -> None:
        self.health.count("refused")
        self.health.error(f"message on {job.route.mqtt_topic!r} refused (acknowledged, not retried): {reason}")
        if job.entry is not None:
            self.acks.confirm(job.entry)

    def stop(self, deadline: float) -> None:
        """Take no new message; let the lanes finish what they hold (until the monotonic
        ``deadline``); what is left unacknowledged the broker sends again."""
        self._taking = False
        for q in self._queues:
            q.put(None)
        for thread in self._threads:
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
        if len(self.acks):
            log.warning("%d messages still unconfirmed at stop: the broker sends them again", len(self.acks))

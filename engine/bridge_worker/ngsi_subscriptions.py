"""NGSI -> MQTT: the context broker subscriptions a bridge owns, and keeping them as they should be.

Each ``ngsi-to-mqtt`` route is one subscription on the context broker: subject the route's entity
(id and type), ``notification.mqtt`` = the worker's own MQTT broker, the route's topic and QoS,
``attrsFormat`` keyValues. The context broker then publishes every change of the entity on the
MQTT broker itself; the worker is not in that path (killing it loses nothing there).

A bridge finds its own subscriptions by their description, ``plantkg bridge <bridge id> <topic>``
(:func:`description`), so making them is idempotent: :func:`reconcile` compares what the context
broker holds with what the routes want and returns what to delete and what to create — a
subscription that differs (moved broker, other QoS, other entity) is replaced, one left by a route
that is gone is deleted, a duplicate is deleted. Other clients' subscriptions are never touched.
The functions here are pure; :class:`SubscriptionKeeper` does the HTTP.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from typing import Any

from engine.bridge_worker.ngsi_client import NgsiClient, NgsiError
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiRoute, NgsiWorkerConfig
from engine.bridge_worker.ngsi_health import NgsiHealth
from engine.security import principal_key

log = logging.getLogger("plantkg.bridge.ngsi-subscriptions")

PREFIX = "plantkg bridge"
RETRY_DELAY = (0.2, 5.0)   # seconds between attempts while the context broker is away: first, cap


def description(bridge_id: str, topic: str) -> str:
    return f"{PREFIX} {bridge_id} {topic}"


def owned_by(bridge_id: str, sub: dict[str, Any]) -> bool:
    text = sub.get("description")
    return isinstance(text, str) and text.startswith(f"{PREFIX} {bridge_id} ")


def subscription_body(cfg: NgsiWorkerConfig, route: NgsiRoute) -> dict[str, Any]:
    """The subscription of one ``ngsi-to-mqtt`` route, as POSTed. With a notify user (a closed
    broker), the context broker publishes the notifications as the bridge's notify principal: its
    ``user`` and ``passwd`` (Orion's fields; the context broker never shows the password back).
    To a TLS broker the url is ``mqtts://``."""
    mqtt: dict[str, Any] = {"url": cfg.mqtt_url, "topic": route.mqtt_topic, "qos": route.qos}
    if cfg.notify_username is not None:
        mqtt.update(user=cfg.notify_username, passwd=principal_key.password_for(cfg.notify_username))
    return {
        "description": description(cfg.bridge_id, route.mqtt_topic),
        "subject": {"entities": [{"id": route.entity_id, "type": route.entity_type}]},
        "notification": {"mqtt": mqtt, "attrsFormat": "keyValues"},
    }


def _essence(sub: dict[str, Any]) -> tuple[Any, ...]:
    """What decides whether a subscription does what the route wants (ids, counters and status
    the context broker adds are left out)."""
    subject = sub.get("subject") or {}
    notification = sub.get("notification") or {}
    mqtt = notification.get("mqtt") or {}
    entities = tuple((e.get("id"), e.get("idPattern"), e.get("type"))
                     for e in subject.get("entities") or [] if isinstance(e, dict))
    condition = subject.get("condition") or {}
    return (sub.get("description"), entities, bool(condition.get("attrs")),
            bool((condition.get("expression") or {})), mqtt.get("url"), mqtt.get("topic"), mqtt.get("user"),
            int(mqtt.get("qos", 0) or 0), notification.get("attrsFormat", "normalized"),
            tuple(notification.get("attrs") or ()), sub.get("status", "active") in ("active", "failed"))


@dataclass(frozen=True)
class SubscriptionPlan:
    delete: tuple[str, ...]               # subscription ids
    create: tuple[dict[str, Any], ...]    # bodies
    kept: int


def reconcile(cfg: NgsiWorkerConfig, existing: list[dict[str, Any]], *, remove_all: bool = False) -> SubscriptionPlan:
    """What to delete and create so the bridge owns exactly one right subscription per
    ``ngsi-to-mqtt`` route (none with ``remove_all``: the bridge is being deleted)."""
    wanted = {} if remove_all else {
        description(cfg.bridge_id, r.mqtt_topic): subscription_body(cfg, r)
        for r in cfg.routes_of(NgsiDirection.NGSI_TO_MQTT)
    }
    delete: list[str] = []
    satisfied: set[str] = set()
    for sub in existing:
        if not owned_by(cfg.bridge_id, sub) or not isinstance(sub.get("id"), str):
            continue
        desc = sub["description"]
        body = wanted.get(desc)
        if body is not None and desc not in satisfied and _essence(sub) == _essence(body):
            satisfied.add(desc)
        else:
            delete.append(sub["id"])
    create = tuple(body for desc, body in wanted.items() if desc not in satisfied)
    return SubscriptionPlan(tuple(delete), create, len(satisfied))


class SubscriptionKeeper:
    """Makes the bridge's subscriptions right once the context broker answers (on its own
    thread, retrying with backoff), sets ``health.subscriptions_made``, and checks them again
    every ``check_every`` seconds: one deleted by someone else, or lost with a context broker
    that started anew on empty data, is made again."""

    def __init__(self, cfg: NgsiWorkerConfig, health: NgsiHealth, stopping: threading.Event) -> None:
        self.cfg = cfg
        self.health = health
        self.stopping = stopping
        self._thread = threading.Thread(target=self._run, name="ngsi-subscriptions", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        client = NgsiClient(self.cfg.ngsi_url, self.cfg.token_file, ca_file=self.cfg.ngsi_ca_file)
        delay = RETRY_DELAY[0]
        first = True
        try:
            while not self.stopping.is_set():
                try:
                    plan = apply_plan(client, self.cfg)
                except NgsiError as exc:
                    self.health.error(f"context broker subscriptions: {exc.text}; retrying")
                    self.stopping.wait(delay)
                    delay = min(delay * 2, RETRY_DELAY[1])
                    continue
                if first or plan.create or plan.delete:
                    log.info("subscriptions: %d kept, %d created, %d deleted", plan.kept,
                             len(plan.create), len(plan.delete))
                first, delay = False, RETRY_DELAY[0]
                self.health.set(subscriptions_made=True)
                self.stopping.wait(self.cfg.check_every)
        finally:
            client.close()


def apply_plan(client: NgsiClient, cfg: NgsiWorkerConfig, *, remove_all: bool = False) -> SubscriptionPlan:
    """Read the context broker's subscriptions, delete and create what :func:`reconcile` says."""
    plan = reconcile(cfg, client.list_subscriptions(), remove_all=remove_all)
    for sub_id in plan.delete:
        client.delete_subscription(sub_id)
    for body in plan.create:
        client.create_subscription(body)
    return plan

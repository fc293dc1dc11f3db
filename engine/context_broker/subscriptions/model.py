"""A subscription as plantkg holds it: frozen dataclasses, and their rendering as Orion's JSON.

The shapes follow Orion's ``doc/manuals/orion-api.md`` ("Subscription payload datamodel"):
``subject`` (entities, condition), ``notification`` (one of ``http``, ``httpCustom``, ``mqtt``,
``kafka``; ``attrs``/``exceptAttrs``, ``attrsFormat``, ``onlyChangedAttrs``, ``covered``,
``metadata``, ``maxFailsLimit``), ``expires``, ``status``, ``throttling``. Parsing and validation
live in :mod:`.parse`; the delivery counters (``timesSent``, ``lastSuccess``, ...) are a separate
:class:`DeliveryStatus`, kept by the registry and merged in only when a subscription is shown.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

from engine.context_broker.contract import Tenant
from engine.context_broker.store import ReadScope
from engine.context_broker.dates import from_epoch


class Status(str, enum.Enum):
    """What a client can set. ``expired`` and ``failed`` are only ever reported (see :func:`shown_status`)."""

    ACTIVE = "active"
    INACTIVE = "inactive"
    ONESHOT = "oneshot"


class AttrsFormat(str, enum.Enum):
    NORMALIZED = "normalized"
    KEY_VALUES = "keyValues"
    VALUES = "values"
    SIMPLIFIED_NORMALIZED = "simplifiedNormalized"
    SIMPLIFIED_KEY_VALUES = "simplifiedKeyValues"


class Alteration(str, enum.Enum):
    CREATE = "entityCreate"
    UPDATE = "entityUpdate"
    CHANGE = "entityChange"
    DELETE = "entityDelete"


#: Orion's default when ``alterationTypes`` is omitted: creations and actual changes, no deletions.
DEFAULT_ALTERATIONS = frozenset({Alteration.CREATE, Alteration.CHANGE})


@dataclass(frozen=True)
class EntitySelector:
    """One element of ``subject.entities``: ``id`` xor ``idPattern``; ``type`` xor ``typePattern``
    or neither (any type)."""

    id: str | None = None
    id_pattern: str | None = None
    type: str | None = None
    type_pattern: str | None = None


@dataclass(frozen=True)
class Condition:
    attrs: tuple[str, ...] = ()
    q: str | None = None
    alterations: frozenset[Alteration] = DEFAULT_ALTERATIONS
    alterations_given: bool = False
    notify_on_metadata_change: bool = True
    mq: str | None = None


@dataclass(frozen=True)
class HttpTarget:
    """``notification.http`` (``custom`` False) or ``notification.httpCustom``."""

    url: str
    custom: bool = False
    headers: tuple[tuple[str, str], ...] = ()
    qs: tuple[tuple[str, str], ...] = ()
    method: str = "POST"
    timeout_ms: int = 0


@dataclass(frozen=True)
class MqttTarget:
    url: str
    host: str
    port: int
    topic: str
    qos: int = 0
    retain: bool = False
    user: str | None = None
    passwd: str | None = None
    tls: bool = False   # mqtts://: TLS, the broker verified against the plant CA


@dataclass(frozen=True)
class KafkaTarget:
    """``notification.kafka``. ``bootstrap`` is the ``host:port[,host:port...]`` of ``url``."""

    url: str
    bootstrap: str
    topic: str
    key: str | None = None


@dataclass(frozen=True)
class PlantKafkas:
    """The plant's Kafka brokers of their own, as (address, port), that ``kafka://``
    notifications treat as the plant's (the NGSI driver renders them from the plant): ``closed``
    ones are logged in to as plantkg's own principal, ``tls`` ones reached over TLS trusting only
    the plant CA. A Kafka in neither gets a plain, anonymous producer."""

    closed: frozenset[tuple[str, int]] = frozenset()
    tls: frozenset[tuple[str, int]] = frozenset()


Target = HttpTarget | MqttTarget | KafkaTarget


@dataclass(frozen=True)
class Notification:
    target: Target
    attrs: tuple[str, ...] = ()
    except_attrs: tuple[str, ...] = ()
    attrs_format: AttrsFormat = AttrsFormat.NORMALIZED
    only_changed_attrs: bool = False
    covered: bool = False
    metadata: tuple[str, ...] = ()
    max_fails_limit: int | None = None


@dataclass(frozen=True)
class Subscription:
    id: str
    tenant: Tenant
    entities: tuple[EntitySelector, ...]
    notification: Notification
    condition: Condition = field(default_factory=Condition)
    description: str | None = None
    expires: float | None = None
    status: Status = Status.ACTIVE
    throttling: int = 0
    #: the service paths it watches, from ``tenant.service_path`` read as a query (see .scope)
    scope: ReadScope = field(default_factory=ReadScope)
    #: the principal that created it (None: plantkg's own token), see .ownership; never rendered
    owner: str | None = None


@dataclass(frozen=True)
class DeliveryStatus:
    """What delivery has done for one subscription (Orion's read-only notification fields, plus
    ``dropped``: notifications thrown away because the subscription's queue was full)."""

    times_sent: int = 0
    last_notification: float | None = None
    last_success: float | None = None
    last_success_code: int | None = None
    last_failure: float | None = None
    last_failure_reason: str | None = None
    fails_counter: int = 0
    dropped: int = 0

    def as_json(self) -> dict[str, Any]:
        return {k: v for k, v in self.__dict__.items()}

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> DeliveryStatus:
        known = {k: data[k] for k in cls.__dataclass_fields__ if k in data}
        return cls(**known)


def iso(ts: float) -> str:
    """Orion's timestamp form: ``2026-11-24T16:30:00.000Z``."""
    return from_epoch(ts)


def shown_status(sub: Subscription, delivery: DeliveryStatus, now: float) -> str:
    """``expired`` once ``expires`` has passed (whatever the stored status); ``failed`` while an
    active subscription's last attempt failed (NGSIv2's original meaning, back to ``active`` on the
    next success; Orion 3.4+ shows ``active`` and only ``failsCounter``); else the stored status."""
    if sub.expires is not None and now >= sub.expires:
        return "expired"
    if sub.status is Status.ACTIVE and delivery.fails_counter > 0:
        return "failed"
    return sub.status.value


def _render_target(target: Target) -> tuple[str, dict[str, Any]]:
    if isinstance(target, HttpTarget):
        if not target.custom:
            body: dict[str, Any] = {"url": target.url}
            if target.timeout_ms:
                body["timeout"] = target.timeout_ms
            return "http", body
        body = {"url": target.url}
        if target.headers:
            body["headers"] = dict(target.headers)
        if target.qs:
            body["qs"] = dict(target.qs)
        if target.method != "POST":
            body["method"] = target.method
        if target.timeout_ms:
            body["timeout"] = target.timeout_ms
        return "httpCustom", body
    if isinstance(target, MqttTarget):
        body = {"url": target.url, "topic": target.topic, "qos": target.qos,
                "retain": target.retain}
        if target.user is not None:
            body["user"] = target.user
            body["passwd"] = "*****"  # Orion never shows it back
        return "mqtt", body
    body = {"url": target.url, "topic": target.topic}
    if target.key is not None:
        body["key"] = target.key
    return "kafka", body


def _render_entity(sel: EntitySelector) -> dict[str, str]:
    out: dict[str, str] = {}
    if sel.id is not None:
        out["id"] = sel.id
    if sel.id_pattern is not None:
        out["idPattern"] = sel.id_pattern
    if sel.type is not None:
        out["type"] = sel.type
    if sel.type_pattern is not None:
        out["typePattern"] = sel.type_pattern
    return out


def render(sub: Subscription, delivery: DeliveryStatus, now: float) -> dict[str, Any]:
    """The subscription as ``GET /v2/subscriptions/{id}`` shows it (Orion's field order)."""
    out: dict[str, Any] = {"id": sub.id}
    if sub.description is not None:
        out["description"] = sub.description
    condition: dict[str, Any] = {"attrs": list(sub.condition.attrs),
                                 "notifyOnMetadataChange": sub.condition.notify_on_metadata_change}
    expression = {k: v for k, v in (("q", sub.condition.q), ("mq", sub.condition.mq)) if v is not None}
    if expression:
        condition["expression"] = expression
    if sub.condition.alterations_given:
        condition["alterationTypes"] = sorted(a.value for a in sub.condition.alterations)
    out["subject"] = {"entities": [_render_entity(e) for e in sub.entities],
                      "condition": condition}
    n = sub.notification
    kind, target = _render_target(n.target)
    notification: dict[str, Any] = {}
    if n.except_attrs:
        notification["exceptAttrs"] = list(n.except_attrs)
    else:
        notification["attrs"] = list(n.attrs)
    notification["onlyChangedAttrs"] = n.only_changed_attrs
    notification["attrsFormat"] = n.attrs_format.value
    notification[kind] = target
    if n.metadata:
        notification["metadata"] = list(n.metadata)
    notification["covered"] = n.covered
    if n.max_fails_limit is not None:
        notification["maxFailsLimit"] = n.max_fails_limit
    _render_delivery(notification, delivery, http=isinstance(n.target, HttpTarget))
    out["notification"] = notification
    if sub.expires is not None:
        out["expires"] = iso(sub.expires)
    out["status"] = shown_status(sub, delivery, now)
    if sub.throttling:
        out["throttling"] = sub.throttling
    return out


def _render_delivery(out: dict[str, Any], d: DeliveryStatus, *, http: bool) -> None:
    """Orion's read-only fields, each present only once it has a value; ``lastSuccessCode`` only for
    HTTP (as Orion). ``lastFailureReason`` also for MQTT and Kafka (Orion leaves it out there; the
    reason helps) and ``droppedNotifications`` are plantkg's own."""
    if d.times_sent:
        out["timesSent"] = d.times_sent
    if d.last_notification is not None:
        out["lastNotification"] = iso(d.last_notification)
    if d.last_failure is not None:
        out["lastFailure"] = iso(d.last_failure)
        if d.last_failure_reason:
            out["lastFailureReason"] = d.last_failure_reason
    if d.last_success is not None:
        out["lastSuccess"] = iso(d.last_success)
        if http and d.last_success_code is not None:
            out["lastSuccessCode"] = d.last_success_code
    if d.fails_counter:
        out["failsCounter"] = d.fails_counter
    if d.dropped:
        out["droppedNotifications"] = d.dropped

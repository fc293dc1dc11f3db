"""Parse and validate a subscription's JSON (``POST`` body, or a stored body after ``PATCH``).

Every refusal is an :class:`NgsiError` 400 whose description starts with the offending field's
path (``notification.mqtt.qos: ...``) and says what is allowed, so a client never has to guess
(Orion's most heard complaint is a bare "Invalid characters"). Orion features plantkg does not
implement (geo-queries, JEXL, ``mqttCustom``, ``kafkaCustom``, custom payloads, Kafka SASL)
are refused by name rather than silently ignored (:mod:`.fields`); the transports are checked in
:mod:`.parse_targets`. The read-only delivery fields a client may echo back from a ``GET`` (``timesSent``, ``lastSuccess``, ...) are ignored, as Orion does.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from engine.context_broker.contract import NgsiError, Tenant, bad_request
from engine.context_broker.dates import parse_datetime
from engine.context_broker.subscriptions.fields import (
    boolean, fail, integer, json_object, kind_of, name_list, only_known, regex_field, text_field,
)
from engine.context_broker.subscriptions.model import (
    DEFAULT_ALTERATIONS, Alteration, AttrsFormat, Condition, EntitySelector, Notification, Status,
    Subscription, Target,
)
from engine.context_broker.subscriptions.parse_targets import http_target, kafka_target, mqtt_target
from engine.context_broker.subscriptions.scope import scope_of

MAX_DESCRIPTION = 1024
READ_ONLY = frozenset({"timesSent", "lastNotification", "lastFailure", "lastFailureReason",
                       "lastSuccess", "lastSuccessCode", "failsCounter", "droppedNotifications"})
#: ``parse_q(text)`` for ``q``, ``parse_q(text, metadata=True)`` for ``mq`` (engine.context_broker.q).
QParser = Callable[..., Any]


def parse_expires(value: Any, path: str = "expires") -> float:
    """An ISO 8601 date or date-time as Orion reads it (``Z`` or an offset; none means UTC), as
    epoch seconds."""
    if not isinstance(value, str) or not value:
        raise fail(path, f"must be an ISO 8601 date-time string, got {kind_of(value)}")
    dt = parse_datetime(value)
    if dt is None:
        raise fail(path, f"{value!r} is not an ISO 8601 date-time (e.g. "
                          "2030-04-05T14:00:00.000Z)")
    return dt.timestamp()


def _entities(value: Any) -> tuple[EntitySelector, ...]:
    path = "subject.entities"
    if value is None:
        raise fail(path, "missing: give at least one {id|idPattern, type|typePattern}")
    if not isinstance(value, list):
        raise fail(path, f"must be an array, got {kind_of(value)}")
    if not value:
        raise fail(path, "must not be empty")
    out = []
    for i, item in enumerate(value):
        where = f"{path}[{i}]"
        obj = json_object(item, where)
        only_known(obj, where, {"id", "idPattern", "type", "typePattern"})
        if ("id" in obj) == ("idPattern" in obj):
            raise fail(where, "give exactly one of id and idPattern")
        if "type" in obj and "typePattern" in obj:
            raise fail(where, "give at most one of type and typePattern")
        out.append(EntitySelector(
            id=text_field(obj["id"], f"{where}.id") if "id" in obj else None,
            id_pattern=regex_field(obj["idPattern"], f"{where}.idPattern") if "idPattern" in obj else None,
            type=text_field(obj["type"], f"{where}.type") if "type" in obj else None,
            type_pattern=(regex_field(obj["typePattern"], f"{where}.typePattern")
                          if "typePattern" in obj else None),
        ))
    return tuple(out)


def _condition(value: Any, parse_q: QParser) -> Condition:
    path = "subject.condition"
    obj = json_object(value, path)
    if not obj:
        raise fail(path, "must not be empty: leave it out to notify on any attribute")
    only_known(obj, path, {"attrs", "expression", "alterationTypes", "notifyOnMetadataChange"})
    attrs = name_list(obj["attrs"], f"{path}.attrs") if "attrs" in obj else ()
    q = mq = None
    if "expression" in obj:
        expr = json_object(obj["expression"], f"{path}.expression")
        only_known(expr, f"{path}.expression", {"q", "mq"})
        if not expr:
            raise fail(f"{path}.expression", "must not be empty: give q or mq")
        q = _query(expr, "q", path, parse_q)
        mq = _query(expr, "mq", path, parse_q)
    alterations, given = DEFAULT_ALTERATIONS, False
    if "alterationTypes" in obj:
        names = name_list(obj["alterationTypes"], f"{path}.alterationTypes", allow_empty=False)
        known = {a.value: a for a in Alteration}
        for i, name in enumerate(names):
            if name not in known:
                raise fail(f"{path}.alterationTypes[{i}]", f"unknown alteration type {name!r} "
                            f"(allowed: {', '.join(known)})")
        alterations, given = frozenset(known[n] for n in names), True
    notify_md = (boolean(obj["notifyOnMetadataChange"], f"{path}.notifyOnMetadataChange")
                 if "notifyOnMetadataChange" in obj else True)
    if not notify_md:
        raise fail(f"{path}.notifyOnMetadataChange", "false is not supported by plantkg's context "
                    "broker (a write reports the attributes it wrote, not whether only metadata "
                    "changed); leave it out or set it true")
    return Condition(attrs, q, alterations, given, notify_md, mq)


def _query(expr: Mapping[str, Any], name: str, path: str, parse_q: QParser) -> str | None:
    if name not in expr:
        return None
    text = expr[name]
    where = f"{path}.expression.{name}"
    if not isinstance(text, str) or not text.strip():
        raise fail(where, f"must be a non-empty string, got {text!r}")
    try:
        parse_q(text, metadata=True) if name == "mq" else parse_q(text)
    except NgsiError as err:
        raise fail(where, err.description) from None
    return text


def _notification(value: Any) -> Notification:
    path = "notification"
    obj = json_object(value, path)
    only_known(obj, path, {"http", "httpCustom", "mqtt", "kafka", "attrs", "exceptAttrs", "attrsFormat",
                       "onlyChangedAttrs", "covered", "metadata", "maxFailsLimit"}, READ_ONLY)
    kinds = [k for k in ("http", "httpCustom", "mqtt", "kafka") if k in obj]
    if len(kinds) != 1:
        raise fail(path, "give exactly one of http, httpCustom, mqtt, kafka" +
                    (f" (got {', '.join(kinds)})" if kinds else ""))
    kind = kinds[0]
    body = json_object(obj[kind], f"{path}.{kind}")
    target: Target
    if kind in ("http", "httpCustom"):
        target = http_target(body, f"{path}.{kind}", custom=kind == "httpCustom")
    elif kind == "mqtt":
        target = mqtt_target(body)
    else:
        target = kafka_target(body)
    if "attrs" in obj and "exceptAttrs" in obj:
        raise fail(path, "give at most one of attrs and exceptAttrs")
    attrs = name_list(obj["attrs"], f"{path}.attrs") if "attrs" in obj else ()
    except_attrs = (name_list(obj["exceptAttrs"], f"{path}.exceptAttrs", allow_empty=False)
                    if "exceptAttrs" in obj else ())
    fmt = AttrsFormat.NORMALIZED
    if "attrsFormat" in obj:
        formats = {f.value: f for f in AttrsFormat}
        if not isinstance(obj["attrsFormat"], str) or obj["attrsFormat"] not in formats:
            raise fail(f"{path}.attrsFormat", f"{obj['attrsFormat']!r} is not one of "
                                               f"{', '.join(formats)}")
        fmt = formats[obj["attrsFormat"]]
    covered = boolean(obj["covered"], f"{path}.covered") if "covered" in obj else False
    if covered and not attrs:
        raise fail(f"{path}.covered", "covered true cannot be used if notification attributes "
                                       "list is empty")
    return Notification(
        target=target, attrs=attrs, except_attrs=except_attrs, attrs_format=fmt,
        only_changed_attrs=(boolean(obj["onlyChangedAttrs"], f"{path}.onlyChangedAttrs")
                            if "onlyChangedAttrs" in obj else False),
        covered=covered,
        metadata=name_list(obj["metadata"], f"{path}.metadata") if "metadata" in obj else (),
        max_fails_limit=(integer(obj["maxFailsLimit"], f"{path}.maxFailsLimit", 1)
                         if "maxFailsLimit" in obj else None),
    )


def parse_subscription(doc: Any, *, sub_id: str, tenant: Tenant, parse_q: QParser) -> Subscription:
    """The subscription a JSON document describes, or :class:`NgsiError` 400 naming the field.
    ``parse_q`` checks ``subject.condition.expression.q`` (raises :class:`NgsiError` 400)."""
    obj = json_object(doc, "subscription")
    if not obj:
        raise bad_request("empty payload: a subscription needs subject and notification")
    only_known(obj, "", {"description", "subject", "notification", "expires", "status", "throttling"},
           frozenset({"id"}))
    if "subject" not in obj:
        raise fail("subject", "missing: no subject for subscription specified")
    if "notification" not in obj:
        raise fail("notification", "missing: no notification for subscription specified")
    subject = json_object(obj["subject"], "subject")
    only_known(subject, "subject", {"entities", "condition"})
    status = Status.ACTIVE
    if "status" in obj:
        values = {s.value: s for s in Status}
        if not isinstance(obj["status"], str) or obj["status"] not in values:
            raise fail("status", f"{obj['status']!r} is not valid: it has to be either active, "
                                  "inactive or oneshot")
        status = values[obj["status"]]
    return Subscription(
        id=sub_id, tenant=tenant, scope=scope_of(tenant),
        entities=_entities(subject.get("entities")),
        condition=_condition(subject["condition"], parse_q) if "condition" in subject else Condition(),
        notification=_notification(obj["notification"]),
        description=(text_field(obj["description"], "description", max_len=MAX_DESCRIPTION, free_text=True)
                     if "description" in obj else None),
        expires=parse_expires(obj["expires"]) if "expires" in obj else None,
        status=status,
        throttling=integer(obj["throttling"], "throttling", 0) if "throttling" in obj else 0,
    )


def merge_patch(stored: Mapping[str, Any], patch: Any) -> dict[str, Any]:
    """Orion's ``PATCH``: each top-level field given replaces the stored one (``subject`` and
    ``notification`` as wholes). The result is parsed again before anything is stored."""
    obj = json_object(patch, "subscription")
    if not obj:
        raise bad_request("empty payload: give the fields to change")
    merged = dict(stored)
    merged.update(obj)
    merged.pop("id", None)
    return merged

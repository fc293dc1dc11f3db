"""Parse and validate a subscription's JSON (``POST`` body, or a stored body after ``PATCH``).

Every refusal is an :class:`NgsiError` 400 whose description starts with the offending field's
path (``notification.mqtt.qos: ...``) and says what is allowed, so a client never has to guess
(Orion's most heard complaint is a bare "Invalid characters"). Orion features plantkg does not
implement (geo-queries, JEXL, ``mqttCustom``, ``kafkaCustom``, custom payloads, Kafka SASL) are refused by name rather than silently ignored. The read-only delivery fields a client may
echo back from a ``GET`` (``timesSent``, ``lastSuccess``, ...) are ignored, as Orion does.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from typing import Any
from urllib.parse import urlsplit

from engine.context_broker.contract import NgsiError, Tenant, bad_request
from engine.context_broker.dates import parse_datetime
from engine.context_broker.subscriptions.model import (
    Alteration, AttrsFormat, Condition, DEFAULT_ALTERATIONS, EntitySelector, HttpTarget,
    KafkaTarget, MqttTarget, Notification, Status, Subscription, Target,
)

MAX_DESCRIPTION = 1024
MAX_ID = 256
MAX_HTTP_TIMEOUT_MS = 1_800_000
#: Orion's forbidden characters in identifiers and free text (its "Invalid characters").
FORBIDDEN = set('<>"\'=;()')
HTTP_METHODS = ("GET", "PUT", "POST", "DELETE", "PATCH", "HEAD", "OPTIONS", "TRACE", "CONNECT")
READ_ONLY = frozenset({"timesSent", "lastNotification", "lastFailure", "lastFailureReason",
                       "lastSuccess", "lastSuccessCode", "failsCounter", "droppedNotifications"})
NOT_SUPPORTED = {
    "mqttCustom": "use notification.mqtt (custom MQTT payloads are not implemented)",
    "kafkaCustom": "use notification.kafka (custom Kafka payloads are not implemented)",
    "jexlExpression": "use expression.q",
    "georel": "geo-queries are not implemented",
    "geometry": "geo-queries are not implemented",
    "coords": "geo-queries are not implemented",
    "payload": "custom payloads are not implemented; the notification is Orion's default",
    "json": "custom payloads are not implemented; the notification is Orion's default",
    "ngsi": "custom payloads are not implemented; the notification is Orion's default",
}
KAFKA_TOPIC = re.compile(r"[A-Za-z0-9._-]{1,249}")
#: ``parse_q(text)`` for ``q``, ``parse_q(text, metadata=True)`` for ``mq`` (engine.context_broker.q).
QParser = Callable[..., Any]


def _fail(path: str, message: str) -> NgsiError:
    return bad_request(f"{path}: {message}")


def _object(value: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise _fail(path, f"must be a JSON object, got {_kind(value)}")
    return value


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    return {bool: "a boolean", str: "a string", int: "a number", float: "a number",
            list: "an array", dict: "an object"}.get(type(value), type(value).__name__)


def _known(obj: Mapping[str, Any], path: str, allowed: set[str], ignored: frozenset[str] = frozenset()) -> None:
    for key in obj:
        if key in allowed or key in ignored:
            continue
        where = f"{path}.{key}" if path else key
        if key in NOT_SUPPORTED:
            raise _fail(where, f"not supported by plantkg's context broker: {NOT_SUPPORTED[key]}")
        raise _fail(where, f"unknown field (allowed here: {', '.join(sorted(allowed))})")


def _string(value: Any, path: str, *, max_len: int = MAX_ID, free_text: bool = False) -> str:
    if not isinstance(value, str):
        raise _fail(path, f"must be a string, got {_kind(value)}")
    if not value:
        raise _fail(path, "must not be empty")
    if len(value) > max_len:
        raise _fail(path, f"at most {max_len} characters, got {len(value)}")
    for i, char in enumerate(value):
        if char in FORBIDDEN or (not free_text and (char.isspace() or not char.isprintable())):
            raise _fail(path, f"forbidden character {char!r} at position {i} (not allowed: "
                              f"{''.join(sorted(FORBIDDEN))}" + ("" if free_text else ", whitespace")
                              + ")")
    return value


def _pattern(value: Any, path: str) -> str:
    """A regular expression (Orion's character restrictions do not apply to patterns)."""
    if not isinstance(value, str) or not value:
        raise _fail(path, f"must be a non-empty string, got {value!r}")
    text = value
    try:
        re.compile(text)
    except re.error as err:
        raise _fail(path, f"not a valid regular expression: {err}") from None
    return text


def _bool(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise _fail(path, f"must be true or false, got {_kind(value)}")
    return value


def _int(value: Any, path: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise _fail(path, f"must be an integer, got {value!r}")
    if value < low or (high is not None and value > high):
        bound = f"from {low} to {high}" if high is not None else f"at least {low}"
        raise _fail(path, f"must be an integer {bound}, got {value}")
    return value


def _names(value: Any, path: str, *, allow_empty: bool = True) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise _fail(path, f"must be an array of attribute names, got {_kind(value)}")
    if not value and not allow_empty:
        raise _fail(path, "must not be empty")
    return tuple(_string(v, f"{path}[{i}]") for i, v in enumerate(value))


def parse_expires(value: Any, path: str = "expires") -> float:
    """An ISO 8601 date or date-time as Orion reads it (``Z`` or an offset; none means UTC), as
    epoch seconds."""
    if not isinstance(value, str) or not value:
        raise _fail(path, f"must be an ISO 8601 date-time string, got {_kind(value)}")
    dt = parse_datetime(value)
    if dt is None:
        raise _fail(path, f"{value!r} is not an ISO 8601 date-time (e.g. "
                          "2030-04-05T14:00:00.000Z)")
    return dt.timestamp()


def _entities(value: Any) -> tuple[EntitySelector, ...]:
    path = "subject.entities"
    if value is None:
        raise _fail(path, "missing: give at least one {id|idPattern, type|typePattern}")
    if not isinstance(value, list):
        raise _fail(path, f"must be an array, got {_kind(value)}")
    if not value:
        raise _fail(path, "must not be empty")
    out = []
    for i, item in enumerate(value):
        where = f"{path}[{i}]"
        obj = _object(item, where)
        _known(obj, where, {"id", "idPattern", "type", "typePattern"})
        if ("id" in obj) == ("idPattern" in obj):
            raise _fail(where, "give exactly one of id and idPattern")
        if "type" in obj and "typePattern" in obj:
            raise _fail(where, "give at most one of type and typePattern")
        out.append(EntitySelector(
            id=_string(obj["id"], f"{where}.id") if "id" in obj else None,
            id_pattern=_pattern(obj["idPattern"], f"{where}.idPattern") if "idPattern" in obj else None,
            type=_string(obj["type"], f"{where}.type") if "type" in obj else None,
            type_pattern=(_pattern(obj["typePattern"], f"{where}.typePattern")
                          if "typePattern" in obj else None),
        ))
    return tuple(out)


def _condition(value: Any, parse_q: QParser) -> Condition:
    path = "subject.condition"
    obj = _object(value, path)
    if not obj:
        raise _fail(path, "must not be empty: leave it out to notify on any attribute")
    _known(obj, path, {"attrs", "expression", "alterationTypes", "notifyOnMetadataChange"})
    attrs = _names(obj["attrs"], f"{path}.attrs") if "attrs" in obj else ()
    q = mq = None
    if "expression" in obj:
        expr = _object(obj["expression"], f"{path}.expression")
        _known(expr, f"{path}.expression", {"q", "mq"})
        if not expr:
            raise _fail(f"{path}.expression", "must not be empty: give q or mq")
        q = _query(expr, "q", path, parse_q)
        mq = _query(expr, "mq", path, parse_q)
    alterations, given = DEFAULT_ALTERATIONS, False
    if "alterationTypes" in obj:
        names = _names(obj["alterationTypes"], f"{path}.alterationTypes", allow_empty=False)
        known = {a.value: a for a in Alteration}
        for i, name in enumerate(names):
            if name not in known:
                raise _fail(f"{path}.alterationTypes[{i}]", f"unknown alteration type {name!r} "
                            f"(allowed: {', '.join(known)})")
        alterations, given = frozenset(known[n] for n in names), True
    notify_md = (_bool(obj["notifyOnMetadataChange"], f"{path}.notifyOnMetadataChange")
                 if "notifyOnMetadataChange" in obj else True)
    if not notify_md:
        raise _fail(f"{path}.notifyOnMetadataChange", "false is not supported by plantkg's context "
                    "broker (a write reports the attributes it wrote, not whether only metadata "
                    "changed); leave it out or set it true")
    return Condition(attrs, q, alterations, given, notify_md, mq)


def _query(expr: Mapping[str, Any], name: str, path: str, parse_q: QParser) -> str | None:
    if name not in expr:
        return None
    text = expr[name]
    where = f"{path}.expression.{name}"
    if not isinstance(text, str) or not text.strip():
        raise _fail(where, f"must be a non-empty string, got {text!r}")
    try:
        parse_q(text, metadata=True) if name == "mq" else parse_q(text)
    except NgsiError as err:
        raise _fail(where, err.description) from None
    return text


def _http_url(value: Any, path: str) -> str:
    url = _string(value, path, max_len=2048)
    parts = urlsplit(url)
    if parts.scheme in ("mqtt", "kafka"):
        raise _fail(path, f"{parts.scheme} URL cannot be used in HTTP notifications (use "
                          f"notification.{parts.scheme})")
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise _fail(path, f"{url!r} is not an http:// or https:// URL with a host")
    try:
        parts.port
    except ValueError as err:
        raise _fail(path, f"bad port in {url!r}: {err}") from None
    return url


def _key_map(value: Any, path: str) -> tuple[tuple[str, str], ...]:
    obj = _object(value, path)
    if not obj:
        raise _fail(path, "must not be empty (leave it out instead)")
    out = []
    for key, val in obj.items():
        _string(key, f"{path} (a name)", max_len=256)
        if not isinstance(val, str):
            raise _fail(f"{path}.{key}", f"must be a string, got {_kind(val)}")
        if any(c in "\r\n" for c in val):
            raise _fail(f"{path}.{key}", "must not contain a line break")
        out.append((key, val))
    return tuple(out)


def _http(obj: Mapping[str, Any], path: str, custom: bool) -> HttpTarget:
    allowed = {"url", "timeout"} | ({"headers", "qs", "method"} if custom else set())
    _known(obj, path, allowed)
    if "url" not in obj:
        raise _fail(f"{path}.url", "missing")
    method = "POST"
    if "method" in obj:
        method = obj["method"]
        if method not in HTTP_METHODS:
            raise _fail(f"{path}.method", f"unknown method {method!r} (allowed: {', '.join(HTTP_METHODS)})")
    return HttpTarget(
        url=_http_url(obj["url"], f"{path}.url"), custom=custom,
        headers=_key_map(obj["headers"], f"{path}.headers") if "headers" in obj else (),
        qs=_key_map(obj["qs"], f"{path}.qs") if "qs" in obj else (),
        method=method,
        timeout_ms=_int(obj["timeout"], f"{path}.timeout", 0, MAX_HTTP_TIMEOUT_MS) if "timeout" in obj else 0,
    )


def _broker_url(value: Any, path: str, scheme: str) -> tuple[str, list[tuple[str, int]]]:
    url = _string(value, path, max_len=2048)
    prefix = f"{scheme}://"
    if not url.startswith(prefix):
        raise _fail(path, f"{url!r} must start with {prefix} (e.g. {prefix}127.0.0.1:"
                          f"{1883 if scheme == 'mqtt' else 9092})")
    rest = url[len(prefix):].rstrip("/")
    if "/" in rest or "?" in rest:
        raise _fail(path, f"path cannot be used in a {scheme} url, use topic instead")
    hosts = rest.split(",") if scheme == "kafka" else [rest]
    out = []
    for item in hosts:
        parts = urlsplit(f"//{item}")
        try:
            port = parts.port
        except ValueError:
            raise _fail(path, f"bad port in {item!r}") from None
        if not parts.hostname or parts.username or parts.password:
            raise _fail(path, f"{item!r} is not host:port")
        if port is None:
            if scheme == "kafka":
                raise _fail(path, f"{item!r} needs a port (host:port)")
            port = 1883
        out.append((parts.hostname, port))
    return url, out


def _mqtt(obj: Mapping[str, Any]) -> MqttTarget:
    path = "notification.mqtt"
    _known(obj, path, {"url", "topic", "qos", "retain", "user", "passwd"})
    for name in ("url", "topic"):
        if name not in obj:
            raise _fail(f"{path}.{name}", "missing")
    url, [(host, port)] = _broker_url(obj["url"], f"{path}.url", "mqtt")
    topic = obj["topic"]
    if not isinstance(topic, str) or not topic:
        raise _fail(f"{path}.topic", f"must be a non-empty string, got {topic!r}")
    for i, char in enumerate(topic):
        if char in "+#" or char == "\0":
            raise _fail(f"{path}.topic", f"{char!r} at position {i}: + and # are not allowed in a "
                                         "topic to publish to")
    if ("user" in obj) != ("passwd" in obj):
        raise _fail(path, "user and passwd go together")
    return MqttTarget(
        url=url, host=host, port=port, topic=topic,
        qos=_int(obj["qos"], f"{path}.qos", 0, 2) if "qos" in obj else 0,
        retain=_bool(obj["retain"], f"{path}.retain") if "retain" in obj else False,
        user=_string(obj["user"], f"{path}.user") if "user" in obj else None,
        passwd=_string(obj["passwd"], f"{path}.passwd", free_text=True) if "passwd" in obj else None,
    )


def _kafka(obj: Mapping[str, Any]) -> KafkaTarget:
    path = "notification.kafka"
    sasl = {"user", "passwd", "saslMechanism", "securityProtocol"}
    for name in sasl & set(obj):
        raise _fail(f"{path}.{name}", "not supported by plantkg's context broker: Kafka SASL "
                                      "authentication is not implemented")
    _known(obj, path, {"url", "topic", "key"})
    for name in ("url", "topic"):
        if name not in obj:
            raise _fail(f"{path}.{name}", "missing")
    url, hosts = _broker_url(obj["url"], f"{path}.url", "kafka")
    topic = obj["topic"]
    if not isinstance(topic, str) or not KAFKA_TOPIC.fullmatch(topic) or topic in (".", ".."):
        raise _fail(f"{path}.topic", f"{topic!r} is not a Kafka topic name (1 to 249 of "
                                     "A-Z a-z 0-9 . _ -)")
    key = obj.get("key")
    if key is not None:
        key = _string(key, f"{path}.key", free_text=True)
    return KafkaTarget(url=url, bootstrap=",".join(f"{h}:{p}" for h, p in hosts), topic=topic, key=key)


def _notification(value: Any) -> Notification:
    path = "notification"
    obj = _object(value, path)
    _known(obj, path, {"http", "httpCustom", "mqtt", "kafka", "attrs", "exceptAttrs", "attrsFormat",
                       "onlyChangedAttrs", "covered", "metadata", "maxFailsLimit"}, READ_ONLY)
    kinds = [k for k in ("http", "httpCustom", "mqtt", "kafka") if k in obj]
    if len(kinds) != 1:
        raise _fail(path, "give exactly one of http, httpCustom, mqtt, kafka" +
                    (f" (got {', '.join(kinds)})" if kinds else ""))
    kind = kinds[0]
    body = _object(obj[kind], f"{path}.{kind}")
    target: Target
    if kind in ("http", "httpCustom"):
        target = _http(body, f"{path}.{kind}", custom=kind == "httpCustom")
    elif kind == "mqtt":
        target = _mqtt(body)
    else:
        target = _kafka(body)
    if "attrs" in obj and "exceptAttrs" in obj:
        raise _fail(path, "give at most one of attrs and exceptAttrs")
    attrs = _names(obj["attrs"], f"{path}.attrs") if "attrs" in obj else ()
    except_attrs = (_names(obj["exceptAttrs"], f"{path}.exceptAttrs", allow_empty=False)
                    if "exceptAttrs" in obj else ())
    fmt = AttrsFormat.NORMALIZED
    if "attrsFormat" in obj:
        formats = {f.value: f for f in AttrsFormat}
        if obj["attrsFormat"] not in formats:
            raise _fail(f"{path}.attrsFormat", f"{obj['attrsFormat']!r} is not one of "
                                               f"{', '.join(formats)}")
        fmt = formats[obj["attrsFormat"]]
    covered = _bool(obj["covered"], f"{path}.covered") if "covered" in obj else False
    if covered and not attrs:
        raise _fail(f"{path}.covered", "covered true cannot be used if notification attributes "
                                       "list is empty")
    return Notification(
        target=target, attrs=attrs, except_attrs=except_attrs, attrs_format=fmt,
        only_changed_attrs=(_bool(obj["onlyChangedAttrs"], f"{path}.onlyChangedAttrs")
                            if "onlyChangedAttrs" in obj else False),
        covered=covered,
        metadata=_names(obj["metadata"], f"{path}.metadata") if "metadata" in obj else (),
        max_fails_limit=(_int(obj["maxFailsLimit"], f"{path}.maxFailsLimit", 1)
                         if "maxFailsLimit" in obj else None),
    )


def parse_subscription(doc: Any, *, sub_id: str, tenant: Tenant, parse_q: QParser) -> Subscription:
    """The subscription a JSON document describes, or :class:`NgsiError` 400 naming the field.
    ``parse_q`` checks ``subject.condition.expression.q`` (raises :class:`NgsiError` 400)."""
    obj = _object(doc, "subscription")
    if not obj:
        raise bad_request("empty payload: a subscription needs subject and notification")
    _known(obj, "", {"description", "subject", "notification", "expires", "status", "throttling"},
           frozenset({"id"}))
    if "subject" not in obj:
        raise _fail("subject", "missing: no subject for subscription specified")
    if "notification" not in obj:
        raise _fail("notification", "missing: no notification for subscription specified")
    subject = _object(obj["subject"], "subject")
    _known(subject, "subject", {"entities", "condition"})
    status = Status.ACTIVE
    if "status" in obj:
        values = {s.value: s for s in Status}
        if obj["status"] not in values:
            raise _fail("status", f"{obj['status']!r} is not valid: it has to be either active, "
                                  "inactive or oneshot")
        status = values[obj["status"]]
    return Subscription(
        id=sub_id, tenant=tenant,
        entities=_entities(subject.get("entities")),
        condition=_condition(subject["condition"], parse_q) if "condition" in subject else Condition(),
        notification=_notification(obj["notification"]),
        description=(_string(obj["description"], "description", max_len=MAX_DESCRIPTION, free_text=True)
                     if "description" in obj else None),
        expires=parse_expires(obj["expires"]) if "expires" in obj else None,
        status=status,
        throttling=_int(obj["throttling"], "throttling", 0) if "throttling" in obj else 0,
    )


def merge_patch(stored: Mapping[str, Any], patch: Any) -> dict[str, Any]:
    """Orion's ``PATCH``: each top-level field given replaces the stored one (``subject`` and
    ``notification`` as wholes). The result is parsed again before anything is stored."""
    obj = _object(patch, "subscription")
    if not obj:
        raise bad_request("empty payload: give the fields to change")
    merged = dict(stored)
    merged.update(obj)
    merged.pop("id", None)
    return merged

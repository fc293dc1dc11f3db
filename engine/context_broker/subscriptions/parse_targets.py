"""The transports of ``notification``: ``http``, ``httpCustom``, ``mqtt``, ``kafka``.

URLs as Orion checks them: ``http(s)://host[:port]/...`` for HTTP (an ``mqtt://`` or ``kafka://``
URL there is refused with the field to use instead), ``mqtt://host[:port]`` (``mqtts://``: over
TLS, the broker's certificate verified against the plant CA) and
``kafka://host:port[,host:port]`` with no path. MQTT topics to publish to hold no ``+``/``#``;
Kafka topic names are Kafka's legal ones. Header values hold no line breaks.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any
from urllib.parse import urlsplit

from engine.context_broker.subscriptions.fields import (
    boolean, fail, integer, json_object, kind_of, only_known, text_field,
)
from engine.context_broker.subscriptions.model import HttpTarget, KafkaTarget, MqttTarget

MAX_HTTP_TIMEOUT_MS = 1_800_000
HTTP_METHODS = ("GET", "PUT", "POST", "DELETE", "PATCH", "HEAD", "OPTIONS", "TRACE", "CONNECT")
#: A broker URL's port when it names none; ``mqtts://`` is MQTT over TLS (plantkg's extension).
DEFAULT_PORTS = {"mqtt": 1883, "mqtts": 8883, "kafka": 9092}
KAFKA_TOPIC = re.compile(r"[A-Za-z0-9._-]{1,249}")

def _http_url(value: Any, path: str) -> str:
    """Orion's rule: no ``<>"'=;()`` in a notification URL, so query parameters with values go
    in ``httpCustom.qs``."""
    if isinstance(value, str) and "?" in value and "=" in value.split("?", 1)[1]:
        raise fail(path, f"forbidden character '=' in the query of {value!r}: give query "
                         "parameters in notification.httpCustom.qs instead (as Orion)")
    url = text_field(value, path, max_len=2048)
    parts = urlsplit(url)
    if parts.scheme in ("mqtt", "kafka"):
        raise fail(path, f"{parts.scheme} URL cannot be used in HTTP notifications (use "
                          f"notification.{parts.scheme})")
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise fail(path, f"{url!r} is not an http:// or https:// URL with a host")
    try:
        parts.port
    except ValueError as err:
        raise fail(path, f"bad port in {url!r}: {err}") from None
    return url


def _key_map(value: Any, path: str) -> tuple[tuple[str, str], ...]:
    obj = json_object(value, path)
    if not obj:
        raise fail(path, "must not be empty (leave it out instead)")
    out = []
    for key, val in obj.items():
        text_field(key, f"{path} (a name)", max_len=256)
        if not isinstance(val, str):
            raise fail(f"{path}.{key}", f"must be a string, got {kind_of(val)}")
        if any(c in "\r\n" for c in val):
            raise fail(f"{path}.{key}", "must not contain a line break")
        out.append((key, val))
    return tuple(out)


def http_target(obj: Mapping[str, Any], path: str, custom: bool) -> HttpTarget:
    allowed = {"url", "timeout"} | ({"headers", "qs", "method"} if custom else set())
    only_known(obj, path, allowed)
    if "url" not in obj:
        raise fail(f"{path}.url", "missing")
    method = "POST"
    if "method" in obj:
        method = obj["method"]
        if method not in HTTP_METHODS:
            raise fail(f"{path}.method", f"unknown method {method!r} (allowed: {', '.join(HTTP_METHODS)})")
    return HttpTarget(
        url=_http_url(obj["url"], f"{path}.url"), custom=custom,
        headers=_key_map(obj["headers"], f"{path}.headers") if "headers" in obj else (),
        qs=_key_map(obj["qs"], f"{path}.qs") if "qs" in obj else (),
        method=method,
        timeout_ms=integer(obj["timeout"], f"{path}.timeout", 0, MAX_HTTP_TIMEOUT_MS) if "timeout" in obj else 0,
    )


def _broker_url(value: Any, path: str, scheme: str) -> tuple[str, list[tuple[str, int]]]:
    url = text_field(value, path, max_len=2048)
    prefix = f"{scheme}://"
    if not url.startswith(prefix):
        raise fail(path, f"{url!r} must start with {prefix} (e.g. {prefix}127.0.0.1:"
                          f"{DEFAULT_PORTS[scheme]})")
    rest = url[len(prefix):].rstrip("/")
    if "/" in rest or "?" in rest:
        raise fail(path, f"path cannot be used in a {scheme} url, use topic instead")
    hosts = rest.split(",") if scheme == "kafka" else [rest]
    out = []
    for item in hosts:
        parts = urlsplit(f"//{item}")
        try:
            port = parts.port
        except ValueError:
            raise fail(path, f"bad port in {item!r}") from None
        if not parts.hostname or parts.username or parts.password:
            raise fail(path, f"{item!r} is not host:port")
        if port is None:
            if scheme == "kafka":
                raise fail(path, f"{item!r} needs a port (host:port)")
            port = DEFAULT_PORTS[scheme]
        out.append((parts.hostname, port))
    return url, out


def mqtt_target(obj: Mapping[str, Any]) -> MqttTarget:
    path = "notification.mqtt"
    only_known(obj, path, {"url", "topic", "qos", "retain", "user", "passwd"})
    for name in ("url", "topic"):
        if name not in obj:
            raise fail(f"{path}.{name}", "missing")
    given = obj["url"]
    tls = isinstance(given, str) and given.startswith("mqtts://")
    url, [(host, port)] = _broker_url(given, f"{path}.url", "mqtts" if tls else "mqtt")
    topic = obj["topic"]
    if not isinstance(topic, str) or not topic:
        raise fail(f"{path}.topic", f"must be a non-empty string, got {topic!r}")
    for i, char in enumerate(topic):
        if char in "+#" or char == "\0":
            raise fail(f"{path}.topic", f"{char!r} at position {i}: + and # are not allowed in a "
                                         "topic to publish to")
    if ("user" in obj) != ("passwd" in obj):
        raise fail(path, "user and passwd go together")
    return MqttTarget(
        url=url, host=host, port=port, topic=topic,
        qos=integer(obj["qos"], f"{path}.qos", 0, 2) if "qos" in obj else 0,
        retain=boolean(obj["retain"], f"{path}.retain") if "retain" in obj else False,
        user=text_field(obj["user"], f"{path}.user") if "user" in obj else None,
        passwd=text_field(obj["passwd"], f"{path}.passwd", free_text=True) if "passwd" in obj else None,
        tls=tls,
    )


def kafka_target(obj: Mapping[str, Any]) -> KafkaTarget:
    path = "notification.kafka"
    sasl = {"user", "passwd", "saslMechanism", "securityProtocol"}
    for name in sasl & set(obj):
        raise fail(f"{path}.{name}", "not supported by plantkg's context broker: Kafka SASL "
                                      "authentication is not implemented")
    only_known(obj, path, {"url", "topic", "key"})
    for name in ("url", "topic"):
        if name not in obj:
            raise fail(f"{path}.{name}", "missing")
    url, hosts = _broker_url(obj["url"], f"{path}.url", "kafka")
    topic = obj["topic"]
    if not isinstance(topic, str) or not KAFKA_TOPIC.fullmatch(topic) or topic in (".", ".."):
        raise fail(f"{path}.topic", f"{topic!r} is not a Kafka topic name (1 to 249 of "
                                     "A-Z a-z 0-9 . _ -)")
    key = obj.get("key")
    if key is not None:
        key = text_field(key, f"{path}.key", free_text=True)
    return KafkaTarget(url=url, bootstrap=",".join(f"{h}:{p}" for h, p in hosts), topic=topic, key=key)

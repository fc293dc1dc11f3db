"""Checks of single JSON fields, each refusal a 400 that starts with the field's path.

Shared by :mod:`.parse` (the subscription) and :mod:`.parse_targets` (its transports). Orion's
identifier rules: at most 256 printable characters, none of its forbidden ``<>"'=;()`` (nor
whitespace, outside free text). Fields Orion has and plantkg does not implement are refused by
name (:data:`NOT_SUPPORTED`), never silently ignored.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from engine.context_broker.contract import NgsiError, bad_request

MAX_ID = 256
#: Orion's forbidden characters in identifiers and free text (its "Invalid characters").
FORBIDDEN = set('<>"\'=;()')
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

def fail(path: str, message: str) -> NgsiError:
    return bad_request(f"{path}: {message}")


def json_object(value: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise fail(path, f"must be a JSON object, got {kind_of(value)}")
    return value


def kind_of(value: Any) -> str:
    if value is None:
        return "null"
    return {bool: "a boolean", str: "a string", int: "a number", float: "a number",
            list: "an array", dict: "an object"}.get(type(value), type(value).__name__)


def only_known(obj: Mapping[str, Any], path: str, allowed: set[str], ignored: frozenset[str] = frozenset()) -> None:
    for key in obj:
        if key in allowed or key in ignored:
            continue
        where = f"{path}.{key}" if path else key
        if key in NOT_SUPPORTED:
            raise fail(where, f"not supported by plantkg's context broker: {NOT_SUPPORTED[key]}")
        raise fail(where, f"unknown field (allowed here: {', '.join(sorted(allowed))})")


def text_field(value: Any, path: str, *, max_len: int = MAX_ID, free_text: bool = False) -> str:
    if not isinstance(value, str):
        raise fail(path, f"must be a string, got {kind_of(value)}")
    if not value:
        raise fail(path, "must not be empty")
    if len(value) > max_len:
        raise fail(path, f"at most {max_len} characters, got {len(value)}")
    for i, char in enumerate(value):
        if char in FORBIDDEN or (not free_text and (char.isspace() or not char.isprintable())):
            raise fail(path, f"forbidden character {char!r} at position {i} (not allowed: "
                              f"{''.join(sorted(FORBIDDEN))}" + ("" if free_text else ", whitespace")
                              + ")")
    return value


def regex_field(value: Any, path: str) -> str:
    """A regular expression (Orion's character restrictions do not apply to patterns)."""
    if not isinstance(value, str) or not value:
        raise fail(path, f"must be a non-empty string, got {value!r}")
    text = value
    try:
        re.compile(text)
    except re.error as err:
        raise fail(path, f"not a valid regular expression: {err}") from None
    return text


def boolean(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise fail(path, f"must be true or false, got {kind_of(value)}")
    return value


def integer(value: Any, path: str, low: int, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise fail(path, f"must be an integer, got {value!r}")
    if value < low or (high is not None and value > high):
        bound = f"from {low} to {high}" if high is not None else f"at least {low}"
        raise fail(path, f"must be an integer {bound}, got {value}")
    return value


def name_list(value: Any, path: str, *, allow_empty: bool = True) -> tuple[str, ...]:
    if not isinstance(value, list):
        raise fail(path, f"must be an array of attribute names, got {kind_of(value)}")
    if not value and not allow_empty:
        raise fail(path, "must not be empty")
    return tuple(text_field(v, f"{path}[{i}]") for i, v in enumerate(value))

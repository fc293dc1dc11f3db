"""MQTT payloads as NGSI-v2 entity updates, and the loop rule (pure functions, no I/O).

One MQTT message becomes one upsert of its topic's entity (``POST /v2/entities?options=upsert``):

- a JSON object: each top-level field one attribute, typed by its JSON type (``Number``,
  ``Text``, ``Boolean``, ``StructuredValue`` for objects and arrays, ``None`` for null);
- anything else (other JSON, plain text): one attribute ``value`` of type ``Text`` holding the
  payload as text (a JSON string: its content, without the quotes);
- always ``TimeInstant`` (``DateTime``): when the worker received the message (ISO 8601, UTC).

Orion's field syntax restrictions decide what is refused: an attribute name is 1..256 printable
ASCII characters without whitespace, ``& ? / #`` or the generally forbidden ``< > " ' = ; ( )``;
``id``, ``type``, ``*`` and the builtin ``dateCreated``/``dateModified``/``dateExpires`` are
reserved; a string value contains none of ``< > " ' = ; ( )``. Names are *mapped* where that is
unambiguous (:func:`attribute_name`: each forbidden character becomes ``_``, a reserved name gets a
trailing ``_``); a message whose names cannot be mapped (empty, too long, non-ASCII, two fields
mapping to one name) or whose strings Orion would refuse, or whose payload is not UTF-8, raises
:class:`Refused` with the reason — the worker counts and logs it and acknowledges the message
instead of blocking the topic with it.

The loop rule (:func:`is_notification`): on a topic bridged both ways the context broker publishes
its notifications on the same MQTT topic the worker reads, including the ones caused by the
worker's own writes. The worker never writes a notification back: an MQTT message that is a JSON
object with a string ``subscriptionId`` and a ``data`` array is skipped (counted in ``skipped``).
"""

from __future__ import annotations

import json
import math
from datetime import datetime, timezone
from typing import Any

from engine.ngsi_syntax import FORBIDDEN_CHARS, MAX_NAME_LENGTH, NAME_ONLY_CHARS, default_attr_type

RESERVED_NAMES = frozenset({"id", "type", "*", "dateCreated", "dateModified", "dateExpires",
                            "geo:distance", "TimeInstant"})
MAX_NAME = MAX_NAME_LENGTH
TIME_ATTRIBUTE = "TimeInstant"
VALUE_ATTRIBUTE = "value"


class Refused(ValueError):
    """A message the context broker would refuse; ``reason`` says which part and why."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def iso_time(epoch: float) -> str:
    """``epoch`` seconds as ISO 8601 UTC with milliseconds (``2026-11-24T16:40:00.123Z``)."""
    stamp = datetime.fromtimestamp(epoch, tz=timezone.utc)
    return stamp.strftime("%Y-%m-%dT%H:%M:%S.") + f"{stamp.microsecond // 1000:03d}Z"


def check_name(what: str, name: str) -> None:
    """An entity id, entity type or attribute name as Orion accepts it; else :class:`Refused`."""
    if not 1 <= len(name) <= MAX_NAME:
        raise Refused(f"{what} {name[:40]!r}: must be 1 to {MAX_NAME} characters")
    for i, char in enumerate(name):
        if not ("!" <= char <= "~") or char in FORBIDDEN_CHARS or char in NAME_ONLY_CHARS:
            raise Refused(f"{what} {name[:40]!r}: character {char!r} at position {i} is not "
                          "allowed in NGSI-v2 names")


def attribute_name(field: str) -> str:
    """The attribute name of a top-level payload field: forbidden characters become ``_``,
    reserved names get a trailing ``_``. Raises :class:`Refused` if no name can be made."""
    if not field:
        raise Refused("an empty field name cannot be an NGSI attribute name")
    mapped = "".join("_" if c in FORBIDDEN_CHARS or c in NAME_ONLY_CHARS or c == " " else c
                     for c in field)
    if mapped in RESERVED_NAMES:
        mapped += "_"
    check_name(f"field {field[:40]!r} as attribute", mapped)
    return mapped


def _check_value(where: str, value: Any) -> None:
    """Strings anywhere in ``value`` must avoid Orion's forbidden characters."""
    if isinstance(value, str):
        for i, char in enumerate(value):
            if char in FORBIDDEN_CHARS:
                raise Refused(f"{where}: character {char!r} at position {i} of a text value is "
                              "refused by NGSI-v2 (forbidden: < > \" ' = ; ( ))")
    elif isinstance(value, dict):
        for key, item in value.items():
            _check_value(f"{where}.{key}", item)
            for i, char in enumerate(key):
                if char in FORBIDDEN_CHARS:
                    raise Refused(f"{where}: key {key[:40]!r} has {char!r} at position {i}, "
                                  "refused by NGSI-v2")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _check_value(f"{where}[{index}]", item)


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def parse_json(payload: bytes) -> Any:
    """The payload as strict JSON (no NaN/Infinity); raises ValueError if it is not."""
    return json.loads(payload.decode("utf-8"), parse_constant=_no_constant)


def attributes(payload: bytes, received_at: float) -> dict[str, dict[str, Any]]:
    """The normalized NGSI attributes of one MQTT message (see the module docstring)."""
    try:
        data = parse_json(payload)
    except UnicodeDecodeError as exc:
        raise Refused(f"the payload is not UTF-8 text (byte {exc.start}); NGSI holds text") from None
    except ValueError:
        data = None
        text = payload.decode("utf-8")
        _check_value(f"attribute {VALUE_ATTRIBUTE!r}", text)
        attrs = {VALUE_ATTRIBUTE: {"type": "Text", "value": text}}
    else:
        if isinstance(data, dict):
            attrs = {}
            for field, value in data.items():
                name = attribute_name(field)
                if name in attrs:
                    raise Refused(f"fields map to the same attribute name {name!r}; rename one")
                if isinstance(value, float) and not math.isfinite(value):
                    raise Refused(f"attribute {name!r}: {value} is not a JSON number")
                _check_value(f"attribute {name!r}", value)
                attrs[name] = {"type": default_attr_type(value), "value": value}
        else:  # a JSON string is its text; other JSON is kept as written
            text = data if isinstance(data, str) else payload.decode("utf-8").strip()
            _check_value(f"attribute {VALUE_ATTRIBUTE!r}", text)
            attrs = {VALUE_ATTRIBUTE: {"type": "Text", "value": text}}
    attrs[TIME_ATTRIBUTE] = {"type": "DateTime", "value": iso_time(received_at)}
    return attrs


def upsert_body(entity_id: str, entity_type: str, payload: bytes, received_at: float) -> dict[str, Any]:
    """The body of ``POST /v2/entities?options=upsert`` for one message."""
    return {"id": entity_id, "type": entity_type, **attributes(payload, received_at)}


def is_notification(payload: bytes) -> bool:
    """The loop rule: is this MQTT message a context broker notification (never written back)?"""
    if not payload.startswith(b"{") and not payload.lstrip().startswith(b"{"):
        return False
    try:
        data = parse_json(payload)
    except ValueError:
        return False
    return (isinstance(data, dict) and isinstance(data.get("subscriptionId"), str)
            and isinstance(data.get("data"), list))

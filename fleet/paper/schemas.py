"""JSON-schema checks of the paper's messages, with the schemas kept in this package (``schemas/``).

Each message kind has one draft 2020-12 schema file (``motion_item.json``, ``action_item.json``,
``status.json``, ``movement.json``, ``description.json``). A refused message raises
:class:`~fleet.paper.errors.MessageError` with the path inside the message (``point/0``), the
value found there and the reason. Before the schema: payloads over 1 MB, non-UTF-8, non-JSON,
``NaN``/``Infinity`` (Python's json would accept them, JSON does not) and non-objects are refused.

Commands reach the vehicle either bare or the way the context broker's MQTT notification delivers
them (the paper's "REST calls to the OCB" on motion_channel/action_channel, carried by the
mqtt-ngsi bridge): ``{"subscriptionId": ..., "data": [entity, ...]}`` with each entity in
``keyValues`` (``{"id", "type", <attribute>: <value>}``) or normalized
(``<attribute>: {"type", "value", "metadata"}``). :func:`decode` unwraps those into one message per
entity, dropping the entity's ``id``/``type`` and the attributes the broker adds
(``TimeInstant``, ``dateCreated``, ``dateModified``, ``dateExpires``).
"""

from __future__ import annotations

import enum
import json
import math
from functools import lru_cache
from importlib import resources
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError, best_match

from fleet.paper.errors import MISSING, MessageError

MAX_MESSAGE_BYTES = 1_000_000
NGSI_BUILTIN = frozenset({"id", "type", "TimeInstant", "dateCreated", "dateModified", "dateExpires"})


class Kind(str, enum.Enum):
    MOTION_ITEM = "motion_item"
    ACTION_ITEM = "action_item"
    STATUS = "status"
    MOVEMENT = "movement"
    DESCRIPTION = "description"


def schema(kind: Kind | str) -> dict[str, Any]:
    """The schema of ``kind`` as data (a fresh copy)."""
    text = resources.files("fleet.paper").joinpath("schemas", f"{Kind(kind).value}.json").read_text(encoding="utf-8")
    return json.loads(text)


@lru_cache(maxsize=None)
def validator(kind: Kind) -> Draft202012Validator:
    document = schema(kind)
    Draft202012Validator.check_schema(document)
    return Draft202012Validator(document)


def _path(error: ValidationError) -> str:
    return "/".join(str(part) for part in error.absolute_path)


def _non_finite(value: Any, path: str = "") -> tuple[str, float] | None:
    """The first NaN/inf float inside ``value`` (a dict built in Python may hold one), with its path."""
    if isinstance(value, float) and not math.isfinite(value):
        return path, value
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return None
    for key, inner in items:
        found = _non_finite(inner, f"{path}/{key}" if path else str(key))
        if found:
            return found
    return None


def check(kind: Kind | str, message: Any) -> dict[str, Any]:
    """Return ``message`` if it is a valid ``kind``, else raise :class:`MessageError`."""
    kind = Kind(kind)
    if not isinstance(message, dict):
        raise MessageError(kind.value, "", message, f"a message is a JSON object, got {type(message).__name__}")
    bad = _non_finite(message)
    if bad:
        raise MessageError(kind.value, bad[0], bad[1], "numbers must be finite (no NaN or infinity)")
    errors = list(validator(kind).iter_errors(message))
    if errors:
        best = best_match(errors)
        path, value = _path(best), best.instance
        if best.validator == "required" and isinstance(best.instance, dict):
            missing = [name for name in best.validator_value if name not in best.instance]
            path, value = "/".join(p for p in (path, missing[0] if missing else "") if p), MISSING
            raise MessageError(kind.value, path, value, "is required but missing")
        raise MessageError(kind.value, path, value, best.message)
    return message


def _refuse_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def load(kind: Kind | str, payload: bytes | str) -> Any:
    """Decode a payload (UTF-8 JSON, at most 1 MB) without checking its content."""
    name = Kind(kind).value
    size = len(payload)
    if size > MAX_MESSAGE_BYTES:
        raise MessageError(name, "", size, f"message is {size} bytes, more than the {MAX_MESSAGE_BYTES} accepted")
    try:
        text = payload.decode("utf-8") if isinstance(payload, bytes) else payload
        return json.loads(text, parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise MessageError(name, "", None, f"not UTF-8 JSON: {exc}") from None


def is_notification(message: Any) -> bool:
    return isinstance(message, dict) and isinstance(message.get("subscriptionId"), str) and "data" in message


def _from_entity(kind: str, index: int, entity: Any) -> dict[str, Any]:
    if not isinstance(entity, dict):
        raise MessageError(kind, f"data/{index}", entity, "a notified entity is a JSON object")
    attributes = {k: v for k, v in entity.items() if k not in NGSI_BUILTIN}
    normalized = bool(attributes) and all(isinstance(v, dict) and "value" in v and "type" in v
                                          for v in attributes.values())
    return {k: v["value"] for k, v in attributes.items()} if normalized else attributes


def unwrap(kind: Kind | str, message: Any) -> list[Any]:
    """The messages inside a context broker notification, or ``[message]`` for a bare one."""
    name = Kind(kind).value
    if not is_notification(message):
        return [message]
    data = message["data"]
    if not isinstance(data, list) or not data:
        raise MessageError(name, "data", data, "a notification carries a non-empty list of entities")
    return [_from_entity(name, i, entity) for i, entity in enumerate(data)]


def decode(kind: Kind | str, payload: bytes | str) -> list[dict[str, Any]]:
    """A received payload as checked messages of ``kind`` (several for a notification of several
    entities). The first bad one raises; check them one by one with :func:`unwrap` and :func:`check`
    to keep the good ones."""
    return [check(kind, m) for m in unwrap(kind, load(kind, payload))]

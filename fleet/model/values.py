"""Checks of the values a vehicle description brings in, before any of them becomes a triple.

Each check returns the value it accepted or raises :class:`~fleet.model.errors.DescriptionError`
naming the field path and the value. The rules are the ones the shapes hold a plant to
(``shapes/plantkg-fleet.ttl``, ``shapes/plantkg-shapes.ttl``), checked here first so a bad
factsheet is refused with its own field name rather than as a violation of a generated node:

- serial number (VDA 5050 ``serialNumber``, the paper's ``agv_id``): 1 to 64 characters of
  ``A-Z a-z 0-9 _ . : -`` (VDA 5050's serial number characters; a topic level and part of the NGSI
  entity id ``urn:ngsi-ld:AGV:<serial>``);
- manufacturer: the same characters (a topic level, and a text value Orion must accept);
- skill (VDA 5050 ``actionType``, a paper skill): a plantkg ``pk:id``, 1 to 128 of ``A-Z a-z 0-9 _ . -``
  starting with a letter, digit or ``_``;
- names: 1 to 128 characters, no control character;
- numbers: JSON numbers (not booleans), finite, within ``0 .. MAX_NUMBER``;
- the whole payload: at most ``MAX_PAYLOAD_BYTES`` of JSON, nested at most ``MAX_DEPTH`` deep,
  measured by a walk that stops as soon as the limit is passed (a 10 MB factsheet costs little).
"""

from __future__ import annotations

import json
import math
import re
import unicodedata
from decimal import Decimal
from typing import Any

from fleet.model.errors import DescriptionError

SERIAL = re.compile(r"[A-Za-z0-9_.:\-]{1,64}")
MANUFACTURER = SERIAL
SKILL = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,127}")
MAX_NAME = 128
MAX_NUMBER = 1_000_000.0
MAX_PAYLOAD_BYTES = 512 * 1024
MAX_DEPTH = 32
MAX_SKILLS = 256


def serial(field: str, value: object) -> str:
    if not isinstance(value, str):
        raise DescriptionError(field, value, f"must be a string, not {type(value).__name__}")
    if not SERIAL.fullmatch(value):
        raise DescriptionError(field, value, _why(value, 64, "A-Z a-z 0-9 _ . : -", SERIAL))
    return value


def manufacturer(field: str, value: object) -> str:
    if not isinstance(value, str):
        raise DescriptionError(field, value, f"must be a string, not {type(value).__name__}")
    if not MANUFACTURER.fullmatch(value):
        raise DescriptionError(field, value, _why(value, 64, "A-Z a-z 0-9 _ . : -", MANUFACTURER))
    return value


def skill(field: str, value: object) -> str:
    if not isinstance(value, str):
        raise DescriptionError(field, value, f"must be a string, not {type(value).__name__}")
    if not SKILL.fullmatch(value):
        if value and not re.fullmatch(r"[A-Za-z0-9_]", value[0]):
            raise DescriptionError(field, value, "must start with a letter, a digit or _")
        raise DescriptionError(field, value, _why(value, 128, "A-Z a-z 0-9 _ . -", re.compile(r"[A-Za-z0-9_.\-]+")))
    return value


def name(field: str, value: object) -> str:
    if not isinstance(value, str):
        raise DescriptionError(field, value, f"must be a string, not {type(value).__name__}")
    if not 1 <= len(value) <= MAX_NAME:
        raise DescriptionError(field, value, f"must be 1 to {MAX_NAME} characters, is {len(value)}")
    for position, char in enumerate(value):
        if unicodedata.category(char) in ("Cc", "Zl", "Zp"):
            raise DescriptionError(field, value, f"control character {char!r} at position {position}")
    return value


def number(field: str, value: object, *, positive: bool = False) -> float:
    """A JSON number in ``0 .. MAX_NUMBER`` (``positive``: above 0)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DescriptionError(field, value, f"must be a number, not {type(value).__name__}")
    number_ = float(value)
    if not math.isfinite(number_):
        raise DescriptionError(field, value, "must be a finite number")
    if number_ < 0 or (positive and number_ == 0):
        raise DescriptionError(field, value, "must be above 0" if positive else "must not be negative")
    if number_ > MAX_NUMBER:
        raise DescriptionError(field, value, f"must be at most {MAX_NUMBER:g} (SI units: m, m/s, kg, Wh)")
    return number_


def obj(field: str, value: object) -> dict[str, Any]:
    if not isinstance(value, dict):
        what = "missing" if value is None else f"a {type(value).__name__}"
        raise DescriptionError(field, value, f"must be a JSON object, is {what}")
    return value


def member(parent: dict[str, Any], key: str, path: str) -> Any:
    """``parent[key]``, or a DescriptionError naming ``path`` when it is missing."""
    if key not in parent:
        raise DescriptionError(path, None, "is missing")
    return parent[key]


def decimal_text(value: float) -> str:
    """The xsd:decimal lexical form of ``value`` (plain notation, never 1e-05)."""
    text = format(Decimal(repr(value)), "f")
    return text if "." in text else text + ".0"


def payload(field: str, value: object) -> dict[str, Any]:
    """A JSON object of bounded size: a dict, or bytes/str holding one."""
    if isinstance(value, (bytes, bytearray, str)):
        size = len(value)
        if size > MAX_PAYLOAD_BYTES:
            raise DescriptionError(field, f"<{size} bytes>", f"is larger than {MAX_PAYLOAD_BYTES} bytes")
        try:
            value = json.loads(value)
        except (ValueError, UnicodeDecodeError) as exc:
            raise DescriptionError(field, f"<{size} bytes>", f"is not JSON: {exc}") from None
    data = obj(field, value)
    _bounded(field, data)
    return data


def _bounded(field: str, data: object) -> None:
    """Refuse a structure whose JSON would pass MAX_PAYLOAD_BYTES or MAX_DEPTH (early exit)."""
    budget = MAX_PAYLOAD_BYTES
    stack: list[tuple[object, int]] = [(data, 0)]
    while stack:
        item, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise DescriptionError(field, "<deeply nested JSON>", f"is nested more than {MAX_DEPTH} levels deep")
        if isinstance(item, dict):
            budget -= 2
            for key, inner in item.items():
                budget -= len(key) + 4 if isinstance(key, str) else 24
                stack.append((inner, depth + 1))
        elif isinstance(item, (list, tuple)):
            budget -= 2 + len(item)
            stack.extend((inner, depth + 1) for inner in item)
        elif isinstance(item, str):
            budget -= len(item) + 2
        else:
            budget -= 8
        if budget < 0:
            raise DescriptionError(field, f"<more than {MAX_PAYLOAD_BYTES} bytes of JSON>",
                                   f"is larger than {MAX_PAYLOAD_BYTES} bytes; a factsheet or "
                                   "description is a few kilobytes")


def _why(value: str, longest: int, allowed: str, chars: re.Pattern[str]) -> str:
    if not value:
        return "must not be empty"
    if len(value) > longest:
        return f"is {len(value)} characters, at most {longest}"
    for position, char in enumerate(value):
        if not chars.fullmatch(char):
            return f"character {char!r} at position {position} is not one of {allowed}"
    return f"must be 1 to {longest} of {allowed}"

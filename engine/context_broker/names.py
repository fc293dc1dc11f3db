"""Orion's rules for identifiers and string values, with errors that say which character and where.

orion-api.md, "Identifiers syntax restrictions": entity ids and types, attribute and metadata
names and types are 1 to 256 plain ASCII characters, without control characters, whitespace,
``&``, ``?``, ``/``, ``#``, nor the characters forbidden everywhere ("General syntax
restrictions"): ``< > " ' = ; ( )``. Those eight are also refused inside string values (an
attribute whose type is ``TextUnrestricted`` is exempt). Attribute names ``id``, ``type``,
``geo:distance`` and ``*`` are reserved ("Attribute names restrictions").

Orion answers "Invalid characters in attribute type"; plantkg names the field, the character and
its position (0-based), since users cannot otherwise find it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from engine.context_broker.contract import NgsiError, bad_request
from engine.ngsi_syntax import FORBIDDEN_CHARS, MAX_NAME_LENGTH, NAME_ONLY_CHARS

MAX_ID_LENGTH = MAX_NAME_LENGTH
FORBIDDEN = FORBIDDEN_CHARS
FORBIDDEN_IN_IDS = FORBIDDEN_CHARS | NAME_ONLY_CHARS
RESERVED_ATTR_NAMES = frozenset({"id", "type", "geo:distance", "*"})
UNRESTRICTED_TYPE = "TextUnrestricted"


def _describe(char: str) -> str:
    if char.isspace() or ord(char) < 32 or ord(char) == 127:
        return f"whitespace or control character {char!r} (U+{ord(char):04X})"
    if not char.isascii():
        return f"non-ASCII character {char!r} (U+{ord(char):04X})"
    return f"forbidden character '{char}'"


def check_identifier(value: Any, field: str) -> str:
    """``value`` if it is a valid identifier, else :class:`NgsiError` 400 naming ``field``, the
    character and its position. ``field`` reads like "entity id" or "attribute name 'x'"."""
    if not isinstance(value, str):
        raise bad_request(f"{field} must be a JSON string, got {type(value).__name__}")
    if not value:
        raise bad_request(f"{field} is empty: length 0, min length supported: 1")
    if len(value) > MAX_ID_LENGTH:
        raise bad_request(f"{field} too long: {len(value)} characters, max length supported: "
                          f"{MAX_ID_LENGTH}")
    for position, char in enumerate(value):
        if char in FORBIDDEN_IN_IDS or not char.isascii() or not char.isprintable() or char.isspace():
            raise bad_request(f"Invalid characters in {field}: {_describe(char)} at position "
                              f"{position} of {value!r}")
    return value


def check_attribute_name(name: Any) -> str:
    check_identifier(name, "attribute name")
    if name in RESERVED_ATTR_NAMES:
        raise bad_request(f"attribute name {name!r} is reserved (id, type, geo:distance and * "
                          "cannot be attribute names)")
    return name


def check_metadata_name(name: Any, attr: str) -> str:
    check_identifier(name, f"metadata name of attribute {attr!r}")
    if name == "*":
        raise bad_request(f"metadata name '*' of attribute {attr!r} is reserved")
    return name


def check_value(value: Any, where: str) -> None:
    """Refuse the characters forbidden everywhere inside any string of a JSON value (keys of
    structured values included), naming ``where`` (e.g. "value of attribute 'name'"), the path
    inside the value, the character and its position."""
    _check_value(value, where, "")


def _check_value(value: Any, where: str, path: str) -> None:
    if isinstance(value, str):
        for position, char in enumerate(value):
            if char in FORBIDDEN:
                inside = f" at {path}" if path else ""
                raise bad_request(f"Invalid characters in {where}{inside}: forbidden character "
                                  f"'{char}' at position {position} (< > \" ' = ; ( ) are not "
                                  f"allowed in values; use type {UNRESTRICTED_TYPE} to allow them)")
    elif isinstance(value, Mapping):
        for key, item in value.items():
            _check_value(key, where, f"{path}.{key}" if path else str(key))
            _check_value(item, where, f"{path}.{key}" if path else str(key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _check_value(item, where, f"{path}[{index}]")


def check_url_identifier(value: str, field: str) -> str:
    """An identifier taken from the URL (path segment or parameter): the same rules."""
    return check_identifier(value, field)


__all__ = ["NgsiError", "check_attribute_name", "check_identifier", "check_metadata_name",
           "check_url_identifier", "check_value"]

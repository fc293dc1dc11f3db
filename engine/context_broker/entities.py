"""NGSI-v2 entities: the in-memory model, request bodies parsed into it, and its renderings.

- :class:`Attribute` and :class:`Entity` are frozen: a write builds a new entity, so a reader
  holding the old one never sees half a write. An entity keeps its normalized JSON (what
  listeners, notifications and ``q`` see) computed once.
- Parsing follows orion-api.md "JSON Entity/Attribute Representation" and "Partial
  Representations": ``id`` required, ``type`` defaults to ``Thing``; an attribute's ``type``
  defaults from its value (Text, Number, Boolean, StructuredValue, None); ``value`` may be left
  out (null); ``options=keyValues`` bodies give bare values. Names, types and string values are
  checked by :mod:`.names`. ``DateTime`` (or ``ISO8601``) values must be dates and are stored as
  Orion renders them (``YYYY-MM-DDThh:mm:ss.sssZ``).
- Updates are pure functions (:func:`merge_attrs`, :func:`replace_attrs`, ...) following Orion's
  metadata semantics: metadata of the request is merged into the attribute's unless
  ``overrideMetadata``; ``"metadata": {}`` clears it.
- Renderings: normalized, ``keyValues``, ``values`` and ``unique``, with ``attrs`` (order and the
  builtins ``dateCreated``, ``dateModified``, ``servicePath``; ``*`` for all user attributes) and
  ``metadata`` filters (builtins ``dateCreated``, ``dateModified``; ``*``).
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from engine.context_broker.contract import NgsiError, bad_request
from engine.context_broker.dates import from_epoch, parse_datetime, render_datetime
from engine.context_broker.names import (
    UNRESTRICTED_TYPE, check_attribute_name, check_identifier, check_metadata_name, check_value,
)
from engine.ngsi_syntax import default_attr_type

DEFAULT_ENTITY_TYPE = "Thing"
DATE_TYPES = frozenset({"DateTime", "ISO8601"})
BUILTIN_ATTRS = ("dateCreated", "dateModified", "servicePath")
BUILTIN_METADATA = ("dateCreated", "dateModified")
ATTR_KEYS = frozenset({"value", "type", "metadata"})


@dataclass(frozen=True)
class AttrInput:
    """One attribute as a request gives it: ``metadata`` None when the request has none."""

    name: str
    type: str
    value: Any
    metadata: Mapping[str, Mapping[str, Any]] | None = None


@dataclass(frozen=True)
class Attribute:
    type: str
    value: Any
    metadata: Mapping[str, Mapping[str, Any]]
    created: float
    modified: float

    def json(self) -> dict[str, Any]:
        return {"type": self.type, "value": self.value,
                "metadata": {k: dict(v) for k, v in self.metadata.items()}}


@dataclass(frozen=True)
class Entity:
    id: str
    type: str
    service_path: str
    attrs: Mapping[str, Attribute]
    created: float
    modified: float
    normalized: Mapping[str, Any] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def make(cls, id: str, type: str, service_path: str, attrs: Mapping[str, Attribute],
             created: float, modified: float) -> Entity:
        normalized: dict[str, Any] = {"id": id, "type": type}
        for name, attr in attrs.items():
            normalized[name] = attr.json()
        return cls(id, type, service_path, dict(attrs), created, modified, normalized)

    @property
    def query_view(self) -> Mapping[str, Any]:
        """The normalized entity plus the builtins ``dateCreated``, ``dateModified`` and
        ``servicePath`` (what ``q`` filters on, as Orion: builtins over same-named attributes).
        Built on first use and kept: an entity never changes."""
        view = self.__dict__.get("_query_view")
        if view is None:
            view = dict(self.normalized)
            view.update(_builtins(self.created, self.modified, self.service_path))
            object.__setattr__(self, "_query_view", view)
        return view

    def with_attrs(self, attrs: Mapping[str, Attribute], now: float) -> Entity:
        return Entity.make(self.id, self.type, self.service_path, attrs, self.created, now)


def _builtins(created: float, modified: float, service_path: str) -> dict[str, Any]:
    return {"dateCreated": {"type": "DateTime", "value": from_epoch(created), "metadata": {}},
            "dateModified": {"type": "DateTime", "value": from_epoch(modified), "metadata": {}},
            "servicePath": {"type": "Text", "value": service_path, "metadata": {}}}


# --- parsing -----------------------------------------------------------------------------

MAX_NESTING = 50  # Orion's MAX_JSON_NESTING


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def _finite(text: str) -> float:
    number = float(text)
    if number in (float("inf"), float("-inf")):
        raise ValueError(f"number {text[:40]} is too big (out of the range of a double)")
    return number


def _depth(value: Any) -> int:
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, depth = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, depth)
            if depth > MAX_NESTING:
                return depth
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, depth + 1) for child in children)
    return deepest


def parse_json(raw: bytes) -> Any:
    """The JSON document ``raw`` holds: 400 ParseError for bad JSON, NaN/Infinity, or a
    ``\\ud800``-style escape that is no Unicode character (a lone surrogate cannot be stored)."""
    try:
        value = json.loads(raw, parse_constant=_no_constant, parse_float=_finite)
        if b"\\u" in raw:
            json.dumps(value, ensure_ascii=False).encode("utf-8")
    except RecursionError:
        raise NgsiError(400, "ParseError", f"Errors found in incoming JSON buffer: nesting deeper "
                                           f"than {MAX_NESTING} levels") from None
    except (ValueError, UnicodeDecodeError, UnicodeEncodeError) as err:
        raise NgsiError(400, "ParseError", f"Errors found in incoming JSON buffer: {err}") from None
    if _depth(value) > MAX_NESTING:
        raise NgsiError(400, "ParseError", f"Errors found in incoming JSON buffer: nesting deeper "
                                           f"than {MAX_NESTING} levels (Orion's limit)")
    return value


def _object(body: Any, what: str) -> Mapping[str, Any]:
    if not isinstance(body, Mapping):
        raise NgsiError(400, "ParseError", f"Errors found in incoming JSON buffer: {what} must be "
                                           f"a JSON object, got {_kind(body)}")
    return body


def _kind(value: Any) -> str:
    return {dict: "an object", list: "an array", str: "a string", bool: "a boolean",
            type(None): "null"}.get(type(value), "a number")


def parse_entity(body: Any, *, key_values: bool = False) -> tuple[str, str, dict[str, AttrInput]]:
    """(id, type, attributes) of a create body; 400 naming the field for anything wrong."""
    obj = _object(body, "the entity")
    if "id" not in obj:
        raise bad_request("entity id is missing: give \"id\" (a string of 1 to 256 characters)")
    entity_id = check_identifier(obj.get("id"), "entity id")
    entity_type = obj.get("type", DEFAULT_ENTITY_TYPE)
    check_identifier(entity_type, "entity type")
    attrs = parse_attrs({k: v for k, v in obj.items() if k not in ("id", "type")},
                        key_values=key_values)
    return entity_id, entity_type, attrs


def parse_attrs(body: Any, *, key_values: bool = False) -> dict[str, AttrInput]:
    obj = _object(body, "the attributes")
    out = {}
    for name, item in obj.items():
        if name in ("id", "type"):
            raise bad_request(f"attribute name {name!r} is reserved: id and type cannot be changed "
                              "or used as attribute names")
        out[name] = parse_attr(name, item, key_values=key_values)
    return out


def parse_attr(name: Any, item: Any, *, key_values: bool = False) -> AttrInput:
    check_attribute_name(name)
    if key_values:
        return _attr_input(name, None, item, None)
    if not isinstance(item, Mapping):
        raise bad_request(f"attribute {name!r} must be a JSON object with value, type and metadata "
                          f"(got {_kind(item)}); use options=keyValues to send bare values")
    unknown = set(item) - ATTR_KEYS
    if unknown:
        raise bad_request(f"unrecognized property for attribute {name!r}: {', '.join(sorted(unknown))} "
                          "(value, type and metadata only)")
    metadata = None
    if "metadata" in item:
        metadata = _metadata(name, item["metadata"])
    return _attr_input(name, item.get("type"), item.get("value"), metadata, "type" in item)


def _attr_input(name: str, type_: Any, value: Any, metadata: Any, type_given: bool = False) -> AttrInput:
    if type_given or type_ is not None:
        check_identifier(type_, f"type of attribute {name!r}")
    attr_type = type_ if isinstance(type_, str) else default_attr_type(value)
    value = _checked_value(value, attr_type, f"value of attribute {name!r}", metadata)
    return AttrInput(name, attr_type, value, metadata)


def _checked_value(value: Any, value_type: str, where: str,
                   metadata: Mapping[str, Mapping[str, Any]] | None = None) -> Any:
    unrestricted = value_type == UNRESTRICTED_TYPE or bool(
        metadata and (metadata.get(UNRESTRICTED_TYPE) or {}).get("value") is True)
    if not unrestricted:
        check_value(value, where)
    if value_type in DATE_TYPES and value is not None:
        date = parse_datetime(value) if isinstance(value, str) else None
        if date is None:
            raise bad_request(f"{where}: {value!r} is not a date (type {value_type}); write ISO 8601 "
                              "such as 2024-05-01T10:00:00Z")
        return render_datetime(date)
    return value


def _metadata(attr: str, value: Any) -> dict[str, dict[str, Any]]:
    if not isinstance(value, Mapping):
        raise bad_request(f"metadata of attribute {attr!r} must be a JSON object, got {_kind(value)}")
    out = {}
    for name, item in value.items():
        check_metadata_name(name, attr)
        if not isinstance(item, Mapping):
            raise bad_request(f"metadata {name!r} of attribute {attr!r} must be a JSON object with "
                              f"value and type, got {_kind(item)}")
        unknown = set(item) - {"value", "type"}
        if unknown:
            raise bad_request(f"unrecognized property for metadata {name!r} of attribute {attr!r}: "
                              f"{', '.join(sorted(unknown))}")
        md_value = item.get("value")
        md_type = item.get("type")
        if "type" in item:
            check_identifier(md_type, f"type of metadata {name!r} of attribute {attr!r}")
        else:
            md_type = default_attr_type(md_value)
        md_value = _checked_value(md_value, md_type, f"value of metadata {name!r} of attribute {attr!r}")
        out[name] = {"type": md_type, "value": md_value}
    return out


def parse_text_value(raw: bytes) -> Any:
    """A ``text/plain`` attribute value, as Orion reads it: ``"..."`` a string, true/false, null,
    else a number; anything else is a 400."""
    try:
        text = raw.decode("utf-8").strip()
    except UnicodeDecodeError:
        raise bad_request("text/plain value is not UTF-8") from None
    if len(text) >= 2 and text[0] == '"' and text[-1] == '"':
        try:
            value = json.loads(text)
        except ValueError:
            value = text[1:-1]
        return value
    if text in ("true", "false"):
        return text == "true"
    if text == "null":
        return None
    try:
        number = float(text)
    except ValueError:
        raise bad_request(f"text/plain value {text[:60]!r} is not a quoted string, true, false, null "
                          "or a number") from None
    if number != number or number in (float("inf"), float("-inf")):
        raise bad_request(f"text/plain value {text[:60]!r} is not a finite number")
    return int(text) if text.lstrip("+-").isdigit() else number


# --- updates (pure) ----------------------------------------------------------------------

def new_attribute(given: AttrInput, old: Attribute | None, now: float,
                  override_metadata: bool = False) -> Attribute:
    if old is None or override_metadata or (given.metadata is not None and not given.metadata):
        metadata = dict(given.metadata or {})
    else:
        metadata = dict(old.metadata)
        metadata.update(given.metadata or {})
    return Attribute(given.type, given.value, metadata, old.created if old else now, now)


def create_entity(entity_id: str, entity_type: str, service_path: str,
                  attrs: Mapping[str, AttrInput], now: float) -> Entity:
    return Entity.make(entity_id, entity_type, service_path,
                       {n: new_attribute(a, None, now) for n, a in attrs.items()}, now, now)


@dataclass(frozen=True)
class Split:
    """The attributes of a request that apply to an entity, and those skipped (and why)."""

    applicable: Mapping[str, AttrInput]
    skipped: tuple[str, ...]
    reason: str = ""

    def refusal(self, entity: Entity) -> NgsiError | None:
        """None when nothing was skipped; else Orion's 422: ``PartialUpdate`` when some
        attributes applied, ``Unprocessable`` when none did."""
        if not self.skipped:
            return None
        names = ", ".join(self.skipped)
        if self.reason == "exist":
            text = f"Already Exists: {entity.id}/{entity.type} - [{names}] (append adds new attributes only)"
        else:
            text = f"do not exist: {entity.id}/{entity.type} - [{names}] (update changes existing attributes only)"
        return NgsiError(422, "PartialUpdate" if self.applicable else "Unprocessable", text)


def split_attrs(entity: Entity, attrs: Mapping[str, AttrInput], *, strict: bool = False,
                existing_only: bool = False) -> Split:
    """As Orion: ``options=append`` (``strict``) appends the new attributes and skips those that
    exist; PATCH (``existing_only``) updates those that exist and skips the missing ones."""
    if strict:
        skipped = tuple(n for n in attrs if n in entity.attrs)
        return Split({n: a for n, a in attrs.items() if n not in entity.attrs}, skipped, "exist")
    if existing_only:
        skipped = tuple(n for n in attrs if n not in entity.attrs)
        return Split({n: a for n, a in attrs.items() if n in entity.attrs}, skipped, "missing")
    return Split(attrs, ())


def merge_attrs(entity: Entity, attrs: Mapping[str, AttrInput], now: float, *,
                override_metadata: bool = False) -> Entity:
    """POST /attrs: update the given attributes, append the new ones (metadata merged)."""
    new = dict(entity.attrs)
    for name, given in attrs.items():
        new[name] = new_attribute(given, entity.attrs.get(name), now, override_metadata)
    return entity.with_attrs(new, now)


def replace_attrs(entity: Entity, attrs: Mapping[str, AttrInput], now: float) -> Entity:
    new = {n: new_attribute(a, entity.attrs.get(n), now, True) for n, a in attrs.items()}
    return entity.with_attrs(new, now)


def delete_attrs(entity: Entity, names: Iterable[str], now: float) -> Entity:
    names = list(names)
    missing = [n for n in names if n not in entity.attrs]
    if missing:
        raise NgsiError(404, "NotFound", f"The entity does not have such an attribute: "
                                         f"{', '.join(missing)}")
    return entity.with_attrs({n: a for n, a in entity.attrs.items() if n not in names}, now)


def set_value(entity: Entity, name: str, value: Any, now: float) -> Entity:
    old = entity.attrs.get(name)
    if old is None:
        raise NgsiError(404, "NotFound", f"The entity does not have such an attribute: {name}")
    value = _checked_value(value, old.type, f"value of attribute {name!r}", old.metadata)
    new = dict(entity.attrs)
    new[name] = Attribute(old.type, value, old.metadata, old.created, now)
    return entity.with_attrs(new, now)


# --- rendering ---------------------------------------------------------------------------

def parse_list_param(raw: str | None) -> list[str] | None:
    if raw is None:
        return None
    return [item for item in raw.split(",") if item]


def _metadata_view(attr: Attribute, wanted: Sequence[str] | None) -> dict[str, Any]:
    if wanted is None:
        return {k: dict(v) for k, v in attr.metadata.items()}
    out = {k: dict(v) for k, v in attr.metadata.items() if "*" in wanted or k in wanted}
    for name in BUILTIN_METADATA:
        if name in wanted and name not in out:
            stamp = attr.created if name == "dateCreated" else attr.modified
            out[name] = {"type": "DateTime", "value": from_epoch(stamp)}
    return out


def attribute_json(entity: Entity, name: str, metadata: Sequence[str] | None = None) -> dict[str, Any] | None:
    attr = entity.attrs.get(name)
    if attr is not None:
        return {"type": attr.type, "value": attr.value, "metadata": _metadata_view(attr, metadata)}
    if name in BUILTIN_ATTRS:
        return dict(_builtins(entity.created, entity.modified, entity.service_path)[name])
    return None


def selected_attrs(entity: Entity, attrs: Sequence[str] | None) -> list[str]:
    if attrs is None:
        return list(entity.attrs)
    names: list[str] = []
    for name in attrs:
        if name == "*":
            names.extend(n for n in entity.attrs if n not in names)
        elif name not in names and (name in entity.attrs or name in BUILTIN_ATTRS):
            names.append(name)
    return names


def render(entity: Entity, mode: str = "normalized", attrs: Sequence[str] | None = None,
           metadata: Sequence[str] | None = None) -> Any:
    """``mode``: normalized, keyValues, values or unique."""
    if mode == "normalized" and attrs is None and metadata is None:
        return entity.normalized
    names = selected_attrs(entity, attrs)
    if mode in ("values", "unique"):
        values = [attribute_json(entity, n)["value"] for n in names]  # type: ignore[index]
        return _unique(values) if mode == "unique" else values
    out: dict[str, Any] = {"id": entity.id, "type": entity.type}
    for name in names:
        data = attribute_json(entity, name, metadata)
        assert data is not None
        out[name] = data["value"] if mode == "keyValues" else data
    return out


def render_attrs(entity: Entity, mode: str, attrs: Sequence[str] | None,
                 metadata: Sequence[str] | None) -> Any:
    whole = render(entity, mode, attrs, metadata)
    if isinstance(whole, list):
        return whole
    return {k: v for k, v in whole.items() if k not in ("id", "type")}


def _unique(values: list[Any]) -> list[Any]:
    seen: list[str] = []
    out = []
    for value in values:
        key = json.dumps(value, sort_keys=True)
        if key not in seen:
            seen.append(key)
            out.append(value)
    return out

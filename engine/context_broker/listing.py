"""Selecting, ordering and paging entities for ``GET /v2/entities`` and ``POST /v2/op/query``.

Pure functions over :class:`Entity` lists: :class:`Selector` (``id``/``idPattern``, ``type``/
``typePattern``, ``q``, ``mq``), :func:`parse_order_by` / :func:`order` (Orion's ``orderBy``:
attributes, ``id``, ``type``, ``dateCreated``, ``dateModified``, ``!`` for descending; values of
mixed JSON kinds ordered as MongoDB does: null < number < string < object < array < boolean)
and :func:`type_summaries` (``GET /v2/types``).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from engine.context_broker.contract import bad_request
from engine.context_broker.entities import Entity
from engine.context_broker.q import Query


@dataclass(frozen=True)
class Selector:
    """One way of naming entities: exact ids or an id pattern, exact types or a type pattern.
    ``None`` means any."""

    ids: frozenset[str] | None = None
    id_pattern: re.Pattern[str] | None = None
    types: frozenset[str] | None = None
    type_pattern: re.Pattern[str] | None = None

    def matches(self, entity: Entity) -> bool:
        if self.ids is not None and entity.id not in self.ids:
            return False
        if self.types is not None and entity.type not in self.types:
            return False
        if self.id_pattern is not None and not self.id_pattern.search(entity.id):
            return False
        return self.type_pattern is None or bool(self.type_pattern.search(entity.type))


def pattern(text: str, field: str) -> re.Pattern[str]:
    try:
        return re.compile(text)
    except re.error as err:
        raise bad_request(f"Invalid regex for {field}: {text!r} ({err})") from None


def select(entities: Iterable[Entity], selectors: Sequence[Selector], q: Query | None,
           mq: Query | None) -> list[Entity]:
    """The entities any selector names and ``q`` and ``mq`` match, in their order."""
    out = list(entities)
    active = [sel for sel in selectors if sel != Selector()]
    if len(active) == 1 and active[0].types is not None and active[0] == Selector(types=active[0].types):
        types = active[0].types
        out = [e for e in out if e.type in types]
    elif active:
        out = [e for e in out if any(sel.matches(e) for sel in active)]
    for query in (q, mq):
        if query is not None:
            for test in query.tests:
                out = [e for e in out if test(e.query_view)]
    return out


def parse_order_by(text: str | None) -> list[tuple[str, bool]] | None:
    """[(field, descending)], or None without ``orderBy``; 400 for an empty or repeated field."""
    if text is None:
        return None
    tokens = text.split(",")
    out: list[tuple[str, bool]] = []
    seen = set()
    for position, token in enumerate(tokens):
        descending = token.startswith("!")
        name = token[1:] if descending else token
        if not name:
            raise bad_request(f"Invalid orderBy: empty field at item {position} of {text!r}")
        if name == "geo:distance":
            raise bad_request("orderBy geo:distance needs a geographical query, which plantkg does "
                              "not support")
        if name in seen:
            raise bad_request(f"Invalid orderBy: field {name!r} repeated in {text!r} (each field once)")
        seen.add(name)
        out.append((name, descending))
    return out


def _rank(value: Any) -> tuple[int, Any]:
    if value is None:
        return (0, 0)
    if isinstance(value, bool):
        return (5, value)
    if isinstance(value, (int, float)):
        return (1, value)
    if isinstance(value, str):
        return (2, value)
    if isinstance(value, dict):
        return (3, json.dumps(value, sort_keys=True))
    return (4, json.dumps(value, sort_keys=True))


def _field(entity: Entity, name: str) -> Any:
    if name == "id":
        return entity.id
    if name == "type":
        return entity.type
    if name == "dateCreated":
        return entity.created
    if name == "dateModified":
        return entity.modified
    attr = entity.attrs.get(name)
    return None if attr is None else attr.value


def order(entities: list[Entity], order_by: list[tuple[str, bool]] | None) -> list[Entity]:
    if not order_by:
        return entities
    out = list(entities)
    for name, descending in reversed(order_by):
        out.sort(key=lambda e: _rank(_field(e, name)), reverse=descending)
    return out


def type_summaries(entities: Iterable[Entity], detail: bool = True) -> dict[str, dict[str, Any]]:
    """{type: {"attrs": {name: {"types": [...]}}, "count": n}}, types in alphabetical order."""
    acc: dict[str, tuple[dict[str, set[str]], list[int]]] = {}
    for entity in entities:
        attrs, count = acc.setdefault(entity.type, ({}, [0]))
        count[0] += 1
        for name, attr in entity.attrs.items():
            attrs.setdefault(name, set()).add(attr.type)
    return {t: {"attrs": {n: {"types": sorted(ts) if detail else []} for n, ts in sorted(attrs.items())},
                "count": count[0]}
            for t, (attrs, count) in sorted(acc.items())}

"""Restrict a constraint's sub-queries to the values its few focus nodes can join (semi-join).

An incremental validation re-runs a query for a few focus nodes, but Oxigraph evaluates a
sub-query of it (``{ SELECT ... GROUP BY ... }``) whole, for every node of the plant: a grouped
sub-query over every Kafka broker's topics cost ~0.4 s at 100k resources for 20 focus nodes.

When the sub-query projects a variable ``?v`` that it binds in a triple pattern before any
OPTIONAL, MINUS, BIND or nested group (as :func:`kg.sparql_scope.binds_this` reads it) and groups by it (or
does not group at all), restricting its input to ``?v`` in a set ``S`` keeps exactly its result
rows whose ``?v`` is in ``S`` (each group is one value of ``?v``). If ``S`` holds every value of
``?v`` a solution of the whole query can have, the join with the rest of the query gives the same
solutions. :func:`reduce_subqueries` takes ``S`` from walking the query's patterns that hold in
every solution (:mod:`kg.sparql_deps`) from the focus nodes to ``?v`` — every solution binds all of
them, so its value of ``?v`` is reached — and writes ``VALUES ?v { S }`` into the sub-query. A
sub-query that does not meet these conditions is left whole. The query text is otherwise as
written, so the answer is the one the unrestricted query gives (tests/unit/test_incremental.py).
"""

from __future__ import annotations

import re

import pyoxigraph as ox

from kg.sparql_deps import ALL, Deps, Lookup, _TooMany
from kg.sparql_scope import _STRING_OR_IRI, _TOKEN, _bound_before_any_operator, _skip

_SELECT = re.compile(r"(?i)\bselect\b")
_MODIFIERS = {"order", "limit", "offset", "values"}  # HAVING filters whole groups: kept


def _blank_same_length(text: str) -> str:
    """``text`` with strings, IRIs and comments filled in, every offset kept."""
    def fill(m: re.Match[str]) -> str:
        t = m.group(0)
        if t.startswith("#"):
            return " " * len(t)
        return t[0] + "x" * (len(t) - 2) + t[-1]
    return _STRING_OR_IRI.sub(fill, text)


def reduce_subqueries(query: str, deps: Deps, focus: list[object], lookup: Lookup, target: str = "this") -> str:
    """``query`` with each sub-query (but the first, the focus join) restricted as the module
    doc says; ``deps`` is the query's reading and ``focus`` the focus nodes it is run for."""
    blank = _blank_same_length(query)
    spans = []
    for m in _SELECT.finditer(blank):
        brace = blank.rfind("{", 0, m.start())
        if brace < 0 or blank[brace + 1:m.start()].strip():
            continue  # the outer SELECT, or a SELECT not opening a group
        spans.append((brace, _skip(blank, brace, "{", "}")))
    edits: list[tuple[int, str]] = []
    for start, end in spans[1:]:
        where = blank.find("{", start + 1)
        head = blank[start + 1:where]
        close = _skip(blank, where, "{", "}")
        tail = _TOKEN.findall(blank[close:end - 1])
        if any(t.lower() in _MODIFIERS for t in tail):
            continue
        keys = _group_keys(tail)
        body = blank[where + 1:close - 1]
        for var in _projected(head):
            if (keys is not None and var not in keys) or not _bound_before_any_operator(body, var):
                continue
            values = _values_of(deps, var, focus, lookup, target)
            if values is None:
                continue
            terms = " ".join(str(v) for v in values if not isinstance(v, ox.BlankNode))
            if len(terms.split()) != len(values):
                continue
            edits.append((where + 1, f" VALUES ?{var} {{ {terms} }} "))
            break
    for pos, text in sorted(edits, reverse=True):
        query = query[:pos] + text + query[pos:]
    return query


def _projected(head: str) -> list[str]:
    """Plain variables a SELECT clause projects (not computed ones, not ``*``)."""
    depth, out = 0, []
    for t in _TOKEN.findall(head):
        if t == "(":
            depth += 1
        elif t == ")":
            depth -= 1
        elif depth == 0 and t[0] in "?$":
            out.append(t[1:])
    return out


def _group_keys(tail: list[str]) -> set[str] | None:
    """GROUP BY variables of a sub-query's tail; None when it does not group (then every
    projected variable is a key); an empty set when it groups by expressions only."""
    lowered = [t.lower() for t in tail]
    if "group" not in lowered:
        return None
    keys, depth = set(), 0
    for t in tail[lowered.index("group") + 2:]:
        if t == "(":
            depth += 1
        elif t == ")":
            depth -= 1
        elif depth == 0 and t[0] in "?$":
            keys.add(t[1:])
        elif depth == 0:
            break
    return keys


def _values_of(deps: Deps, var: str, focus: list[object], lookup: Lookup, target: str) -> set[object] | None:
    """Values of ``?var`` reached from the focus nodes along the patterns that hold in every
    solution (no conditional part); None when ``?var`` is not reached that way."""
    usable = [i for i, p in enumerate(deps.patterns) if not p.scopes and not p.unsafe]
    if not deps._reachable(var, {target}, -1, usable):
        return None
    try:
        found = deps._levels(var, {target: set(focus)}, usable, lookup, stop=False)  # type: ignore[arg-type]
    except _TooMany:
        return None
    return found if found is not ALL else None

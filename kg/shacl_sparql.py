"""The fast SHACL engine: each constraint of the shapes model becomes one SPARQL SELECT on Oxigraph.

Why: pySHACL walks the data graph node by node in Python and needs ~10 s for a 10k-resource plant;
one query per constraint over Oxigraph's indexes answers the same question in a fraction of that.
pySHACL stays the reference: the test suite runs both engines over every shape case and requires
identical results (``tests/unit/test_validate_engines.py``).

Every query returns the violations only: rows of ``?this`` (focus node), ``?value`` and ``?path``.
Constants taken from the shapes (classes, predicates, patterns, bounds) are written into the query
as RDF terms serialised by Oxigraph itself (``str(term)`` is N-Triples syntax, which SPARQL
accepts), never as raw strings, so a quote or brace in a pattern cannot change the query.

Semantics follow SHACL §2.1 (targets, SHACL instances through rdfs:subClassOf*), §4 (core
components) and §5 (SPARQL-based constraints, ``$this`` pre-bound by joining the target pattern
into the query's top-level group).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Iterator

import pyoxigraph as ox
from rdflib import Literal, URIRef
from rdflib.term import Node

from kg.namespaces import SH, XSD
from kg.shapes import CoreConstraint, Shape, ShapesGraph, SparqlConstraint, Target

_TYPE = "<http://www.w3.org/1999/02/22-rdf-syntax-ns#type>/<http://www.w3.org/2000/01/rdf-schema#subClassOf>*"

#: XSD datatypes whose well-formedness a SPARQL cast can check (an ill-typed literal fails the cast).
_CASTABLE = {XSD.integer, XSD.decimal, XSD.double, XSD.float, XSD.boolean, XSD.dateTime}

_NODE_KIND = {
    SH.IRI: "isIRI(?value)",
    SH.Literal: "isLiteral(?value)",
    SH.BlankNode: "isBlank(?value)",
    SH.BlankNodeOrIRI: "!isLiteral(?value)",
    SH.BlankNodeOrLiteral: "!isIRI(?value)",
    SH.IRIOrLiteral: "!isBlank(?value)",
}


@dataclass(frozen=True)
class Violation:
    """One raw result row before rendering: the shape and constraint it came from, and the terms."""

    shape: Shape
    component: str
    source: Node | None  # the sh:sparql node, for SPARQL constraints
    focus: ox.NamedNode | ox.BlankNode | ox.Literal
    path: str | None
    value: ox.NamedNode | ox.BlankNode | ox.Literal | None
    message: str


def term(node: Node) -> str:
    """``node`` (rdflib) in SPARQL syntax, serialised by Oxigraph."""
    if isinstance(node, URIRef):
        return str(ox.NamedNode(str(node)))
    if isinstance(node, Literal):
        if node.language:
            return str(ox.Literal(str(node), language=node.language))
        if node.datatype:
            return str(ox.Literal(str(node), datatype=ox.NamedNode(str(node.datatype))))
        return str(ox.Literal(str(node)))
    raise ValueError(f"a blank node cannot be a constant in a query: {node}")


def _focus_pattern(targets: list[Target]) -> str:
    parts = []
    for t in targets:
        if t.kind == "targetClass":
            parts.append(f"?this {_TYPE} {term(t.term)} .")
        elif t.kind == "targetNode":
            parts.append(f"VALUES ?this {{ {term(t.term)} }}")
        elif t.kind == "targetSubjectsOf":
            parts.append(f"?this {term(t.term)} ?_t .")
        elif t.kind == "targetObjectsOf":
            parts.append(f"?_t {term(t.term)} ?this .")
    return " UNION ".join(f"{{ {p} }}" for p in parts)


def _path_triple(shape: Shape, value: str = "?value") -> str:
    assert shape.path is not None
    pred = term(shape.path.predicate)
    return f"{value} {pred} ?this ." if shape.path.inverse else f"?this {pred} {value} ."


def _value_filter(c: CoreConstraint) -> str:
    """A FILTER expression true for a value node that violates ``c``."""
    v = c.value
    match c.component:
        case "DatatypeConstraintComponent":
            ok = f"isLiteral(?value) && sameTerm(DATATYPE(?value), {term(v)})"  # type: ignore[arg-type]
            if v in _CASTABLE:
                ok += f" && COALESCE(isLiteral({term(v)}(STR(?value))), false)"  # type: ignore[arg-type]
            return f"!({ok})"
        case "NodeKindConstraintComponent":
            return f"!({_NODE_KIND[v]})"  # type: ignore[index]
        case "ClassConstraintComponent":
            return f"NOT EXISTS {{ ?value {_TYPE} {term(v)} }}"  # type: ignore[arg-type]
        case "PatternConstraintComponent":
            flags = f", {term(Literal(c.flags))}" if c.flags else ""
            return f"isBlank(?value) || !REGEX(STR(?value), {term(v)}{flags})"  # type: ignore[arg-type]
        case "InConstraintComponent":
            members = " || ".join(f"sameTerm(?value, {term(m)})" for m in v)  # type: ignore[union-attr]
            return f"!({members or 'false'})"
        case "MinInclusiveConstraintComponent":
            return f"!COALESCE(?value >= {term(v)}, false)"  # type: ignore[arg-type]
        case "MaxInclusiveConstraintComponent":
            return f"!COALESCE(?value <= {term(v)}, false)"  # type: ignore[arg-type]
        case "MinExclusiveConstraintComponent":
            return f"!COALESCE(?value > {term(v)}, false)"  # type: ignore[arg-type]
        case "MaxExclusiveConstraintComponent":
            return f"!COALESCE(?value < {term(v)}, false)"  # type: ignore[arg-type]
        case "MinLengthConstraintComponent":
            return f"isBlank(?value) || STRLEN(STR(?value)) < {int(v)}"  # type: ignore[arg-type]
        case "MaxLengthConstraintComponent":
            return f"isBlank(?value) || STRLEN(STR(?value)) > {int(v)}"  # type: ignore[arg-type]
    raise AssertionError(c.component)


def core_query(shape: Shape, focus: str, c: CoreConstraint) -> str:
    """The SELECT returning the violations of core constraint ``c`` of ``shape``."""
    if c.component == "MinCountConstraintComponent":
        n = int(c.value)  # type: ignore[arg-type]
        if n == 1:
            return f"SELECT DISTINCT ?this WHERE {{ {focus} FILTER NOT EXISTS {{ {_path_triple(shape)} }} }}"
        return (f"SELECT ?this WHERE {{ {{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} "
                f"OPTIONAL {{ {_path_triple(shape)} }} }} GROUP BY ?this HAVING (COUNT(DISTINCT ?value) < {n})")
    if c.component == "MaxCountConstraintComponent":
        n = int(c.value)  # type: ignore[arg-type]
        if n == 1:  # two different values: an index join, ~3x faster than grouping every focus node
            return (f"SELECT DISTINCT ?this WHERE {{ {_path_triple(shape, '?value')} {_path_triple(shape, '?_other')} "
                    f"FILTER(!sameTerm(?value, ?_other)) {{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} }}")
        return (f"SELECT ?this WHERE {{ {{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} "
                f"{_path_triple(shape)} }} GROUP BY ?this HAVING (COUNT(DISTINCT ?value) > {n})")
    if c.component == "HasValueConstraintComponent":
        if shape.path is None:
            return f"SELECT DISTINCT ?this WHERE {{ {focus} FILTER(!sameTerm(?this, {term(c.value)})) }}"  # type: ignore[arg-type]
        return (f"SELECT DISTINCT ?this WHERE {{ {focus} "
                f"FILTER NOT EXISTS {{ {_path_triple(shape, term(c.value))} }} }}")  # type: ignore[arg-type]
    return value_query(shape, focus, [c])


#: Components whose violations are single value nodes, each tested on its own by a FILTER.
_COUNTS = ("MinCountConstraintComponent", "MaxCountConstraintComponent", "HasValueConstraintComponent")


def value_query(shape: Shape, focus: str, constraints: list[CoreConstraint]) -> str:
    """One SELECT for all value-node constraints of ``shape``: the focus nodes and their values are
    walked once; ``?f<i>`` is true when the value violates ``constraints[i]``.

    The inner FILTER (any constraint violated; an error in one test counts as false, as in a
    FILTER of its own) sits on the value scan, where Oxigraph evaluates it before joining the focus
    nodes; the flags are computed for the violating rows only (``COALESCE`` for the same reason).
    """
    values = _path_triple(shape) if shape.path else "BIND(?this AS ?value)"
    tests = [_value_filter(c) for c in constraints]
    if len(tests) == 1:  # nothing to tell apart: the plain query, one level less for Oxigraph
        return (f"SELECT DISTINCT ?this ?value (true AS ?f0) WHERE {{ {{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} "
                f"{values} FILTER({tests[0]}) }}")
    binds = " ".join(f"BIND(COALESCE({t}, false) AS ?f{i})" for i, t in enumerate(tests))
    flags = " ".join(f"?f{i}" for i in range(len(constraints)))
    either = " || ".join(f"({t})" for t in tests)
    return (f"SELECT ?this ?value {flags} WHERE {{ {{ SELECT DISTINCT ?this ?value WHERE {{ "
            f"{{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} {values} FILTER({either}) }} }} {binds} }}")


_STRING_OR_IRI = re.compile(r'"""(?:[^"\\]|\\.|"(?!""))*"""|\'\'\'(?:[^\'\\]|\\.|\'(?!\'\'))*\'\'\'|"(?:[^"\\\n]|\\.)*"|\'(?:[^\'\\\n]|\\.)*\'|<[^<>"{}|^`\\\s]*>|#[^\n]*')


def _top_level_brace(query: str) -> int:
    """Index of the ``{`` that opens the WHERE clause (skipping strings, IRIs and comments)."""
    pos = 0
    while pos < len(query):
        match = _STRING_OR_IRI.search(query, pos)
        end = match.start() if match else len(query)
        brace = query.find("{", pos, end)
        if brace != -1:
            return brace
        if not match:
            break
        pos = match.end()
    raise ValueError("no WHERE clause")


def sparql_query(shape: Shape, focus: str, c: SparqlConstraint) -> str:
    """The constraint's SELECT with ``$this`` joined to the targets and ``$PATH`` substituted."""
    text = c.select.replace("$this", "?this")
    if shape.path is not None:
        pred = term(shape.path.predicate)
        text = text.replace("$PATH", f"^{pred}" if shape.path.inverse else pred)
    brace = _top_level_brace(text)
    prefixes = "".join(f"PREFIX {p}: <{ns}>\n" for p, ns in c.prefixes)
    return prefixes + text[: brace + 1] + f" {{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} " + text[brace + 1 :]


_TEMPLATE = re.compile(r"\{[?$]([A-Za-z_][A-Za-z0-9_]*)\}")


def _lexical(t: ox.NamedNode | ox.BlankNode | ox.Literal | None) -> str:
    return "" if t is None else t.value


def _message(messages: tuple[Literal, ...], fallback: str, row: ox.QuerySolution | None) -> str:
    if not messages:
        return fallback
    english = [m for m in messages if m.language in (None, "en")]
    text = str((english or list(messages))[0])
    if row is None:
        return text

    def fill(match: re.Match[str]) -> str:
        try:
            return _lexical(row[match.group(1)])
        except (KeyError, IndexError):
            return match.group(0)

    return _TEMPLATE.sub(fill, text)


def _path_text(shape: Shape) -> str | None:
    if shape.path is None:
        return None
    return ("^" if shape.path.inverse else "") + str(shape.path.predicate)


def _get(row: ox.QuerySolution, name: str):  # noqa: ANN202 - Oxigraph term or None
    try:
        return row[name]
    except (KeyError, IndexError):
        return None


def _fallback(c: CoreConstraint) -> str:
    return f"{c.component.removesuffix('ConstraintComponent')} constraint violated"


def _present(store: ox.Store, predicate: Node) -> bool:
    """Whether any graph of ``store`` uses ``predicate`` (if not, a path over it has no values)."""
    return any(True for _ in store.quads_for_pattern(None, ox.NamedNode(str(predicate)), None, None))


def run_shape(store: ox.Store, shape: Shape, focus: str) -> Iterator[Violation]:
    """Every violation of ``shape``'s constraints for the focus nodes matched by ``focus``."""
    used = shape.path is None or _present(store, shape.path.predicate)
    per_value = [c for c in shape.core if c.component not in _COUNTS]
    if per_value and used:
        for row in store.query(value_query(shape, focus, per_value), use_default_graph_as_union=True):
            for i, c in enumerate(per_value):
                if row[f"f{i}"].value == "true":
                    yield Violation(shape, c.component, None, row["this"], _path_text(shape), row["value"],
                                    _message(shape.messages, _fallback(c), None))
    for c in shape.core:
        if c.component not in _COUNTS or (c.component == "MaxCountConstraintComponent" and not used):
            continue  # no value at all: nothing can exceed a maximum
        for row in store.query(core_query(shape, focus, c), use_default_graph_as_union=True):
            yield Violation(shape, c.component, None, row["this"], _path_text(shape), None,
                            _message(shape.messages, _fallback(c), None))
    for s in shape.sparql:
        query = sparql_query(shape, focus, s)
        for row in store.query(query, use_default_graph_as_union=True):
            path = _path_text(shape)
            if path is None and (p := _get(row, "path")) is not None:
                path = p.value
            value = _get(row, "value")
            if value is None and shape.path is None:
                value = row["this"]
            yield Violation(shape, "SPARQLConstraintComponent", s.node, row["this"], path, value,
                            _message(s.messages or shape.messages, "SPARQL constraint violated", row))


def run(store: ox.Store, shapes: ShapesGraph) -> Iterator[Violation]:
    """Validate ``store`` (union of its graphs) against every active shape."""
    for node_shape in shapes.node_shapes:
        if node_shape.deactivated or not node_shape.targets:
            continue
        focus = _focus_pattern(node_shape.targets)
        yield from run_shape(store, node_shape, focus)
        for prop in node_shape.properties:
            if not prop.deactivated:
                yield from run_shape(store, prop, focus)



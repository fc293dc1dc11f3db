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
from typing import Callable, Iterable, Iterator

import pyoxigraph as ox
from rdflib import Literal, URIRef
from rdflib.term import Node

from kg.focus import Focus
from kg.namespaces import SH, XSD
from kg.shapes import CoreConstraint, Shape, ShapesGraph, SparqlConstraint, Target
from kg.sparql_scope import binds_this

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


@dataclass(frozen=True)
class Targets:
    """A node shape's targets three ways: the SPARQL group binding ``?this``, the (kind, term)
    pairs :class:`~kg.focus.Focus` tests a node against, and a key naming them for its cache."""

    pattern: str
    pairs: tuple[tuple[str, object], ...]

    @property
    def key(self) -> str:
        return self.pattern


def targets_of(targets: list[Target]) -> Targets:
    pairs = tuple((t.kind, _ox(t.term) if t.kind == "targetNode" else str(t.term)) for t in targets)
    return Targets(_focus_pattern(targets), pairs)


def _ox(node: Node) -> ox.NamedNode | ox.Literal:
    """``node`` (rdflib) as an Oxigraph term."""
    if isinstance(node, URIRef):
        return ox.NamedNode(str(node))
    if isinstance(node, Literal):
        if node.language:
            return ox.Literal(str(node), language=node.language)
        if node.datatype:
            return ox.Literal(str(node), datatype=ox.NamedNode(str(node.datatype)))
        return ox.Literal(str(node))
    raise ValueError(f"a blank node cannot be a target node: {node}")


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


def core_query(shape: Shape, focus: str, c: CoreConstraint, scoped: bool = True) -> str:
    """The SELECT returning the violations of core constraint ``c`` of ``shape``; ``scoped``
    False leaves the focus pattern out of a maximum count (the path binds ``?this``)."""
    if c.component == "MinCountConstraintComponent":
        n = int(c.value)  # type: ignore[arg-type]
        if n == 1:
            return f"SELECT DISTINCT ?this WHERE {{ {focus} FILTER NOT EXISTS {{ {_path_triple(shape)} }} }}"
        return (f"SELECT ?this WHERE {{ {{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} "
                f"OPTIONAL {{ {_path_triple(shape)} }} }} GROUP BY ?this HAVING (COUNT(DISTINCT ?value) < {n})")
    if c.component == "MaxCountConstraintComponent":
        n = int(c.value)  # type: ignore[arg-type]
        scope = f"{{ SELECT DISTINCT ?this WHERE {{ {focus} }} }}" if scoped else ""
        if n == 1:  # two different values: an index join, ~3x faster than grouping every focus node
            return (f"SELECT DISTINCT ?this WHERE {{ {_path_triple(shape, '?value')} {_path_triple(shape, '?_other')} "
                    f"FILTER(!sameTerm(?value, ?_other)) {scope} }}")
        return (f"SELECT ?this WHERE {{ {scope} {_path_triple(shape)} }} GROUP BY ?this "
                f"HAVING (COUNT(DISTINCT ?value) > {n})")
    if c.component == "HasValueConstraintComponent":
        if shape.path is None:
            return f"SELECT DISTINCT ?this WHERE {{ {focus} FILTER(!sameTerm(?this, {term(c.value)})) }}"  # type: ignore[arg-type]
        return (f"SELECT DISTINCT ?this WHERE {{ {focus} "
                f"FILTER NOT EXISTS {{ {_path_triple(shape, term(c.value))} }} }}")  # type: ignore[arg-type]
    return value_query(shape, focus, [c])


#: Components whose violations are single value nodes, each tested on its own by a FILTER.
_COUNTS = ("MinCountConstraintComponent", "MaxCountConstraintComponent", "HasValueConstraintComponent")


def value_query(shape: Shape, focus: str | None, constraints: list[CoreConstraint]) -> str:
    """One SELECT for all value-node constraints of ``shape``: the focus nodes and their values are
    walked once; ``?f<i>`` is true when the value violates ``constraints[i]``.

    The inner FILTER (any constraint violated; an error in one test counts as false, as in a
    FILTER of its own) sits on the value scan, where Oxigraph evaluates it before joining the focus
    nodes; the flags are computed for the violating rows only (``COALESCE`` for the same reason).
    ``focus`` None (a property shape only: its path binds ``?this``): every subject of the path,
    the caller keeps the focus nodes' rows.
    """
    values = _path_triple(shape) if shape.path else "BIND(?this AS ?value)"
    scope = "" if focus is None else f"{{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} "
    tests = [_value_filter(c) for c in constraints]
    if len(tests) == 1:  # nothing to tell apart: the plain query, one level less for Oxigraph
        return f"SELECT DISTINCT ?this ?value (true AS ?f0) WHERE {{ {scope}{values} FILTER({tests[0]}) }}"
    binds = " ".join(f"BIND(COALESCE({t}, false) AS ?f{i})" for i, t in enumerate(tests))
    flags = " ".join(f"?f{i}" for i in range(len(constraints)))
    either = " || ".join(f"({t})" for t in tests)
    return (f"SELECT ?this ?value {flags} WHERE {{ {{ SELECT DISTINCT ?this ?value WHERE {{ "
            f"{scope}{values} FILTER({either}) }} }} {binds} }}")


def class_query(shape: Shape, c: CoreConstraint, focus: str | None = None, per_row: bool = False) -> str:
    """A property shape's ``sh:class`` alone, without the focus nodes: the path's values that are
    no SHACL instance of the class. ``MINUS`` anti-joins the class's instances (found once) by
    hash, where ``FILTER NOT EXISTS`` walked ``rdf:type/rdfs:subClassOf*`` per value (~20x slower
    on 100k values). The two agree here: the right side binds ``?value`` only, never to a literal."""
    scope = "" if focus is None else f"{{ SELECT DISTINCT ?this WHERE {{ {focus} }} }} "
    if per_row:  # a few focus nodes: test each value, rather than finding every instance
        return (f"SELECT DISTINCT ?this ?value WHERE {{ {scope}{_path_triple(shape)} "
                f"FILTER NOT EXISTS {{ ?value {_TYPE} {term(c.value)} }} }}")  # type: ignore[arg-type]
    return (f"SELECT DISTINCT ?this ?value WHERE {{ {scope}{_path_triple(shape)} "
            f"MINUS {{ ?value {_TYPE} {term(c.value)} }} }}")  # type: ignore[arg-type]


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


def sparql_free_query(shape: Shape, c: SparqlConstraint) -> str:
    """The constraint's SELECT as written (``$PATH`` substituted), for a query that binds ``?this``
    itself (:func:`kg.sparql_scope.binds_this`): its rows are kept for the focus nodes afterwards."""
    text = c.select.replace("$this", "?this")
    if shape.path is not None:
        pred = term(shape.path.predicate)
        text = text.replace("$PATH", f"^{pred}" if shape.path.inverse else pred)
    return "".join(f"PREFIX {p}: <{ns}>\n" for p, ns in c.prefixes) + text


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


#: Components whose query needs no focus pattern (the path binds ``?this``): the rows are kept
#: for the focus nodes afterwards.
_UNSCOPED = ("MaxCountConstraintComponent",)


@dataclass(frozen=True, eq=False)
class Unit:
    """One query of the validator: some constraints of one shape, for the focus nodes of its
    node shape. ``query(focus)`` is its text joined with the focus pattern ``focus`` (a SPARQL
    group binding ``?this``), or without any when ``focus`` is None and ``free`` allows it;
    ``violations(row)`` reads one result row. Units are what an incremental validation re-runs
    for the focus nodes an edit may have changed (:mod:`kg.validate_delta`)."""

    shape: Shape
    targets: Targets
    kind: str  # "values", "class", "count" or "sparql"
    constraints: tuple[CoreConstraint, ...] = ()
    sparql: SparqlConstraint | None = None

    @property
    def free(self) -> bool:
        """Whether the query binds ``?this`` itself, so it may run without the focus pattern."""
        if self.kind in ("values", "class"):
            return self.shape.path is not None
        if self.kind == "count":
            return self.constraints[0].component in _UNSCOPED
        return binds_this(self.sparql.select.replace("$this", "?this"))  # type: ignore[union-attr]

    @property
    def predicate(self) -> URIRef | None:
        """The path's predicate a core unit reads (no value, no violation but a minimum count)."""
        if self.kind == "sparql" or self.shape.path is None:
            return None
        if self.kind == "count" and self.constraints[0].component != "MaxCountConstraintComponent":
            return None
        return self.shape.path.predicate

    def query(self, focus: str | None, few: bool = False) -> str:
        """``few``: the focus is a few nodes (an incremental run), where per-row tests beat
        set operations."""
        if self.kind == "values":
            return value_query(self.shape, focus, list(self.constraints))
        if self.kind == "class":
            return class_query(self.shape, self.constraints[0], focus, per_row=few)
        if self.kind == "count":
            return core_query(self.shape, focus or "", self.constraints[0], focus is not None)
        if focus is None:
            return sparql_free_query(self.shape, self.sparql)  # type: ignore[arg-type]
        return sparql_query(self.shape, focus, self.sparql)  # type: ignore[arg-type]

    def violations(self, row: ox.QuerySolution) -> list[Violation]:
        shape, path = self.shape, _path_text(self.shape)
        if self.kind == "values":
            return [Violation(shape, c.component, None, row["this"], path, row["value"],
                              _message(shape.messages, _fallback(c), None))
                    for i, c in enumerate(self.constraints) if row[f"f{i}"].value == "true"]
        if self.kind in ("class", "count"):
            c = self.constraints[0]
            value = row["value"] if self.kind == "class" else None
            return [Violation(shape, c.component, None, row["this"], path, value,
                              _message(shape.messages, _fallback(c), None))]
        s = self.sparql
        assert s is not None
        if path is None and (p := _get(row, "path")) is not None:
            path = p.value
        value = _get(row, "value")
        if value is None and shape.path is None:
            value = row["this"]
        return [Violation(shape, "SPARQLConstraintComponent", s.node, row["this"], path, value,
                          _message(s.messages or shape.messages, "SPARQL constraint violated", row))]


def shape_units(shape: Shape, targets: Targets) -> list[Unit]:
    """The queries that check ``shape``: its value constraints merged into one (a property
    shape's ``sh:class`` apart, anti-joined by MINUS), one per count or value-presence
    constraint, one per SPARQL constraint."""
    out: list[Unit] = []
    separate_class = shape.path is not None
    per_value = tuple(c for c in shape.core if c.component not in _COUNTS
                      and not (separate_class and c.component == "ClassConstraintComponent"))
    if per_value:
        out.append(Unit(shape, targets, "values", per_value))
    out += [Unit(shape, targets, "class", (c,)) for c in shape.core
            if separate_class and c.component == "ClassConstraintComponent"]
    out += [Unit(shape, targets, "count", (c,)) for c in shape.core if c.component in _COUNTS]
    out += [Unit(shape, targets, "sparql", sparql=s) for s in shape.sparql]
    return out


def units(shapes: ShapesGraph) -> list[Unit]:
    """Every query of every active shape, in the order the validator runs them."""
    out: list[Unit] = []
    for node_shape in shapes.node_shapes:
        if node_shape.deactivated or not node_shape.targets:
            continue
        targets = targets_of(node_shape.targets)
        out += shape_units(node_shape, targets)
        for prop in node_shape.properties:
            if not prop.deactivated:
                out += shape_units(prop, targets)
    return out


def run_unit(store: ox.Store, unit: Unit, focus: Focus, options: dict[str, object],
             nodes: Iterable[ox.NamedNode | ox.BlankNode | ox.Literal] | None = None,
             rewrite: Callable[[str, list], str] | None = None) -> Iterator[Violation]:
    """The violations ``unit`` finds: for every focus node, or for the focus nodes among
    ``nodes`` only (the query then starts from them, a ``VALUES`` block of the few; ``rewrite``
    may restrict the query further for them, giving the same rows: kg.subquery_reduce)."""
    targets = unit.targets

    def keep(node: object) -> bool:
        return focus.contains(targets.key, targets.pattern, list(targets.pairs), node)  # type: ignore[arg-type]

    predicate = unit.predicate
    if predicate is not None and not _present(store, predicate):
        return  # no value at all: nothing to check, nothing can exceed a maximum
    if nodes is not None:
        chosen = [n for n in nodes if keep(n)]
        if not chosen:
            return
        text = unit.query(f"VALUES ?this {{ {' '.join(str(n) for n in chosen)} }}", few=True)
        if rewrite is not None:
            text = rewrite(text, chosen)
        for row in store.query(text, **options):  # type: ignore[arg-type]
            yield from unit.violations(row)
        return
    if focus.is_empty(targets.key, list(targets.pairs)):
        return  # no focus node: the shape has no results
    free = unit.free and focus.is_large(targets.key, list(targets.pairs))
    for row in store.query(unit.query(None if free else targets.pattern), **options):  # type: ignore[arg-type]
        if not free or keep(row["this"]):
            yield from unit.violations(row)


def dataset(graphs: list[ox.NamedNode] | None) -> dict[str, object]:
    """Query options reading the union of every graph (None) or ``graphs`` only."""
    return {"use_default_graph_as_union": True} if graphs is None else {"default_graph": list(graphs)}


def run(store: ox.Store, shapes: ShapesGraph, graphs: list[ox.NamedNode] | None = None) -> Iterator[Violation]:
    """Validate ``store`` against every active shape: over the union of its graphs, or over
    ``graphs`` only (e.g. the plant and ontology of a store that also holds inferred facts)."""
    options = dataset(graphs)
    focus = Focus(store, graphs, options)
    for unit in units(shapes):
        yield from run_unit(store, unit, focus, options)

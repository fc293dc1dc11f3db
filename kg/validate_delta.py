"""Validation after an edit: re-run each constraint for the focus nodes the edit may have changed.

:class:`Revalidator` holds the raw violations of every query unit of the fast validator
(:func:`kg.shacl_sparql.units`) from the last run. Given the triples an edit removes and adds, it
asks each unit's dependency reading (:mod:`kg.sparql_deps`, on the data before and after the edit)
which focus nodes' results may change, drops the unit's old violations of those nodes and re-runs
the unit for them alone (all of them when the reading cannot narrow the change down). A unit that
reads none of the changed triples keeps its violations as they are. The report is built exactly as
a full validation builds it, and must equal one: ``tests/unit/test_incremental.py`` holds the two
to that on random edits.
"""

from __future__ import annotations

from typing import Callable

import pyoxigraph as ox

from kg.focus import Focus
from kg.load import PlantGraph
from kg.shacl_sparql import Unit, Violation, dataset, run_unit, units
from kg.shapes import ShapesGraph
from kg.namespaces import RDF, RDFS
from kg.sparql_deps import ALL, Deps, Path, Pattern, Triple, analyse, store_lookup
from kg.subquery_reduce import reduce_subqueries
from kg.validate import ValidationReport, report_of

Affected = dict[int, set | None]


_TYPE = ox.NamedNode(str(RDF.type))
_INSTANCE = Path("seq", parts=(Path("iri", _TYPE), Path("star", parts=(Path("iri", ox.NamedNode(str(RDFS.subClassOf))),))))


def focus_patterns(unit: Unit) -> list[Pattern]:
    """The triple patterns of a unit's focus pattern (:func:`kg.shacl_sparql._focus_pattern`)."""
    out = []
    for i, (kind, value) in enumerate(unit.targets.pairs):
        if kind == "targetClass":
            out.append(Pattern("this", _INSTANCE, None, ox.NamedNode(str(value))))
        elif kind == "targetSubjectsOf":
            out.append(Pattern("this", Path("iri", ox.NamedNode(str(value))), None, f"_t{i}"))
        elif kind == "targetObjectsOf":
            out.append(Pattern(f"_t{i}", Path("iri", ox.NamedNode(str(value))), None, "this"))
    return out


def core_deps(unit: Unit) -> Deps:
    """The :class:`~kg.sparql_deps.Deps` of a core unit, written from the queries
    :mod:`kg.shacl_sparql` generates for it (no parsing): the focus patterns, the path's triple
    pattern, and for ``sh:class`` the value's class (under MINUS for a property shape; under a
    FILTER NOT EXISTS on a value that BIND made, i.e. not certainly bound, for a node shape)."""
    shape = unit.shape
    out = Deps(patterns=focus_patterns(unit))
    if shape.path is not None:
        pred = Path("iri", ox.NamedNode(str(shape.path.predicate)))
        triple = (Pattern("value", pred, None, "this") if shape.path.inverse
                  else Pattern("this", pred, None, "value"))
        out.patterns.append(triple)
        if unit.kind == "count":
            c = unit.constraints[0]
            if c.component == "MaxCountConstraintComponent":
                out.patterns.append(Pattern(triple.s if triple.s != "value" else "_other", pred, None,
                                            triple.o if triple.o != "value" else "_other"))
            elif c.component == "HasValueConstraintComponent":
                out.patterns[-1] = Pattern(*(_ox_term(c.value) if x == "value" else x  # type: ignore[arg-type]
                                              for x in (triple.s, triple.path, triple.pvar, triple.o)))
    else:
        out.links.append({"this", "value"})
    for c in unit.constraints:
        if c.component == "ClassConstraintComponent":
            out.patterns.append(Pattern("value", _INSTANCE, None, _ox_term(c.value), unsafe=shape.path is None))  # type: ignore[arg-type]
    return out


def _ox_term(node: object) -> ox.NamedNode | ox.Literal:
    from kg.shacl_sparql import _ox  # noqa: PLC0415

    return _ox(node)  # type: ignore[arg-type]


def _sparql_deps(unit: Unit) -> Deps:
    """A SPARQL unit's reading: its query with a stand-in triple binding ``?this`` at the start
    of the group (where the focus join sits), the stand-in then replaced by the focus patterns
    (a shorter text for rdflib's slow parser, the same reading)."""
    query = unit.query(f"?this <{_STAND_IN}> ?_focus .")
    deps = analyse(query)
    stand_in = ox.NamedNode(_STAND_IN)
    patterns = [p for p in deps.patterns if not (p.path is not None and p.path.iri == stand_in)]
    return Deps(focus_patterns(unit) + patterns, deps.links, deps.opaque)


_STAND_IN = "urn:plantkg:focus"


class Revalidator:
    """The fast validator's state for one plant, kept current edit by edit."""

    def __init__(self, plant: PlantGraph, shapes: ShapesGraph, graphs: list[ox.NamedNode]) -> None:
        self.plant = plant
        self.shapes = shapes
        self.graphs = graphs
        self.units: list[Unit] = units(shapes)
        self._deps: list[Deps | None] = [None] * len(self.units)
        self.found: list[list[Violation]] = []
        #: units re-run (fully, for some nodes) by the last update, for benchmarks and tests
        self.last: dict[str, int] = {}

    def deps(self, i: int) -> Deps:
        if self._deps[i] is None:
            unit = self.units[i]
            self._deps[i] = _sparql_deps(unit) if unit.kind == "sparql" else core_deps(unit)
        return self._deps[i]  # type: ignore[return-value]

    def _reducer(self, i: int) -> Callable[[str, list], str]:
        deps, lookup = self.deps(i), store_lookup(self.plant.store, self.graphs)
        return lambda text, chosen: reduce_subqueries(text, deps, chosen, lookup)

    def full(self) -> ValidationReport:
        """Validate every unit (the store's ``graphs`` only) and remember the violations."""
        store, options = self.plant.store, dataset(self.graphs)
        focus = Focus(store, self.graphs, options)
        self.found = [list(run_unit(store, u, focus, options)) for u in self.units]
        return self.report()

    def report(self) -> ValidationReport:
        return report_of(self.plant, self.shapes, [v for vs in self.found for v in vs])

    def affected(self, changes: list[Triple]) -> Affected:
        """Per unit that reads a changed triple: the focus nodes whose results may change (ALL:
        every one), on the store as it is now. Call it before and after applying the edit."""
        lookup = store_lookup(self.plant.store, self.graphs)
        out: Affected = {}
        for i in range(len(self.units)):
            deps = self.deps(i)
            relevant = [t for t in changes if deps.reads(t)]
            if relevant:
                out[i] = deps.affected("this", relevant, lookup)
        return out

    def update(self, before: Affected, after: Affected) -> ValidationReport:
        """Re-run the units ``before`` | ``after`` name (the store now holds the edited plant)."""
        store, options = self.plant.store, dataset(self.graphs)
        focus = Focus(store, self.graphs, options)
        full = partial = 0
        for i in sorted(set(before) | set(after)):
            a, b = before.get(i, set()), after.get(i, set())
            nodes = ALL if a is ALL or b is ALL else a | b
            if nodes is not ALL and any(isinstance(n, ox.BlankNode) for n in nodes):
                nodes = ALL  # a blank node cannot be written in the query: re-run the whole unit
            unit = self.units[i]
            if nodes is ALL:
                self.found[i] = list(run_unit(store, unit, focus, options))
                full += 1
            elif nodes:
                kept = [v for v in self.found[i] if v.focus not in nodes]
                rewrite = self._reducer(i) if unit.kind == "sparql" else None
                self.found[i] = kept + list(run_unit(store, unit, focus, options, nodes, rewrite))
                partial += 1
        self.last = {"units_full": full, "units_partial": partial}
        return self.report()

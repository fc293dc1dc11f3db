"""Reasoning: what the ontology's OWL definitions and SWRL rules conclude about a plant.

``reason(plant)`` writes the concluded facts into the named graph ``GRAPH_INFERRED`` of the plant's
store, where SPARQL (``engine.derive``, ``plantkg query``, the dashboard) sees them next to the
asserted facts. Nothing here decides what must exist: the TBox files (``ontology/*.ttl``, in
particular ``plantkg-rules.ttl``) do; Python only runs a reasoner and copies its conclusions.

Two engines, held to the same answer by ``tests/unit/test_reason_engines.py``:

- ``owlready2`` (reference): HermiT through owlready2 in a child process with a deadline
  (:mod:`engine.reasoning.rules_owlready`). Complete OWL 2 DL + DL-safe SWRL, but a JVM start per call and a
  cost that grows with the square of the plant (5 s at 1k resources, minutes at 10k).
- ``fast``: the TBox read from the graph (:mod:`engine.reasoning.rules_tbox`) and compiled to SPARQL run on
  Oxigraph to a fixpoint (:mod:`engine.reasoning.rules_fast`). It refuses, naming it, any construct it cannot
  translate, and any plant where its answer could differ from HermiT's.
- ``auto``: ``fast``, and ``owlready2`` when ``fast`` refuses.

What ``GRAPH_INFERRED`` holds afterwards: the entailed facts that no input graph asserts, of two
kinds — ``?x rdf:type pk:C`` for plantkg classes ``pk:C`` and named individuals ``?x``, and the
values of the *derived* object properties (those a SWRL rule concludes or another property is a
sub-property of: ``pk:requiresBridge``, ``pk:mustCarry``), asserted ones included (a ``pk:bridgesTo``
assertion gives a ``pk:requiresBridge`` fact) — plus one marker triple saying which engine ran.
Both engines read the plant under the unique-name assumption (distinct IRIs are distinct things),
which the plant's unique ``pk:id`` s state.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal as Lit

import pyoxigraph as ox

from engine.reasoning import rules_fast, rules_owlready, tbox_cache
from engine.reasoning.rules_errors import (
    InconsistentPlantError, ReasonerFailedError, ReasonerTimeoutError, ReasoningError,
    UnsupportedConstructError,
)
from engine.reasoning.rules_tbox import RESERVED_NAMESPACES
from kg.load import PlantGraph
from kg.namespaces import GRAPH_INFERRED, GRAPH_ONTOLOGY, OWL, PK, RDF, RDFS, SWRL

__all__ = [
    "ENGINES", "Inferences", "InconsistentPlantError", "ReasonerFailedError", "ReasonerTimeoutError",
    "ReasoningError", "UnsupportedConstructError", "input_graphs", "is_reasoned", "reason",
]

Engine = Lit["auto", "fast", "owlready2"]
ENGINES: tuple[str, ...] = ("auto", "fast", "owlready2")
#: Deadline of one HermiT run (JVM included), seconds.
HERMIT_TIMEOUT = 600.0

INFERRED = ox.NamedNode(GRAPH_INFERRED)
_TYPE = ox.NamedNode(str(RDF.type))
_MARKER = ox.NamedNode(str(RDFS.comment))


@dataclass(frozen=True)
class Inferences:
    """What one ``reason`` run wrote into ``GRAPH_INFERRED``.

    ``classes``: plantkg class IRI → individuals newly known to be in it; ``properties``: derived
    property IRI → pairs; both sorted by IRI. ``fallback`` says why ``auto`` did not use ``fast``.
    """

    engine: str
    seconds: float
    classes: tuple[tuple[str, int], ...]
    properties: tuple[tuple[str, int], ...]
    fallback: str | None = None

    def count(self, term: str) -> int:
        """Facts inferred about one class or property (0 when none)."""
        return dict(self.classes).get(term, 0) or dict(self.properties).get(term, 0)

    @property
    def total(self) -> int:
        return sum(n for _, n in self.classes) + sum(n for _, n in self.properties)

    def to_dict(self) -> dict[str, object]:
        return {"engine": self.engine, "seconds": self.seconds, "classes": dict(self.classes),
                "properties": dict(self.properties), "total": self.total, "fallback": self.fallback}


def input_graphs(plant: PlantGraph) -> list[ox.NamedNode]:
    """What reasoning reads: the ontology graph (every TBox file) and the plant files."""
    return [ox.NamedNode(GRAPH_ONTOLOGY), *plant.plant_graphs]


def is_reasoned(plant: PlantGraph) -> bool:
    """Whether ``reason`` ran on this store (its marker is in ``GRAPH_INFERRED``)."""
    return any(True for _ in plant.store.quads_for_pattern(INFERRED, _MARKER, None, INFERRED))


def reason(plant: PlantGraph, *, engine: Engine = "auto", timeout: float = HERMIT_TIMEOUT,
           scratch: ox.NamedNode | None = None) -> Inferences:
    """Infer what the ontology's definitions and rules conclude about ``plant``; write it into
    ``GRAPH_INFERRED`` (replacing an earlier run's) and summarise it.

    ``scratch`` (the fast engine only): keep the facts the fixpoint needed but ``GRAPH_INFERRED``
    does not hold in that graph instead of dropping them, so an incremental run
    (:mod:`engine.reasoning.rules_delta`) can continue from the whole fixpoint.

    Raises :class:`InconsistentPlantError` when the plant contradicts the ontology,
    :class:`UnsupportedConstructError` when ``engine="fast"`` cannot translate the TBox or the
    plant, :class:`ReasonerTimeoutError` / :class:`ReasonerFailedError` from HermiT. On error the
    inferred graph is left empty and unmarked.
    """
    if engine not in ENGINES:
        raise ReasoningError(f"unknown reasoning engine {engine!r}", hint=f"use one of {', '.join(ENGINES)}")
    start = time.perf_counter()
    store = plant.store
    _clear(store, scratch)
    fallback = None
    try:
        if engine in ("auto", "fast"):
            try:
                used = _run_fast(plant, scratch)
            except UnsupportedConstructError as exc:
                if engine == "fast":
                    raise
                _clear(store, scratch)
                fallback = exc.message
                used = _run_owlready2(plant, timeout)
        else:
            used = _run_owlready2(plant, timeout)
    except BaseException:
        _clear(store, scratch)
        raise
    seconds = time.perf_counter() - start
    store.add(ox.Quad(INFERRED, _MARKER, ox.Literal(f"inferred by plantkg reason, engine {used}"), INFERRED))
    classes, properties = _counts(store)
    return Inferences(used, seconds, classes, properties, fallback)


def _clear(store: ox.Store, scratch: ox.NamedNode | None = None) -> None:
    for graph in (INFERRED, scratch):
        if graph is not None and store.contains_named_graph(graph):
            store.remove_graph(graph)


def _where(plant: PlantGraph):  # noqa: ANN202 - a small closure
    """Describe a node for a message: its IRI (or label) and the file it comes from."""
    def describe(node: object) -> str:
        if isinstance(node, ox.NamedNode):
            text = rules_fast.short_name(node.value)
        else:
            text = str(node)
        if isinstance(node, (ox.NamedNode, ox.BlankNode)):
            path = plant.source_of(node)
            if path is not None:
                return f"{text} ({path})"
        return text
    return describe


def _run_fast(plant: PlantGraph, scratch: ox.NamedNode | None = None) -> str:
    inputs = input_graphs(plant)
    where = _where(plant)
    known = tbox_cache.schema(plant, inputs, where, derived_properties)  # read once per process
    program, exported = known.program, known.exported
    outcome = rules_fast.run(program, plant.store, inputs, INFERRED, where, trace=False)
    # Keep what is read back (plantkg classes of named individuals, derived properties); the
    # rest (other classes, other super-properties, hasValue data) was only a step on the way.
    keep = exported_test(exported)
    aside = [q for q in outcome.added if not keep(q.subject, q.predicate, q.object)]
    for q in aside:
        plant.store.remove(q)
    if scratch is not None:
        plant.store.extend([ox.Quad(q.subject, q.predicate, q.object, scratch) for q in aside])
    return "fast"


def exported_test(exported: frozenset[str]):  # noqa: ANN201 - a predicate on (s, p, o)
    """Whether a fact the fast engine derived belongs in ``GRAPH_INFERRED``: a plantkg class of a
    named individual, or a value of a derived property between named individuals."""
    pk, named = str(PK), ox.NamedNode
    keep = {ox.NamedNode(p) for p in exported}

    def test(s: object, p: ox.NamedNode, o: object) -> bool:
        return (isinstance(s, named) and isinstance(o, named)
                and (p in keep or (p == _TYPE and o.value.startswith(pk))))
    return test


def _run_owlready2(plant: PlantGraph, timeout: float) -> str:
    from engine.parts import java_binary  # noqa: PLC0415 - only this engine needs Java

    inputs = input_graphs(plant)
    store = plant.store
    facts = rules_owlready.infer(store, inputs, individuals(plant), derived_properties(plant),
                                 java=str(java_binary()), timeout=timeout)
    new = [ox.Quad(ox.NamedNode(x), _TYPE, ox.NamedNode(c), INFERRED) for x, c in sorted(facts.types)]
    new += [ox.Quad(ox.NamedNode(s), ox.NamedNode(p), ox.NamedNode(o), INFERRED)
            for s, p, o in sorted(facts.properties)]
    store.extend([q for q in new if not _asserted(store, q, inputs)])
    return "owlready2"


def _asserted(store: ox.Store, q: ox.Quad, graphs: list[ox.NamedNode]) -> bool:
    return any(True for g in graphs for _ in store.quads_for_pattern(q.subject, q.predicate, q.object, g))


def derived_properties(plant: PlantGraph) -> frozenset[str]:
    """Object properties the TBox concludes facts of: heads of SWRL rules, super-properties,
    equivalent and inverse properties. Their values (asserted ones included) are read back."""
    query = f"""
        SELECT DISTINCT ?p WHERE {{
            ?p a <{OWL.ObjectProperty}> .
            {{ ?imp <{SWRL.head}>/<{RDF.rest}>*/<{RDF.first}>/<{SWRL.propertyPredicate}> ?p }}
            UNION {{ ?q <{RDFS.subPropertyOf}> ?p }}
            UNION {{ ?q <{OWL.equivalentProperty}> ?p }} UNION {{ ?p <{OWL.equivalentProperty}> ?q }}
            UNION {{ ?q <{OWL.inverseOf}> ?p FILTER(isIRI(?q)) }} UNION {{ ?p <{OWL.inverseOf}> ?q }}
        }}"""
    rows = plant.store.query(query, default_graph=input_graphs(plant))
    return frozenset(row["p"].value for row in rows)


def individuals(plant: PlantGraph) -> list[str]:
    """The named individuals of the plant: IRIs described by the plant files or linked by an object
    property, that are not classes, properties, ontologies or SWRL variables."""
    reserved = " || ".join(f"STRSTARTS(STR(?t), {ox.Literal(ns)})" for ns in RESERVED_NAMESPACES)
    query = f"""
        SELECT DISTINCT ?x WHERE {{
            {{ ?x ?p ?o }} UNION {{ ?s ?p ?x . ?p a <{OWL.ObjectProperty}> }}
            FILTER(isIRI(?x))
            FILTER NOT EXISTS {{ ?x a ?t FILTER(({reserved}) && ?t != <{OWL.NamedIndividual}> && ?t != <{OWL.Thing}>) }}
        }}"""
    rows = plant.store.query(query, default_graph=input_graphs(plant))
    return sorted(row["x"].value for row in rows)


def _counts(store: ox.Store) -> tuple[tuple[tuple[str, int], ...], tuple[tuple[str, int], ...]]:
    rows = store.query(
        "SELECT ?p ?c (COUNT(*) AS ?n) WHERE { ?s ?p ?o BIND(IF(?p = rdf:type, ?o, ?p) AS ?c) "
        f"FILTER(?s != {INFERRED}) }} GROUP BY ?p ?c",
        default_graph=[INFERRED], prefixes={"rdf": str(RDF)})
    classes, properties = [], []
    for row in rows:
        (classes if row["p"] == _TYPE else properties).append((row["c"].value, int(row["n"].value)))
    return tuple(sorted(classes)), tuple(sorted(properties))

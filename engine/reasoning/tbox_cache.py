"""The fast reasoner's reading of the TBox, kept while the ontology files are unchanged.

Reading the axioms and rules out of the store (:func:`rules_tbox.read_tbox`), compiling them to
SPARQL (:func:`rules_fast.compile_tbox`) and finding the derived properties took most of reasoning
a small plant (~60 % for one broker), and their result depends only on the TBox. A long-running
process (``plantkg serve``, the fleet manager, the reconcile loop, a benchmark) reasons again and
again over the same TBox, so the result is kept per process, keyed by the SHA-256 of the TBox files
as they were loaded into the store (``PlantGraph.tbox_digest``), and used when the plant files add
no axiom of their own:

- a plant file adds axioms when it has a triple whose predicate is one the reader turns into an
  axiom (``rdfs:subClassOf``, ``owl:inverseOf``, ``swrl:body``, ``rdf:first`` ...) or an
  ``rdf:type`` of an axiom kind (``owl:ObjectProperty``, ``swrl:Imp`` ...); then everything is
  read again from the store, as before;
- the vocabulary check (:func:`rules_tbox.scan_vocabulary`: no unknown OWL/RDFS/SWRL construct, no
  anonymous individual) depends on the plant and runs every time;
- the compiled program's rules carry their run's state (``last``): each use gets fresh copies.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, replace

import pyoxigraph as ox

from engine.reasoning import rules_fast
from engine.reasoning.rules_tbox import SUPPORTED_PREDICATES, SUPPORTED_TYPES, TBox, read_tbox, scan_vocabulary
from kg.load import PlantGraph
from kg.namespaces import GRAPH_ONTOLOGY, OWL, RDF, RDFS, SWRL

#: Predicates a plant may use without adding an axiom (what individuals and ontology headers carry).
_HARMLESS_PREDICATES = frozenset(str(p) for p in (
    RDF.type, RDFS.label, RDFS.comment, RDFS.seeAlso, RDFS.isDefinedBy, OWL.imports, OWL.versionInfo,
    OWL.versionIRI, OWL.priorVersion, OWL.backwardCompatibleWith, OWL.incompatibleWith, OWL.deprecated,
))
_HARMLESS_TYPES = frozenset(str(t) for t in (OWL.NamedIndividual, OWL.Thing, OWL.Ontology))
_AXIOM_PREDICATES = tuple(ox.NamedNode(p) for p in sorted(SUPPORTED_PREDICATES - _HARMLESS_PREDICATES))
_AXIOM_TYPES = tuple(ox.NamedNode(t) for t in sorted(SUPPORTED_TYPES - _HARMLESS_TYPES)) + (
    ox.NamedNode(str(SWRL.Imp)), ox.NamedNode(str(SWRL.Variable)))
_TYPE = ox.NamedNode(str(RDF.type))
_LABEL = ox.NamedNode(str(RDFS.label))
_ANNOTATION = ox.NamedNode(str(OWL.AnnotationProperty))
_KEEP = 4  # TBoxes kept (tests load other ontologies)


@dataclass(frozen=True)
class Schema:
    """What reasoning needs of the TBox: its axioms, their compiled program, the properties whose
    values are read back."""

    tbox: TBox
    program: rules_fast.Program
    exported: frozenset[str]


@dataclass(frozen=True)
class _Entry:
    schema: Schema
    annotations: frozenset[str]
    named_rules: tuple[ox.NamedNode, ...]


_cache: dict[str, _Entry] = {}
_lock = threading.Lock()


def schema(plant: PlantGraph, inputs: list[ox.NamedNode], where: Callable[[object], str],
           exported: Callable[[PlantGraph], frozenset[str]]) -> Schema:
    """The TBox of ``plant`` read from ``inputs`` (the ontology graph and the plant files), from
    the cache when the plant files add no axiom; ``exported`` finds the derived properties."""
    key = _key(plant)
    entry = _cache.get(key) if key is not None else None
    if entry is not None and not _adds_axioms(plant, entry.named_rules):
        scan_vocabulary(plant.store, inputs, where, entry.annotations)
        program = entry.schema.program
        fresh = replace(program, rules=[replace(rule, last=-1) for rule in program.rules])
        return replace(entry.schema, program=fresh)
    tbox = read_tbox(plant.store, inputs, where)
    found = Schema(tbox, rules_fast.compile_tbox(tbox), exported(plant))
    if key is None:
        return found
    store, onto = plant.store, ox.NamedNode(GRAPH_ONTOLOGY)
    named = tuple(q.subject for q in store.quads_for_pattern(None, _TYPE, ox.NamedNode(str(SWRL.Imp)), onto)
                  if isinstance(q.subject, ox.NamedNode))
    if _adds_axioms(plant, named):
        return found
    annotations = frozenset(q.subject.value for q in store.quads_for_pattern(None, _TYPE, _ANNOTATION, onto)
                            if isinstance(q.subject, ox.NamedNode))
    kept = replace(found, program=replace(found.program, rules=[replace(r, last=-1) for r in found.program.rules]))
    with _lock:
        if len(_cache) >= _KEEP:
            _cache.pop(next(iter(_cache)))
        _cache[key] = _Entry(kept, annotations, named)
    return found


def _key(plant: PlantGraph) -> str | None:
    """The digest of the TBox as it was loaded into the plant's store (None: not known)."""
    return plant.tbox_digest


def _adds_axioms(plant: PlantGraph, named_rules: tuple[ox.NamedNode, ...]) -> bool:
    """True if a plant file has a triple the TBox reader would take as (part of) an axiom."""
    store = plant.store
    for graph in plant.plant_graphs:
        for predicate in _AXIOM_PREDICATES:
            if next(iter(store.quads_for_pattern(None, predicate, None, graph)), None) is not None:
                return True
        for kind in _AXIOM_TYPES:
            if next(iter(store.quads_for_pattern(None, _TYPE, kind, graph)), None) is not None:
                return True
        for rule in named_rules:  # a label names a rule in messages
            if next(iter(store.quads_for_pattern(rule, _LABEL, None, graph)), None) is not None:
                return True
    return False


def clear() -> None:
    """Forget every kept TBox (tests)."""
    with _lock:
        _cache.clear()

"""Validate a loaded plant against the SHACL shapes and return a typed report.

Two engines give the same answer (the test suite holds them to it):

- ``oxigraph`` (default): :mod:`kg.shacl_sparql` runs each constraint as one SPARQL query over the
  Oxigraph store the loader filled — fast enough for 10k-resource plants in well under 3 s.
- ``pyshacl``: the reference implementation, for shapes that use SHACL features the fast engine
  refuses, and as the oracle in tests.

``auto`` picks ``oxigraph`` and falls back to ``pyshacl`` only when the shapes need it.
The data graph is the plant files plus the ontology (so subclass axioms count); nothing is inferred.
"""

from __future__ import annotations

from dataclasses import asdict, astuple, dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Literal as Lit

import pyoxigraph as ox
import rdflib
from rdflib import BNode, Graph, Literal, URIRef
from rdflib.term import Node

from kg import resources, shape_plugins
from kg.errors import ShapesError
from kg.load import PlantGraph
from kg.namespaces import SH
from kg.shacl_sparql import Violation, run
from kg.shapes import ShapesGraph, load_shapes

if TYPE_CHECKING:  # rdflib's SPARQL engine (~0.25 s to import) is loaded by the pySHACL path only
    from rdflib.plugins.sparql.sparql import Query

Engine = Lit["auto", "oxigraph", "pyshacl"]
ENGINES: tuple[str, ...] = ("auto", "oxigraph", "pyshacl")


@dataclass(frozen=True, order=True)
class ValidationResult:
    """One SHACL result, as plain strings: what is wrong, where, and which shape says so."""

    severity: str
    focus: str
    path: str | None
    value: str | None
    message: str
    shape: str
    component: str
    file: str | None = None

    def key(self) -> tuple[str, str, str | None, str | None, str, str, str]:
        """Everything but the file, blank node labels erased: what two engines must agree on."""
        def b(text: str | None) -> str | None:
            return "_:" if text is not None and text.startswith("_:") else text

        return (self.severity, b(self.focus) or "", b(self.path), b(self.value), self.message,
                b(self.shape) or "", self.component)


@dataclass(frozen=True)
class ValidationReport:
    """The outcome: ``conforms`` is False when any result has severity Violation."""

    conforms: bool
    results: tuple[ValidationResult, ...]
    engine: str
    files: tuple[str, ...]
    shapes: tuple[str, ...]

    @property
    def violations(self) -> tuple[ValidationResult, ...]:
        return tuple(r for r in self.results if r.severity == "Violation")

    @property
    def warnings(self) -> tuple[ValidationResult, ...]:
        return tuple(r for r in self.results if r.severity != "Violation")

    def to_dict(self) -> dict[str, object]:
        return {
            "conforms": self.conforms,
            "engine": self.engine,
            "files": list(self.files),
            "shapes": list(self.shapes),
            "violations": len(self.violations),
            "warnings": len(self.warnings),
            "results": [asdict(r) for r in self.results],
        }


def _local(iri: str) -> str:
    return iri.rsplit("#", 1)[-1].rsplit("/", 1)[-1]


def _ox_text(t: ox.NamedNode | ox.BlankNode | ox.Literal | None) -> str | None:
    if t is None:
        return None
    if isinstance(t, ox.BlankNode):
        return f"_:{t.value}"
    return t.value


def _rdflib_text(t: Node | None) -> str | None:
    if t is None:
        return None
    if isinstance(t, BNode):
        return f"_:{t}"
    return str(t)


def _files_by_focus(plant: PlantGraph, focus_nodes: Iterable[ox.NamedNode | ox.BlankNode]) -> dict[str, str]:
    graphs = {s.graph: str(s.path) for s in (*plant.sources, plant.ontology)}
    found: dict[str, str] = {}
    for node in focus_nodes:
        if isinstance(node, ox.Literal):
            continue
        for quad in plant.store.quads_for_pattern(node, None, None, None):
            gname = quad.graph_name.value if isinstance(quad.graph_name, ox.NamedNode) else None
            if gname in graphs:
                found[_ox_text(node)] = graphs[gname]  # type: ignore[index]
                break
    return found


def _from_violations(plant: PlantGraph, violations: list[Violation]) -> list[ValidationResult]:
    files = _files_by_focus(plant, {v.focus for v in violations})
    out = []
    for v in violations:
        focus = _ox_text(v.focus)
        out.append(ValidationResult(
            severity=_local(str(v.shape.severity)),
            focus=focus or "",
            path=v.path,
            value=_ox_text(v.value),
            message=v.message,
            shape=_rdflib_text(v.shape.node) or "",
            component=v.component,
            file=files.get(focus or ""),
        ))
    return out


@lru_cache(maxsize=1024)
def _prepared(query: str) -> Query:
    from rdflib.plugins.sparql import prepareQuery  # noqa: PLC0415 - only pySHACL needs it

    return prepareQuery(query)


class PreparedQueryGraph(Graph):
    """An rdflib Graph that parses each SPARQL text once.

    pySHACL runs a SHACL-SPARQL constraint once per focus node, and rdflib re-parses the query text
    on every call (about 0.1 s with pyparsing): 5 s for the small robot cell. Parsing once makes the
    reference engine ~15x faster with the same results.
    """

    def query(self, query_object, processor="sparql", result="sparql", initNs=None,  # type: ignore[override]  # noqa: N803
              initBindings=None, use_store_provided=True, **kwargs):  # noqa: N803
        if isinstance(query_object, str) and not initNs:
            query_object = _prepared(query_object)
        return super().query(query_object, processor, result, initNs, initBindings,
                             use_store_provided, **kwargs)


def plant_as_rdflib(plant: PlantGraph) -> Graph:
    """The union of the plant files and the ontology as one rdflib Graph (for pySHACL, exports).

    Literals keep their lexical form (rdflib would otherwise rewrite an ill-typed ``"maybe"`` typed
    xsd:boolean as ``false``, and a report would show a value the user never wrote).
    """
    graphs = [ox.NamedNode(s.graph) for s in (plant.ontology, *plant.sources)]
    data = b"".join(plant.store.dump(format=ox.RdfFormat.N_TRIPLES, from_graph=g) for g in graphs)
    previous = rdflib.NORMALIZE_LITERALS
    rdflib.NORMALIZE_LITERALS = False
    try:
        return PreparedQueryGraph().parse(data=data, format="nt")
    finally:
        rdflib.NORMALIZE_LITERALS = previous


def _run_pyshacl(plant: PlantGraph, shapes: ShapesGraph) -> list[ValidationResult]:
    import warnings

    import pyshacl

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # rdflib's "weird boolean" notes on ill-typed literals
        _conforms, results_graph, _text = pyshacl.validate(
            plant_as_rdflib(plant), shacl_graph=shapes.graph, inference="none",
            advanced=True, allow_warnings=True, inplace=True,  # the graph is ours to use up
        )
    rows = []
    focus_by_text: dict[str, ox.NamedNode | ox.BlankNode] = {}
    for r in results_graph.subjects(URIRef(str(SH) + "resultSeverity"), None):
        def one(pred: str) -> Node | None:
            return results_graph.value(r, SH[pred])

        focus = one("focusNode")
        path = one("resultPath")
        if isinstance(path, BNode) and (inverse := results_graph.value(path, SH.inversePath)) is not None:
            path = URIRef("^" + str(inverse))
        if isinstance(focus, URIRef):
            focus_by_text[str(focus)] = ox.NamedNode(str(focus))
        msg = one("resultMessage")
        rows.append(ValidationResult(
            severity=_local(str(one("resultSeverity"))),
            focus=_rdflib_text(focus) or "",
            path=_rdflib_text(path),
            value=_rdflib_text(one("value")),
            message=str(msg) if isinstance(msg, Literal) else "",
            shape=_rdflib_text(one("sourceShape")) or "",
            component=_local(str(one("sourceConstraintComponent"))),
        ))
    files = _files_by_focus(plant, focus_by_text.values())
    return [ValidationResult(**{**asdict(r), "file": files.get(r.focus)}) for r in rows]


def validate(
    plant: PlantGraph,
    shapes: ShapesGraph | None = None,
    *,
    engine: Engine = "auto",
) -> ValidationReport:
    """Validate ``plant`` against ``shapes`` (default: the project's shapes/*.ttl)."""
    if engine not in ENGINES:
        raise ShapesError(f"unknown validation engine {engine!r}", hint=f"use one of {', '.join(ENGINES)}")
    if shapes is None:
        shapes = load_default_shapes()
    used = "pyshacl" if engine == "pyshacl" else "oxigraph"
    if engine == "auto":
        try:
            shapes.node_shapes  # noqa: B018 - compiles the model, refusing unsupported features
        except ShapesError:
            used = "pyshacl"
    if used == "oxigraph":
        return report_of(plant, shapes, list(run(plant.store, shapes)))
    return _report(plant, shapes, _run_pyshacl(plant, shapes), used)


def report_of(plant: PlantGraph, shapes: ShapesGraph, violations: list[Violation]) -> ValidationReport:
    """The fast engine's report from its raw violations (shared with kg.validate_delta)."""
    return _report(plant, shapes, _from_violations(plant, violations), "oxigraph")


def _report(plant: PlantGraph, shapes: ShapesGraph, results: list[ValidationResult], used: str) -> ValidationReport:
    # None (no path or value) sorts first: plain tuple order would compare None with a string
    # when two results differ only there (e.g. MaxCount and Datatype on one property).
    results = sorted(set(results), key=lambda r: tuple("" if x is None else x for x in astuple(r)))
    return ValidationReport(
        conforms=not any(r.severity == "Violation" for r in results),
        results=tuple(results),
        engine=used,
        files=tuple(str(s.path) for s in plant.sources),
        shapes=tuple(str(p) for p in shapes.files),
    )


def load_default_shapes() -> ShapesGraph:
    """The project's shapes; a ShapesError here means shapes/*.ttl needs pySHACL.

    Parsed (and compiled, on first use) once per process for as long as the files keep their
    size and modification time: re-reading them was two thirds of validating a small plant
    (``benchmarks/RESULTS.md``, deployment latency). The object is shared: read it, never change it.
    Installed packages add to them (:mod:`kg.shape_plugins`): their own shapes files, and the
    ``pk:brokerType`` values, which are the names of the registered drivers.
    """
    files = [Path(f) for f in (*resources.shapes_files(), *shape_plugins.plugin_shapes_files())]
    return _shapes_once(tuple((str(f), f.stat().st_mtime_ns, f.stat().st_size) for f in files),
                        shape_plugins.registered_broker_types())


@lru_cache(maxsize=4)
def _shapes_once(stamps: tuple[tuple[str, int, int], ...], kinds: tuple[str, ...]) -> ShapesGraph:
    shapes = load_shapes(Path(name) for name, _, _ in stamps)
    shape_plugins.with_broker_types(shapes.graph, kinds)
    return shapes



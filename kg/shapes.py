"""Read SHACL shapes into a small typed model the fast validator can compile.

The model covers the part of SHACL Core that plantkg's shapes use — class/node/subjects-of/
objects-of targets, single-IRI and inverse paths, the value-type, cardinality, value-range,
string and list constraint components — and SHACL-SPARQL constraints (SHACL §5). A shape using
anything else is refused with :class:`~kg.errors.ShapesError` naming the shape and the predicate,
so nothing is silently skipped: the caller then validates with pySHACL instead.

Spec: https://www.w3.org/TR/shacl/
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from rdflib import Graph, Literal, URIRef
from rdflib.collection import Collection
from rdflib.term import Node

from kg.errors import ShapesError
from kg.namespaces import OWL, RDF, RDFS, SH

#: Constraint parameters the compiler understands, with the component each belongs to.
CORE_PARAMETERS: dict[URIRef, str] = {
    SH.minCount: "MinCountConstraintComponent",
    SH.maxCount: "MaxCountConstraintComponent",
    SH.datatype: "DatatypeConstraintComponent",
    SH.nodeKind: "NodeKindConstraintComponent",
    SH["class"]: "ClassConstraintComponent",
    SH.pattern: "PatternConstraintComponent",
    SH["in"]: "InConstraintComponent",
    SH.minInclusive: "MinInclusiveConstraintComponent",
    SH.maxInclusive: "MaxInclusiveConstraintComponent",
    SH.minExclusive: "MinExclusiveConstraintComponent",
    SH.maxExclusive: "MaxExclusiveConstraintComponent",
    SH.minLength: "MinLengthConstraintComponent",
    SH.maxLength: "MaxLengthConstraintComponent",
    SH.hasValue: "HasValueConstraintComponent",
}

#: Predicates that describe a shape without constraining (or that the compiler handles itself).
_STRUCTURAL = {
    RDF.type, SH.targetClass, SH.targetNode, SH.targetSubjectsOf, SH.targetObjectsOf,
    SH.property, SH.path, SH.sparql, SH.severity, SH.message, SH.deactivated, SH.flags,
    SH.name, SH.description, SH.order, SH.group, SH.defaultValue,
}


@dataclass(frozen=True)
class Target:
    """A SHACL target: ``kind`` is targetClass, targetNode, targetSubjectsOf or targetObjectsOf."""

    kind: str
    term: Node


@dataclass(frozen=True)
class Path_:
    """A property path: one IRI, possibly inverse (``sh:inversePath``)."""

    predicate: URIRef
    inverse: bool = False


@dataclass(frozen=True)
class CoreConstraint:
    """One core constraint component with its parameter (a term, or a list for ``sh:in``)."""

    component: str
    parameter: URIRef
    value: Node | tuple[Node, ...]
    flags: str = ""


@dataclass(frozen=True)
class SparqlConstraint:
    """A SHACL-SPARQL constraint: a SELECT with ``$this``, its prefixes and message."""

    node: Node
    select: str
    prefixes: tuple[tuple[str, str], ...]
    messages: tuple[Literal, ...]


@dataclass
class Shape:
    """A node shape (``path`` None) or a property shape."""

    node: Node
    path: Path_ | None
    targets: list[Target] = field(default_factory=list)
    severity: URIRef = SH.Violation
    messages: tuple[Literal, ...] = ()
    core: list[CoreConstraint] = field(default_factory=list)
    sparql: list[SparqlConstraint] = field(default_factory=list)
    properties: list["Shape"] = field(default_factory=list)
    deactivated: bool = False


@dataclass
class ShapesGraph:
    """The shapes as read (an rdflib graph and its files); the compiled model is built on demand.

    Building the model lazily lets pySHACL validate with shapes the fast engine would refuse.
    """

    graph: Graph
    files: tuple[Path, ...]
    _model: list[Shape] | None = field(default=None, repr=False)

    @property
    def node_shapes(self) -> list[Shape]:
        """Node shapes with their property shapes; raises ShapesError for unsupported features."""
        if self._model is None:
            self._model = parse_model(self.graph)
        return self._model


def _refuse(shape: Node, predicate: Node, why: str) -> ShapesError:
    return ShapesError(
        f"shape {shape} uses {predicate}: {why}",
        hint="validate with --engine pyshacl, or express the constraint with the supported "
        "components (see docs/validation.md)",
    )


def _path(g: Graph, shape: Node, path: Node) -> Path_:
    if isinstance(path, URIRef):
        return Path_(path)
    inverse = g.value(path, SH.inversePath)
    if isinstance(inverse, URIRef) and len(list(g.predicate_objects(path))) == 1:
        return Path_(inverse, inverse=True)
    raise _refuse(shape, SH.path, "only an IRI or sh:inversePath of an IRI is supported")


def _prefixes(g: Graph, sparql_node: Node) -> tuple[tuple[str, str], ...]:
    out: list[tuple[str, str]] = []
    for holder in g.objects(sparql_node, SH.prefixes):
        for decl in g.objects(holder, SH.declare):
            out.append((str(g.value(decl, SH.prefix)), str(g.value(decl, SH.namespace))))
    return tuple(sorted(set(out)))


def _sparql(g: Graph, shape: Node) -> list[SparqlConstraint]:
    out = []
    for node in g.objects(shape, SH.sparql):
        if (node, SH.deactivated, Literal(True)) in g:
            continue
        select = g.value(node, SH.select)
        if select is None:
            raise _refuse(shape, SH.sparql, "only sh:select constraints are supported")
        msgs = tuple(m for m in g.objects(node, SH.message) if isinstance(m, Literal))
        out.append(SparqlConstraint(node, str(select), _prefixes(g, node), msgs))
    return out


def _core(g: Graph, shape: Node, is_node_shape: bool) -> list[CoreConstraint]:
    out = []
    for predicate, obj in g.predicate_objects(shape):
        if predicate in CORE_PARAMETERS:
            if is_node_shape and predicate in (SH.minCount, SH.maxCount):
                raise _refuse(shape, predicate, "cardinality belongs on property shapes")
            value: Node | tuple[Node, ...] = obj
            if predicate == SH["in"]:
                value = tuple(Collection(g, obj))
            flags = str(g.value(shape, SH.flags) or "") if predicate == SH.pattern else ""
            out.append(CoreConstraint(CORE_PARAMETERS[predicate], predicate, value, flags))
        elif str(predicate).startswith(str(SH)) and predicate not in _STRUCTURAL:
            raise _refuse(shape, predicate, "this constraint component is not supported by the fast engine")
    return out


def _targets(g: Graph, shape: Node) -> list[Target]:
    targets = [
        Target(kind, obj)
        for kind in ("targetClass", "targetNode", "targetSubjectsOf", "targetObjectsOf")
        for obj in g.objects(shape, SH[kind])
    ]
    if (shape, RDF.type, RDFS.Class) in g or (shape, RDF.type, OWL.Class) in g:
        targets.append(Target("targetClass", shape))  # implicit class target (SHACL 2.1.3.3)
    return targets


def _shape(g: Graph, node: Node, path: Path_ | None) -> Shape:
    return Shape(
        node=node,
        path=path,
        targets=_targets(g, node),
        severity=g.value(node, SH.severity) or SH.Violation,  # type: ignore[arg-type]
        messages=tuple(m for m in g.objects(node, SH.message) if isinstance(m, Literal)),
        core=_core(g, node, path is None),
        sparql=_sparql(g, node),
        deactivated=(node, SH.deactivated, Literal(True)) in g,
    )


def parse_model(graph: Graph) -> list[Shape]:
    """Build the model from a shapes graph; raises ShapesError for unsupported features."""
    node_nodes = set(graph.subjects(RDF.type, SH.NodeShape))
    for kind in ("targetClass", "targetNode", "targetSubjectsOf", "targetObjectsOf"):
        for subject in graph.subjects(SH[kind], None):
            if graph.value(subject, SH.path) is not None:
                raise _refuse(subject, SH[kind], "targets on property shapes are not supported")
            node_nodes.add(subject)
    shapes = []
    for node in sorted(node_nodes, key=str):
        shape = _shape(graph, node, None)
        for prop in graph.objects(node, SH.property):
            path = graph.value(prop, SH.path)
            if path is None:
                raise _refuse(prop, SH.path, "a property shape needs sh:path")
            pshape = _shape(graph, prop, _path(graph, prop, path))
            if (prop, SH.property, None) in graph:
                raise _refuse(prop, SH.property, "nested property shapes are not supported")
            shape.properties.append(pshape)
        shape.properties.sort(key=lambda s: str(s.node))
        shapes.append(shape)
    return shapes


def load_shapes(paths: Iterable[Path]) -> ShapesGraph:
    """Parse shapes files (Turtle) into a :class:`ShapesGraph`."""
    files = [Path(p) for p in paths]
    g = Graph()
    for path in files:
        g.parse(path, format="turtle")
    return ShapesGraph(graph=g, files=tuple(files))


"""pySHACL, the reference engine, gives exactly the expected results on every shape case.

Each folder under ``tests/cases/shapes/`` is a small plant (``plant.ttl``) and the exact SHACL
results it must produce (``expected.json``). Here the data graph is the plant merged with the
ontology, parsed by rdflib directly, and validated by pySHACL without inference; the same cases
are run by the fast Oxigraph engine in ``tests/unit/test_validate_engines.py``. Where pySHACL is
known to differ from the SHACL spec, the case holds ``pyshacl-deviation.json`` with pySHACL's
results and the reason, and that is what pySHACL must give here.

Also: every (shape, constraint component) of the shapes is broken by at least one case, every
shape is documented in docs/shapes.md, and the shipped example plants conform.
"""

from __future__ import annotations

import json
import re
import sys
import warnings
from pathlib import Path

import pyshacl
import pytest
import rdflib
from rdflib import BNode, Graph, Literal, URIRef
from rdflib.collection import Collection
from rdflib.namespace import OWL, RDF, RDFS, SH

from kg.validate import PreparedQueryGraph

ROOT = Path(__file__).resolve().parents[2]
CASES_DIR = ROOT / "tests" / "cases" / "shapes"
CASES = sorted(p for p in CASES_DIR.iterdir() if (p / "plant.ttl").exists())
ONTOLOGY = ROOT / "ontology" / "plantkg.ttl"
SHAPE_FILES = sorted((ROOT / "shapes").glob("*.ttl"))
EXAMPLES = sorted((ROOT / "ontology" / "examples").glob("*.ttl"))
PKS = "https://w3id.org/plantkg/shapes#"

Row = tuple[str, str | None, str | None, str, str, str, str]


@pytest.fixture(scope="module")
def shapes() -> Graph:
    g = Graph()
    for f in SHAPE_FILES:
        g.parse(f, format="turtle")
    return g


@pytest.fixture(scope="module")
def ontology() -> Graph:
    if not ONTOLOGY.exists():
        pytest.skip(f"{ONTOLOGY} does not exist yet")
    return Graph().parse(ONTOLOGY, format="turtle")


@pytest.fixture(scope="module")
def all_modules() -> Graph:
    """Every TBox file (ontology/*.ttl), as plantkg validates a plant: a plant may use the
    fleet module's named individuals (fleet:agv is a pk:ResourceType there)."""
    g = Graph()
    for path in sorted(ONTOLOGY.parent.glob("*.ttl")):
        g.parse(path, format="turtle")
    return g


def run_pyshacl(data: Graph, shapes: Graph) -> set[Row]:
    """pySHACL's results as (focus, path, value, shape, component, severity, message) tuples.

    ``data`` is validated in place (no inference, no ontology graph, no advanced mode: pySHACL then
    uses the graph it is given), so a :class:`PreparedQueryGraph` keeps parsing each query once.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # rdflib's notes on ill-typed literals
        _conforms, report, _text = pyshacl.validate(
            data, shacl_graph=shapes, inference="none", advanced=False, allow_warnings=True,
        )
    rows: set[Row] = set()
    for r in report.subjects(RDF.type, SH.ValidationResult):
        def one(p: URIRef) -> str | None:
            objects = list(report.objects(r, p))
            assert len(objects) <= 1, f"{p} has several values in one result: {objects}"
            return str(objects[0]) if objects else None

        rows.add((
            one(SH.focusNode) or "", one(SH.resultPath), one(SH.value), one(SH.sourceShape) or "",
            (one(SH.sourceConstraintComponent) or "").rsplit("#", 1)[-1],
            (one(SH.resultSeverity) or "").rsplit("#", 1)[-1], one(SH.resultMessage) or "",
        ))
    return rows


def as_rows(items: list[dict]) -> set[Row]:
    return {(d["focus"], d["path"], d["value"], d["shape"], d["component"], d["severity"], d["message"])
            for d in items}


def plant_graph(plant: Path, ontology: Graph) -> Graph:
    """Plant + ontology, parsed by rdflib itself (not through kg.load, so the reference does not
    share the product's loader). Literals keep the lexical form written in the file: by default
    rdflib rewrites well-typed literals into a canonical form (1.5e3 becomes 1500.0), and the
    shapes check lexical forms, as the Oxigraph engine sees them.

    The graph is kg.validate's :class:`PreparedQueryGraph`, an rdflib Graph whose ``query`` parses
    each SPARQL text once: pySHACL sends a SPARQL constraint's text once per focus node, and
    rdflib's parser would otherwise take ~90% of the run. Evaluation is rdflib's own, so the
    results are pySHACL's; only the parse is shared (the valid case: ~0.1 s instead of ~2.6 s).
    """
    g = PreparedQueryGraph()
    g += ontology
    previous = rdflib.NORMALIZE_LITERALS
    rdflib.NORMALIZE_LITERALS = False
    try:
        g.parse(plant, format="turtle")
    finally:
        rdflib.NORMALIZE_LITERALS = previous
    return g


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_reference_results(case: Path, shapes: Graph, all_modules: Graph) -> None:
    expected = json.loads((case / "expected.json").read_text(encoding="utf-8"))
    deviation = case / "pyshacl-deviation.json"
    if deviation.exists():
        expected = json.loads(deviation.read_text(encoding="utf-8"))["results"]
    got = run_pyshacl(plant_graph(case / "plant.ttl", all_modules), shapes)
    want = as_rows(expected)
    assert got == want, f"missing: {sorted(want - got)}\nunexpected: {sorted(got - want)}"


def test_there_is_a_valid_case() -> None:
    assert json.loads((CASES_DIR / "valid" / "expected.json").read_text()) == []


def test_cases_are_up_to_date() -> None:
    """The committed case folders are what build_cases.py writes (nobody edited them by hand)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("build_cases", CASES_DIR / "build_cases.py")
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    try:
        spec.loader.exec_module(module)
    finally:
        del sys.modules[spec.name]
    assert module.main(["--check"]) == 0


def _constraints(shapes: Graph) -> set[tuple[str, str]]:
    """Every (shape IRI, constraint component local name) the shapes define."""
    params = {
        SH.minCount: "MinCount", SH.maxCount: "MaxCount", SH.datatype: "Datatype", SH.nodeKind: "NodeKind",
        SH["class"]: "Class", SH.pattern: "Pattern", SH["in"]: "In", SH.minInclusive: "MinInclusive",
        SH.maxInclusive: "MaxInclusive", SH.minLength: "MinLength", SH.maxLength: "MaxLength",
        SH.sparql: "SPARQL",
    }
    out = set()
    for p, name in params.items():
        for s in shapes.subjects(p, None):
            out.add((str(s), name + "ConstraintComponent"))
    return out


def test_every_constraint_has_a_breaking_case(shapes: Graph) -> None:
    covered = set()
    for case in CASES:
        for row in json.loads((case / "expected.json").read_text(encoding="utf-8")):
            covered.add((row["shape"], row["component"]))
    missing = _constraints(shapes) - covered
    assert not missing, f"constraints no case breaks: {sorted(missing)}"


def test_every_shape_is_named_messaged_and_documented(shapes: Graph) -> None:
    doc = (ROOT / "docs" / "shapes.md").read_text(encoding="utf-8")
    shape_nodes = set(shapes.subjects(RDF.type, SH.NodeShape)) | set(shapes.subjects(RDF.type, SH.PropertyShape))
    shape_nodes |= set(shapes.objects(None, SH.property))
    for s in shape_nodes:
        assert isinstance(s, URIRef) and str(s).startswith(PKS), f"unnamed or foreign shape {s}"
        assert f"pks:{str(s)[len(PKS):]}" in doc, f"{s} is not in docs/shapes.md"
    for shape, _component in _constraints(shapes):
        node = URIRef(shape)
        messages = list(shapes.objects(node, SH.message))
        messages += [m for c in shapes.objects(node, SH.sparql) for m in shapes.objects(c, SH.message)]
        assert len(messages) == 1 and isinstance(messages[0], Literal), (shape, messages)
        assert str(messages[0]).replace("|", "\\|") in doc, f"{shape}: message not in docs/shapes.md"
        if (node, SH.sparql, None) in shapes:
            assert (node, SH.message, None) not in shapes, f"{shape}: put the message on the SPARQL constraint only"
            assert len(list(shapes.objects(node, SH.sparql))) == 1, f"{shape}: one SPARQL constraint per shape"


PK = "https://w3id.org/plantkg/ontology#"
XSD_STRING = URIRef("http://www.w3.org/2001/XMLSchema#string")
#: Property characteristics and axioms a plant can violate that the test below knows how to check.
#: A new kind in the ontology fails the test: add the shape that keeps plants consistent with it.
_KNOWN_PROPERTY_TYPES = {OWL.ObjectProperty, OWL.DatatypeProperty, OWL.AnnotationProperty,
                         OWL.FunctionalProperty, OWL.IrreflexiveProperty}
_UNCHECKED_AXIOMS = [OWL.disjointWith, OWL.propertyDisjointWith, OWL.inverseOf, OWL.propertyChainAxiom,
                     OWL.hasKey, OWL.disjointUnionOf, OWL.complementOf, OWL.oneOf, OWL.cardinality,
                     OWL.maxCardinality, OWL.maxQualifiedCardinality, OWL.qualifiedCardinality,
                     OWL.allValuesFrom, RDFS.subClassOf, RDFS.subPropertyOf]


def _pk(term: URIRef) -> str:
    return "pk:" + str(term)[len(PK):]


def _property_shapes(shapes: Graph, node_shape: URIRef, path: URIRef) -> list[URIRef]:
    return [p for p in shapes.objects(node_shape, SH.property) if (p, SH.path, path) in shapes]


def _select(shapes: Graph, shape: URIRef) -> str:
    return " ".join(str(shapes.value(c, SH.select)) for c in shapes.objects(shape, SH.sparql))


def test_shapes_cover_the_ontology_axioms(shapes: Graph, ontology: Graph) -> None:
    """Every axiom of the ontology a plant could break has its shape (so HermiT never finds a
    conforming plant inconsistent): domains, ranges, functional and irreflexive properties,
    disjoint classes, the defined classes' hasValue. The shapes are written by hand, this keeps
    them in step with the ontology."""
    problems = []
    props = set(ontology.subjects(RDF.type, OWL.ObjectProperty)) | set(ontology.subjects(RDF.type, OWL.DatatypeProperty))
    for p in props:
        unknown = set(ontology.objects(p, RDF.type)) - _KNOWN_PROPERTY_TYPES
        if unknown:
            problems.append(f"{_pk(p)} is {unknown}: no shape checks that")
    disjoint = set(ontology.subjects(OWL.disjointWith, None)) | set(ontology.objects(None, OWL.disjointWith))
    for members in ontology.objects(None, OWL.members):
        disjoint |= set(Collection(ontology, members))
    for axiom in _UNCHECKED_AXIOMS:
        for subject, sup in ontology.subject_objects(axiom):
            if axiom == RDFS.subClassOf and sup not in disjoint and not isinstance(sup, BNode):
                continue  # it only adds a type no disjointness mentions (pk:MqttBroker): nothing to break
            if axiom == RDFS.subClassOf and sup == URIRef(PK + "Broker") and \
                    _pk(subject) in _select(shapes, URIRef(PKS + "PlantElement-disjointClasses")):
                continue  # pk:MqttBroker is a Broker: the disjoint-classes shape counts it as one
            problems.append(f"the ontology uses {axiom} (on {subject}): add shapes for it, then list it here")

    six = {URIRef(PK + c) for c in ("Resource", "ResourceType", "Property", "Skill", "Broker", "Topic")}
    (members_node,) = list(ontology.objects(None, OWL.members))
    if set(Collection(ontology, members_node)) != six:
        problems.append("owl:AllDisjointClasses is not the six classes pks:PlantElement-disjointClasses knows")
    query = _select(shapes, URIRef(PKS + "PlantElement-disjointClasses"))
    problems += [f"{_pk(c)} missing from pks:PlantElement-disjointClasses" for c in six if _pk(c) not in query]

    domains: dict[URIRef, set[URIRef]] = {}
    for p in props:
        for d in ontology.objects(p, RDFS.domain):
            domains.setdefault(d, set()).add(p)  # type: ignore[arg-type]
    for d, ps in domains.items():
        shape = URIRef(PKS + str(d)[len(PK):] + "-domain")
        targets = set(shapes.objects(shape, SH.targetSubjectsOf))
        listed = set(re.findall(r"pk:(\w+)", re.search(r"\?path IN \(([^)]*)\)", _select(shapes, shape) or "?path IN ()").group(1)))
        if targets != ps or listed != {str(p)[len(PK):] for p in ps}:
            problems.append(f"{shape}: targets {sorted(map(_pk, targets))} / listed {sorted(listed)}, "
                            f"ontology domain {_pk(d)}: {sorted(map(_pk, ps))}")

    for p in props:
        domain = ontology.value(p, RDFS.domain)
        owner = URIRef(PKS + (str(domain)[len(PK):] if domain else "PlantElement"))
        here = _property_shapes(shapes, owner, p)
        rng = ontology.value(p, RDFS.range)
        if rng is not None and (p, RDF.type, OWL.ObjectProperty) in ontology:
            if not any((x, SH["class"], rng) in shapes for x in here):
                problems.append(f"{_pk(p)}: no sh:class {_pk(rng)} on {owner}")
        elif rng is not None:
            def typed(x: URIRef) -> bool:
                if (x, SH.datatype, rng) in shapes:
                    return True
                members = [m for lst in shapes.objects(x, SH["in"]) for m in Collection(shapes, lst)]
                return bool(members) and all(isinstance(m, Literal) and (m.datatype or XSD_STRING) == rng
                                             and not m.language for m in members)
            if not any(typed(x) for x in here):
                problems.append(f"{_pk(p)}: no sh:datatype {rng} (or sh:in of such literals) on {owner}")
        if (p, RDF.type, OWL.FunctionalProperty) in ontology:
            if not any((x, SH.maxCount, Literal(1)) in shapes for x in here):
                problems.append(f"{_pk(p)} is functional: no sh:maxCount 1 on {owner}")
        if (p, RDF.type, OWL.IrreflexiveProperty) in ontology:
            if not any(f"$this {_pk(p)} $this" in _select(shapes, s) for s in shapes.subjects(SH.sparql, None)):
                problems.append(f"{_pk(p)} is irreflexive: no SPARQL shape looks for $this {_pk(p)} $this")

    for cls, definition in ontology.subject_objects(OWL.equivalentClass):
        for restriction in ontology.objects(definition, OWL.intersectionOf):
            for r in Collection(ontology, restriction):
                value, on = ontology.value(r, OWL.hasValue), ontology.value(r, OWL.onProperty)
                if value is None:
                    continue
                node_shapes = set(shapes.subjects(SH.targetClass, cls))
                if not any((x, SH["in"], None) in shapes and list(Collection(shapes, shapes.value(x, SH["in"]))) == [value]
                           for n in node_shapes for x in _property_shapes(shapes, n, on)):  # type: ignore[arg-type]
                    problems.append(f"{_pk(cls)} is defined by {_pk(on)} = {value}: no shape checks an "
                                    "asserted type against it")
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.name for e in EXAMPLES])
def test_example_conforms(example: Path, shapes: Graph, all_modules: Graph) -> None:
    rows = run_pyshacl(plant_graph(example, all_modules), shapes)
    assert rows == set(), sorted(rows)


def test_examples_exist() -> None:
    if not EXAMPLES:
        pytest.skip("ontology/examples/*.ttl not written yet")
    assert len(EXAMPLES) >= 2

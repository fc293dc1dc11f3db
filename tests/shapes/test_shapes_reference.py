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

import contextlib
import json
import sys
import time
import warnings
from collections.abc import Iterator
from functools import lru_cache
from pathlib import Path

import pyshacl
import pytest
import rdflib
from rdflib import Graph, Literal, URIRef
from rdflib.namespace import RDF, SH
from rdflib.plugins.sparql import processor as sparql_processor
from rdflib.plugins.sparql.algebra import translateQuery
from rdflib.plugins.sparql.parser import parseQuery

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


@lru_cache(maxsize=256)
def _prepared(text: str, base: str | None, namespaces: tuple[tuple[str, str], ...]) -> sparql_processor.Query:
    return translateQuery(parseQuery(text), base, dict(namespaces))


@contextlib.contextmanager
def parse_each_query_once() -> Iterator[None]:
    """Let rdflib parse each SPARQL text once instead of once per focus node.

    pySHACL 0.40 sends a SPARQL constraint's text to ``Graph.query`` for every focus node (``$this``
    goes in initBindings, so the text is the same each time) and rdflib's pyparsing parser then
    dominates the run (~90% of it). A prepared query is what ``rdflib.plugins.sparql.prepareQuery``
    gives and is meant to be evaluated many times with different initBindings, so results are the
    same; only the parse is shared.
    """
    original = sparql_processor.SPARQLProcessor.query

    def query(self, strOrQuery, initBindings=None, initNs=None, base=None, DEBUG=False):  # noqa: N803
        if isinstance(strOrQuery, str):
            namespaces = tuple(sorted((str(k), str(v)) for k, v in (initNs or {}).items()))
            strOrQuery = _prepared(strOrQuery, base, namespaces)
        return original(self, strOrQuery, initBindings, initNs, base, DEBUG)

    sparql_processor.SPARQLProcessor.query = query  # type: ignore[method-assign]
    try:
        yield
    finally:
        sparql_processor.SPARQLProcessor.query = original  # type: ignore[method-assign]


def run_pyshacl(data: Graph, shapes: Graph) -> set[Row]:
    """pySHACL's results as (focus, path, value, shape, component, severity, message) tuples."""
    with warnings.catch_warnings(), parse_each_query_once():
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
    """Plant + ontology. Literals keep the lexical form written in the file: by default rdflib
    rewrites well-typed literals into a canonical form (1.5e3 becomes 1500.0), and the shapes
    check lexical forms, as the Oxigraph engine sees them."""
    g = Graph()
    g += ontology
    previous = rdflib.NORMALIZE_LITERALS
    rdflib.NORMALIZE_LITERALS = False
    try:
        g.parse(plant, format="turtle")
    finally:
        rdflib.NORMALIZE_LITERALS = previous
    return g


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_reference_results(case: Path, shapes: Graph, ontology: Graph) -> None:
    expected = json.loads((case / "expected.json").read_text(encoding="utf-8"))
    deviation = case / "pyshacl-deviation.json"
    if deviation.exists():
        expected = json.loads(deviation.read_text(encoding="utf-8"))["results"]
    got = run_pyshacl(plant_graph(case / "plant.ttl", ontology), shapes)
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


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.name for e in EXAMPLES])
def test_example_conforms(example: Path, shapes: Graph, ontology: Graph) -> None:
    rows = run_pyshacl(plant_graph(example, ontology), shapes)
    assert rows == set(), sorted(rows)


def test_examples_exist() -> None:
    if not EXAMPLES:
        pytest.skip("ontology/examples/*.ttl not written yet")
    assert len(EXAMPLES) >= 2


def test_reference_timing(shapes: Graph, ontology: Graph, capsys: pytest.CaptureFixture[str]) -> None:
    """Not a benchmark: prints how long pySHACL takes on the valid case and the examples."""
    plants = [CASES_DIR / "valid" / "plant.ttl", *EXAMPLES]
    lines = []
    for plant in plants:
        data = plant_graph(plant, ontology)
        start = time.perf_counter()
        run_pyshacl(data, shapes)
        lines.append(f"{plant.relative_to(ROOT)}: {len(data)} triples, {time.perf_counter() - start:.3f} s")
    with capsys.disabled():
        print("\npySHACL reference timings:\n  " + "\n  ".join(lines))

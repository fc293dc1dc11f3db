"""Focus sets decided once (kg.focus) and queries run without the focus pattern (kg.sparql_scope).

On a big plant the fast validator runs a query that binds ``?this`` itself without the shape's
focus pattern and keeps the rows of focus nodes afterwards — per row, or through the whole focus
set once there are many rows. Small plants never reach those paths (the focus is small), so here
the thresholds are forced to zero: every shape case and every mutant must give exactly its
expected results through each path.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from kg import focus as focus_module
from kg import resources
from kg.load import load_plant
from kg.shapes import load_shapes
from kg.sparql_scope import binds_this
from kg.validate import validate
from tests.unit.test_validate_engines import CASES, _expected, _keys

BINDS = [
    ("SELECT ?this WHERE { ?this <p> ?v }", True),
    ("SELECT DISTINCT ?this ?path ?value WHERE { ?this ?path ?value . FILTER (?path IN (<a>)) }", True),
    ("SELECT * WHERE { ?x <p> ?this }", True),
    ("SELECT ?this WHERE { FILTER (?x != ?this) ?this <p> ?x }", True),
    ("SELECT ?this WHERE { FILTER NOT EXISTS { ?this <q> ?y } ?this <p> ?x }", True),
    ("SELECT ?this WHERE { FILTER regex(STR(?x), \"{\") ?this <p> ?x }", True),
    # the focus join sits at the start of the group: an operator before ?this is bound changes it
    ("SELECT ?this WHERE { OPTIONAL { ?this a ?c } FILTER(!BOUND(?c)) ?this <p> ?v }", False),
    ("SELECT ?this WHERE { BIND(<x> AS ?y) ?this <p> ?y }", False),
    ("SELECT ?this WHERE { MINUS { ?this <q> ?y } ?this <p> ?x }", False),
    ("SELECT ?this WHERE { { ?this <p> ?x } UNION { ?this <q> ?x } }", False),
    ("SELECT ?this WHERE { VALUES ?this { <a> } ?this <p> ?x }", False),
    ("SELECT ?this WHERE { GRAPH ?g { ?this <p> ?x } }", False),
    ("SELECT ?this WHERE { OPTIONAL { ?this <p> ?x } }", False),
    # ?this only in a string, a FILTER or an IRI is not bound
    ("SELECT ?this WHERE { ?x <p> \"?this\" FILTER(?x = ?this) }", False),
    ("SELECT ?this WHERE { ?x <urn:?this> ?y }", False),
    # not projected, or solution modifiers that a later filter would not commute with
    ("SELECT ?x WHERE { ?this <p> ?x }", False),
    ("SELECT ?this WHERE { ?this <p> ?x } LIMIT 5", False),
    ("SELECT ?this (COUNT(?x) AS ?n) WHERE { ?this <p> ?x } GROUP BY ?this", False),
    ("SELECT ?this WHERE { ?this <p> ?x } ORDER BY ?x", False),
]


@pytest.mark.parametrize(("query", "expected"), BINDS, ids=[q for q, _ in BINDS])
def test_binds_this_reads_the_group_conservatively(query: str, expected: bool) -> None:
    assert binds_this(query) is expected


@pytest.fixture(params=["per-row", "whole-set"])
def unscoped(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Every focus counts as large (queries that bind ?this run unscoped); rows are kept per row,
    or through the whole focus set from the first row on."""
    monkeypatch.setattr(focus_module, "LARGE", 0)
    if request.param == "whole-set":
        monkeypatch.setattr(focus_module, "ROWS_BEFORE_SET", 0)
    return request.param


@pytest.fixture(scope="module")
def shapes():
    return load_shapes(resources.shapes_files())  # as the shape cases were written (no plugin rewrite)


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_unscoped_queries_give_each_shape_case_its_results(case: Path, unscoped: str, shapes) -> None:  # noqa: ANN001
    plant = load_plant([case / "plant.ttl"])
    report = validate(plant, shapes, engine="oxigraph")
    assert _keys(report.results) == _expected(case)


def test_the_unscoped_path_is_taken(monkeypatch: pytest.MonkeyPatch, shapes) -> None:  # noqa: ANN001
    """The forced thresholds do reach the rewritten queries (else the test above proves nothing)."""
    calls: list[str] = []
    real = focus_module.Focus.contains

    def spy(self, key, pattern, targets, node):  # noqa: ANN001, ANN202
        calls.append(key)
        return real(self, key, pattern, targets, node)

    monkeypatch.setattr(focus_module, "LARGE", 0)
    monkeypatch.setattr(focus_module.Focus, "contains", spy)
    case = next(c for c in CASES if c.name == "broker-hasTopic-not-topic")
    report = validate(load_plant([case / "plant.ttl"]), shapes, engine="oxigraph")
    assert not report.conforms and calls

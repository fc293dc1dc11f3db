"""The fast validator's scale rewrites, held to pySHACL on small inline plants.

At scale the fast engine walks a property shape's values once for all its value constraints (one
flag per constraint), finds ``sh:maxCount 1`` violations by a self-join instead of grouping every
focus node, and skips value and maximum-count checks on a predicate no graph uses. Each case here
is built so the rewrite matters — several constraints broken by one value, two distinct terms
with equal values, an inverse path, an absent predicate — and must give pySHACL's results.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rdflib import Graph

from kg.load import load_plant
from kg.shapes import ShapesGraph
from kg.validate import validate

PREFIXES = """@prefix sh: <http://www.w3.org/ns/shacl#> .
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix xsd: <http://www.w3.org/2001/XMLSchema#> .
@prefix ex: <urn:ex#> .
"""

DATA = PREFIXES + """
ex:a a pk:Broker ; pk:id "ok-1" ; pk:port 1883 ; pk:hasTopic ex:t1 .
ex:b a pk:Broker ; pk:id "bad id"@en , "-x" ; pk:port 1 , 1.0 ; pk:hasTopic ex:a , ex:t1 , ex:t2 .
ex:c a pk:Broker ; pk:id 7 ; pk:port "1883" , "1883" .
ex:t1 a pk:Topic ; pk:id "t1" .
ex:t2 a pk:Topic ; pk:id "" .
ex:r a pk:Resource ; pk:id "r" ; pk:sendsTo ex:a , ex:b .
ex:s a pk:Resource ; pk:id "s" ; pk:sendsTo ex:a .
"""

PROPERTY_CASES = {
    # one value breaking datatype, pattern and length at once: one result per constraint
    "merged-value-constraints": 'sh:path pk:id ; sh:datatype xsd:string ; sh:pattern "^[a-z0-9][a-z0-9-]*$" ; '
                                "sh:minLength 2 ; sh:maxLength 3",
    "merged-with-class-and-nodekind": "sh:path pk:hasTopic ; sh:class pk:Topic ; sh:nodeKind sh:IRI ; sh:maxCount 2",
    "maxCount-1-distinct-terms-equal-values": "sh:path pk:port ; sh:maxCount 1",
    "maxCount-1-inverse": "sh:path [ sh:inversePath pk:sendsTo ] ; sh:maxCount 1 ; sh:class pk:Resource",
    "maxCount-2": "sh:path pk:hasTopic ; sh:maxCount 2",
    "minCount-and-maxCount": "sh:path pk:port ; sh:minCount 1 ; sh:maxCount 1",
}

#: Constraints on a predicate nobody uses: nothing to check but the minimum count.
ABSENT = "sh:path pk:noSuchProperty ; sh:maxCount 1 ; sh:datatype xsd:string ; sh:minCount 1"


def _shapes(body: str, target: str = "pk:Broker") -> ShapesGraph:
    ttl = PREFIXES + (f"ex:S a sh:NodeShape ; sh:targetClass {target} ; sh:property ex:P .\n"
                      f"ex:P {body} ; sh:message \"m\" .\n")
    return ShapesGraph(graph=Graph().parse(data=ttl, format="turtle"), files=())


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory):
    path: Path = tmp_path_factory.mktemp("plant") / "data.ttl"
    path.write_text(DATA)
    return load_plant([path])


def _both(plant, shapes: ShapesGraph) -> tuple[set, set]:  # noqa: ANN001
    fast = {r.key() for r in validate(plant, shapes, engine="oxigraph").results}
    reference = {r.key() for r in validate(plant, shapes, engine="pyshacl").results}
    return fast, reference


@pytest.mark.parametrize("name", list(PROPERTY_CASES))
def test_rewritten_constraints_match_pyshacl(name: str, plant) -> None:  # noqa: ANN001
    target = "pk:Broker , pk:Topic" if name == "merged-value-constraints" else "pk:Broker"
    fast, reference = _both(plant, _shapes(PROPERTY_CASES[name], target))
    assert fast == reference
    assert fast, "every case is built to produce at least one result"


def test_one_value_breaking_several_constraints_gives_one_result_each(plant) -> None:  # noqa: ANN001
    shapes = _shapes(PROPERTY_CASES["merged-value-constraints"])
    found = {(r.focus, r.value, r.component) for r in validate(plant, shapes, engine="oxigraph").results}
    assert {("urn:ex#b", "bad id", c) for c in (
        "DatatypeConstraintComponent", "PatternConstraintComponent", "MaxLengthConstraintComponent")} <= found
    assert ("urn:ex#b", "-x", "PatternConstraintComponent") in found
    assert ("urn:ex#b", "-x", "DatatypeConstraintComponent") not in found


def test_maximum_count_counts_terms_not_values(plant) -> None:  # noqa: ANN001
    results = validate(plant, _shapes(PROPERTY_CASES["maxCount-1-distinct-terms-equal-values"]), engine="oxigraph")
    # 1 and 1.0 are two value nodes; "1883" twice is one triple, so ex:c has one value
    assert {r.focus for r in results.results} == {"urn:ex#b"}


def test_absent_predicate_still_reports_the_minimum_count(plant) -> None:  # noqa: ANN001
    fast, reference = _both(plant, _shapes(ABSENT))
    assert fast == reference
    assert {k[6] for k in fast} == {"MinCountConstraintComponent"}
    assert len(fast) == 3  # ex:a, ex:b and ex:c

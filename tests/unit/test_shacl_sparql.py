"""Each SHACL component the fast engine compiles, checked against pySHACL on a small inline plant.

The project's shapes use only some components; these cases cover every one the compiler accepts, so
a future shape cannot silently hit an untested path. Unsupported features are refused, and ``auto``
then falls back to pySHACL.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rdflib import Graph

from kg.errors import ShapesError
from kg.load import load_plant
from kg.shapes import ShapesGraph
from kg.validate import validate

PREFIXES = """@prefix sh: <http://www.w3.org/ns/shacl#> .
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix xsd: <http://www.w3.org/2001/XMLSchema#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix ex: <urn:ex#> .
"""

DATA = PREFIXES + """
ex:Special rdfs:subClassOf pk:Broker .
ex:a a pk:Broker ; pk:port 1883 ; pk:ip "127.0.0.1" ; pk:name "a" ; pk:hasTopic ex:t1 ; pk:retain true .
ex:b a ex:Special ; pk:port 70000, 1 ; pk:ip ex:notALiteral ; pk:name "" ; pk:hasTopic ex:a ; pk:retain "yes" .
ex:c a pk:Broker ; pk:port "1883" ; pk:name "ccc", "dd" ; pk:hasTopic [ a pk:Topic ] ; pk:retain "maybe"^^xsd:boolean .
ex:d a pk:Broker ; pk:port 1883.0 ; pk:name "x"@en .
ex:t1 a pk:Topic ; pk:name "t1" .
ex:r a pk:Resource ; pk:sendsTo ex:a, ex:t1 .
"""

CASES = {
    "minCount-2": "sh:path pk:name ; sh:minCount 2",
    "maxCount-1": "sh:path pk:port ; sh:maxCount 1",
    "datatype-integer": "sh:path pk:port ; sh:datatype xsd:integer",
    "datatype-boolean-illtyped": "sh:path pk:retain ; sh:datatype xsd:boolean",
    "datatype-string-vs-langString": "sh:path pk:name ; sh:datatype xsd:string",
    "nodeKind-literal": "sh:path pk:ip ; sh:nodeKind sh:Literal",
    "nodeKind-iri": "sh:path pk:hasTopic ; sh:nodeKind sh:IRI",
    "class": "sh:path pk:hasTopic ; sh:class pk:Topic",
    "pattern-flags": 'sh:path pk:name ; sh:pattern "^[A-C]+$" ; sh:flags "i"',
    "in-sameTerm": "sh:path pk:port ; sh:in ( 1883 1 )",
    "range-inclusive": "sh:path pk:port ; sh:minInclusive 1 ; sh:maxInclusive 65535",
    "range-exclusive": "sh:path pk:port ; sh:minExclusive 1 ; sh:maxExclusive 65535",
    "length": "sh:path pk:name ; sh:minLength 1 ; sh:maxLength 2",
    "hasValue": 'sh:path pk:name ; sh:hasValue "a"',
    "inverse-path": "sh:path [ sh:inversePath pk:sendsTo ] ; sh:minCount 1",
}

NODE_CASES = {
    "node-class-target-subclass": "sh:targetClass pk:Broker ; sh:nodeKind sh:IRI ; sh:class pk:Topic",
    "node-targetNode": "sh:targetNode ex:a, ex:b ; sh:hasValue ex:a",
    "node-subjectsOf": "sh:targetSubjectsOf pk:sendsTo ; sh:class pk:Broker",
    "node-objectsOf": "sh:targetObjectsOf pk:sendsTo ; sh:class pk:Broker",
    "node-sparql-with-path-and-template": """sh:targetClass pk:Broker ; sh:sparql [
        sh:message "{$this} has port {?value}" ;
        sh:select \"\"\"SELECT $this ?value ?path WHERE { $this pk:port ?value .
            BIND(pk:port AS ?path) FILTER(isLiteral(?value) && STR(?value) != "1883") }\"\"\" ;
        sh:prefixes [ sh:declare [ sh:prefix "pk" ; sh:namespace "https://w3id.org/plantkg/ontology#"^^xsd:anyURI ] ] ]""",
    "node-sparql-not-exists": """sh:targetClass pk:Broker ; sh:sparql [ sh:message "no ip" ;
        sh:select "SELECT $this WHERE { FILTER NOT EXISTS { $this <https://w3id.org/plantkg/ontology#ip> ?ip } }" ]""",
}


def _shapes(body: str, node: bool) -> ShapesGraph:
    if node:
        ttl = PREFIXES + f"ex:S a sh:NodeShape ; sh:message \"m\" ; {body} .\n"
    else:
        ttl = PREFIXES + f"ex:S a sh:NodeShape ; sh:targetClass pk:Broker ; sh:property ex:P .\nex:P {body} ; sh:message \"m\" .\n"
    return ShapesGraph(graph=Graph().parse(data=ttl, format="turtle"), files=())


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory):
    path: Path = tmp_path_factory.mktemp("plant") / "data.ttl"
    path.write_text(DATA)
    return load_plant([path])


@pytest.mark.parametrize("name", list(CASES) + list(NODE_CASES))
def test_component_matches_pyshacl(name: str, plant) -> None:
    shapes = _shapes(CASES.get(name) or NODE_CASES[name], node=name in NODE_CASES)
    fast = {r.key() for r in validate(plant, shapes, engine="oxigraph").results}
    reference = {r.key() for r in validate(plant, shapes, engine="pyshacl").results}
    assert fast == reference
    assert fast, "every case is built to produce at least one result"


def test_sparql_message_template_is_filled(plant) -> None:
    shapes = _shapes(NODE_CASES["node-sparql-with-path-and-template"], node=True)
    messages = {r.message for r in validate(plant, shapes, engine="oxigraph").results}
    assert "urn:ex#b has port 70000" in messages


def test_unsupported_feature_is_refused_and_auto_falls_back(plant) -> None:
    shapes = _shapes("sh:path pk:name ; sh:uniqueLang true", node=False)
    with pytest.raises(ShapesError, match="uniqueLang"):
        validate(plant, shapes, engine="oxigraph")
    assert validate(plant, shapes, engine="auto").engine == "pyshacl"


def test_sequence_paths_are_refused(plant) -> None:
    shapes = _shapes("sh:path ( pk:sendsTo pk:port ) ; sh:minCount 1", node=False)
    with pytest.raises(ShapesError, match="only an IRI or sh:inversePath"):
        validate(plant, shapes, engine="oxigraph")

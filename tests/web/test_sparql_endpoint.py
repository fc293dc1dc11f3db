"""The SPARQL endpoint answers independent clients (SPARQLWrapper, rdflib's SPARQLStore) with what a
direct query (kg.query) gives, and refuses bad requests with the protocol's status codes."""

from __future__ import annotations

import csv
import io
import json

import pytest
import rdflib
from flask.testing import FlaskClient
from rdflib.plugins.stores.sparqlstore import SPARQLStore
from SPARQLWrapper import CSV, JSON, TURTLE, XML, SPARQLWrapper

from engine.web.plant_state import PlantState
from engine.web.sparql_protocol import Limits
from kg.namespaces import GRAPH_INFERRED, GRAPH_OBSERVED, PREFIXES
from kg.query import run_query
from tests.web.conftest import make_app

SENDS = """PREFIX pk: <https://w3id.org/plantkg/ontology#>
SELECT ?resource ?broker WHERE { ?r pk:id ?resource ; pk:sendsTo ?b . ?b pk:id ?broker } ORDER BY ?resource"""
CONSTRUCT = """PREFIX pk: <https://w3id.org/plantkg/ontology#>
CONSTRUCT { ?b pk:id ?id ; pk:port ?port } WHERE { ?b a pk:Broker ; pk:id ?id ; pk:port ?port }"""


def direct_rows(state: PlantState, query: str) -> list[tuple[str, ...]]:
    result = run_query(state.snapshot.plant, query)
    return [tuple(t.value for t in row) for row in result.rows]


def test_sparqlwrapper_json_xml_csv_match_a_direct_query(state: PlantState, served: str) -> None:
    expected = direct_rows(state, SENDS)
    assert ("ros-machine", "mosquitto") in expected and len(expected) == 3
    client = SPARQLWrapper(served + "/sparql")
    client.setQuery(SENDS)
    client.setReturnFormat(JSON)
    data = client.query().convert()
    assert [(b["resource"]["value"], b["broker"]["value"]) for b in data["results"]["bindings"]] == expected
    client.setReturnFormat(XML)
    doc = client.query().convert()
    values = [n.firstChild.data for n in doc.getElementsByTagName("literal")]
    assert list(zip(values[::2], values[1::2])) == expected
    client.setReturnFormat(CSV)
    rows = list(csv.reader(io.StringIO(client.query().convert().decode())))
    assert rows[0] == ["resource", "broker"] and [tuple(r) for r in rows[1:]] == expected


def test_sparqlwrapper_post_and_construct(state: PlantState, served: str) -> None:
    client = SPARQLWrapper(served + "/sparql")
    client.setMethod("POST")
    client.setQuery(CONSTRUCT)
    client.setReturnFormat(TURTLE)
    graph = rdflib.Graph().parse(data=client.query().convert(), format="turtle")
    direct = run_query(state.snapshot.plant, CONSTRUCT)
    assert len(graph) == len(direct.triples) == 4
    assert {str(o) for o in graph.objects(None, rdflib.URIRef(PREFIXES["pk"] + "id"))} == {"kafka", "mosquitto"}


def test_rdflib_sparqlstore_matches_a_direct_query(state: PlantState, served: str) -> None:
    store = SPARQLStore(served + "/sparql")
    graph = rdflib.Graph(store=store)
    got = [tuple(str(v) for v in row) for row in graph.query(SENDS)]
    assert got == direct_rows(state, SENDS)
    ask = graph.query("ASK { ?b <https://w3id.org/plantkg/ontology#brokerType> \"kafka\" }")
    assert ask.askAnswer is True


def test_jsonld_and_turtle_by_accept(client: FlaskClient) -> None:
    r = client.get("/sparql", query_string={"query": CONSTRUCT}, headers={"Accept": "application/ld+json"})
    assert r.status_code == 200 and r.mimetype == "application/ld+json"
    assert len(rdflib.Graph().parse(data=r.data, format="json-ld")) == 4
    r = client.get("/sparql", query_string={"query": "DESCRIBE <https://w3id.org/plantkg/examples/robot-cell#kafka>"})
    assert r.status_code == 200 and r.mimetype == "text/turtle"
    assert len(rdflib.Graph().parse(data=r.data, format="turtle")) > 5


def test_tsv_writes_terms(client: FlaskClient) -> None:
    r = client.get("/sparql", query_string={"query": SENDS}, headers={"Accept": "text/tab-separated-values"})
    lines = r.get_data(as_text=True).splitlines()
    assert lines[0] == "?resource\t?broker" and '"ros-machine"\t"mosquitto"' in lines


def test_named_graphs_and_their_union(client: FlaskClient) -> None:
    q = "SELECT DISTINCT ?g WHERE { GRAPH ?g { ?s ?p ?o } }"
    graphs = {b["g"]["value"] for b in client.get("/sparql", query_string={"query": q}).json["results"]["bindings"]}
    assert {GRAPH_INFERRED, GRAPH_OBSERVED} <= graphs
    assert any(g.endswith("robot-cell.ttl") for g in graphs)
    status = "SELECT ?s WHERE { ?b pk:id \"kafka\" ; pk:status ?s }"  # default graph: the union
    (row,) = client.get("/sparql", query_string={"query": status}).json["results"]["bindings"]
    assert row["s"]["value"] == PREFIXES["pk"] + "Unknown"  # the agents of the fixture do not answer
    only_inferred = client.get("/sparql", query_string={"query": status, "default-graph-uri": GRAPH_INFERRED})
    assert only_inferred.json["results"]["bindings"] == []


@pytest.mark.parametrize("kwargs, status, words", [
    ({"data": "SELECT * {}", "content_type": "text/plain"}, 415, "cannot be sent as text/plain"),
    ({"data": {"update": "INSERT DATA { <a:b> <a:c> <a:d> }"}}, 403, "read-only"),
    ({"data": "DELETE WHERE { ?s ?p ?o }", "content_type": "application/sparql-update"}, 403, "read-only"),
    ({"data": "DROP ALL", "content_type": "application/sparql-query"}, 403, "updates are not allowed"),
    ({"data": {"query": "SELEC ?x"}}, 400, "malformed SPARQL query at line 1"),
    ({"data": {"query": "SELEC nonsense"}}, 400, "malformed SPARQL query"),
    ({"data": {"default-graph-uri": "urn:x"}}, 400, "no query given"),
])
def test_bad_posts(client: FlaskClient, kwargs: dict, status: int, words: str) -> None:
    r = client.post("/sparql", **kwargs)
    assert r.status_code == status and words in r.get_data(as_text=True), r.get_data(as_text=True)


def test_bad_gets(client: FlaskClient) -> None:
    r = client.get("/sparql", query_string=[("query", "ASK {}"), ("query", "ASK {}")])
    assert r.status_code == 400 and "exactly one query" in r.get_data(as_text=True)
    r = client.get("/sparql", query_string={"query": "INSERT DATA { <a:b> <a:c> <a:d> }"})
    assert r.status_code == 403
    r = client.get("/sparql", query_string={"query": SENDS}, headers={"Accept": "image/png"})
    assert r.status_code == 406 and "text/csv" in r.get_data(as_text=True)
    r = client.get("/sparql", query_string={"query": "ASK {}"}, headers={"Accept": "text/csv"})
    assert r.status_code == 406  # CSV has no boolean form
    assert client.get("/sparql", headers={"Accept": "text/html"}).status_code == 302  # a person: the page


def test_result_size_limit(state: PlantState) -> None:
    client = make_app(state, Limits(max_rows=5)).test_client()
    r = client.get("/sparql", query_string={"query": "SELECT * WHERE { ?s ?p ?o }"})
    assert r.status_code == 413 and "more than 5 results" in r.get_data(as_text=True)
    assert client.get("/sparql", query_string={"query": "SELECT * WHERE { ?s ?p ?o } LIMIT 5"}).status_code == 200


@pytest.mark.parametrize("query", [
    "SELECT * WHERE { ?a ?b ?c . ?d ?e ?f }",  # streams: stopped between rows
    "SELECT (COUNT(*) AS ?n) WHERE { ?a ?b ?c . ?d ?e ?f . ?g a owl:Class }",  # computed before its first row
])
def test_timeout(state: PlantState, query: str) -> None:
    client = make_app(state, Limits(timeout_s=0.2, max_rows=10**8)).test_client()
    r = client.get("/sparql", query_string={"query": query})
    assert r.status_code == 503 and "timeout of 0.2 s" in r.get_data(as_text=True)


def test_json_results_match_the_spec_terms(client: FlaskClient) -> None:
    q = 'SELECT ?i ?l ?s WHERE { BIND (42 AS ?i) BIND ("x"@en AS ?l) BIND ("s" AS ?s) }'
    (row,) = json.loads(client.get("/sparql", query_string={"query": q}).data)["results"]["bindings"]
    assert row["i"] == {"type": "literal", "value": "42", "datatype": "http://www.w3.org/2001/XMLSchema#integer"}
    assert row["l"] == {"type": "literal", "value": "x", "xml:lang": "en"}
    assert row["s"] == {"type": "literal", "value": "s"}

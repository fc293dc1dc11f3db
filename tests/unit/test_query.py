"""SPARQL over a plant: kinds of query, bound variables that stay values, read-only."""

from __future__ import annotations

import json
from pathlib import Path

import click
import pyoxigraph as ox
import pytest

from kg.errors import QueryError
from kg.load import load_plant
from kg.query import parse_binding, run_query
from kg.render import query_csv, query_json, query_table

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <urn:plant#> .
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "Shop floor" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1883 .
:kafka a pk:Broker ; pk:id "kafka" ; pk:name "Aggregation" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ; pk:port 9092 .
:odd a pk:Broker ; pk:id "odd" ; pk:name "x\\" } UNION { ?b ?p ?o" .
"""


@pytest.fixture
def plant(tmp_path: Path):
    path = tmp_path / "plant.ttl"
    path.write_text(PLANT)
    return load_plant([path])


def test_select_reads_plant_and_ontology(plant) -> None:
    result = run_query(plant, "SELECT ?b ?ip WHERE { ?b a pk:Broker ; pk:ip ?ip } ORDER BY ?ip")
    assert result.kind == "select"
    assert [t.value for t in result.column("ip")] == ["127.0.0.2", "127.0.0.3"]
    labels = run_query(plant, "SELECT ?l WHERE { pk:Broker rdfs:label ?l }")
    assert [t.value for t in labels.column("l")] == ["Broker"]


def test_binding_is_a_value_not_query_text(plant) -> None:
    query = "SELECT ?b WHERE { ?b pk:name ?name }"
    hostile = '"x\\" } UNION { ?b ?p ?o'
    _, term = parse_binding(f"name={hostile[1:]}")
    assert isinstance(term, ox.Literal)
    result = run_query(plant, query, {"name": ox.Literal('x" } UNION { ?b ?p ?o')})
    assert [t.value for t in result.column("b")] == ["urn:plant#odd"]
    none = run_query(plant, query, {"name": ox.Literal('x" } UNION { ?b ?p ?o }')})
    assert none.rows == ()


def test_binding_of_unprojected_variable_and_ask(plant) -> None:
    result = run_query(plant, "SELECT ?b WHERE { ?b pk:ip ?ip }", {"ip": ox.Literal("127.0.0.3")})
    assert [t.value for t in result.column("b")] == ["urn:plant#kafka"]
    ask = run_query(plant, "ASK { ?b pk:port ?port }", {"port": ox.Literal("9092", datatype=ox.NamedNode("http://www.w3.org/2001/XMLSchema#integer"))})
    assert ask.kind == "ask" and ask.boolean is True
    ask = run_query(plant, "ASK { ?b pk:port ?port }", dict([parse_binding("port=1")]))
    assert ask.boolean is False


def test_parse_binding_kinds() -> None:
    assert parse_binding("c=pk:Broker") == ("c", ox.NamedNode("https://w3id.org/plantkg/ontology#Broker"))
    assert parse_binding("?c=<urn:x>") == ("c", ox.NamedNode("urn:x"))
    assert parse_binding("n=42")[1].datatype.value.endswith("#integer")
    assert parse_binding("s=hello world") == ("s", ox.Literal("hello world"))
    with pytest.raises(QueryError, match="not NAME=VALUE"):
        parse_binding("1x=3")


def test_construct_and_formats(plant) -> None:
    result = run_query(plant, "CONSTRUCT { ?b pk:port ?p } WHERE { ?b pk:port ?p }")
    assert result.kind == "construct" and len(result.triples) == 2
    assert "pk:port 1883" in query_table(result)
    doc = json.loads(query_json(result))
    assert {d["@id"] for d in doc} == {"urn:plant#mqtt", "urn:plant#kafka"}


def test_select_formats(plant) -> None:
    result = run_query(plant, "SELECT ?b ?port WHERE { ?b pk:port ?port } ORDER BY ?port")
    data = json.loads(query_json(result))
    assert data["head"]["vars"] == ["b", "port"]
    assert data["results"]["bindings"][0] == {
        "b": {"type": "uri", "value": "urn:plant#mqtt"},
        "port": {"type": "literal", "value": "1883", "datatype": "http://www.w3.org/2001/XMLSchema#integer"},
    }
    assert query_csv(result).splitlines() == ["b,port", "urn:plant#mqtt,1883", "urn:plant#kafka,9092"]
    table = click.unstyle(query_table(result, {"": "urn:plant#"})).splitlines()
    assert table[0].split() == ["b", "port"]
    assert table[2].split() == [":mqtt", "1883"]
    assert table[-1] == "(2 rows)"


def test_updates_refused(plant) -> None:
    with pytest.raises(QueryError, match="updates are not allowed"):
        run_query(plant, "PREFIX x: <urn:x#>\nDELETE WHERE { ?s ?p ?o }")
    assert run_query(plant, "ASK { ?s pk:port 1883 }").boolean is True


def test_malformed_query_points_at_the_position(plant) -> None:
    with pytest.raises(QueryError) as err:
        run_query(plant, "SELECT ?b\nWHERE { ?b pk:port }")
    text = str(err.value)
    assert "line 2, column" in text and "WHERE { ?b pk:port }" in text and "^" in text

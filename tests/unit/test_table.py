"""kg.table: SELECT answers as tables of plain values, shown as HTML and text."""

from __future__ import annotations

import pyoxigraph as ox
import pytest

from kg.errors import QueryError
from kg.query import run_query
from kg.table import Table, from_records, select, table, value

XSD = "http://www.w3.org/2001/XMLSchema#"


@pytest.fixture()
def store() -> ox.Store:
    s = ox.Store()
    pk = "https://w3id.org/plantkg/ontology#"
    ex = "https://example.org/plant#"
    s.load(f"""
        <{ex}b1> <{pk}port> 1883 ; <{pk}name> "cell <A> & co" ; <{pk}retain> true .
        <{ex}b2> <{pk}port> 9092 .
    """.encode(), format=ox.RdfFormat.TURTLE)
    return s


def test_select_becomes_plain_values_with_short_names(store: ox.Store) -> None:
    answer = run_query(store, "SELECT ?b ?port ?name ?retain WHERE { ?b pk:port ?port "
                              "OPTIONAL { ?b pk:name ?name } OPTIONAL { ?b pk:retain ?retain } } ORDER BY ?port")
    t = table(answer, {"ex": "https://example.org/plant#"})
    assert t.headers == ("b", "port", "name", "retain")
    assert t.rows == (("ex:b1", 1883, "cell <A> & co", True), ("ex:b2", 9092, None, None))
    assert t.column("port") == [1883, 9092]
    assert t.records()[1] == {"b": "ex:b2", "port": 9092, "name": None, "retain": None}


def test_html_escapes_every_cell_and_text_is_aligned(store: ox.Store) -> None:
    t = table(run_query(store, "SELECT ?name WHERE { ?b pk:name ?name }"))
    assert "<td>cell &lt;A&gt; &amp; co</td>" in t._repr_html_()
    assert "<A>" not in t._repr_html_()
    text = str(t).splitlines()
    assert text[0] == "name" and text[2] == "cell <A> & co" and text[-1] == "(1 row)"


def test_only_select_answers_are_tables(store: ox.Store) -> None:
    with pytest.raises(QueryError, match="only a SELECT"):
        table(run_query(store, "ASK { ?b pk:port 1883 }"))


def test_unknown_column_names_the_columns() -> None:
    t = from_records([{"id": "a", "status": "running"}, {"id": "b"}], ["id", "status"])
    assert t.rows == (("a", "running"), ("b", None))
    with pytest.raises(QueryError) as info:
        t.column("pid")
    assert "id, status" in (info.value.hint or "")


@pytest.mark.parametrize(("term", "expected"), [
    (ox.Literal("7", datatype=ox.NamedNode(XSD + "int")), 7),
    (ox.Literal("2.5", datatype=ox.NamedNode(XSD + "decimal")), 2.5),
    (ox.Literal("false", datatype=ox.NamedNode(XSD + "boolean")), False),
    (ox.Literal("x7", datatype=ox.NamedNode(XSD + "integer")), "x7"),  # ill-typed stays text
    (ox.NamedNode("https://w3id.org/plantkg/ontology#Broker"), "pk:Broker"),
    (None, None),
])
def test_value_converts_typed_literals(term: ox.Literal | ox.NamedNode | None, expected: object) -> None:
    assert value(term) == expected
    assert type(value(term)) is type(expected)


def test_table_is_frozen() -> None:
    t = Table(("a",), ((1,),))
    with pytest.raises(AttributeError):
        t.rows = ()  # type: ignore[misc]


def test_select_uses_the_plant_prefixes_and_bound_values() -> None:
    from kg.load import load_plant
    from kg.resources import examples_dir

    plant = load_plant([examples_dir() / "multi-machine.ttl"])
    t = select(plant, "SELECT ?broker WHERE { ?b pk:id ?broker ; pk:ip ?ip } ORDER BY ?broker",
               {"ip": ox.Literal("127.0.0.2")})
    assert t.column("broker") == ["mosquitto-a"]
    t = select(plant, "SELECT ?b WHERE { ?b pk:brokerType \"kafka\" }")
    assert t.column("b") == ["mm:kafka"]

"""Entities (engine.context_broker.entities) and their RDF mapping (engine.context_broker.rdf):
parsing with defaults, update semantics, renderings, and the round trip through Oxigraph."""

from __future__ import annotations

import pyoxigraph as ox
import pytest

from engine.context_broker import entities as ent
from engine.context_broker import rdf
from engine.context_broker.contract import NgsiError, Tenant
from kg.namespaces import NGSI, NGSI_ENTITY_BASE, NGSI_GRAPH_BASE, NGSI_TYPE_BASE

# (JSON value, default type)
DEFAULT_TYPES = [("x", "Text"), (1, "Number"), (1.5, "Number"), (True, "Boolean"), (None, "None"),
                 ({"a": 1}, "StructuredValue"), ([1, 2], "StructuredValue")]


@pytest.mark.parametrize(("value", "expected"), DEFAULT_TYPES)
def test_attribute_type_defaults_from_the_value(value: object, expected: str) -> None:
    _, _, attrs = ent.parse_entity({"id": "E", "a": {"value": value}})
    assert attrs["a"].type == expected
    _, _, attrs = ent.parse_entity({"id": "E", "a": value}, key_values=True)
    assert attrs["a"].type == expected


def test_entity_defaults_type_thing_and_missing_value_is_null() -> None:
    entity_id, entity_type, attrs = ent.parse_entity({"id": "E", "a": {"type": "Number"}})
    assert (entity_id, entity_type, attrs["a"].value, attrs["a"].type) == ("E", "Thing", None, "Number")


# (body, words of the 400)
BAD_BODIES = [
    ({"type": "T"}, ["id", "missing"]),
    ({"id": "E", "a": 5}, ["attribute 'a'", "keyValues"]),
    ({"id": "E", "a": {"value": 1, "unit": "x"}}, ["unrecognized", "unit"]),
    ({"id": "E", "a": {"value": 1, "metadata": []}}, ["metadata", "'a'"]),
    ({"id": "E", "a": {"value": 1, "metadata": {"m": {"value": 1, "x": 2}}}}, ["'m'", "x"]),
    ({"id": "E", "a": {"value": "2024-13-01", "type": "DateTime"}}, ["not a date"]),
    ({"id": "E", "a": {"value": 1, "type": ""}}, ["type of attribute 'a'"]),
    ({"id": "E", "a": {"value": 1, "type": 5}}, ["type of attribute 'a'"]),
]


@pytest.mark.parametrize(("body", "words"), BAD_BODIES, ids=[str(b)[:40] for b, _ in BAD_BODIES])
def test_bad_bodies_are_400_naming_the_field(body: dict, words: list[str]) -> None:
    with pytest.raises(NgsiError) as info:
        ent.parse_entity(body)
    assert info.value.status == 400
    for word in words:
        assert word in info.value.description, info.value.description


def test_non_object_bodies_are_parse_errors() -> None:
    for body in ([], "x", 5, None):
        with pytest.raises(NgsiError) as info:
            ent.parse_entity(body)
        assert info.value.error == "ParseError"


def test_datetime_values_are_stored_as_orion_renders_them() -> None:
    _, _, attrs = ent.parse_entity({"id": "E", "t": {"type": "DateTime", "value": "2024-05-01T12:00+02:00"}})
    assert attrs["t"].value == "2024-05-01T10:00:00.000Z"


# (text/plain body, value)
TEXT_VALUES = [(b'"moving"', "moving"), (b"12.5", 12.5), (b"7", 7), (b"-3", -3), (b"true", True),
               (b"false", False), (b"null", None), (b'"a \\"b\\""', 'a "b"'), (b" 1e3 ", 1000.0)]


@pytest.mark.parametrize(("raw", "value"), TEXT_VALUES)
def test_text_plain_values_as_orion_reads_them(raw: bytes, value: object) -> None:
    assert ent.parse_text_value(raw) == value


@pytest.mark.parametrize("raw", [b"moving", b"nan", b"inf", b"{", b"\xff"])
def test_bad_text_plain_values(raw: bytes) -> None:
    with pytest.raises(NgsiError):
        ent.parse_text_value(raw)


def _entity() -> ent.Entity:
    _, _, attrs = ent.parse_entity({"id": "urn:ngsi-ld:AGV:1", "type": "AGV",
                                    "state": {"value": "idle", "metadata": {"unit": {"value": "x"}}},
                                    "battery": {"value": 80}, "pose": {"value": {"x": 1}}})
    return ent.create_entity("urn:ngsi-ld:AGV:1", "AGV", "/", attrs, 1000.0)


def test_merge_keeps_metadata_unless_overridden_and_empty_metadata_clears() -> None:
    old = _entity()
    given = ent.parse_attrs({"state": {"value": "moving", "metadata": {"since": {"value": 1}}}})
    merged = ent.merge_attrs(old, given, 2000.0)
    assert set(merged.attrs["state"].metadata) == {"unit", "since"}
    assert merged.attrs["state"].created == 1000.0 and merged.attrs["state"].modified == 2000.0
    assert merged.modified == 2000.0 and merged.created == 1000.0
    assert set(ent.merge_attrs(old, given, 2.0, override_metadata=True).attrs["state"].metadata) == {"since"}
    cleared = ent.merge_attrs(old, ent.parse_attrs({"state": {"value": 1, "metadata": {}}}), 2.0)
    assert cleared.attrs["state"].metadata == {}


def test_patch_skips_missing_and_append_strict_skips_existing_as_orion() -> None:
    old = _entity()
    given = ent.parse_attrs({"state": {"value": 1}, "nope": {"value": 1}})
    update = ent.split_attrs(old, given, existing_only=True)
    assert list(update.applicable) == ["state"] and update.skipped == ("nope",)
    refusal = update.refusal(old)
    assert refusal is not None and (refusal.status, refusal.error) == (422, "PartialUpdate")
    assert "nope" in refusal.description
    append = ent.split_attrs(old, given, strict=True)
    assert list(append.applicable) == ["nope"] and append.skipped == ("state",)
    only_existing = ent.split_attrs(old, ent.parse_attrs({"state": {"value": 1}}), strict=True)
    refusal = only_existing.refusal(old)
    assert refusal is not None and refusal.error == "Unprocessable" and "Already Exists" in refusal.description
    assert ent.split_attrs(old, given).refusal(old) is None


def test_renderings() -> None:
    e = _entity()
    assert ent.render(e, "keyValues") == {"id": e.id, "type": "AGV", "state": "idle", "battery": 80,
                                          "pose": {"x": 1}}
    assert ent.render(e, "values", ["battery", "state"]) == [80, "idle"]
    assert ent.render(e, "unique", ["state", "battery", "state"]) == ["idle", 80]
    normalized = ent.render(e)
    assert normalized["state"] == {"type": "Text", "value": "idle", "metadata": {"unit": {"type": "Text", "value": "x"}}}
    picked = ent.render(e, "normalized", ["dateCreated", "battery", "missing"], ["dateModified"])
    assert list(picked) == ["id", "type", "dateCreated", "battery"]
    assert picked["dateCreated"]["value"] == "1970-01-01T00:16:40.000Z"
    assert picked["battery"]["metadata"] == {"dateModified": {"type": "DateTime", "value": "1970-01-01T00:16:40.000Z"}}
    assert ent.render_attrs(e, "keyValues", ["*"], None) == {"state": "idle", "battery": 80, "pose": {"x": 1}}


# (value, NGSI type, expected datatype local name)
LITERALS = [("idle", "Text", "string"), (80, "Number", "integer"), (81.5, "Number", "double"),
            (True, "Boolean", "boolean"), (None, "None", "JSON"), ({"x": [1, None]}, "StructuredValue", "JSON"),
            ("2024-05-01T10:00:00.000Z", "DateTime", "dateTime"), ("1", "Number", "string"),
            (2**70, "Number", "integer"), (-1e-300, "Number", "double")]


@pytest.mark.parametrize(("value", "ngsi_type", "datatype"), LITERALS)
def test_values_become_typed_literals_and_come_back(value: object, ngsi_type: str, datatype: str) -> None:
    store = ox.Store()
    _, _, attrs = ent.parse_entity({"id": "E1", "type": "T", "a": {"value": value, "type": ngsi_type}})
    entity = ent.create_entity("E1", "T", "/plant", attrs, 1700000000.123456)
    graph = rdf.graph_iri(Tenant("acme", "/plant"))
    store.update(rdf.update_text(graph, [], rdf.entity_triples(entity, rdf.preferred_node("E1", "T"))))
    literal = next(store.quads_for_pattern(None, ox.NamedNode(str(NGSI.hasValue)), None, None)).object
    assert literal.datatype.value.endswith("#" + datatype)
    [(back, node)] = rdf.entities_from_quads(store.quads_for_pattern(None, None, None, ox.NamedNode(graph)), "/plant")
    assert back.normalized == entity.normalized
    assert (back.created, back.modified) == pytest.approx((entity.created, entity.modified), abs=1e-6)
    assert node == NGSI_ENTITY_BASE + "T/E1"


def test_iri_ids_are_the_node_types_become_classes_and_graphs_name_the_tenant() -> None:
    assert rdf.preferred_node("urn:ngsi-ld:AGV:1", "AGV") == "urn:ngsi-ld:AGV:1"
    assert rdf.preferred_node("Room 1", "Room") == NGSI_ENTITY_BASE + "Room/Room%201"
    assert rdf.type_iri("AGV") == NGSI_TYPE_BASE + "AGV"
    assert rdf.type_iri("https://smartdatamodels.org/dataModel.Transportation/Vehicle") == \
        "https://smartdatamodels.org/dataModel.Transportation/Vehicle"
    assert rdf.graph_iri(Tenant()) == NGSI_GRAPH_BASE + "_/"
    assert rdf.graph_iri(Tenant("acme", "/a/b")) == NGSI_GRAPH_BASE + "acme/a/b"
    for tenant in (Tenant(), Tenant("acme", "/a/b")):
        assert rdf.tenant_of_graph(rdf.graph_iri(tenant)) == tenant
    assert rdf.tenant_of_graph("https://example.org/other") is None


def test_update_text_escapes_every_term() -> None:
    store = ox.Store()
    _, _, attrs = ent.parse_entity({"id": "E", "a": {"value": "line\nbreak \\ and } braces {",
                                                     "type": "TextUnrestricted"}})
    entity = ent.create_entity("E", "T", "/", attrs, 1.0)
    triples = rdf.entity_triples(entity, rdf.preferred_node("E", "T"))
    store.update(rdf.update_text("urn:g", [], triples))
    [(back, _)] = rdf.entities_from_quads(store.quads_for_pattern(None, None, None, None), "/")
    assert back.attrs["a"].value == "line\nbreak \\ and } braces {"
    store.update(rdf.update_text("urn:g", triples, []))
    assert list(store.quads_for_pattern(None, None, None, None)) == []


@pytest.mark.parametrize("text", ["plain", 'quo"te', "back\\slash", "line\nfeed\r", "tab\tbell\x07",
                                  "ünï©ødé ✓ 𝄞", "", "\\u0041 not an escape"])
def test_literals_serialize_as_pyoxigraph_does(text: str) -> None:
    for datatype in (rdf.XSD_STRING, rdf.XSD_DOUBLE, rdf.RDF_JSON):
        assert rdf._literal(text, datatype) == str(ox.Literal(text, datatype=ox.NamedNode(datatype)))


def test_lone_surrogates_and_nan_are_parse_errors() -> None:
    for raw in (b'{"id": "E", "a": {"value": "\\ud800"}}', b'{"id": "E", "a": {"value": NaN}}',
                b'{"id": "E", "\\udfff": 1}'):
        with pytest.raises(NgsiError) as info:
            ent.parse_json(raw)
        assert info.value.error == "ParseError"
    assert ent.parse_json(b'{"a": "\\u00e9\\ud834\\udd1e"}') == {"a": "é𝄞"}


def test_an_id_oxigraph_would_refuse_as_iri_gets_a_minted_node() -> None:
    assert rdf.preferred_node("urn:bad%zz", "T") == NGSI_ENTITY_BASE + "T/urn%3Abad%25zz"

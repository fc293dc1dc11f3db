"""The Simple Query Language (engine.context_broker.q): matching and refusals as data."""

from __future__ import annotations

import pytest

from engine.context_broker.contract import NgsiError
from engine.context_broker.q import parse_q


def attr(value, type_="Text", **metadata):
    return {"type": type_, "value": value,
            "metadata": {k: {"type": "Text" if isinstance(v, str) else "Number", "value": v}
                         for k, v in metadata.items()}}


AGV = {
    "id": "urn:ngsi-ld:AGV:1", "type": "AGV",
    "state": attr("moving"),
    "battery": attr(81.5, "Number", accuracy=0.5, unit="percent"),
    "speed": attr(2, "Number"),
    "count": attr("20"),
    "charging": attr(False, "Boolean"),
    "pose": attr({"x": 3.5, "y": -1, "map": {"id": "hall.1"}, "label": "a,b"}, "StructuredValue"),
    "tags": attr(["red", "fast"], "StructuredValue"),
    "seen": attr("2024-05-01T10:00:00.000Z", "DateTime"),
    "note": attr(None, "None"),
    "a.b": attr(7, "Number"),
}

# (q, matches AGV)
MATCH_CASES = [
    ("state", True), ("!state", False), ("missing", False), ("!missing", True),
    ("state==moving", True), ("state==idle", False), ("state:moving", True),
    ("state=='moving'", True), ("state!=moving", False), ("state!=idle", True),
    ("missing!=idle", False),
    ("state==idle,moving", True), ("state==idle,error", False), ("state!=idle,error", True),
    ("state!=idle,moving", False),
    ("battery>80", True), ("battery>81.5", False), ("battery>=81.5", True), ("battery<90", True),
    ("battery<=81.4", False), ("battery==81.5", True), ("battery==81.50", True),
    ("battery==80..90", True), ("battery==90..100", False), ("battery!=90..100", True),
    ("battery!=80..90", False), ("speed==2", True), ("speed==2.0", True), ("speed>1e0", True),
    ("battery>-1", True),
    ("count==20", True), ("count=='20'", True), ("speed=='2'", False), ("count>10", False),
    ("charging==false", True), ("charging==true", False), ("charging!=true", True),
    ("pose.x>3", True), ("pose.x<3", False), ("pose.y==-1", True), ("pose.map.id==hall.1", True),
    ("pose.map.id=='hall.1'", True), ("pose.z", False), ("!pose.z", True), ("pose.x.q", False),
    ("pose.label=='a,b'", True), ("pose.label==a,b", False),
    ("tags==red", True), ("tags==blue", False), ("tags==blue,fast", True), ("tags!=red", False),
    ("seen>2024-01-01", True), ("seen<2024-01-01", False), ("seen>2024-05-01T09:59:59Z", True),
    ("seen>2024-05-01T12:00:00+02:00", False), ("seen>=2024-05-01T12:00:00+02:00", True),
    ("seen==2024-04-30..2024-05-02", True), ("seen==2024-05-02..2024-05-03", False),
    ("note==null", True), ("state==null", False), ("note", True),
    ("state~=ov", True), ("state~=^mov", True), ("state~=x", False), ("battery~=8", False),
    ("state==a..z", True), ("state==n..z", False), ("state>m", True), ("state<m", False),
    ("'a.b'==7", True), ("a.b==7", False),
    ("state==moving;battery>80", True), ("state==moving;battery>90", False),
    ("state;!missing;speed==1..3", True),
    ("battery>abc", False), ("charging>0", False),
]

MQ_CASES = [
    ("battery.accuracy<1", True), ("battery.accuracy>1", False), ("battery.unit==percent", True),
    ("battery.unit", True), ("battery.nothing", False), ("!battery.nothing", True),
    ("state.accuracy", False),
]

# (q, words the description must hold)
BAD_CASES = [
    ("", ["empty"]), ("   ", ["empty"]),
    ("temperature>", ["temperature", "no value"]),
    (">5", ["no attribute"]),
    ("temperature>1..5", ["range"]), ("temperature<1,5", ["list"]), ("temperature~=a,b", ["list"]),
    ("temperature==1,", ["empty value", "character 15"]),
    ("temperature==1;;pressure==2", ["empty statement", "character 15"]),
    (";a", ["empty statement", "character 0"]), ("a;", ["empty statement"]),
    ("a=='x", ["unterminated quote"]), ("a==x'y", ["quote"]), ("a=='x'y'", ["quote"]),
    ("a==1..b", ["range", "number"]), ("a==1..2..3", ["range"]), ("a==1..2,3", ["range"]),
    ("a..b==1", ["empty name"]), ("a b==1", ["character 1", "path"]),
    ("state~=(", ["regular expression"]), ("!!a", ["'!'"]),
]


@pytest.mark.parametrize(("text", "expected"), MATCH_CASES, ids=[c[0] for c in MATCH_CASES])
def test_q_matches(text: str, expected: bool) -> None:
    assert parse_q(text).matches(AGV) is expected


@pytest.mark.parametrize(("text", "expected"), MQ_CASES, ids=[c[0] for c in MQ_CASES])
def test_mq_matches(text: str, expected: bool) -> None:
    assert parse_q(text, metadata=True).matches(AGV) is expected


@pytest.mark.parametrize(("text", "words"), BAD_CASES, ids=[repr(c[0]) for c in BAD_CASES])
def test_bad_q_is_a_400_naming_the_problem(text: str, words: list[str]) -> None:
    with pytest.raises(NgsiError) as info:
        parse_q(text)
    err = info.value
    assert (err.status, err.error) == (400, "BadRequest")
    for word in words:
        assert word.lower() in err.description.lower(), err.description


def test_mq_needs_a_metadata_name() -> None:
    with pytest.raises(NgsiError) as info:
        parse_q("battery>1", metadata=True)
    assert "metadata" in info.value.description


def test_query_lists_its_attributes_and_statements() -> None:
    query = parse_q("state==moving;!pose.z;battery>1")
    assert query.attributes == {"state", "pose", "battery"}
    assert [s.op for s in query.statements] == ["==", "absent", ">"]
    assert [s.position for s in query.statements] == [0, 14, 22]


def test_entity_without_value_or_with_bare_values_does_not_match() -> None:
    assert not parse_q("state==moving").matches({"id": "x", "type": "T", "state": "moving"})
    assert not parse_q("state").matches({"id": "x", "type": "T", "state": {"type": "Text"}})


@pytest.mark.parametrize(("text", "expected"), MATCH_CASES, ids=[c[0] for c in MATCH_CASES])
def test_fast_predicates_agree_with_the_general_matcher(text: str, expected: bool) -> None:
    from engine.context_broker.q import _matches

    query = parse_q(text)
    for entity in (AGV, {"id": "x", "type": "T"}, {"id": "y", "type": "T", "state": {"value": 5},
                                                    "battery": {"value": "81.5"}, "speed": {"value": [2, 3]},
                                                    "count": {"value": 20}, "charging": {"value": None}}):
        general = all(_matches(s, entity, False) for s in query.statements)
        assert query.matches(entity) is general

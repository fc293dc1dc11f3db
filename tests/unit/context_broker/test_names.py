"""Orion's identifier and value rules (engine.context_broker.names), refusals as data."""

from __future__ import annotations

import pytest

from engine.context_broker.contract import NgsiError
from engine.context_broker.names import (
    check_attribute_name, check_identifier, check_metadata_name, check_value,
)

GOOD_IDS = ["Room1", "urn:ngsi-ld:AGV:1", "a-b_c.d:e", "x" * 256, "Ünicode"[1:], "!$%*+,@[]^`{|}~"]

# (value, words the description must hold)
BAD_IDS = [
    ("", ["empty", "length 0"]),
    ("x" * 257, ["257", "256"]),
    ("ab<cd", ["'<'", "position 2"]), ("ab>cd", ["'>'", "position 2"]),
    ('ab"cd', ["'\"'", "position 2"]), ("ab'cd", ["'''", "position 2"]),
    ("ab=cd", ["'='"]), ("ab;cd", ["';'"]), ("ab(cd", ["'('"]), ("ab)cd", ["')'"]),
    ("ab cd", ["whitespace", "position 2"]), ("ab\tcd", ["U+0009", "position 2"]),
    ("ab\x01cd", ["U+0001"]), ("a&b", ["'&'", "position 1"]), ("a?b", ["'?'"]), ("a/b", ["'/'"]),
    ("a#b", ["'#'"]), ("aé", ["non-ASCII", "position 1"]), (5, ["string"]), (None, ["string"]),
]


@pytest.mark.parametrize("value", GOOD_IDS)
def test_good_identifiers_pass(value: str) -> None:
    assert check_identifier(value, "entity id") == value


@pytest.mark.parametrize(("value", "words"), BAD_IDS, ids=[repr(v)[:20] for v, _ in BAD_IDS])
def test_bad_identifiers_name_the_field_character_and_position(value: object, words: list[str]) -> None:
    with pytest.raises(NgsiError) as info:
        check_identifier(value, "entity id")
    assert (info.value.status, info.value.error) == (400, "BadRequest")
    assert "entity id" in info.value.description
    for word in words:
        assert word in info.value.description, info.value.description


@pytest.mark.parametrize("name", ["id", "type", "geo:distance", "*"])
def test_reserved_attribute_names(name: str) -> None:
    with pytest.raises(NgsiError, match="reserved"):
        check_attribute_name(name)


def test_metadata_star_is_reserved_and_names_the_attribute() -> None:
    with pytest.raises(NgsiError, match="temperature"):
        check_metadata_name("*", "temperature")


# (value, words) for values with forbidden characters, anywhere inside
BAD_VALUES = [
    ("<script>", ["'<'", "position 0"]),
    ({"a": {"b": "x=y"}}, ["a.b", "'='", "position 1"]),
    ([1, "ok", "(x"], ["[2]", "'('"]),
    ({"k;": 1}, ["';'"]),
]


@pytest.mark.parametrize(("value", "words"), BAD_VALUES, ids=[repr(v)[:20] for v, _ in BAD_VALUES])
def test_forbidden_characters_in_values(value: object, words: list[str]) -> None:
    with pytest.raises(NgsiError) as info:
        check_value(value, "value of attribute 'name'")
    assert "value of attribute 'name'" in info.value.description
    for word in words:
        assert word in info.value.description, info.value.description


@pytest.mark.parametrize("value", ["moving", 1.5, None, True, {"x": [1, "a b & c"]}, "#/?&"])
def test_allowed_values_pass(value: object) -> None:
    check_value(value, "value")

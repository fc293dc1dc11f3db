"""VDA 5050 topics (names, validation errors, QoS/retain rules) and headers, cases as data."""

from __future__ import annotations

from datetime import datetime, timedelta, timezone

import pytest

from fleet.vda5050 import headers, topics
from fleet.vda5050.errors import TopicError
from fleet.vda5050.topics import Subtopic


def test_topic_layout() -> None:
    assert topics.topic("KIT", "0001", Subtopic.ORDER) == "uagv/v2/KIT/0001/order"
    assert topics.topic("KIT", "a_b.c:d-1", "instantActions") == "uagv/v2/KIT/a_b.c:d-1/instantActions"
    assert topics.subscription(Subtopic.STATE) == "uagv/v2/+/+/state"


@pytest.mark.parametrize(
    ("manufacturer", "serial", "field", "fragment"),
    [
        ("KIT", "ab/c", "serialNumber", "'/' at position 2"),
        ("KIT", "+", "serialNumber", "'+' at position 0"),
        ("KIT", "x#", "serialNumber", "'#' at position 1"),
        ("KIT", "$SYS", "serialNumber", "'$' at position 0"),
        ("KIT", "a b", "serialNumber", "' ' at position 1 is not one of"),
        ("KIT", "wagen-ä", "serialNumber", "'ä' at position 6"),
        ("KIT", "", "serialNumber", "non-empty"),
        ("K/T", "1", "manufacturer", "'/' at position 1"),
        ("K+", "1", "manufacturer", "'+' at position 1"),
        ("", "1", "manufacturer", "non-empty"),
        ("KIT", "x" * 129, "serialNumber", "at most 128"),
    ],
)
def test_bad_levels_name_the_character(manufacturer: str, serial: str, field: str, fragment: str) -> None:
    with pytest.raises(TopicError) as caught:
        topics.topic(manufacturer, serial, Subtopic.STATE)
    assert caught.value.field == field
    assert fragment in str(caught.value)


def test_manufacturer_may_hold_spaces_but_serial_may_not() -> None:
    assert topics.topic("Acme Robots", "7", "state") == "uagv/v2/Acme Robots/7/state"


@pytest.mark.parametrize(
    ("name", "fragment"),
    [
        ("uagv/v2/KIT/1", "has 4 levels"),
        ("agv/v2/KIT/1/state", "interface name 'agv'"),
        ("uagv/v1/KIT/1/state", "major version 'v1'"),
        ("uagv/v2/KIT/1/status", "'status' is not one of"),
        ("uagv/v2/KIT/1 2/state", "' ' at position 1"),
    ],
)
def test_parse_refuses_with_reason(name: str, fragment: str) -> None:
    with pytest.raises(TopicError, match=fragment.replace("(", r"\(")):
        topics.parse(name)


def test_parse_roundtrip() -> None:
    parsed = topics.parse("uagv/v2/KIT/0001/connection")
    assert (parsed.manufacturer, parsed.serial, parsed.subtopic) == ("KIT", "0001", Subtopic.CONNECTION)


def test_qos_and_retain_rules() -> None:
    rules = {s.value: (topics.rule(s).qos, topics.rule(s).retain) for s in Subtopic}
    assert rules == {
        "order": (0, False), "instantActions": (0, False), "state": (0, False),
        "visualization": (0, False), "connection": (1, True), "factsheet": (0, False),
    }


def test_header_ids_count_per_topic_and_timestamps_are_utc_ms() -> None:
    moments = iter(datetime(2026, 11, 24, 16, 0, 0, 123456, tzinfo=timezone.utc) + timedelta(seconds=i) for i in range(10))
    counter = headers.HeaderCounter("KIT", "7", clock=lambda: next(moments))
    first = counter.next(Subtopic.STATE)
    assert first == {"headerId": 0, "timestamp": "2026-11-24T16:00:00.123Z", "version": "2.1.0",
                     "manufacturer": "KIT", "serialNumber": "7"}
    assert counter.next("state")["headerId"] == 1
    assert counter.next("connection")["headerId"] == 0  # a topic of its own
    assert counter.next("state")["headerId"] == 2
    assert counter.peek("visualization") == 0


def test_timestamp_converts_other_zones_and_refuses_naive() -> None:
    cet = timezone(timedelta(hours=1))
    assert headers.timestamp(datetime(2026, 1, 1, 1, 0, tzinfo=cet)) == "2026-01-01T00:00:00.000Z"
    with pytest.raises(ValueError, match="naive"):
        headers.timestamp(datetime(2026, 1, 1))


def test_header_counter_checks_its_names() -> None:
    with pytest.raises(TopicError):
        headers.HeaderCounter("KIT", "a/b")

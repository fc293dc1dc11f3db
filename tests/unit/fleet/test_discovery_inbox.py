"""fleet.discovery.inbox: what each received message becomes, and every hostile one refused with its reason."""

from __future__ import annotations

import copy
from typing import Any

import pytest

from fleet.discovery.errors import RefusedMessage
from fleet.discovery.inbox import (SUBSCRIPTIONS, ConnectionSeen, DescriptionSeen, Interface, StateSeen, VehicleKey,
                                   classify)
from tests.unit.fleet import discovery_data as d

KEY = VehicleKey(Interface.VDA5050, d.MANUFACTURER, d.SERIAL)


def test_subscriptions_are_the_five_filters_of_plug_and_play() -> None:
    assert SUBSCRIPTIONS == ("uagv/v2/+/+/connection", "uagv/v2/+/+/factsheet", "uagv/v2/+/+/state",
                             "+/description_channel", "+/status_channel")


@pytest.mark.parametrize("state", ["ONLINE", "OFFLINE", "CONNECTIONBROKEN"])
def test_connection_states(state: str) -> None:
    event = classify(d.topic("connection"), d.wire(d.connection(state)), retained=True)
    assert event == ConnectionSeen(KEY, state, True)


def test_factsheet_is_a_description_of_the_topic_vehicle() -> None:
    sheet = d.factsheet()
    assert classify(d.topic("factsheet"), d.wire(sheet)) == DescriptionSeen(KEY, sheet)


def test_state_keeps_last_node_action_states_and_battery() -> None:
    event = classify(d.topic("state"), d.wire(d.state()))
    assert isinstance(event, StateSeen) and event.key == KEY
    s = event.state
    assert (s.last_node_id, s.last_node_sequence_id, s.battery_charge, s.charging) == ("n2", 4, 81.5, False)
    assert [(a.action_id, a.status) for a in s.action_states] == [("p1", "FINISHED")]
    assert s.to_json()["actionStates"] == [{"actionId": "p1", "actionType": "pick", "actionStatus": "FINISHED"}]


def test_paper_channels() -> None:
    desc = d.paper_description()
    key = VehicleKey(Interface.PAPER, "", "agv-7")
    assert classify("agv-7/description_channel", d.wire(desc), True) == DescriptionSeen(key, desc)
    assert classify("agv-7/description_channel", b"", True) == DescriptionSeen(key, None)
    assert classify("agv-7/status_channel", d.wire({"state": "OFFLINE"}), True) == ConnectionSeen(key, "OFFLINE", True)
    assert classify("agv-7/status_channel", d.wire({"state": "MOVING"})) == ConnectionSeen(key, "ONLINE", False)


def _without(message: dict[str, Any], *path: str) -> dict[str, Any]:
    out = copy.deepcopy(message)
    target = out
    for part in path[:-1]:
        target = target[part]
    del target[path[-1]]
    return out


def _with(message: dict[str, Any], value: Any, *path: str) -> dict[str, Any]:
    out = copy.deepcopy(message)
    target = out
    for part in path[:-1]:
        target = target[part]
    target[path[-1]] = value
    return out


# (case, topic, payload, words the reason must contain)
HOSTILE = [
    ("factsheet without typeSpecification", d.topic("factsheet"), d.wire(_without(d.factsheet(), "typeSpecification")),
     "'typeSpecification' is a required property"),
    ("factsheet without physicalParameters.speedMax", d.topic("factsheet"),
     d.wire(_without(d.factsheet(), "physicalParameters", "speedMax")), "'speedMax' is a required property"),
    ("factsheet speedMax as text", d.topic("factsheet"),
     d.wire(_with(d.factsheet(), "fast", "physicalParameters", "speedMax")), "'fast' is not of type 'number'"),
    ("factsheet agvActions not a list", d.topic("factsheet"),
     d.wire(_with(d.factsheet(), {"pick": 1}, "protocolFeatures", "agvActions")), "is not of type 'array'"),
    ("header serial with /", d.topic("factsheet"), d.wire(_with(d.factsheet(), "agv/42", "serialNumber")),
     "character '/' at position 3"),
    ("header serial with #", d.topic("connection"), d.wire(_with(d.connection(), "agv#42", "serialNumber")),
     "character '#' at position 3"),
    ("header serial of another vehicle", d.topic("factsheet"), d.wire(_with(d.factsheet(), "agv-43", "serialNumber")),
     "is not the topic's 'agv-42'"),
    ("header manufacturer of another", d.topic("state"), d.wire(_with(d.state(), "evil", "manufacturer")),
     "header manufacturer 'evil'"),
    ("10 MB factsheet", d.topic("factsheet"), b"{" + b" " * 10_000_000 + b"}", "10000002 bytes, more than"),
    ("not JSON", d.topic("connection"), b"ONLINE", "not UTF-8 JSON"),
    ("not UTF-8", d.topic("connection"), b"\xff\xfe", "not UTF-8 JSON"),
    ("a JSON list", d.topic("connection"), b"[]", "a message is a JSON object"),
    ("unknown connection state", d.topic("connection"), d.wire(_with(d.connection(), "MAYBE", "connectionState")),
     "'MAYBE' is not one of"),
    ("headerId as text", d.topic("connection"), d.wire(_with(d.connection(), "1", "headerId")),
     "'1' is not of type 'integer'"),
    ("wrong interface name", "xagv/v2/acme/agv-42/connection", d.wire(d.connection()), "interface name 'xagv'"),
    ("serial level with bad char", "uagv/v2/acme/agv*42/connection", d.wire(d.connection()), "character '*'"),
    ("paper agv id of another", "agv-7/description_channel", d.wire(d.paper_description("agv-8")),
     "agv_id 'agv-8' is not the topic's 'agv-7'"),
    ("paper status without state", "agv-7/status_channel", d.wire({"battery": 3}), "state: expected a non-empty string"),
    ("paper agv id with bad char", "agv*7/status_channel", d.wire({"state": "IDLE"}), "character '*'"),
]


@pytest.mark.parametrize("case,topic,payload,reason", HOSTILE, ids=[c[0] for c in HOSTILE])
def test_hostile_messages_are_refused_with_the_reason(case: str, topic: str, payload: bytes, reason: str) -> None:
    with pytest.raises(RefusedMessage) as info:
        classify(topic, payload)
    assert reason in info.value.reason, info.value.reason
    assert info.value.topic == topic and "refused" in str(info.value)

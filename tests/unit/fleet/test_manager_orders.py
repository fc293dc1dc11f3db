"""fleet.manager.orders: node arguments, orders that pass the official schema and the order rules."""

from __future__ import annotations

import pytest

from fleet.manager.orders import NodeSpec, OrderError, build_order, order_json, parse_node
from fleet.sim.map import default_map
from fleet.vda5050 import schemas
from fleet.vda5050.headers import HeaderCounter
from fleet.vda5050.order_rules import structure_problems

SITE = default_map()


@pytest.mark.parametrize("text,expected", [
    ("park-1", NodeSpec("park-1", SITE.station("park-1").x, SITE.station("park-1").y, "hall-1")),
    ("pick-1:pick", NodeSpec("pick-1", SITE.station("pick-1").x, SITE.station("pick-1").y, "hall-1", ("pick",))),
    ("n1@2.5,-4:pick,drop", NodeSpec("n1", 2.5, -4.0, "hall-1", ("pick", "drop"))),
    ("n2@1e1,0", NodeSpec("n2", 10.0, 0.0, "hall-1")),
])
def test_node_arguments(text: str, expected: NodeSpec) -> None:
    assert parse_node(text, SITE) == expected


@pytest.mark.parametrize("text,reason", [
    ("nowhere", "has no station 'nowhere'"),
    ("n1@x,y", "expected STATION, NAME@X,Y"),
    ("n1@1,2:pick drop", "expected STATION"),
    ("", "expected STATION"),
])
def test_bad_node_arguments_say_why(text: str, reason: str) -> None:
    with pytest.raises(OrderError, match=reason):
        parse_node(text, SITE)


def test_an_order_is_schema_valid_well_formed_and_carries_its_actions() -> None:
    nodes = [NodeSpec("n0", 0, 0, "hall-1"), NodeSpec("n1", 1, 0, "hall-1", ("pick",)),
             NodeSpec("n2", 2, 0, "hall-1", ("drop",))]
    order = build_order("o-7", nodes)
    assert structure_problems(order) == []
    wire = order_json(order, HeaderCounter("acme", "agv-42").next("order"))
    schemas.check("order", wire)
    assert [n["sequenceId"] for n in wire["nodes"]] == [0, 2, 4]
    assert [(e["sequenceId"], e["startNodeId"], e["endNodeId"]) for e in wire["edges"]] == [(1, "n0", "n1"), (3, "n1", "n2")]
    assert [(a["actionType"], a["actionId"]) for a in wire["nodes"][1]["actions"]] == [("pick", "o-7-n1-0")]


@pytest.mark.parametrize("data,reason", [
    ({"nodeId": "n", "x": 1, "y": 2}, r"nodes\[0\].mapId"),
    ({"nodeId": "", "x": 1, "y": 2, "mapId": "m"}, r"nodes\[0\].nodeId"),
    ({"nodeId": "n", "x": "1", "y": 2, "mapId": "m"}, r"nodes\[0\].x: expected a finite number, got '1'"),
    ({"nodeId": "n", "x": float("nan"), "y": 2, "mapId": "m"}, r"nodes\[0\].x"),
    ({"nodeId": "n", "x": True, "y": 2, "mapId": "m"}, r"nodes\[0\].x"),
    ({"nodeId": "n", "x": 1, "y": 2, "mapId": "m", "actions": "pick"}, r"nodes\[0\].actions"),
    ("n", r"nodes\[0\]: expected an object"),
])
def test_bad_nodes_from_the_api_name_the_field(data: object, reason: str) -> None:
    with pytest.raises(OrderError, match=reason):
        NodeSpec.from_json(data, 0)


def test_empty_order_and_repeated_action_ids_are_refused() -> None:
    with pytest.raises(OrderError, match="at least one node"):
        build_order("o", [])
    with pytest.raises(OrderError):
        build_order("o", [NodeSpec("a", 0, 0, "m", ("pick",)), NodeSpec("a", 1, 0, "m", ("pick",))])

"""Schema validation of received VDA 5050 messages (good and bad as data) and message round trips."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest

from fleet.vda5050 import schemas
from fleet.vda5050.errors import SchemaError
from fleet.vda5050.factsheet import Factsheet
from fleet.vda5050.messages import (
    Action, ActionParameter, ActionState, ActionStatus, AgvPosition, BatteryState, BlockingType,
    Connection, ConnectionState, Edge, EdgeState, ErrorLevel, InstantActions, Node, NodePosition,
    NodeState, Order, State, VehicleError, visualization_json,
)
from fleet.vda5050.order_rules import structure_problems

HEADER = {"headerId": 3, "timestamp": "2026-11-24T16:00:00.000Z", "version": "2.1.0",
          "manufacturer": "KIT", "serialNumber": "7"}


def node(i: int, seq: int, released: bool = True, actions: tuple[Action, ...] = ()) -> Node:
    return Node(f"n{i}", seq, released, actions, NodePosition(float(i), 0.0, "hall-1"))


def edge(i: int, seq: int, released: bool = True) -> Edge:
    return Edge(f"e{i}", seq, f"n{i}", f"n{i + 1}", released)


ORDER = Order("o1", 0, (node(0, 0), node(1, 2, actions=(Action("pick", "a1", BlockingType.HARD, (ActionParameter("duration", 1.5),)),)),
                        node(2, 4, released=False)),
              (edge(0, 1), edge(1, 3, released=False)))
STATE = State("o1", 0, "n1", 2, True, BatteryState(80.5, False, 100),
              (NodeState("n2", 4, False),), (EdgeState("e1", 3, False),),
              (ActionState("a1", ActionStatus.RUNNING, "pick"),),
              (VehicleError("actionError", ErrorLevel.WARNING, "x", (("actionId", "a9"),)),),
              position=AgvPosition(1.0, 0.0, 0.0, "hall-1"), velocity=(0.5, 0.0))

GOOD: list[tuple[str, dict[str, Any]]] = [
    ("order", ORDER.to_json(HEADER)),
    ("instantActions", InstantActions((Action("cancelOrder", "c1", BlockingType.NONE),)).to_json(HEADER)),
    ("state", STATE.to_json(HEADER)),
    ("connection", Connection(ConnectionState.CONNECTIONBROKEN).to_json(HEADER)),
    ("visualization", visualization_json(HEADER, AgvPosition(1, 2, 0, "m"), (0.1, 0.0))),
]


def broken(kind: str, edit) -> dict[str, Any]:
    message = copy.deepcopy(dict(GOOD)[kind])
    edit(message)
    return message


BAD: list[tuple[str, str, dict[str, Any], str, str]] = [
    # (case, kind, message, expected path, fragment of the reason)
    ("order without orderId", "order", broken("order", lambda m: m.pop("orderId")), "", "'orderId' is a required property"),
    ("sequenceId as text", "order", broken("order", lambda m: m["nodes"][1].update(sequenceId="2")), "nodes/1/sequenceId", "is not of type 'integer'"),
    ("negative orderUpdateId", "order", broken("order", lambda m: m.update(orderUpdateId=-1)), "orderUpdateId", "less than the minimum"),
    ("unknown blockingType", "order", broken("order", lambda m: m["nodes"][1]["actions"][0].update(blockingType="MAYBE")), "nodes/1/actions/0/blockingType", "is not one of"),
    ("node without released", "order", broken("order", lambda m: m["nodes"][0].pop("released")), "nodes/0", "'released' is a required property"),
    ("instant action without id", "instantActions", broken("instantActions", lambda m: m["actions"][0].pop("actionId")), "actions/0", "'actionId' is a required property"),
    ("state with unknown action status", "state", broken("state", lambda m: m["actionStates"][0].update(actionStatus="DONE")), "actionStates/0/actionStatus", "is not one of"),
    ("state without safetyState", "state", broken("state", lambda m: m.pop("safetyState")), "", "'safetyState' is a required property"),
    ("battery charge as text", "state", broken("state", lambda m: m["batteryState"].update(batteryCharge="80")), "batteryState/batteryCharge", "is not of type 'number'"),
    ("unknown connection state", "connection", broken("connection", lambda m: m.update(connectionState="GONE")), "connectionState", "is not one of"),
    ("headerId as float", "connection", broken("connection", lambda m: m.update(headerId=1.5)), "headerId", "is not of type 'integer'"),
]


@pytest.mark.parametrize(("kind", "message"), GOOD, ids=[k for k, _ in GOOD])
def test_good_messages_pass_the_official_schema(kind: str, message: dict[str, Any]) -> None:
    assert schemas.problems(kind, message) == []
    assert schemas.parse(kind, json.dumps(message).encode()) == message


@pytest.mark.parametrize(("case", "kind", "message", "path", "fragment"), BAD, ids=[c[0] for c in BAD])
def test_bad_messages_are_refused_with_path_and_reason(case: str, kind: str, message: dict, path: str, fragment: str) -> None:
    with pytest.raises(SchemaError) as caught:
        schemas.parse(kind, json.dumps(message))
    assert caught.value.path == path, case
    assert fragment in caught.value.reason, caught.value.reason
    assert (path or "(message)") in str(caught.value)


@pytest.mark.parametrize(
    ("payload", "fragment"),
    [(b"\xff\xfe", "not UTF-8 JSON"), (b"{", "not UTF-8 JSON"), (b"[1, 2]", "got list"),
     (b" " * (schemas.MAX_MESSAGE_BYTES + 1), "more than the")],
)
def test_unusable_payloads(payload: bytes, fragment: str) -> None:
    with pytest.raises(SchemaError, match=fragment):
        schemas.parse("order", payload)


def test_schemas_come_from_the_installed_sdk_not_from_this_repository() -> None:
    folder = schemas.schema_dir()
    assert folder.parts[-3:] == ("vda5050", "validation", "schemas")
    assert (folder / "state.json").is_file()


def test_round_trips() -> None:
    assert Order.from_json(ORDER.to_json(HEADER)) == ORDER
    assert State.from_json(STATE.to_json(HEADER)) == STATE
    assert InstantActions.from_json(GOOD[1][1]).actions[0].action_type == "cancelOrder"
    assert Connection.from_json(GOOD[3][1]).state is ConnectionState.CONNECTIONBROKEN


def test_factsheet_of_the_simulator_is_valid_and_round_trips() -> None:
    from fleet.sim.map import default_map
    from fleet.sim.vehicle import SimVehicle, VehicleSpec

    site = default_map()
    sheet = SimVehicle(VehicleSpec("KIT", "7", site, site.parking()[0])).factsheet()
    wire = sheet.to_json(HEADER)
    assert schemas.problems("factsheet", wire) == []
    assert Factsheet.from_json(wire) == sheet
    assert {"pick", "drop", "startCharging", "cancelOrder", "factsheetRequest"} <= sheet.action_types()


@pytest.mark.parametrize(
    ("order", "fragment"),
    [
        (Order("o", 0, ()), "at least one node"),
        (Order("o", 0, (node(0, 0), node(1, 2)), ()), "0 edges for 2 nodes"),
        (Order("o", 0, (node(0, 0), node(1, 3)), (edge(0, 1),)), "must lie between"),
        (Order("o", 0, (node(0, 0), node(1, 2)), (Edge("e0", 1, "n0", "nX"),)), "joins n0 -> nX"),
        (Order("o", 0, (node(0, 0), node(1, 2, released=False)), (edge(0, 1, released=True),)), "released=True but its end node"),
        (Order("o", 0, (node(0, 0, released=False),)), "first node must be released"),
        (Order("o", 0, (node(0, 0, actions=(Action("wait", "a"),)), node(1, 2, actions=(Action("pick", "a"),))), (edge(0, 1),)), "used twice"),
    ],
)
def test_order_structure_rules(order: Order, fragment: str) -> None:
    problems = structure_problems(order)
    assert any(fragment in p for p in problems), problems


def test_well_formed_order_has_no_structure_problem() -> None:
    assert structure_problems(ORDER) == []

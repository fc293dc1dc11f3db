"""The paper's messages: round trips of every type, and bad messages refused with the field path
and the value (cases as data)."""

from __future__ import annotations

import copy
import json
from typing import Any

import pytest

from fleet.paper import schemas
from fleet.paper.errors import MessageError
from fleet.paper.messages import (
    ActionItem, ActionKind, Description, HeaderCounter, MachineState, MotionItem, Movement, Status, iso_stamp,
)
from tests.unit.fleet.paper_cases import DESCRIPTION, MOVEMENT, STATUS, action, motion

TYPES = {"motion_item": MotionItem, "action_item": ActionItem, "status": Status, "movement": Movement,
         "description": Description}

GOOD: list[tuple[str, dict[str, Any]]] = [
    ("motion_item", motion()),
    ("motion_item", motion(point=[40.0, 20.0, -3.1])),  # on the area's corner, with a heading
    ("action_item", action("load", duration=2.5)),
    ("action_item", action("charge")),
    ("status", STATUS),
    ("status", {"header": STATUS["header"], "agv_id": "agv-7", "state": "OFFLINE"}),  # the last will
    ("movement", MOVEMENT),
    ("description", DESCRIPTION),
    ("description", {**DESCRIPTION, "physical": {k: v for k, v in DESCRIPTION["physical"].items()
                                                 if k != "battery_capacity_wh"}}),
]


@pytest.mark.parametrize(("kind", "message"), GOOD, ids=[f"{k}-{i}" for i, (k, _) in enumerate(GOOD)])
def test_round_trip(kind: str, message: dict[str, Any]) -> None:
    parsed = TYPES[kind].from_json(copy.deepcopy(message))
    assert parsed.to_json() == message
    assert schemas.check(kind, parsed.to_json()) == message
    assert TYPES[kind].from_json(json.loads(json.dumps(parsed.to_json()))) == parsed


def _set(message: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    out = copy.deepcopy(message)
    *parents, last = path.split("/")
    target: Any = out
    for part in parents:
        target = target[int(part)] if isinstance(target, list) else target[part]
    if value is DELETE:
        del target[last]
    elif isinstance(target, list):
        target[int(last)] = value
    else:
        target[last] = value
    return out


DELETE = object()
HUGE = 1e300

# (kind, base message, path to change, new value, expected error path, fragment of the reason)
BAD: list[tuple[str, dict[str, Any], str, Any, str, str]] = [
    ("motion_item", motion(), "point/0", "5", "point/0", "is not of type 'number'"),
    ("motion_item", motion(), "point/1", float("nan"), "point/1", "finite"),
    ("motion_item", motion(), "point/0", float("inf"), "point/0", "finite"),
    ("motion_item", motion(), "point/0", HUGE, "point/0", "maximum"),
    ("motion_item", motion(), "point/1", -HUGE, "point/1", "minimum"),
    ("motion_item", motion(), "point", [1.0], "point", "too short"),
    ("motion_item", motion(), "point", [1.0, 2.0, 0.0, 4.0], "point", "too long"),
    ("motion_item", motion(), "task_id", DELETE, "task_id", "required"),
    ("motion_item", motion(), "motion_id", DELETE, "motion_id", "required"),
    ("motion_item", motion(), "point_id", "not-a-uuid", "point_id", "does not match"),
    ("motion_item", motion(), "task_id", 42, "task_id", "is not of type 'string'"),
    ("motion_item", motion(), "sequence", "1", "sequence", "is not of type 'integer'"),
    ("motion_item", motion(), "sequence", 1.5, "sequence", "is not of type 'integer'"),
    ("motion_item", motion(), "sequence", -1, "sequence", "minimum"),
    ("motion_item", motion(), "motion_area", [[0, 0], [1, 1]], "motion_area", "too short"),
    ("motion_item", motion(), "motion_area", [[0, 0], [1, 1], [2, 2]], "motion_area", "no area"),
    ("motion_item", motion(), "motion_area", [[0, 0], [1, 0], [1]], "motion_area/2", "too short"),
    ("motion_item", motion(), "point", [50.0, 4.0], "point", "outside motion_area"),
    ("motion_item", motion(), "max_velocity", [0.0, 0.0, 1.0], "max_velocity/0", "could not drive"),
    ("motion_item", motion(), "max_acceleration", [0.5, 0.0, 0.0], "max_acceleration/2", "could not turn"),
    ("motion_item", motion(), "max_velocity", [1.0, 1.0], "max_velocity", "too short"),
    ("motion_item", motion(), "max_velocity/1", -1, "max_velocity/1", "minimum"),
    ("motion_item", motion(), "header/stamp", "yesterday", "header/stamp", "does not match"),
    ("motion_item", motion(), "header", DELETE, "header", "required"),
    ("motion_item", motion(), "extra", 1, "", "Additional properties"),
    ("action_item", action(), "action", "dance", "action", "is not one of"),
    ("action_item", action(), "action_id", DELETE, "action_id", "required"),
    ("action_item", action(), "duration", -1, "duration", "minimum"),
    ("action_item", action(), "duration", float("nan"), "duration", "finite"),
    ("status", STATUS, "state", "SLEEPING", "state", "is not one of"),
    ("status", STATUS, "battery", 101, "battery", "maximum"),
    ("status", STATUS, "agv_id", "a/b", "agv_id", "does not match"),
    ("movement", MOVEMENT, "pose/x", None, "pose/x", "is not of type 'number'"),
    ("movement", MOVEMENT, "velocity", DELETE, "velocity", "required"),
    ("description", DESCRIPTION, "agv_id", "agv#7", "agv_id", "does not match"),
    ("description", DESCRIPTION, "agv_id", "a" * 65, "agv_id", "does not match"),
    ("description", DESCRIPTION, "skills", [], "skills", "should be non-empty"),
    ("description", DESCRIPTION, "skills", ["move", "move"], "skills", "non-unique"),
    ("description", DESCRIPTION, "manufacturer", "a/b", "manufacturer", "does not match"),
    ("description", DESCRIPTION, "physical/max_velocity", [1.0, 0.0], "physical/max_velocity", "too short"),
    ("description", DESCRIPTION, "physical/footprint/width", 0, "physical/footprint/width", "less than or equal to the minimum"),
    ("description", DESCRIPTION, "physical/payload_kg", "100", "physical/payload_kg", "is not of type 'number'"),
]


@pytest.mark.parametrize(("kind", "base", "path", "value", "where", "fragment"), BAD,
                         ids=[f"{c[0]}:{c[2]}={'<deleted>' if c[3] is DELETE else repr(c[3])}"[:60]
                              for c in BAD])
def test_bad_messages_are_refused_naming_path_and_value(kind: str, base: dict[str, Any], path: str, value: Any,
                                                        where: str, fragment: str) -> None:
    message = _set(base, path, value)
    with pytest.raises(MessageError) as caught:
        TYPES[kind].from_json(message)
    error = caught.value
    assert (error.kind, error.path) == (kind, where)
    assert fragment in error.reason or fragment in str(error), str(error)
    if value is not DELETE and where == path and not isinstance(value, float):
        assert repr(value)[:40] in str(error)  # the value is shown


@pytest.mark.parametrize(("payload", "fragment"), [
    (b"\xff\xfe", "not UTF-8 JSON"),
    (b"{", "not UTF-8 JSON"),
    (b'{"point": [NaN, 1]}', "NaN is not a JSON number"),
    (b'{"point": [Infinity, 1]}', "Infinity is not a JSON number"),
    (b"x" * (schemas.MAX_MESSAGE_BYTES + 1), "more than the 1000000 accepted"),
])
def test_unreadable_payloads_are_refused(payload: bytes, fragment: str) -> None:
    with pytest.raises(MessageError) as caught:
        schemas.decode("motion_item", payload)
    assert fragment in str(caught.value)


def test_a_non_object_is_refused() -> None:
    with pytest.raises(MessageError, match="a message is a JSON object, got list"):
        schemas.decode("action_item", b"[1, 2]")


def test_notifications_are_unwrapped_key_values_and_normalized() -> None:
    item = motion()
    key_values = {"subscriptionId": "s1", "data": [{"id": "urn:ngsi-ld:Thing:agv-7:motion_channel", "type": "Thing",
                                                    "TimeInstant": "2026-11-24T20:00:00.000Z", **item}]}
    assert schemas.decode("motion_item", json.dumps(key_values)) == [item]
    normalized = {"subscriptionId": "s1", "data": [{"id": "e", "type": "MotionCommand",
                                                    **{k: {"type": "StructuredValue", "value": v, "metadata": {}}
                                                       for k, v in item.items()}}]}
    assert schemas.decode("motion_item", json.dumps(normalized)) == [item]
    two = {"subscriptionId": "s1", "data": [{"id": "a", "type": "T", **item}, {"id": "b", "type": "T", **item}]}
    assert len(schemas.decode("motion_item", json.dumps(two))) == 2


@pytest.mark.parametrize(("data", "path"), [([], "data"), ("x", "data"), ([7], "data/0")])
def test_broken_notifications_are_refused(data: Any, path: str) -> None:
    with pytest.raises(MessageError) as caught:
        schemas.decode("motion_item", json.dumps({"subscriptionId": "s", "data": data}))
    assert caught.value.path == path


def test_header_counter_counts_per_channel_with_the_clock() -> None:
    headers = HeaderCounter("hall-1", clock=lambda: 1795550400.25)
    assert headers.next("status_channel").to_json() == {"seq": 0, "stamp": "2026-11-24T20:00:00.250Z", "frame_id": "hall-1"}
    assert headers.next("status_channel").seq == 1
    assert headers.next("movement_channel").seq == 0
    assert iso_stamp(0.0) == "1970-01-01T00:00:00.000Z"


def test_enums_cover_the_schema() -> None:
    assert [k.value for k in ActionKind] == schemas.schema("action_item")["properties"]["action"]["enum"]
    assert [s.value for s in MachineState] == schemas.schema("status")["properties"]["state"]["enum"]


def test_every_schema_is_valid_draft_2020_12() -> None:
    for kind in schemas.Kind:
        assert schemas.validator(kind).schema["$schema"].endswith("2020-12/schema")

"""What the planner puts on the wire: a sub-task as a VDA 5050 order's nodes (checked by the
manager's own order builder and the official schema) and a task as an NGSI-v2 entity."""

from __future__ import annotations

from dataclasses import replace

import fleet.lotlan
from fleet.manager.orders import build_order, order_json
from fleet.planner import build, machine, ngsi
from fleet.planner.dispatch import order_nodes
from fleet.planner.machine import SendOrder
from fleet.vda5050.headers import HeaderCounter
from tests.unit.fleet.planner_data import JOBS, SITE

SEND = SendOrder("j1-first-1", 0, "m/agv-1", "j1-first-1-0-1", "load-1", 2.0, 6.0, ("pick",))


def test_an_order_starts_where_the_vehicle_stands_and_acts_at_the_station() -> None:
    nodes = order_nodes(SEND, (5.0, 4.0), "hall-t")
    assert [(n.node_id, n.x, n.y, n.actions) for n in nodes] == [
        ("j1-first-1-0-1-start", 5.0, 4.0, ()), ("load-1", 2.0, 6.0, ("pick",))]
    order = build_order(SEND.order_id, nodes)
    wire = order_json(order, HeaderCounter("m", "agv-1").next("order"))  # the official schema accepts it
    assert [a["actionId"] for a in wire["nodes"][1]["actions"]] == ["j1-first-1-0-1-load-1-0"]
    # what the planner's tracking looks for (fleet/planner/machine.py: <orderId>-<station>-<i>)
    leg = build.build_task("j1-first-1", "j1", fleet.lotlan.parse(JOBS, "jobs.tl").task("first"), 1, SITE).legs[0]
    leg = replace(leg, order_id=SEND.order_id)
    view = machine.VehicleView("m/agv-1", True, SEND.order_id, "load-1", (("j1-first-1-0-1-load-1-0", "FINISHED"),))
    assert machine.leg_progress(leg, view) == "finished"


def test_a_vehicle_already_on_the_station_gets_the_station_alone() -> None:
    nodes = order_nodes(SEND, (2.0, 6.0), "hall-t")
    assert [n.node_id for n in nodes] == ["load-1"]


def test_a_task_as_an_ngsi_entity() -> None:
    task = build.build_task("j1-first-1", "j1", fleet.lotlan.parse(JOBS, "jobs.tl").task("first"), 1, SITE,
                            at="2026-11-24T20:00:00.000Z")
    entity = ngsi.entity(task)
    assert entity["id"] == "urn:ngsi-ld:Task:j1-first-1" and entity["type"] == "Task"
    assert entity["state"] == {"type": "Text", "value": "RAW"}
    assert entity["step"]["value"] == "0: load-1 [pick] READY" and entity["stepIndex"]["value"] == 0
    assert [leg["station"] for leg in entity["legs"]["value"]] == ["load-1", "unload-1"]
    assert entity["dateModified"]["value"] == "2026-11-24T20:00:00.000Z"


def strings(value: object) -> list[str]:
    if isinstance(value, str):
        return [value]
    if isinstance(value, dict):
        return [s for v in value.values() for s in strings(v)]
    if isinstance(value, list):
        return [s for v in value for s in strings(v)]
    return []


def test_no_string_of_a_task_entity_has_a_character_ngsi_refuses() -> None:
    task = build.build_task("j1-first-1", "j1", fleet.lotlan.parse(JOBS, "jobs.tl").task("first"), 1, SITE)
    task = replace(task, reason="assign.rq rows (best first): a = b; 'x' <y> \"z\"", vehicle="m/agv-1")
    values = strings({k: v for k, v in ngsi.entity(task).items() if k not in ("id", "type")})
    assert values and not [v for v in values if set(v) & set("<>\"'=;()")], values
    assert ngsi.entity(task)["reason"]["value"] == "assign.rq rows [best first]: a is b, `x` lt ygt  `z`"

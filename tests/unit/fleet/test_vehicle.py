"""The simulated vehicle's order executor, stepped with a fixed tick (fake time, no sleeps)."""

from __future__ import annotations

import pytest

from fleet.sim.kinematics import Limits
from fleet.sim.map import SiteMap, Station
from fleet.sim.vehicle import SimVehicle, VehicleSpec
from fleet.vda5050.messages import (
    Action, ActionParameter, ActionStatus, BlockingType, Edge, InstantActions, Node, NodePosition, Order,
)

DT = 0.05
SITE = SiteMap("m", 10.0, 10.0, (Station("A", 1, 1), Station("B", 4, 1), Station("C", 4, 4),
                                  Station("D", 1, 4, charger=True)))
POS = {s.name: (s.x, s.y) for s in SITE.stations}


def vehicle(start: str = "A") -> SimVehicle:
    return SimVehicle(VehicleSpec("KIT", "7", SITE, SITE.station(start), Limits(1.0, 1.0, 2.0, 2.0)))


def act(kind: str, action_id: str, **params) -> Action:
    return Action(kind, action_id, BlockingType.HARD, tuple(ActionParameter(k, v) for k, v in params.items()))


def order(order_id: str, path: list[str], update: int = 0, first_seq: int = 0, released: int | None = None,
          actions: dict[str, tuple[Action, ...]] | None = None, edge_actions: dict[int, tuple[Action, ...]] | None = None) -> Order:
    released = len(path) if released is None else released
    actions, edge_actions = actions or {}, edge_actions or {}
    nodes = tuple(Node(name, first_seq + 2 * i, i < released, actions.get(name, ()), NodePosition(*POS[name], "m"))
                  for i, name in enumerate(path))
    edges = tuple(Edge(f"{a}-{b}", first_seq + 2 * i + 1, a, b, i + 1 < released, edge_actions.get(i, ()))
                  for i, (a, b) in enumerate(zip(path, path[1:])))
    return Order(order_id, update, nodes, edges)


def run(v: SimVehicle, seconds: float, until=None) -> list:
    """Tick for up to ``seconds``; collect (time, lastNodeId) at each new node."""
    visits, t = [], 0.0
    while t < seconds:
        last = v.last_node_id
        v.tick(DT)
        t += DT
        if v.last_node_id != last:
            visits.append((round(t, 2), v.last_node_id))
        if until is not None and until(v):
            break
    return visits


def status(v: SimVehicle, action_id: str) -> ActionStatus | None:
    return v.state().action_status(action_id)


def test_drives_the_nodes_in_order_and_runs_node_actions() -> None:
    v = vehicle()
    assert v.receive_order(order("o1", ["A", "B", "C"], actions={"B": (act("pick", "p", duration=1.0),), "C": (act("drop", "d", duration=0.5),)}))
    s = v.state()
    assert (s.last_node_id, s.last_node_sequence_id) == ("A", 0)
    assert [n.node_id for n in s.node_states] == ["B", "C"] and [e.edge_id for e in s.edge_states] == ["A-B", "B-C"]
    assert status(v, "p") is ActionStatus.WAITING and status(v, "d") is ActionStatus.WAITING
    seen_running, seen_driving = False, False
    for _ in range(400):
        v.tick(DT)
        seen_running |= status(v, "p") is ActionStatus.RUNNING
        seen_driving |= v.state().driving
        if status(v, "d") is ActionStatus.FINISHED:
            break
    assert seen_running and seen_driving
    s = v.state()
    assert (s.last_node_id, s.last_node_sequence_id) == ("C", 4)
    assert s.node_states == () and s.edge_states == () and not s.driving
    assert status(v, "p") is ActionStatus.FINISHED
    assert (s.position.x, s.position.y) == pytest.approx(POS["C"])
    assert s.operating_mode.value == "AUTOMATIC" and s.errors == ()


def test_states_shrink_node_by_node_and_driving_waits_for_hard_actions() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B", "C"], actions={"B": (act("wait", "w", duration=2.0),)}))
    run(v, 10, until=lambda x: x.last_node_id == "B")
    s = v.state()
    assert [n.node_id for n in s.node_states] == ["C"] and [e.edge_id for e in s.edge_states] == ["B-C"]
    x, y = s.position.x, s.position.y
    run(v, 1.5)  # the wait runs 2 s: the vehicle has not left B
    assert status(v, "w") is ActionStatus.RUNNING and (v.state().position.x, v.state().position.y) == (x, y)
    run(v, 10, until=lambda x: x.last_node_id == "C")
    assert status(v, "w") is ActionStatus.FINISHED


def test_edge_actions_run_while_the_edge_is_driven() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B"], edge_actions={0: (act("wait", "ew", duration=0),)}))
    v.tick(DT)
    assert status(v, "ew") is ActionStatus.RUNNING
    run(v, 10, until=lambda x: x.last_node_id == "B")
    assert status(v, "ew") is ActionStatus.FINISHED


def test_unknown_or_bad_action_fails_with_an_error_and_the_order_goes_on() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B"], actions={"A": (act("dance", "x"),), "B": (act("pick", "p", duration="soon"),)}))
    v.tick(DT)
    assert status(v, "x") is ActionStatus.FAILED
    run(v, 10, until=lambda x: x.last_node_id == "B")
    v.tick(DT)
    assert status(v, "p") is ActionStatus.FAILED
    errors = {(e.error_type, dict(e.references).get("actionId")) for e in v.state().errors}
    assert errors == {("actionError", "x"), ("actionError", "p")}
    assert "'soon' is not a number" in " ".join(e.description for e in v.state().errors)


def test_horizon_waits_for_an_update_that_stitches() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B", "C"], released=2))
    run(v, 15)
    s = v.state()
    assert s.last_node_id == "B" and [(n.node_id, n.released) for n in s.node_states] == [("C", False)]
    assert (s.position.x, s.position.y) == pytest.approx(POS["B"])
    # an update must start at the last base node (B, sequence 2)
    assert not v.receive_order(order("o1", ["A", "B"], update=1))
    assert v.state().errors[-1].error_type == "orderUpdateError"
    assert v.receive_order(order("o1", ["B", "C", "D"], update=1, first_seq=2, actions={"D": (act("drop", "d", duration=0),)}))
    assert all(e.error_type != "orderUpdateError" for e in v.state().errors)  # cleared on acceptance
    visits = run(v, 30, until=lambda x: status(x, "d") is ActionStatus.FINISHED)
    assert [n for _, n in visits] == ["C", "D"]
    assert (v.state().order_update_id, v.state().last_node_sequence_id) == (1, 6)


def test_update_while_driving_extends_the_base() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B"]))
    v.tick(DT)
    assert v.receive_order(order("o1", ["B", "C"], update=1, first_seq=2))
    visits = run(v, 30, until=lambda x: x.last_node_id == "C")
    assert [n for _, n in visits] == ["B", "C"]


def test_stale_update_is_refused_and_a_resent_one_ignored() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B"]))
    v.receive_order(order("o1", ["B", "C"], update=2, first_seq=2))
    assert not v.receive_order(order("o1", ["B", "C"], update=1, first_seq=2))
    error = v.state().errors[-1]
    assert error.error_type == "orderUpdateError" and "older than 2" in error.description
    before = v.state()
    assert v.receive_order(order("o1", ["B", "C"], update=2, first_seq=2))
    assert v.state().errors == before.errors and v.state().node_states == before.node_states


def test_new_order_refused_while_busy_or_far_away() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B"]))
    assert not v.receive_order(order("o2", ["A", "C"]))
    assert v.state().order_id == "o1" and "still executing order 'o1'" in v.state().errors[-1].description
    far = vehicle()
    assert not far.receive_order(order("o3", ["C", "B"]))
    assert far.state().errors[-1].error_type == "orderError" and "from the vehicle" in far.state().errors[-1].description
    assert far.state().order_id == ""


def test_malformed_order_is_a_validation_error_and_changes_nothing() -> None:
    v = vehicle()
    bad = Order("o1", 0, order("o1", ["A", "B"]).nodes, ())
    assert not v.receive_order(bad)
    assert v.state().errors[-1].error_type == "validationError" and v.state().order_id == ""


def test_cancel_stops_fails_the_rest_and_finishes() -> None:
    v = vehicle()
    v.receive_order(order("o1", ["A", "B", "C"], actions={"C": (act("drop", "d"),)}))
    run(v, 1.0)
    assert v.state().driving
    v.receive_instant_actions(InstantActions((Action("cancelOrder", "c", BlockingType.NONE),)))
    assert status(v, "c") is ActionStatus.RUNNING and status(v, "d") is ActionStatus.FAILED
    assert v.state().node_states == () and v.state().edge_states == ()
    run(v, 5, until=lambda x: status(x, "c") is ActionStatus.FINISHED)
    s = v.state()
    assert status(v, "c") is ActionStatus.FINISHED and not s.driving and s.velocity == (0.0, 0.0)
    assert s.order_id == "o1"  # kept, as the standard says
    # nothing to cancel any more
    v.receive_instant_actions(InstantActions((Action("cancelOrder", "c2", BlockingType.NONE),)))
    assert status(v, "c2") is ActionStatus.FAILED and v.state().errors[-1].error_type == "noOrderToCancel"
    assert not v.busy  # a new order is welcome again


def test_instant_actions_state_and_factsheet_requests() -> None:
    v = vehicle()
    v.take_outbox()
    v.receive_instant_actions(InstantActions((Action("factsheetRequest", "f", BlockingType.NONE),
                                              Action("stateRequest", "s", BlockingType.NONE),
                                              Action("teleport", "t", BlockingType.NONE))))
    out = v.take_outbox()
    assert out.factsheet and out.state
    assert (status(v, "f"), status(v, "s"), status(v, "t")) == (ActionStatus.FINISHED, ActionStatus.FINISHED, ActionStatus.FAILED)
    assert v.state().errors[-1].error_type == "actionError"
    assert v.take_outbox() == type(out)()  # taken once


def test_charging_only_at_a_charger_and_battery_drains_with_distance() -> None:
    v = vehicle()
    v.receive_instant_actions(InstantActions((Action("startCharging", "c1", BlockingType.HARD),)))
    assert status(v, "c1") is ActionStatus.FAILED and "not on a charger" in v.state().errors[-1].description
    v.receive_order(order("o1", ["A", "D"], actions={"D": (act("startCharging", "c2"),)}))
    start = v.battery.charge
    run(v, 10, until=lambda x: x.last_node_id == "D")
    after_drive = v.battery.charge
    assert after_drive < start - 0.05 * 3 * 0.99  # 3 m at 0.05 %/m at least
    run(v, 1, until=lambda x: status(x, "c2") is ActionStatus.FINISHED)
    assert v.state().battery.charging
    run(v, 4)
    assert v.battery.charge > after_drive
    v.receive_instant_actions(InstantActions((Action("stopCharging", "c3", BlockingType.HARD),)))
    assert not v.state().battery.charging and status(v, "c3") is ActionStatus.FINISHED


def test_state_is_flagged_on_every_event() -> None:
    v = vehicle()
    v.take_outbox()
    v.tick(DT)
    assert not v.take_outbox().state  # idle: nothing happened
    v.receive_order(order("o1", ["A", "B"]))
    assert v.take_outbox().state
    flags = []
    for _ in range(200):
        v.tick(DT)
        flags.append((v.last_node_id, v.take_outbox().state))
    assert ("B", True) in flags and sum(f for _, f in flags) <= 4  # start driving, arrival, stop: not every tick

"""The planner's loop without processes: a real journal and plant graph, the vehicles given as
data (what the manager's API and the MQTT states would say), orders recorded instead of sent.

Repeat and OnDone create their follow-ups once; a planner started again on the same data
directory resumes: a SENT sub-task the vehicle does not show is sent again under the same orderId,
one it shows is not; operators' requests are checked (4xx naming the field).
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

import fleet.lotlan
from fleet.model.binding import fleet_binding
from fleet.model.description import from_factsheet
from fleet.model.graph import agv_turtle
from fleet.planner.journal import Journal
from fleet.planner.machine import SendOrder
from fleet.planner.plantview import PlantView
from fleet.planner.service import Planner, PlannerConfig, RequestError
from fleet.planner.states import TaskState
from fleet.planner.vehicles import Vehicle
from tests.unit.fleet import discovery_data as d
from tests.unit.fleet.planner_data import JOBS, SITE

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "ontology" / "examples" / "agv-fleet.ttl"

PROGRAM = JOBS.replace("""Task second
    Transport
    From atOtherLoad
    To atOtherUnload
    TriggeredBy first.IsDone
End""", """Task second
    Transport
    From atOtherLoad
    To atOtherUnload
    Repeat 2
End

Task chain
    Transport
    From atOtherLoad
    To atOtherUnload
    OnDone third
End

Task third
    Transport
    From atOtherUnload
    To atOtherLoad
End""")


class States:
    changed = threading.Event()


class GivenFleet:
    """The vehicles as data: what fleet.planner.vehicles.Fleet would report."""

    def __init__(self) -> None:
        self.reachable = True
        self.states = States()
        self.v: dict[str, Vehicle] = {}

    def refresh(self) -> None:
        pass

    def vehicles(self) -> dict[str, Vehicle]:
        return dict(self.v)

    def put(self, serial: str, x: float, y: float, *, online: bool = True, order: str = "",
            actions: tuple[tuple[str, str], ...] = ()) -> None:
        state = {"agvPosition": {"x": x, "y": y}, "batteryState": {"batteryCharge": 90.0}, "orderId": order,
                 "lastNodeId": "", "actionStates": [{"actionId": i, "actionStatus": s} for i, s in actions]}
        self.v[f"t/{serial}"] = Vehicle(f"t/{serial}", serial, "t", "vda5050", online,
                                        "ONLINE" if online else "CONNECTIONBROKEN", state)

    def finish(self, send: SendOrder) -> None:
        self.put(send.vehicle.split("/")[1], send.x, send.y, order=send.order_id,
                 actions=tuple((f"{send.order_id}-{send.station}-{i}", "FINISHED") for i in range(len(send.actions))))


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> PlantView:
    folder = tmp_path_factory.mktemp("discovered")
    binding = fleet_binding([EXAMPLE])
    for serial in ("a-1", "a-2"):
        (folder / f"t--{serial}.ttl").write_text(
            agv_turtle(from_factsheet("t", serial, d.factsheet("t", serial)), binding), encoding="utf-8")
    view = PlantView((EXAMPLE,), folder)
    view.current()
    return view


def planner_on(data: Path, given: GivenFleet, plant: PlantView, sent: list[SendOrder]) -> Planner:
    program = fleet.lotlan.parse(PROGRAM, "jobs.tl")
    return Planner(PlannerConfig(SITE, settle=0.0), program, Journal(data), given, plant,
                   lambda order, vehicle: sent.append(order))


def test_repeat_and_on_done_follow_ups_are_created_once_in_order(tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-1", 2.0, 2.0)
    planner = planner_on(tmp_path, given, plant, sent)
    assert planner.start_job(["second"]) == {"job": "j1", "tasks": ["j1-second-1"]}

    def drive(count: int) -> list[str]:
        finished: list[str] = []
        for _ in range(40):
            planner.tick()
            if sent:
                given.finish(sent.pop(0))
            finished = [t.id for t in planner.tasks.values() if t.state is TaskState.FINISHED]
            if len(finished) == count:
                break
        return finished
    assert drive(2) == ["j1-second-1", "j1-second-2"]
    assert planner.start_job(["chain"]) == {"job": "j2", "tasks": ["j2-chain-1"]}
    assert drive(4) == ["j1-second-1", "j1-second-2", "j2-chain-1", "j2-third-1"]
    for _ in range(3):
        planner.tick()
    assert list(planner.tasks) == ["j1-second-1", "j1-second-2", "j2-chain-1", "j2-third-1"]  # none twice
    planner.journal.close()


def test_a_restarted_planner_resends_what_the_vehicle_does_not_show_under_the_same_order_id(
        tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-1", 9.0, 6.0)
    given.put("a-2", 3.0, 6.0)
    first = planner_on(tmp_path, given, plant, sent)
    first.start_job(["first"])
    first.tick()
    assert [(s.vehicle, s.order_id, s.station) for s in sent] == [("t/a-2", "j1-first-1-0-1", "load-1")]
    first.journal.close()  # as if killed: nothing else was written
    again_sent: list[SendOrder] = []
    again = planner_on(tmp_path, given, plant, again_sent)
    assert again.tasks["j1-first-1"].state is TaskState.BEING_PROCESSED
    again.tick()
    assert [s.order_id for s in again_sent] == ["j1-first-1-0-1"]  # the same order again
    again.journal.close()
    given.finish(sent[0])
    third_sent: list[SendOrder] = []
    third = planner_on(tmp_path, given, plant, third_sent)
    third.tick()  # the vehicle shows the order finished: acted, waiting for Loaded; nothing resent
    assert third_sent == [] and third.tasks["j1-first-1"].legs[0].state.value == "ACTED"
    third.journal.close()


def test_a_lost_vehicle_sends_the_task_back_and_the_next_nearest_takes_it(tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-1", 9.0, 6.0)
    given.put("a-2", 3.0, 6.0)
    planner = planner_on(tmp_path, given, plant, sent)
    planner.start_job(["first"])
    planner.tick()
    given.put("a-2", 3.0, 6.0, online=False)
    planner.tick()
    task = planner.tasks["j1-first-1"]
    assert task.vehicle == "t/a-1" and [s.order_id for s in sent] == ["j1-first-1-0-1", "j1-first-1-0-2"]
    assert "vehicle t/a-2 is CONNECTIONBROKEN; re-assigning" in (tmp_path / "journal.jsonl").read_text()
    planner.journal.close()


REQUESTS: list[tuple[str, Any, int, str]] = [  # (what, call, status, in the message)
    ("an unknown event", ("fire", "nope", True), 404, "'nope' is no Event"),
    ("a string for a Boolean event", ("fire", "loaded", "yes"), 400, "value: Event loaded is of type Boolean"),
    ("a number for a Boolean event", ("fire", "Loaded", 1), 400, "got 1"),
    ("no event name", ("fire", None, True), 400, "event: expected the name"),
    ("an unknown task to start", ("start_job", ["ghost"]), 400, "'ghost' is no Task"),
    ("withdrawing an unknown task", ("withdraw", "j9-x-1"), 404, "no task 'j9-x-1'"),
]


@pytest.mark.parametrize(("call", "status", "message"), [r[1:] for r in REQUESTS], ids=[r[0] for r in REQUESTS])
def test_bad_requests_are_refused_naming_the_field(tmp_path: Path, plant: PlantView, call: tuple, status: int,
                                                     message: str) -> None:
    planner = planner_on(tmp_path, GivenFleet(), plant, [])
    with pytest.raises(RequestError) as caught:
        getattr(planner, call[0])(*call[1:])
    assert caught.value.status == status and message in caught.value.message
    assert planner.journal.seq == 0  # nothing half-done
    planner.journal.close()


def test_withdraw_is_final(tmp_path: Path, plant: PlantView) -> None:
    planner = planner_on(tmp_path, GivenFleet(), plant, [])
    planner.start_job(["first"])
    assert planner.withdraw("j1-first-1")["state"] == "WITHDRAWN"
    with pytest.raises(RequestError) as caught:
        planner.withdraw("j1-first-1")
    assert caught.value.status == 409
    planner.journal.close()


def test_a_vehicle_missing_from_the_list_for_a_moment_keeps_its_task(tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-2", 3.0, 6.0)
    planner = planner_on(tmp_path, given, plant, sent)
    planner.start_job(["first"])
    planner.tick()
    kept = given.v.pop("t/a-2")  # a manager that has just restarted lists nobody yet
    planner.tick()
    assert planner.tasks["j1-first-1"].vehicle == "t/a-2"
    given.v["t/a-2"] = kept
    planner.tick()
    planner.config = PlannerConfig(SITE, settle=0.0, missing=0.0)
    given.v.pop("t/a-2")  # gone for good (a person removed it)
    planner.tick()
    planner.tick()
    assert planner.tasks["j1-first-1"].state is TaskState.ACTIVE
    assert "vehicle t/a-2 is no longer known" in planner.tasks["j1-first-1"].reason
    planner.journal.close()

"""The planner's loop without processes: a real journal and plant graph, the vehicles given as
data (what the manager's API and the MQTT states would say), orders recorded instead of sent.

Repeat and OnDone create their follow-ups once; a planner started again on the same data
directory resumes: a SENT sub-task the vehicle does not show is sent again under the same orderId,
one it shows is not; operators' requests are checked (4xx naming the field).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import fleet.lotlan
from fleet.model.binding import fleet_binding
from fleet.model.description import from_factsheet
from fleet.model.graph import agv_turtle
from fleet.planner.errors import PlannerError
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


class GivenFleet:
    """The vehicles as data: what fleet.planner.vehicles.Fleet would report."""

    def __init__(self) -> None:
        self.reachable = True
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


def test_nothing_is_lost_while_the_manager_is_not_ready_and_a_vehicle_gone_from_its_list_is(
        tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-2", 3.0, 6.0)
    planner = planner_on(tmp_path, given, plant, sent)
    planner.start_job(["first"])
    planner.tick()
    assert planner.tasks["j1-first-1"].vehicle == "t/a-2"
    given.reachable = False  # the manager restarts: 503 NotReady (or no answer); the planner waits
    given.v.clear()
    for _ in range(3):
        planner.tick()
    assert planner.tasks["j1-first-1"].vehicle == "t/a-2"
    given.reachable = True  # ready, and the vehicle is not in its list (a person removed it)
    planner.tick()
    assert planner.tasks["j1-first-1"].state is TaskState.ACTIVE
    assert "vehicle t/a-2 is no longer known" in planner.tasks["j1-first-1"].reason
    planner.journal.close()


def test_a_withdrawn_task_cancels_the_order_on_its_online_vehicle_before_it_gets_another(
        tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-1", 3.0, 6.0)
    cancels: list[str] = []
    answers = [PlannerError("the fleet manager does not answer"), True]

    def cancel(vehicle: Vehicle) -> bool:
        answer = answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        cancels.append(vehicle.key)
        return answer

    program = fleet.lotlan.parse(PROGRAM, "jobs.tl")
    planner = Planner(PlannerConfig(SITE, settle=0.0), program, Journal(tmp_path), given, plant,
                      lambda order, vehicle: sent.append(order), cancel=cancel)
    planner.start_job(["first", "second"])
    planner.tick()
    held = {t.id: t.vehicle for t in planner.tasks.values() if t.vehicle}
    assert list(held.values()) == ["t/a-1"] and len(sent) == 1
    task_id = next(iter(held))
    planner.withdraw(task_id)  # the first cancelOrder fails: retried; a-1 takes no task meanwhile
    assert cancels == [] and planner.cancels == {"t/a-1": sent[0].order_id}
    planner._assign(given.vehicles())
    assert len(sent) == 1 and all(t.vehicle == "" for t in planner.tasks.values())
    planner.tick()  # retried, sent; then a-1 is free for the other task
    assert cancels == ["t/a-1"] and planner.cancels == {}
    planner.tick()
    assert len(sent) == 2 and sent[1].task_id != task_id
    assert planner.tasks[task_id].state is TaskState.WITHDRAWN
    planner.journal.close()


def test_a_withdrawn_task_of_an_offline_vehicle_sends_no_cancel(tmp_path: Path, plant: PlantView) -> None:
    given, sent = GivenFleet(), []
    given.put("a-1", 3.0, 6.0)
    cancels: list[str] = []
    program = fleet.lotlan.parse(PROGRAM, "jobs.tl")
    planner = Planner(PlannerConfig(SITE, settle=0.0), program, Journal(tmp_path), given, plant,
                      lambda order, vehicle: sent.append(order), cancel=lambda v: cancels.append(v.key) or True)
    planner.start_job(["first"])
    planner.tick()
    given.put("a-1", 3.0, 6.0, online=False)
    planner.withdraw("j1-first-1")
    assert cancels == [] and planner.cancels == {}
    planner.journal.close()


def test_a_paper_vehicle_is_assigned_and_its_status_drives_the_task(tmp_path: Path, plant: PlantView) -> None:
    """cart-1 of the example plant speaks the paper's channels (skills load/unload): it gets the
    task only when the planner can reach it (config.paper), and its status ends each sub-task."""
    from fleet.planner import paperids

    given, sent = GivenFleet(), []

    def cart(status: dict[str, Any]) -> None:
        given.v["/cart-1"] = Vehicle("/cart-1", "cart-1", "", "paper-channels", True, "ONLINE",
                                     {"pose": {"x": 9.0, "y": 2.0, "theta": 0.0}, "battery": 90.0, **status})
    cart({})
    program = fleet.lotlan.parse(PROGRAM, "jobs.tl")
    planner = Planner(PlannerConfig(SITE, settle=0.0), program, Journal(tmp_path), given, plant,
                      lambda order, vehicle: sent.append(order))
    planner.start_job(["second"])
    planner.tick()
    assert planner.tasks["j1-second-1"].state is TaskState.ACTIVE and sent == []  # no paper: not assigned
    planner.journal.close()
    planner = Planner(PlannerConfig(SITE, settle=0.0, paper=True), program, Journal(tmp_path), given, plant,
                      lambda order, vehicle: sent.append(order))
    planner.tick()
    task = planner.tasks["j1-second-1"]
    assert task.vehicle == "/cart-1" and sent[0].station == "load-2" and sent[0].actions == ("pick",)
    count = len(sent)
    planner.tick()
    assert len(sent) == count + 1 and set(sent) == {sent[0]}  # every tick: the paper sender writes what is due
    cart({"finished_task_id": paperids.task_uuid(sent[0].order_id)})
    planner.tick()
    assert planner.tasks["j1-second-1"].legs[0].state.value == "DONE"
    assert sent[-1].station == "unload-2" and sent[-1].actions == ("drop",)
    cart({"finished_task_id": paperids.task_uuid(sent[-1].order_id)})
    planner.tick()
    assert planner.tasks["j1-second-1"].state is TaskState.FINISHED
    planner.journal.close()

"""Idle vehicles: back to the waiting area after a job, to a charger when low (fleet/planner/idle.py
and the planner's loop with the vehicles as data, as in test_planner_service.py).

The pure choices are cases as data; the loop cases check the tasks the planner makes itself
(``park`` / ``charge``), that they never keep a vehicle from a job (the job withdraws them, a
cancelOrder when their order was sent, stopCharging when the vehicle charges), and that a low
vehicle goes charging instead of taking work.
"""

from __future__ import annotations

from pathlib import Path

import pytest

import fleet.lotlan
from fleet.planner import idle
from fleet.planner.errors import BuildError
from fleet.planner.journal import Journal
from fleet.planner.machine import SendOrder
from fleet.planner.plantview import PlantView
from fleet.planner.service import Planner, PlannerConfig
from fleet.planner.states import TaskState
from fleet.planner.vehicles import Vehicle
from fleet.sim.map import SiteMap, Station
from tests.unit.fleet.planner_data import JOBS, SITE
from tests.unit.fleet.test_planner_service import GivenFleet, plant  # noqa: F401  (the module fixture)

CHARGED = SiteMap(SITE.map_id, SITE.width, SITE.height, SITE.stations + (
    Station("charger-1", 1.0, 1.0, charger=True), Station("charger-2", 11.0, 1.0, charger=True)))

NEAREST = [  # (what, from x, y, taken, expected)
    ("the nearest park spot", 4.0, 4.0, (), "park-1"),
    ("the other side", 8.0, 4.0, (), "park-2"),
    ("the nearest is taken", 4.0, 4.0, ("park-1",), "park-2"),
    ("all taken", 4.0, 4.0, ("park-1", "park-2"), None),
    ("a tie goes by name", 6.0, 4.0, (), "park-1"),
]


@pytest.mark.parametrize(("x", "y", "taken", "expected"), [c[1:] for c in NEAREST], ids=[c[0] for c in NEAREST])
def test_the_waiting_spot_is_the_nearest_free_park_station(x: float, y: float, taken: tuple[str, ...],
                                                           expected: str | None) -> None:
    spot = idle.park_station(None, SITE, x, y, taken)
    assert (spot.name if spot else None) == expected


CHARGE = [  # (what, battery, charging, min, expected)
    ("low", 10.0, False, 20.0, True),
    ("low but charging already", 10.0, True, 20.0, False),
    ("at the minimum", 20.0, False, 20.0, False),
    ("battery unknown", None, False, 20.0, False),
]


@pytest.mark.parametrize(("battery", "charging", "minimum", "expected"), [c[1:] for c in CHARGE],
                         ids=[c[0] for c in CHARGE])
def test_who_needs_a_charger(battery: float | None, charging: bool, minimum: float, expected: bool) -> None:
    assert idle.needs_charge(battery, charging, minimum) is expected


WAITING = [  # (what, --waiting-area, the shared station or the error's words)
    ("off", None, None),
    ("park spots", "park", None),
    ("a Location by its name", "otherLoad", "load-2"),
    ("a Location by its physical name", "unload-2", "unload-2"),
    ("no such Location", "hall", "'hall' is no Location of jobs.tl (its Locations: loadStation"),
]


@pytest.mark.parametrize(("spec", "expected"), [c[1:] for c in WAITING], ids=[c[0] for c in WAITING])
def test_the_waiting_area_is_park_spots_or_a_location_of_the_program(spec: str | None, expected: str | None) -> None:
    program = fleet.lotlan.parse(JOBS, "jobs.tl")
    if expected is not None and " " in expected:
        with pytest.raises(BuildError) as caught:
            idle.waiting_area(spec, program, SITE)
        assert expected in caught.value.message
        return
    station = idle.waiting_area(spec, program, SITE)
    assert (station.name if station else None) == expected


def test_park_needs_park_stations() -> None:
    bare = SiteMap("m", 12.0, 8.0, tuple(s for s in SITE.stations if not s.name.startswith("park-")))
    with pytest.raises(BuildError, match="has no park-\\* station"):
        idle.waiting_area("park", fleet.lotlan.parse(JOBS, "jobs.tl"), bare)


class Recorder:
    def __init__(self) -> None:
        self.sent: list[SendOrder] = []
        self.calls: list[tuple[str, str]] = []

    def send(self, order: SendOrder, vehicle: Vehicle) -> None:
        self.sent.append(order)

    def cancel(self, vehicle: Vehicle) -> bool:
        self.calls.append(("cancelOrder", vehicle.key))
        return True

    def stop_charging(self, vehicle: Vehicle) -> None:
        self.calls.append(("stopCharging", vehicle.key))


def put(given: GivenFleet, serial: str, x: float, y: float, battery: float = 90.0, charging: bool = False,
        order: str = "", node: str = "", actions: tuple[tuple[str, str], ...] = ()) -> None:
    state = {"agvPosition": {"x": x, "y": y}, "batteryState": {"batteryCharge": battery, "charging": charging},
             "orderId": order, "lastNodeId": node,
             "actionStates": [{"actionId": i, "actionStatus": s} for i, s in actions]}
    given.v[f"t/{serial}"] = Vehicle(f"t/{serial}", serial, "t", "vda5050", True, "ONLINE", state)


def finish(given: GivenFleet, send: SendOrder, battery: float = 90.0) -> None:
    put(given, send.vehicle.split("/")[1], send.x, send.y, battery, order=send.order_id, node=send.station,
        actions=tuple((f"{send.order_id}-{send.station}-{i}", "FINISHED") for i in range(len(send.actions))))


def planner_on(data: Path, given: GivenFleet, plant: PlantView, rec: Recorder,  # noqa: F811
               waiting: str | None = "park", site: SiteMap = SITE) -> Planner:
    program = fleet.lotlan.parse(JOBS.replace("    FinishedBy loaded == True\n", "").replace(
        "    FinishedBy unloaded\n", ""), "jobs.tl")
    return Planner(PlannerConfig(site, settle=0.0, waiting_area=waiting), program, Journal(data), given, plant,
                   rec.send, None, rec.cancel, rec.stop_charging)


def run_job(planner: Planner, given: GivenFleet, rec: Recorder, battery: float = 90.0) -> None:
    for _ in range(10):
        planner.tick()
        if rec.sent and not rec.sent[0].task_id.endswith("-park") and not rec.sent[0].task_id.startswith("charge"):
            finish(given, rec.sent.pop(0), battery)


def test_after_a_job_its_vehicle_goes_to_the_nearest_waiting_spot_and_that_task_finishes(
        tmp_path: Path, plant: PlantView) -> None:  # noqa: F811
    given, rec = GivenFleet(), Recorder()
    put(given, "a-1", 9.0, 6.0)
    planner = planner_on(tmp_path, given, plant, rec)
    planner.start_job(["first"])
    run_job(planner, given, rec)
    assert planner.tasks["j1-first-1"].state is TaskState.FINISHED
    park = planner.tasks["j1-first-1-park"]
    assert (park.purpose, park.job, park.vehicle, park.state) == ("park", "j1", "t/a-1", TaskState.BEING_PROCESSED)
    assert [(s.task_id, s.station, s.actions) for s in rec.sent] == [("j1-first-1-park", "park-2", ())]
    finish(given, rec.sent.pop(0))
    planner.tick()
    assert planner.tasks["j1-first-1-park"].state is TaskState.FINISHED
    for _ in range(3):
        planner.tick()
    assert sorted(planner.tasks) == ["j1-first-1", "j1-first-1-park"] and rec.sent == []  # made once
    planner.journal.close()


def test_without_a_waiting_area_the_vehicle_stays(tmp_path: Path, plant: PlantView) -> None:  # noqa: F811
    given, rec = GivenFleet(), Recorder()
    put(given, "a-1", 9.0, 6.0)
    planner = planner_on(tmp_path, given, plant, rec, waiting=None)
    planner.start_job(["first"])
    run_job(planner, given, rec)
    assert list(planner.tasks) == ["j1-first-1"] and planner.tasks["j1-first-1"].state is TaskState.FINISHED
    planner.journal.close()


def test_a_job_takes_a_vehicle_on_its_way_to_the_waiting_area(tmp_path: Path, plant: PlantView) -> None:  # noqa: F811
    given, rec = GivenFleet(), Recorder()
    put(given, "a-1", 9.0, 6.0)
    planner = planner_on(tmp_path, given, plant, rec)
    planner.start_job(["first"])
    run_job(planner, given, rec)
    assert rec.sent[0].task_id == "j1-first-1-park"
    planner.start_job(["first"])
    planner.tick()
    park = planner.tasks["j1-first-1-park"]
    assert park.state is TaskState.WITHDRAWN and "job task j2-first-1 needs it" in park.reason
    assert rec.calls == [("cancelOrder", "t/a-1")]  # before the job's order
    assert planner.tasks["j2-first-1"].vehicle == "t/a-1" and rec.sent[-1].task_id == "j2-first-1"
    planner.journal.close()


def test_a_low_vehicle_goes_charging_instead_of_taking_work(tmp_path: Path, plant: PlantView) -> None:  # noqa: F811
    given, rec = GivenFleet(), Recorder()
    put(given, "a-1", 9.0, 6.0, battery=10.0)
    planner = planner_on(tmp_path, given, plant, rec, site=CHARGED)
    planner.start_job(["first"])
    planner.tick()
    charge = planner.tasks["charge-a-1-1"]
    assert (charge.purpose, charge.vehicle, charge.legs[0].station) == ("charge", "t/a-1", "charger-2")
    assert planner.tasks["j1-first-1"].state is TaskState.ACTIVE  # nobody fit for the job
    assert [(s.task_id, s.actions) for s in rec.sent] == [("charge-a-1-1", ("startCharging",))]
    finish(given, rec.sent.pop(0), battery=10.0)
    planner.tick()
    assert planner.tasks["charge-a-1-1"].state is TaskState.FINISHED
    put(given, "a-1", 11.0, 1.0, battery=10.0, charging=True)
    planner.tick()
    assert [t for t in planner.tasks if t.startswith("charge")] == ["charge-a-1-1"]  # charging: no second
    put(given, "a-1", 11.0, 1.0, battery=50.0, charging=True)  # charged enough: the job takes it
    planner.tick()
    assert planner.tasks["j1-first-1"].vehicle == "t/a-1"
    assert rec.calls == [("stopCharging", "t/a-1")]
    planner.journal.close()


def test_a_vehicle_that_finishes_its_job_low_goes_charging_not_parking(
        tmp_path: Path, plant: PlantView) -> None:  # noqa: F811
    given, rec = GivenFleet(), Recorder()
    put(given, "a-1", 9.0, 6.0)
    planner = planner_on(tmp_path, given, plant, rec, site=CHARGED)
    planner.start_job(["first"])
    run_job(planner, given, rec, battery=15.0)
    assert "j1-first-1-park" not in planner.tasks
    assert planner.tasks["charge-a-1-1"].state is TaskState.BEING_PROCESSED
    planner.journal.close()


ROWS = [  # (what, the state the planner got, battery, charging)
    ("the manager's row (flat, fleet/discovery/inbox.py)", {"batteryCharge": 12.5, "charging": True}, 12.5, True),
    ("a raw VDA 5050 state", {"batteryState": {"batteryCharge": 40.0, "charging": False}}, 40.0, False),
    ("no battery reported", {"batteryCharge": None, "charging": None}, None, False),
]


@pytest.mark.parametrize(("state", "battery", "charging"), [r[1:] for r in ROWS], ids=[r[0] for r in ROWS])
def test_battery_and_charging_are_read_from_the_managers_rows(state: dict, battery: float | None,
                                                              charging: bool) -> None:
    vehicle = Vehicle("t/a-1", "a-1", "t", "vda5050", True, "ONLINE", state)
    assert (vehicle.battery(), vehicle.charging()) == (battery, charging)

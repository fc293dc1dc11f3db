"""What the operators' pages show, as pure functions (fleet/hmi/views.py), cases as data: the
jobs a station offers, "ready to load" / "ready to unload" and the events its buttons fire, the
job's state, the task filters and their refusals, each vehicle's position from the manager's row
or else from MQTT."""

from __future__ import annotations

from typing import Any

import pytest

import fleet.lotlan
from fleet.hmi import views
from tests.unit.fleet.planner_data import JOBS, SITE

PROGRAM = fleet.lotlan.parse(JOBS, "jobs.tl")


def leg(index: int, station: str, state: str, actions: tuple[str, ...], step: str) -> dict[str, Any]:
    return {"index": index, "station": station, "state": state, "actions": list(actions), "step": step}


def task(tid: str, state: str, legs: tuple[str, str], vehicle: str = "", job: str = "j1",
         stations: tuple[str, str] = ("load-1", "unload-1"), steps: tuple[str, str] = ("atLoad", "atUnload"),
         lotlan: str = "first") -> dict[str, Any]:
    return {"id": tid, "job": job, "lotlanTask": lotlan, "state": state, "vehicle": vehicle,
            "legs": [leg(0, stations[0], legs[0], ("pick",), steps[0]), leg(1, stations[1], legs[1], ("drop",), steps[1])]}


def test_routes_and_the_stations_with_a_page() -> None:
    assert [r.to_json() for r in views.routes(PROGRAM, SITE)] == [
        {"task": "first", "from": "load-1", "to": "unload-1"}, {"task": "second", "from": "load-2", "to": "unload-2"}]
    assert [s["name"] for s in views.stations(PROGRAM, SITE)] == ["load-1", "unload-1", "load-2", "unload-2"]
    pages = {s["name"]: s["page"] for s in views.site_json(SITE, PROGRAM)["stations"]}
    assert pages["park-1"] is False and pages["load-1"] is True


def test_finish_events_are_the_boolean_events_of_the_steps_finished_by() -> None:
    assert views.finish_events(PROGRAM, "atLoad") == ["loaded"]
    assert views.finish_events(PROGRAM, "atUnload") == ["unloaded"]
    assert views.finish_events(PROGRAM, "atOtherLoad") == []  # no FinishedBy: nobody waits
    assert views.finish_events(PROGRAM, "nowhere") == []


READY = [  # (id, tasks, station, ready text, loadReady, unloadReady)
    ("pick done, waits for Loaded", [task("t1", "BEING_PROCESSED", ("ACTED", "READY"), "m/a")], "load-1",
     "ready to load", True, False),
    ("drop done, waits for Unloaded", [task("t1", "BEING_PROCESSED", ("DONE", "ACTED"), "m/a")], "unload-1",
     "ready to unload", False, True),
    ("the other station sees nothing", [task("t1", "BEING_PROCESSED", ("ACTED", "READY"), "m/a")], "unload-1",
     "", False, False),
    ("still driving there", [task("t1", "BEING_PROCESSED", ("SENT", "READY"), "m/a")], "load-1", "", False, False),
    ("a step without FinishedBy never waits",
     [task("t2", "BEING_PROCESSED", ("ACTED", "READY"), "m/a", stations=("load-2", "unload-2"),
           steps=("atOtherLoad", "atOtherUnload"), lotlan="second")], "load-2", "", False, False),
    ("a withdrawn task does not wait", [task("t1", "WITHDRAWN", ("ACTED", "READY"), "m/a")], "load-1", "", False, False),
    ("two vehicles, both kinds",
     [task("t1", "BEING_PROCESSED", ("ACTED", "READY"), "m/a"),
      task("t3", "BEING_PROCESSED", ("DONE", "ACTED"), "m/b", stations=("unload-1", "load-1"))], "load-1",
     "ready to load and ready to unload", True, True),
]


@pytest.mark.parametrize(("tasks", "station", "text", "load", "unload"), [c[1:] for c in READY], ids=[c[0] for c in READY])
def test_ready_to_load_and_unload(tasks: list[dict[str, Any]], station: str, text: str, load: bool, unload: bool) -> None:
    view = views.station_view(PROGRAM, SITE, station, {"tasks": tasks})
    assert (view["ready"], view["loadReady"], view["unloadReady"]) == (text, load, unload)
    if load:
        assert views.button_events(PROGRAM, station, "loaded", tasks) == ["loaded"]
    else:
        with pytest.raises(views.InputError, match=f"nothing at {station} is ready to load") as info:
            views.button_events(PROGRAM, station, "loaded", tasks)
        assert info.value.status == 409


def test_station_view_lists_the_jobs_passing_there_newest_first_and_who_is_coming() -> None:
    tasks = [task("j1-first-1", "FINISHED", ("DONE", "DONE"), "m/a"),
             task("j2-first-1", "BEING_PROCESSED", ("SENT", "READY"), "m/b", job="j2"),
             task("j2-second-1", "RAW", ("READY", "READY"), job="j2", stations=("load-2", "unload-2"),
                  steps=("atOtherLoad", "atOtherUnload"), lotlan="second")]
    view = views.station_view(PROGRAM, SITE, "load-1", {"tasks": tasks})
    assert [(j["job"], j["state"]) for j in view["jobs"]] == [("j2", "BEING_PROCESSED"), ("j1", "FINISHED")]
    assert [t["id"] for t in view["jobs"][0]["tasks"]] == ["j2-first-1", "j2-second-1"]  # the whole job
    assert view["approaching"] == [{"task": "j2-first-1", "vehicle": "m/b", "step": "0: load-1 [pick] SENT"}]
    assert view["startable"] == [{"task": "first", "from": "load-1", "to": "unload-1"}]
    assert views.station_view(PROGRAM, SITE, "load-2", {"tasks": []})["jobs"] == []


JOB_STATES = [
    (["FINISHED", "FINISHED"], "FINISHED"), (["FINISHED", "RAW"], "RAW"), (["ACTIVE", "BEING_PROCESSED"], "BEING_PROCESSED"),
    (["FINISHED", "FAILED"], "FAILED"), (["WITHDRAWN", "FINISHED"], "WITHDRAWN"), ([], "RAW"),
]


@pytest.mark.parametrize(("states", "expected"), JOB_STATES)
def test_job_state(states: list[str], expected: str) -> None:
    assert views.job_state([{"state": s} for s in states]) == expected


def test_check_start_names_the_field() -> None:
    assert views.check_start(PROGRAM, SITE, "load-1", "first") == "first"
    for bad in ("second", "", None, 5, "ghost"):  # second does not pass load-1
        with pytest.raises(views.InputError, match=r"^task: .*is no LoTLan task of station load-1 \(its tasks: first\)"):
            views.check_start(PROGRAM, SITE, "load-1", bad)


FILTERS_BAD = [("state", "DONE", None), ("state", "finished", None), ("vehicle", None, "a b"),
               ("vehicle", None, "<script>"), ("vehicle", None, "x" * 201)]


@pytest.mark.parametrize(("field", "state", "vehicle"), FILTERS_BAD)
def test_bad_filters_name_the_field(field: str, state: str | None, vehicle: str | None) -> None:
    with pytest.raises(views.InputError) as info:
        views.check_filters(state, vehicle)
    assert info.value.field == field and info.value.status == 400


def test_filters_by_state_and_vehicle() -> None:
    tasks = [task("j1-first-1", "FINISHED", ("DONE", "DONE"), "m/a"),
             task("j2-first-1", "BEING_PROCESSED", ("SENT", "READY"), "m/b", job="j2"),
             task("j10-first-1", "ACTIVE", ("READY", "READY"), job="j10")]
    ids = lambda state, vehicle: [r["id"] for r in views.filter_tasks(tasks, *views.check_filters(state, vehicle))]  # noqa: E731
    assert ids("", "") == ["j10-first-1", "j2-first-1", "j1-first-1"]  # newest job first (j10 after j2)
    assert ids("open", "") == ["j10-first-1", "j2-first-1"]
    assert ids("FINISHED", "") == ["j1-first-1"]
    assert ids("", "m/b") == ["j2-first-1"] and ids("", "b") == ["j2-first-1"]
    assert ids("FINISHED", "b") == []


def test_vehicle_rows_position_battery_and_the_task_held() -> None:
    rows = [{"topicManufacturer": "m", "serial": "a", "connectionState": "ONLINE",
             "state": {"agvPosition": {"x": 1.5, "y": 2.0, "theta": 0.5, "mapId": "hall-t"}, "batteryCharge": 80.0,
                       "driving": True}},
            {"topicManufacturer": "m", "serial": "b", "connectionState": "ONLINE",
             "state": {"agvPosition": None, "batteryCharge": 55.5, "driving": False}},
            {"topicManufacturer": "m", "serial": "c", "connectionState": "CONNECTIONBROKEN", "state": None}]
    tasks = [task("t1", "BEING_PROCESSED", ("SENT", "READY"), "m/b"), task("t0", "FINISHED", ("DONE", "DONE"), "m/a")]
    out = {v["key"]: v for v in views.vehicle_rows(rows, tasks)}
    assert (out["m/a"]["x"], out["m/a"]["y"], out["m/a"]["theta"], out["m/a"]["battery"], out["m/a"]["driving"]) == \
        (1.5, 2.0, 0.5, 80.0, True)
    assert out["m/a"]["task"] == ""  # a finished task holds no vehicle
    assert (out["m/b"]["x"], out["m/b"]["battery"]) == (None, 55.5)  # no position heard yet
    assert (out["m/b"]["task"], out["m/b"]["taskState"], out["m/b"]["step"]) == ("t1", "BEING_PROCESSED", "0: load-1 [pick] SENT")
    assert (out["m/c"]["x"], out["m/c"]["battery"], out["m/c"]["connectionState"]) == (None, None, "CONNECTIONBROKEN")


PARKED = [  # (what, the park task's state, the job's state on the station page)
    ("the vehicle on its way to the waiting area", "BEING_PROCESSED", "BEING_PROCESSED"),
    ("the vehicle back in the waiting area", "FINISHED", "FINISHED"),
]


@pytest.mark.parametrize(("park_state", "expected"), [p[1:] for p in PARKED], ids=[p[0] for p in PARKED])
def test_a_job_is_finished_once_its_vehicle_is_back_in_the_waiting_area(park_state: str, expected: str) -> None:
    park = {"id": "j1-first-1-park", "job": "j1", "lotlanTask": "", "purpose": "park", "state": park_state,
            "vehicle": "m/a", "legs": [leg(0, "park-1", "DONE" if park_state == "FINISHED" else "SENT", (), "park")]}
    view = views.station_view(PROGRAM, SITE, "unload-1", {"tasks": [task("j1-first-1", "FINISHED", ("DONE", "DONE"),
                                                                         "m/a"), park]})
    (job,) = view["jobs"]
    assert job["state"] == expected
    assert [(t["lotlanTask"], t["purpose"]) for t in job["tasks"]] == [("first", "job"), ("(park)", "park")]

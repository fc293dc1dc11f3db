"""The paper's ICENT load/unload workflow (section 5, its eleven steps), end to end on real
processes: agents running Mosquitto and the context broker, the fleet manager, two simulated
VDA 5050 AGVs joining by plug and play, the task planner (``--waiting-area``: the nearest free
``park-*`` spot) and the operator screens (HMI) in a headless Chromium (the rig of
tests/integration/test_fleet_planner.py, the browser of test_fleet_hmi_browser.py).

 1. the operator at the loading station starts the task on the station's page;
 2. the task planner (TP) assigns it to an AGV;
 3. the AGV drives to the loading station (its pick done: the sub-task ACTED);
 4. the TP tells the operator: the station's page says "ready to load";
 5. the operator presses Loaded in the browser (the event in the journal);
 6. the TP sends the movement to the unloading station;
 7. the AGV drives there (its drop done);
 8. the unloading station's page says "ready to unload";
 9. the operator presses Unloaded;
10. the TP creates the movement to the waiting area (a ``park`` task for the same AGV);
11. the AGV drives to the waiting area; the TP finishes the task: the job is FINISHED (on the
    station's page; both Task entities on the context broker FINISHED) and the AGV's marker on the
    fleet page stands on the waiting spot.

Charging: with a ``--min-battery`` above any charge (101 %: the simulator has no option for a low
start charge) every vehicle is low: each gets a ``charge`` task to its own charger, reaches it and
charges (the manager's state: ``batteryState.charging``, its position on the charger), a job
started meanwhile is given to nobody; the planner restarted on the same data with the default
minimum gives the job to a charging vehicle (``stopCharging`` first: it drives) and it finishes.

Every step is asserted in the order of the planner's journal (each record has a sequence number),
and what the HMI showed is tied to it: when the page said "ready to load" the journal had the
pick done and no Loaded yet.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Any

import pytest

from engine import process
from tests.integration.test_fleet_hmi_browser import JOBS, browser, shot, spawn_hmi, wait_js  # noqa: F401
from tests.integration.test_fleet_planner import CB_HOST, PARK, ROOT, Planner, Rig, entities, spawn_sim
from tests.integration.test_fleet_planner import rig as rig  # noqa: F401 - the module's fixture
from tests.integration.test_fleet_planner import manager_row, wait_ready, write_map

pytestmark = pytest.mark.integration
CHARGERS = [{"name": "charger-1", "x": 1.0, "y": 4.0, "charger": True},
            {"name": "charger-2", "x": 11.0, "y": 4.0, "charger": True}]


class WorkflowPlanner(Planner):
    """The rig's planner with ``--waiting-area`` (park spots) and ``extra`` arguments."""

    extra: tuple[str, ...] = ()

    def start(self) -> process.Child:
        self.runs += 1
        self.child = process.spawn(
            [sys.executable, "-m", "fleet.planner", "--plant", self.rig.plant, "--lotlan", self.lotlan,
             "--data-dir", self.data, "--manager-data-dir", self.rig.data, "--map", self.map_file,
             "--ngsi-url", f"http://{CB_HOST}:{self.rig.cb_port}", "--ngsi-token-file", self.rig.cb_token_file,
             "--waiting-area", *self.extra],
            log_dir=self.rig.tmp / "logs", name=f"{self.name}-{self.runs}", cwd=ROOT)
        process.wait_until(lambda: self._where().get("pid") == self.child.pid, 30.0, 0.05,
                           what="the planner's API", child=self.child)
        return self.child


Match = Callable[[dict[str, Any]], bool]


def note(task_id: str, start: str) -> Match:
    return lambda r: r["kind"] == "task" and r["task"]["id"] == task_id and r["note"].startswith(start)


def event(name: str) -> Match:
    return lambda r: r["kind"] == "event" and r["event"] == name


def in_order(journal: list[dict[str, Any]], steps: list[tuple[str, Match]]) -> dict[str, int]:
    """The journal's sequence number of each step, each found after the one before it."""
    at, seqs = -1, {}
    for what, match in steps:
        hit = next((r for r in journal if r["seq"] > at and match(r)), None)
        assert hit is not None, f"step {what!r}: not in the journal after seq {at}: " + \
            "; ".join(f"{r['seq']} {r.get('note') or r.get('event')}" for r in journal if r["seq"] > at)
        at = seqs[what] = hit["seq"]
    return seqs


def last_seq(planner: Planner) -> int:
    return planner.journal()[-1]["seq"]


def test_the_papers_eleven_step_load_unload_workflow(rig: Rig, browser: Any) -> None:  # noqa: F811
    map_file = write_map(rig.tmp / "map-workflow.json", PARK)
    lotlan = rig.tmp / "workflow.tl"
    lotlan.write_text(JOBS, encoding="utf-8")
    shots = rig.tmp / "screenshots-workflow"
    sim = spawn_sim(rig, "wf-", map_file, 2, "sim-workflow")
    planner = WorkflowPlanner(rig, rig.tmp / "planner-workflow", lotlan, map_file, "planner-workflow")
    hmi, context = None, None
    errors: list[str] = []
    seen: dict[str, int] = {}  # what the HMI showed -> the journal's last seq then
    try:
        wait_ready(rig, ["wf-0001", "wf-0002"], sim)
        planner.start()
        hmi, url = spawn_hmi(rig, lotlan, map_file, planner.data)
        context = browser.new_context(viewport={"width": 1280, "height": 1100})
        station = context.new_page()
        station.on("pageerror", lambda exc: errors.append(str(exc)))
        station.goto(url + "/")
        station.fill("#token", (rig.tmp / "hmi-token").read_text(encoding="utf-8").strip())
        station.click("#login")
        station.wait_for_url(url + "/")
        fleet = context.new_page()
        fleet.on("pageerror", lambda exc: errors.append(str(exc)))
        fleet.goto(url + "/")

        # 1. the operator at the loading station starts the task
        station.goto(url + "/stations/load-1")
        wait_js(station, "document.getElementById('ready').textContent === 'no vehicle waits here'")
        station.select_option("#job-task", "transport")
        station.click("#start-job")
        wait_js(station, "document.getElementById('message').dataset.job === 'j1'", "job j1 started")
        task = "j1-transport-1"

        # 2-4. assigned, driven to the loading station, "ready to load" on the station's page
        wait_js(station, "document.getElementById('ready').textContent === 'ready to load'", "ready to load")
        seen["ready to load"] = last_seq(planner)
        assert not station.is_disabled("#loaded") and station.is_disabled("#unloaded")
        vehicle = planner.tasks()[task]["vehicle"]
        assert f"waiting: {vehicle}" in station.inner_text("#approaching")
        shot(station, shots, "4-ready-to-load")

        # 5. Loaded, pressed in the browser
        station.click("#loaded")
        wait_js(station, "document.getElementById('message').textContent.startsWith('Loaded: sent loaded')")

        # 6-8. to the unloading station, "ready to unload" there
        station.goto(url + "/stations/unload-1")
        wait_js(station, "document.getElementById('ready').textContent === 'ready to unload'", "ready to unload")
        seen["ready to unload"] = last_seq(planner)
        assert station.is_disabled("#loaded") and not station.is_disabled("#unloaded")
        shot(station, shots, "8-ready-to-unload")

        # 9. Unloaded
        station.click("#unloaded")
        wait_js(station, "document.getElementById('message').textContent.startsWith('Unloaded: sent unloaded')")

        # 10-11. to the waiting area; the job FINISHED once the vehicle is there
        wait_js(station, "(() => { const r = document.querySelector('#jobs tr[data-job=\"j1\"]');"
                         " return r && r.dataset.jobState === 'FINISHED'; })()", "job j1 FINISHED on the station page")
        seen["job FINISHED"] = last_seq(planner)
        tasks = planner.tasks()
        park = tasks[f"{task}-park"]
        assert (park["purpose"], park["job"], park["vehicle"], park["state"]) == ("park", "j1", vehicle, "FINISHED")
        spot = park["legs"][0]["station"]
        assert spot.startswith("park-") and tasks[task]["state"] == "FINISHED"
        journal = planner.journal()
        seqs = in_order(journal, [
            ("1 started", lambda r: r["kind"] == "job" and r["job"] == "j1"),
            ("2 assigned", note(task, f"ACTIVE -> ASSIGNED to {vehicle}")),
            ("3 sent to the loading station", note(task, "sub-task 0 READY -> SENT")),
            ("3 at the loading station, pick done", note(task, "sub-task 0 SENT -> ACTED")),
            ("5 Loaded", event("loaded")),
            ("5 loading acknowledged", note(task, "sub-task 0 ACTED -> DONE")),
            ("6 sent to the unloading station", note(task, "sub-task 1 READY -> SENT")),
            ("7 at the unloading station, drop done", note(task, "sub-task 1 SENT -> ACTED")),
            ("9 Unloaded", event("unloaded")),
            ("9 unloading acknowledged", note(task, "sub-task 1 ACTED -> DONE")),
            ("9 transport finished", note(task, "-> FINISHED")),
            ("10 movement to the waiting area", note(f"{task}-park", f"created: {vehicle} to the waiting area {spot}")),
            ("10 sent", note(f"{task}-park", "sub-task 0 READY -> SENT")),
            ("11 reached", note(f"{task}-park", "sub-task 0 SENT -> DONE")),
            ("11 task ended", note(f"{task}-park", "-> FINISHED")),
        ])
        # what the operators saw, between the journal's steps
        assert seqs["3 at the loading station, pick done"] <= seen["ready to load"] < seqs["5 Loaded"]
        assert seqs["7 at the unloading station, drop done"] <= seen["ready to unload"] < seqs["9 Unloaded"]
        assert seen["job FINISHED"] >= seqs["11 task ended"]
        legs = [r["task"]["legs"] for r in journal if r["kind"] == "task" and r["task"]["id"] == task][-1]
        assert [(g["station"], g["actions"], g["vehicle"]) for g in legs] == [
            ("load-1", ["pick"], vehicle), ("unload-1", ["drop"], vehicle)]

        # the vehicle stands on its waiting spot (the fleet page's map), the Task entities say FINISHED
        target = next(p for p in PARK if p["name"] == spot)
        wait_js(fleet, f"(() => {{ const m = document.querySelector('#map g.vehicle[data-key=\"{vehicle}\"]');"
                       f" return m && Math.hypot(+m.dataset.x - {target['x']}, +m.dataset.y - {target['y']}) < 0.3;"
                       " })()", f"{vehicle} on {spot} on the map")
        shot(fleet, shots, "11-back-in-the-waiting-area")
        def mine() -> list[tuple[str, str]]:
            return sorted((e["state"], e["purpose"]) for i, e in entities(rig).items()
                          if i.endswith((task, f"{task}-park")))
        # the Task entities are written after the planner's own state changes: poll for them
        process.wait_until(lambda: mine() == [("FINISHED", "job"), ("FINISHED", "park")], 20.0, 0.1,
                           what="the job's and the park's Task entities FINISHED")
        position = fleet.evaluate(f"(() => {{ const m = document.querySelector('#map g.vehicle[data-key=\"{vehicle}\"]');"
                                  " return [+m.dataset.x, +m.dataset.y]; })()")
        assert math.hypot(position[0] - target["x"], position[1] - target["y"]) < 0.3
        assert not errors, f"JavaScript errors: {errors}"
    finally:
        if context is not None:
            context.close()
        if hmi is not None:
            assert process.stop(hmi, grace=10.0) == 0, hmi.log_tail()
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()



def test_low_vehicles_go_charging_and_a_job_takes_one_from_its_charger(rig: Rig) -> None:  # noqa: F811
    map_file = write_map(rig.tmp / "map-charging.json", PARK + CHARGERS)
    lotlan = rig.tmp / "charging.tl"
    lotlan.write_text(JOBS.replace("    FinishedBy loaded == True\n", "").replace("    FinishedBy unloaded == True\n", ""),
                      encoding="utf-8")
    sim = spawn_sim(rig, "ch-", map_file, 2, "sim-charging")
    planner = WorkflowPlanner(rig, rig.tmp / "planner-charging", lotlan, map_file, "planner-charging")
    planner.extra = ("--min-battery", "101")
    serials = ["ch-0001", "ch-0002"]
    try:
        wait_ready(rig, serials, sim)
        planner.start()
        assert planner.call("POST", "/v1/jobs", {"tasks": ["transport"]})[0] == 201

        def charging() -> bool:
            return all((manager_row(rig, s).get("state") or {}).get("charging") is True
                       for s in serials)
        planner.wait(charging, 60.0, "both vehicles charging")
        tasks = planner.tasks()
        charges = {t["vehicle"]: t for t in tasks.values() if t["purpose"] == "charge"}
        assert sorted(charges) == [f"plan/{s}" for s in serials]
        assert sorted(t["legs"][0]["station"] for t in charges.values()) == ["charger-1", "charger-2"]
        planner.wait(lambda: all(t["state"] == "FINISHED" for t in planner.tasks().values()
                                 if t["purpose"] == "charge"), 20.0, "the charge tasks FINISHED")
        for t in charges.values():
            at = next(c for c in CHARGERS if c["name"] == t["legs"][0]["station"])
            pos = manager_row(rig, t["vehicle"].split("/")[1])["state"]["agvPosition"]
            assert math.hypot(pos["x"] - at["x"], pos["y"] - at["y"]) < 0.3
        assert planner.tasks()["j1-transport-1"]["state"] == "ACTIVE"  # nobody fit: all below 101 %
        ids = [t["id"] for t in charges.values()]

        def charge_entities() -> list[str]:
            return sorted(e["state"] for i, e in entities(rig).items() if e.get("purpose") == "charge"
                          and any(i.endswith(t) for t in ids))
        # the Task entities are written after the planner's own state changes: poll for them
        planner.wait(lambda: charge_entities() == ["FINISHED"] * 2, 20.0, "the charge Task entities FINISHED")

        planner.stop()
        planner.extra = ()  # the default minimum (20 %): the charging vehicles fit again
        planner.start()
        planner.wait(lambda: planner.tasks()["j1-transport-1"]["state"] == "FINISHED", 90.0,
                     "j1-transport-1 FINISHED on a vehicle taken from its charger")
        vehicle = planner.tasks()["j1-transport-1"]["vehicle"]
        assert "stopCharging sent to " + vehicle in planner.logs()
        assert len([t for t in planner.tasks().values() if t["purpose"] == "charge"]) == 2  # none made again
    finally:
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()

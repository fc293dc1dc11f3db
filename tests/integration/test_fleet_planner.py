"""The task planner end to end, real processes: agents, Mosquitto, the context broker, the fleet
manager (``python -m fleet.manager``), simulated VDA 5050 AGVs (``python -m fleet.sim``) joining
by plug and play, and the planner (``python -m fleet.planner``).

- Two transport orders of one LoTLan job on two AGVs: both finish, each sub-task after the one
  before it (pick, the operator's "Loaded", then drop), the Task entities on the context broker
  read FINISHED; the planner is killed (kill -9) mid-run and restarted: every task completes once
  (each sub-task's order was sent under one orderId, no leg done twice).
- A vehicle killed (kill -9) mid-task: the task goes to the other vehicle; the sub-task the first
  one finished stays finished (its pick is not sent again).
- A task withdrawn while its vehicle drives: the planner sends ``cancelOrder`` through the
  manager's ``POST /v1/instantActions``; the manager's state of the vehicle (with its
  ``agvPosition``) shows the order's pick FAILED and the vehicle stopped. The manager restarted
  (SIGTERM, a new process on another port) mid-task: the planner waits (503 NotReady / no answer),
  finds it again through its data directory, and the task finishes on the same vehicle.
- A paper-channel vehicle (``python -m fleet.sim --interface paper``) joined by plug and play gets
  a LoTLan transport: motion then action items written on the context broker, progress read from
  its AGV entity; the task and its Task entity end FINISHED.

The assignment latency the planner logged is printed (no timing asserts).
"""

from __future__ import annotations

import json
import os
import re
import signal
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from engine import process
from tests.integration.agents import AgentFleet, plant_copy
from tests.integration.fleet_rig import ROOT, managed_fleet, spawn_manager

pytestmark = pytest.mark.integration

MQTT_HOST, CB_HOST = "127.0.0.2", "127.0.0.3"

STATIONS = [{"name": "load-1", "x": 2.0, "y": 6.0}, {"name": "unload-1", "x": 10.0, "y": 6.0},
            {"name": "load-2", "x": 2.0, "y": 2.0}, {"name": "unload-2", "x": 10.0, "y": 2.0}]
PARK = [{"name": "park-1", "x": 4.0, "y": 5.0}, {"name": "park-2", "x": 4.0, "y": 3.0}]

JOBS = """\
Location loadStation
    name = "load-1"
    type = "pallet"
End

Location unloadStation
    name = "unload-1"
    type = "pallet"
End

Location otherLoad
    name = "load-2"
    type = "pallet"
End

Location otherUnload
    name = "unload-2"
    type = "pallet"
End

Event loaded
    name = "Loaded"
    type = "Boolean"
End

TransportOrderStep atLoad
    Location loadStation
    FinishedBy loaded == True
End

TransportOrderStep atUnload
    Location unloadStation
End

TransportOrderStep atOtherLoad
    Location otherLoad
End

TransportOrderStep atOtherUnload
    Location otherUnload
End

Task first
    Transport
    From atLoad
    To atUnload
End

Task second
    Transport
    From atOtherLoad
    To atOtherUnload
End
"""


@dataclass
class Rig:
    tmp: Path
    plant: Path
    data: Path
    agents: AgentFleet
    manager: process.Child
    mqtt_port: int
    cb_port: int

    def status(self) -> dict[str, Any]:
        try:
            return json.loads((self.data / "status.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}

    @property
    def cb_token_file(self) -> Path:
        return self.agents.agents[CB_HOST].state_dir / "token"

    def files(self) -> list[str]:
        return [str(self.plant), *map(str, sorted((self.data / "discovered").glob("*.ttl")))]

    def wait_started(self) -> None:
        def started() -> bool:
            s = self.status()
            return bool(s.get("manager", {}).get("connected") and (s.get("lastReconcile") or {}).get("ok"))
        process.wait_until(started, 60.0, 0.05, what="the manager connected and reconciled", child=self.manager)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    tmp = tmp_path_factory.mktemp("planner")
    plant, ports = plant_copy("agv-fleet.ttl", tmp)
    data = tmp / "fleet-data"

    def start(agents: AgentFleet) -> Rig:
        manager = spawn_manager(plant, data, agents.agents_file, tmp / "logs", "fleet-manager")
        return Rig(tmp, plant, data, agents, manager, ports["fleet-mqtt"], ports["fleet-context"])

    with managed_fleet(plant, [MQTT_HOST, CB_HOST], tmp / "agents", start) as r:
        yield r


def write_map(path: Path, parking: list[dict[str, float]]) -> Path:
    path.write_text(json.dumps({"mapId": "hall-t", "width": 12, "height": 8, "stations": STATIONS + parking}),
                    encoding="utf-8")
    return path


def spawn_sim(rig: Rig, prefix: str, map_file: Path, count: int, name: str, *extra: str,
              vmax: str = "2") -> process.Child:
    """Simulated vehicles that accelerate and turn briskly (the simulator's default turn, 1 rad/s at
    1 rad/s², takes 4 s for a half turn): what the tests check does not depend on the limits."""
    return process.spawn([sys.executable, "-m", "fleet.sim", "--broker", f"{MQTT_HOST}:{rig.mqtt_port}",
                          "--count", str(count), "--manufacturer", "plan", "--serial-prefix", prefix,
                          "--map", map_file, "--vmax", vmax, "--amax", "2", "--omega-max", "4", "--alpha-max", "8",
                          "--state-interval", "1", *extra],
                         log_dir=rig.tmp / "logs", name=name, cwd=ROOT)


def manager_row(rig: Rig, serial: str) -> dict[str, Any]:
    return next((v for v in rig.status().get("vehicles", []) if v["serial"] == serial), {})


def wait_ready(rig: Rig, serials: list[str], sim: process.Child) -> None:
    def ready() -> bool:
        rows = {v["serial"]: v for v in rig.status().get("vehicles", [])}
        return all(s in rows and rows[s]["readySeconds"] is not None and rows[s]["connectionState"] == "ONLINE"
                   for s in serials)
    process.wait_until(ready, 60.0, 0.05, what=f"{serials} applied and ONLINE", child=sim)


class Planner:
    def __init__(self, rig: Rig, data: Path, lotlan: Path, map_file: Path, name: str) -> None:
        self.rig, self.data, self.lotlan, self.map_file, self.name = rig, data, lotlan, map_file, name
        self.runs = 0
        self.child: process.Child | None = None

    def start(self) -> process.Child:
        self.runs += 1
        self.child = process.spawn(
            [sys.executable, "-m", "fleet.planner", "--plant", self.rig.plant, "--lotlan", self.lotlan,
             "--data-dir", self.data, "--manager-data-dir", self.rig.data, "--map", self.map_file,
             "--ngsi-url", f"http://{CB_HOST}:{self.rig.cb_port}", "--ngsi-token-file", self.rig.cb_token_file],
            log_dir=self.rig.tmp / "logs", name=f"{self.name}-{self.runs}", cwd=ROOT)
        process.wait_until(lambda: self._where().get("pid") == self.child.pid, 30.0, 0.05,
                           what="the planner's API", child=self.child)
        return self.child

    def _where(self) -> dict[str, Any]:
        try:
            return json.loads((self.data / "planner.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}

    def call(self, method: str, path: str, body: Any = None) -> tuple[int, Any]:
        token = (self.data / "planner.token").read_text(encoding="utf-8").strip()
        request = urllib.request.Request(self._where()["url"] + path, method=method,
                                         data=None if body is None else json.dumps(body).encode(),
                                         headers={"Authorization": f"Bearer {token}",
                                                  "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=10) as reply:
                return reply.status, json.loads(reply.read())
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read())

    def tasks(self) -> dict[str, dict[str, Any]]:
        return {t["id"]: t for t in self.call("GET", "/v1/tasks")[1]["tasks"]}

    def wait(self, predicate: Any, deadline: float, what: str) -> Any:
        return process.wait_until(predicate, deadline, 0.05, what=what, child=self.child)

    def kill9(self) -> None:
        assert self.child is not None
        os.killpg(self.child.pid, signal.SIGKILL)
        self.child.popen.wait(timeout=10)

    def stop(self) -> None:
        if self.child is not None and self.child.running():
            assert process.stop(self.child, grace=10.0) == 0, self.child.log_tail()

    def journal(self) -> list[dict[str, Any]]:
        return [json.loads(line) for line in (self.data / "journal.jsonl").read_text().splitlines()]

    def logs(self) -> str:
        return "".join(p.read_text(errors="replace") for p in sorted((self.rig.tmp / "logs").glob(f"{self.name}-*")))


def cb_read(rig: Rig, path: str) -> urllib.request.Request:
    """A read of the fleet's context broker, with its agent's token (closed by default, reads too)."""
    token = rig.cb_token_file.read_text(encoding="utf-8").splitlines()[0].strip()
    return urllib.request.Request(f"http://{CB_HOST}:{rig.cb_port}{path}",
                                  headers={"Authorization": f"Bearer {token}"})


def entities(rig: Rig) -> dict[str, dict[str, Any]]:
    with urllib.request.urlopen(cb_read(rig, "/v2/entities?type=Task&options=keyValues&limit=100"),
                                timeout=10) as reply:
        return {e["id"]: e for e in json.loads(reply.read())}


def notes(journal: list[dict[str, Any]], task_id: str) -> list[str]:
    return [r["note"] for r in journal if r["kind"] == "task" and r["task"]["id"] == task_id]


def latencies(log: str) -> list[float]:
    return [float(m) for m in re.findall(r"ASSIGNED to \S+ in ([0-9.]+) ms", log)]


def leg_order_ok(task_notes: list[str]) -> bool:
    """Sub-task 0 sent, then done, then sub-task 1 sent, then done, then FINISHED: in this order."""
    marks = ["sub-task 0 READY -> SENT", "sub-task 0 ", "sub-task 1 READY -> SENT", "sub-task 1 ", "-> FINISHED"]
    at = -1
    for mark in marks:
        hits = [i for i, n in enumerate(task_notes) if n.startswith(mark) and i > at
                and (mark.endswith("SENT") or "DONE" in n or mark == "-> FINISHED")]
        if not hits:
            return False
        at = hits[0]
    return True


def test_two_transports_on_two_agvs_survive_a_planner_kill_9(rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    map_file = write_map(rig.tmp / "map-a.json", PARK)
    lotlan = rig.tmp / "jobs.tl"
    lotlan.write_text(JOBS, encoding="utf-8")
    sim = spawn_sim(rig, "pl-", map_file, 2, "sim-two")
    planner = Planner(rig, rig.tmp / "planner-1", lotlan, map_file, "planner-a")
    try:
        wait_ready(rig, ["pl-0001", "pl-0002"], sim)
        planner.start()
        status, job = planner.call("POST", "/v1/jobs", {})
        assert status == 201 and job == {"job": "j1", "tasks": ["j1-first-1", "j1-second-1"]}, job
        # bad input: clear 4xx naming the field, never a 500
        assert planner.call("POST", "/v1/events", {"event": "nope", "value": True})[0] == 404
        status, body = planner.call("POST", "/v1/events", {"event": "loaded", "value": "yes"})
        assert status == 400 and "value" in body["description"]
        assert planner.call("POST", "/v1/jobs", {"tasks": ["ghost"]})[0] == 400
        # mid-run: first waits for the operator at load-1 (its pick done); kill -9 the planner there
        planner.wait(lambda: planner.tasks()["j1-first-1"]["legs"][0]["state"] == "ACTED", 60.0,
                     "first's pick done, waiting for Loaded")
        # the HMI's view while the vehicle waits for the operator: the Task entity on the context broker
        waiting = process.wait_until(lambda: entities(rig).get("urn:ngsi-ld:Task:j1-first-1", {}).get("step") ==
                                     "0: load-1 [pick] ACTED" and entities(rig)["urn:ngsi-ld:Task:j1-first-1"],
                                     20.0, 0.1, what="the Task entity waiting at load-1")
        assert waiting["state"] == "BEING_PROCESSED" and waiting["vehicle"] == "plan/pl-0001"
        planner.kill9()
        planner.start()
        assert "resuming 2 task(s) of 1 job(s)" in planner.logs()
        status, event = planner.call("POST", "/v1/events", {"event": "Loaded", "value": True})
        assert status == 201 and event["event"] == "loaded"
        tasks = planner.wait(lambda: (t := planner.tasks()) and all(x["state"] == "FINISHED" for x in t.values()) and t,
                             90.0, "both tasks FINISHED")
        assert set(tasks) == {"j1-first-1", "j1-second-1"}
        vehicles = {t["vehicle"] for t in tasks.values()}
        legs = {tid: [(g["station"], g["state"], g["vehicle"], g["orderId"]) for g in t["legs"]] for tid, t in tasks.items()}
        assert [(s, st) for s, st, _, _ in legs["j1-first-1"]] == [("load-1", "DONE"), ("unload-1", "DONE")]
        assert [(s, st) for s, st, _, _ in legs["j1-second-1"]] == [("load-2", "DONE"), ("unload-2", "DONE")]
        used = {g[2] for t in legs.values() for g in t}
        assert used == {"plan/pl-0001", "plan/pl-0002"}, legs  # one vehicle per transport, both used
        assert all(len({g[2] for g in t}) == 1 for t in legs.values()), legs  # the same vehicle carries it
        journal = planner.journal()
        for tid in tasks:
            task_notes = notes(journal, tid)
            assert leg_order_ok(task_notes), task_notes
            assert task_notes.count("-> FINISHED") == 1
            sent = [n for n in task_notes if "READY -> SENT" in n]
            assert len(sent) == 2, task_notes  # each sub-task sent once: nothing done twice
        assert all(g[3].endswith("-1") for t in legs.values() for g in t)  # first attempt of every leg
        # the vehicles did what the planner asked: their last orders are the drops, all FINISHED (as the
        # manager sees them: its status file follows the states a moment after the planner heard them)
        def done_in_manager() -> bool:
            rows = {f"plan/{v['serial']}": v for v in rig.status().get("vehicles", []) if v["serial"].startswith("pl-")}
            states = [(rows.get(t[1][2]) or {}).get("state") or {} for t in legs.values()]
            return all(s.get("orderId") == t[1][3] and s.get("lastNodeId") == t[1][0]
                       and {a["actionStatus"] for a in s.get("actionStates", [])} == {"FINISHED"}
                       for s, t in zip(states, legs.values()))
        process.wait_until(done_in_manager, 10.0, 0.05, what="the drops FINISHED in the manager's status",
                           child=rig.manager)
        # the Task entities on the context broker (plain HTTP, as any NGSI client)
        seen = process.wait_until(
            lambda: (e := entities(rig)) and all(e.get(f"urn:ngsi-ld:Task:{t}", {}).get("state") == "FINISHED"
                                                 for t in tasks) and e, 20.0, 0.1, what="Task entities FINISHED")
        first = seen["urn:ngsi-ld:Task:j1-first-1"]
        assert first["type"] == "Task" and first["vehicle"] in vehicles and first["step"] == "all sub-tasks done"
        assert "context broker refused" not in planner.logs()  # every Task entity write was accepted
        took = latencies(planner.logs())
        with capsys.disabled():
            print(f"\nplanner: 2 transports on 2 AGVs, planner killed -9 and resumed; assignment latency "
                  f"(assign.rq incl. live graph) {', '.join(f'{t:.1f}' for t in took)} ms")
        assert len(took) == 2
    finally:
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()


def test_a_vehicle_killed_mid_task_hands_its_task_over_and_finished_work_is_not_redone(
        rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    near = write_map(rig.tmp / "map-near.json", PARK)  # its vehicle starts on park-1, next to load-1
    far = write_map(rig.tmp / "map-far.json", PARK[::-1])  # its vehicle starts on park-2
    lotlan = rig.tmp / "one.tl"
    lotlan.write_text(JOBS.split("Task second")[0], encoding="utf-8")
    sim_a = spawn_sim(rig, "ka-", near, 1, "sim-a")
    sim_b = spawn_sim(rig, "kb-", far, 1, "sim-b")
    planner = Planner(rig, rig.tmp / "planner-2", lotlan, near, "planner-b")
    try:
        wait_ready(rig, ["ka-0001"], sim_a)
        wait_ready(rig, ["kb-0001"], sim_b)
        planner.start()
        assert planner.call("POST", "/v1/jobs", {"tasks": ["first"]})[0] == 201
        task = planner.wait(lambda: (t := planner.tasks()["j1-first-1"])["legs"][0]["state"] == "ACTED" and t,
                            60.0, "the pick done by the nearest vehicle")
        assert task["vehicle"] == "plan/ka-0001"
        os.killpg(sim_a.pid, signal.SIGKILL)  # its last will: CONNECTIONBROKEN
        sim_a.popen.wait(timeout=10)
        task = planner.wait(lambda: (t := planner.tasks()["j1-first-1"])["vehicle"] == "plan/kb-0001" and t,
                            30.0, "the task re-assigned to kb-0001")
        assert task["legs"][0]["state"] == "ACTED" and task["legs"][0]["vehicle"] == "plan/ka-0001"
        assert planner.call("POST", "/v1/events", {"event": "loaded", "value": True})[0] == 201
        task = planner.wait(lambda: (t := planner.tasks()["j1-first-1"])["state"] == "FINISHED" and t, 60.0, "FINISHED")
        assert [(g["vehicle"], g["state"], g["orderId"]) for g in task["legs"]] == [
            ("plan/ka-0001", "DONE", "j1-first-1-0-1"), ("plan/kb-0001", "DONE", "j1-first-1-1-1")]
        task_notes = notes(planner.journal(), "j1-first-1")
        assert sum("sub-task 0 READY -> SENT" in n for n in task_notes) == 1, task_notes  # the pick is not redone
        assert any("vehicle plan/ka-0001 is CONNECTIONBROKEN" in n for n in task_notes), task_notes
        assert "context broker refused" not in planner.logs()
    finally:
        planner.stop()
        process.stop(sim_a, grace=5.0)
        assert process.stop(sim_b, grace=15.0) == 0, sim_b.log_tail()


def test_a_paper_vehicle_joined_by_plug_and_play_carries_a_transport(
        rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    map_file = write_map(rig.tmp / "map-p.json", PARK)
    lotlan = rig.tmp / "paper.tl"
    lotlan.write_text(JOBS.split("Task first")[0] + "Task second" + JOBS.split("Task second")[1], encoding="utf-8")
    sim = spawn_sim(rig, "pp-", map_file, 1, "sim-paper", "--interface", "paper", "--rate", "2")
    planner = Planner(rig, rig.tmp / "planner-4", lotlan, map_file, "planner-p")
    try:
        wait_ready(rig, ["pp-0001"], sim)
        assert manager_row(rig, "pp-0001")["interface"] == "paper-channels"
        planner.start()
        began = time.monotonic()
        assert planner.call("POST", "/v1/jobs", {"tasks": ["second"]})[0] == 201
        task = planner.wait(lambda: (t := planner.tasks()["j1-second-1"])["state"] in ("FINISHED", "FAILED") and t,
                            120.0, "the paper vehicle's transport FINISHED")
        took = time.monotonic() - began
        assert task["state"] == "FINISHED", task
        assert [(g["station"], g["state"], g["vehicle"]) for g in task["legs"]] == [
            ("load-2", "DONE", "/pp-0001"), ("unload-2", "DONE", "/pp-0001")]
        agv = process.wait_until(lambda: (e := ngsi_get(rig, "urn:ngsi-ld:AGV:pp-0001")) and e.get("pose")
                                 and abs(e["pose"]["x"] - 10.0) < 0.05 and abs(e["pose"]["y"] - 2.0) < 0.05 and e,
                                 20.0, 0.1, what="the paper AGV at unload-2")
        assert agv["refused"] == 0 and agv["state"] == "IDLE"
        seen = process.wait_until(lambda: (e := entities(rig).get("urn:ngsi-ld:Task:j1-second-1")) and
                                  e.get("state") == "FINISHED" and e, 20.0, 0.1, what="the Task entity FINISHED")
        assert seen["vehicle"] == "/pp-0001"
        logs = planner.logs()
        assert logs.count("motion item to") >= 2 and "action item(s) written" in logs
        assert "context broker refused" not in logs and "Traceback" not in logs
        with capsys.disabled():
            print(f"\nplanner: a paper-channel AGV carried one transport (2 sub-tasks, 11.6 m) in {took:.1f} s")
    finally:
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()


def test_a_withdrawn_task_is_cancelled_on_its_vehicle_and_a_manager_restart_is_waited_for(
        rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    map_file = write_map(rig.tmp / "map-c.json", PARK)
    lotlan = rig.tmp / "cancel.tl"
    lotlan.write_text(JOBS, encoding="utf-8")
    sim = spawn_sim(rig, "cx-", map_file, 1, "sim-cancel", vmax="0.4")
    planner = Planner(rig, rig.tmp / "planner-3", lotlan, map_file, "planner-c")
    try:
        wait_ready(rig, ["cx-0001"], sim)
        # the manager's rows carry the position the planner starts its orders from
        position = process.wait_until(lambda: ((manager_row(rig, "cx-0001").get("state") or {}).get("agvPosition")),
                                      20.0, 0.05, what="cx-0001's agvPosition in the manager's status", child=sim)
        assert (position["x"], position["y"], position["mapId"]) == (4.0, 5.0, "hall-t"), position
        planner.start()
        assert planner.call("POST", "/v1/jobs", {"tasks": ["second"]})[0] == 201
        task = planner.wait(lambda: (t := planner.tasks()["j1-second-1"])["legs"][0]["state"] == "SENT" and t,
                            30.0, "second's first sub-task sent")
        order_id = task["legs"][0]["orderId"]
        process.wait_until(lambda: (s := manager_row(rig, "cx-0001").get("state") or {}).get("orderId") == order_id
                           and s.get("driving"), 20.0, 0.05, what="cx-0001 driving the order", child=sim)
        status, body = planner.call("POST", "/v1/tasks/j1-second-1/withdraw")
        assert status == 200 and body["state"] == "WITHDRAWN", body

        def cancelled() -> dict[str, Any] | None:
            s = manager_row(rig, "cx-0001").get("state") or {}
            kinds = {a["actionType"]: a["actionStatus"] for a in s.get("actionStates", [])}
            return s if kinds.get("cancelOrder") == "FINISHED" and kinds.get("pick") == "FAILED" else None
        state = process.wait_until(cancelled, 20.0, 0.05, what="the order cancelled on cx-0001", child=sim)
        assert state["orderId"] == order_id and not state["driving"]
        assert "cancelOrder sent to plan/cx-0001" in planner.logs()

        # the manager restarts mid-task (the last test of the module: the restarted manager is
        # this test's child, stopped here): the planner waits, finds it again, nobody is lost
        assert planner.call("POST", "/v1/jobs", {"tasks": ["second"]})[0] == 201
        planner.wait(lambda: planner.tasks()["j2-second-1"]["legs"][0]["state"] == "SENT", 30.0, "j2 sent")
        assert process.stop(rig.manager, grace=15.0) == 0
        rig.manager = process.spawn(list(rig.manager.argv), log_dir=rig.tmp / "logs", name="fleet-manager-2", cwd=ROOT)
        task = planner.wait(lambda: (t := planner.tasks()["j2-second-1"])["state"] == "FINISHED" and t, 90.0,
                            "j2 FINISHED after the manager's restart")
        assert {g["vehicle"] for g in task["legs"]} == {"plan/cx-0001"}
        task_notes = notes(planner.journal(), "j2-second-1")
        assert not any("back to ACTIVE" in n for n in task_notes), task_notes
        assert "the fleet manager now answers at" in planner.logs()
        planner.stop()
        assert process.stop(rig.manager, grace=15.0) == 0, rig.manager.log_tail()
    finally:
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()


def ngsi_get(rig: Rig, entity_id: str) -> dict[str, Any] | None:
    try:
        with urllib.request.urlopen(cb_read(rig, f"/v2/entities/{entity_id}?options=keyValues"),
                                    timeout=5) as reply:
            return json.loads(reply.read())
    except (OSError, ValueError):
        return None

"""Benchmark: N LoTLan transport orders carried by M simulated VDA 5050 AGVs (issue 12).

One run (default 200 orders over 20 vehicles; ``--tiny`` is 6 over 2): a fresh copy of
``ontology/examples/agv-fleet.ttl`` on free ports is applied through local agents, the fleet
manager starts, ``python -m fleet.sim --count M`` connects M vehicles that join by plug and play,
then the task planner (``python -m fleet.planner``) takes a generated LoTLan program of N
``Transport From … To …`` tasks (no TriggeredBy, no FinishedBy: nothing waits for an operator, so
it runs unattended) on a generated map, one job starts them all, and the benchmark waits until
every task is FINISHED. Measured:

- **orders/min completed**: N over the makespan (job started -> last task FINISHED, from the
  planner's journal), against the **ideal**: the sum over the orders of the loaded travel time
  (pickup -> drop, straight line, the continuous trapezoid of fleet/sim/kinematics.py at the
  vehicles' ``--vmax``/``--amax``) plus the pick and drop action times, divided by M. The ideal
  leaves out the empty runs between orders, the turns in place and any planner overhead: the
  gap to it is what those cost;
- **assignment latency**: the planner's own timing of each assignment (the SPARQL choice, the
  ``ACTIVE -> ASSIGNED … in X ms`` note of its journal), p50/p99; and, apart, the time tasks
  spent ACTIVE before a vehicle was free (queueing, not latency: N > M);
- the planner's CPU seconds over the run and its RSS (sampled, and the kernel's peak VmHWM);
- the vehicles' positions every ``--sample`` s from the manager's API (``agvPosition`` of each
  vehicle's last state; the simulators send a state every ``--sample`` s) and every task's
  timeline (ASSIGNED -> leg 0 done -> FINISHED): the paths plot (the paper's Fig. 8) and the
  Gantt chart are drawn from the results' JSON by benchmarks/plots.py.

The orders alternate direction (A wall -> B wall, then B -> A), so a vehicle that delivered is
near the next pickup and vehicles never wait on each other (no station is shared at once by
design: stations outnumber vehicles; the simulator has no collisions).
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import tempfile
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

from benchmarks import plots
from benchmarks.common import RESULTS, ROOT, command_line, machine, summarize, write_results
from benchmarks.bench_fleet_join import EXAMPLE, MQTT_HOST, cpu_seconds, read_status, rss_mib
from engine import process
from engine.local_plant import LocalPlant, copy_on_free_ports
from fleet.demo import Api
from fleet.manager.client import ManagerClient
from fleet.sim.actions import ActionTimes

CONTEXT_ID, MQTT_ID = "fleet-context", "fleet-mqtt"
HALL_W, HALL_H = 24.0, 16.0


@dataclass(frozen=True)
class Order:
    name: str
    pickup: str
    drop: str


def trapezoid_seconds(distance: float, v_max: float, a_max: float) -> float:
    """Time to drive ``distance`` from rest to rest with speed ``v_max`` and acceleration ``a_max``:
    ``d/v + v/a`` when the vehicle reaches ``v_max`` (``d >= v²/a``), else the triangle ``2·sqrt(d/a)``."""
    if distance < 0 or v_max <= 0 or a_max <= 0:
        raise ValueError(f"distance >= 0, v_max > 0, a_max > 0 expected, got {distance}, {v_max}, {a_max}")
    if distance >= v_max * v_max / a_max:
        return distance / v_max + v_max / a_max
    return 2.0 * math.sqrt(distance / a_max)


def site(vehicles: int) -> dict[str, Any]:
    """The map: pick/drop stations on two walls (A at x=2, B at x=22, one more per wall than
    vehicles, at most 12 each), a parking spot per vehicle (up to 42) in the middle, one charger."""
    per_wall = min(vehicles + 1, 12)
    gap = (HALL_H - 2.0) / max(per_wall - 1, 1)
    stations = [{"name": f"{wall.lower()}-{i + 1}", "x": x, "y": round(1.0 + i * gap, 3)}
                for wall, x in (("A", 2.0), ("B", HALL_W - 2.0)) for i in range(per_wall)]
    stations += [{"name": f"park-{i + 1}", "x": 6.0 + 2.0 * (i // 7), "y": 2.0 + 2.0 * (i % 7)}
                 for i in range(min(vehicles, 42))]  # the simulator needs a spot per vehicle
    stations.append({"name": "charger-1", "x": 12.0, "y": HALL_H - 0.5, "charger": True})
    return {"mapId": "bench-tasks", "width": HALL_W, "height": HALL_H, "stations": stations}


def orders(count: int, the_map: dict[str, Any], seed: int) -> list[Order]:
    """``count`` orders alternating A -> B and B -> A between random stations of each wall."""
    rnd = random.Random(seed)
    walls = {w: [s["name"] for s in the_map["stations"] if s["name"].startswith(f"{w}-")] for w in ("a", "b")}
    out = []
    for k in range(count):
        src, dst = ("a", "b") if k % 2 == 0 else ("b", "a")
        out.append(Order(f"order{k + 1:04d}", rnd.choice(walls[src]), rnd.choice(walls[dst])))
    return out


def lotlan(all_orders: list[Order]) -> str:
    """The LoTLan program: a Location and a TransportOrderStep per station used, a Task per order."""
    names = sorted({o.pickup for o in all_orders} | {o.drop for o in all_orders})
    parts = ["# Generated by benchmarks/bench_fleet_tasks.py: transport orders, no operator events.\n"]
    for n in names:
        ident = n.replace("-", "")
        parts.append(f"Location loc{ident}\n    name = \"{n}\"\n    type = \"pallet\"\nEnd\n")
        parts.append(f"TransportOrderStep at{ident}\n    Location loc{ident}\nEnd\n")
    for o in all_orders:
        parts.append(f"Task {o.name}\n    Transport\n    From at{o.pickup.replace('-', '')}\n"
                     f"    To at{o.drop.replace('-', '')}\nEnd\n")
    return "\n".join(parts)


def ideal(all_orders: list[Order], the_map: dict[str, Any], vehicles: int, v_max: float, a_max: float) -> dict[str, float]:
    at = {s["name"]: (s["x"], s["y"]) for s in the_map["stations"]}
    times = ActionTimes()
    per_order = [trapezoid_seconds(math.dist(at[o.pickup], at[o.drop]), v_max, a_max) + times.pick + times.drop
                 for o in all_orders]
    total = sum(per_order)
    return {"order_seconds_sum": total, "makespan_s": total / vehicles,
            "loaded_leg_s": {o.name: trapezoid_seconds(math.dist(at[o.pickup], at[o.drop]), v_max, a_max) + times.drop
                             for o in all_orders},
            "orders_per_min": len(all_orders) / (total / vehicles) * 60}


def turning_points(track: list[list[float]], tolerance: float = 0.02) -> list[list[float]]:
    """``[t, x, y]`` samples without those on a straight line between their kept neighbours (within
    ``tolerance`` m): the vehicles drive straight between stations, so the path keeps its shape
    while the results' JSON stays small. The first and last samples and every stop are kept."""
    if len(track) <= 2:
        return list(track)
    kept = [track[0]]
    for point, after in zip(track[1:-1], track[2:]):
        a = kept[-1]
        dx, dy = after[1] - a[1], after[2] - a[2]
        length = math.hypot(dx, dy)
        off = abs(dx * (point[2] - a[2]) - dy * (point[1] - a[1])) / length if length else math.inf
        between = length and 0 <= ((point[1] - a[1]) * dx + (point[2] - a[2]) * dy) / length <= length
        if off > tolerance or not between:
            kept.append(point)
    kept.append(track[-1])
    return kept


def _t(iso: str) -> float:
    return datetime.fromisoformat(iso.replace("Z", "+00:00")).timestamp()


def timeline(journal: Path) -> tuple[float, list[dict[str, Any]]]:
    """From the planner's journal: the job's start (epoch s) and per task its vehicle and the
    times it became ACTIVE, ASSIGNED (with the planner's own assignment ms), its first leg DONE,
    FINISHED."""
    start = None
    tasks: dict[str, dict[str, Any]] = {}
    for line in journal.read_text(encoding="utf-8").splitlines():
        rec = json.loads(line)
        if rec["kind"] == "job" and start is None:
            start = _t(rec["at"])
        if rec["kind"] != "task":
            continue
        task, note = rec["task"], rec.get("note", "")
        row = tasks.setdefault(task["id"], {"id": task["id"], "lotlanTask": task["lotlanTask"]})
        at, state = _t(task["updated"] or task["created"]), task["state"]
        if state == "ACTIVE":
            row.setdefault("active", at)
        elif state == "ASSIGNED" and "assigned" not in row:
            row["assigned"], row["vehicle"] = at, task["vehicle"]
            found = note.split(" in ", 1)[1].split(" ms", 1)[0] if " in " in note and " ms" in note else None
            row["assign_ms"] = float(found) if found else None
        if task["legs"] and task["legs"][0]["state"] == "DONE":
            row.setdefault("leg0_done", at)
        if state == "FINISHED":
            row["finished"] = at
        row["state"] = state
    if start is None:
        raise RuntimeError(f"{journal}: no job was started")
    return start, sorted(tasks.values(), key=lambda r: r["id"])


def run_fleet(work: Path, *, n_orders: int, n_vehicles: int, seed: int = 12, sample: float = 0.2,
              v_max: float = 2.0, a_max: float = 1.0, deadline: float | None = None) -> dict[str, Any]:
    """One run on a fresh plant under ``work``; returns the measurements (JSON-able)."""
    work.mkdir(parents=True, exist_ok=True)
    logs, mdata, pdata = work / "logs", work / "fleet-manager", work / "planner"
    plant_file = work / "agv-fleet.ttl"
    ports = copy_on_free_ports(EXAMPLE, plant_file)
    the_map = site(n_vehicles)
    map_file = work / "map.json"
    map_file.write_text(json.dumps(the_map))
    all_orders = orders(n_orders, the_map, seed)
    jobs = work / "jobs.tl"
    jobs.write_text(lotlan(all_orders))
    deadline = deadline or 120 + 60 * n_orders / n_vehicles
    children: list[process.Child] = []
    with LocalPlant.start([plant_file], work / "plant") as plant:
        if not plant.apply().ok:
            raise RuntimeError(f"the plant did not apply; see the agents' logs under {work}")
        try:
            manager = process.spawn([sys.executable, "-m", "fleet.manager", plant_file, "--data-dir", mdata,
                                     "--agents", plant.agents.agents_file], log_dir=logs, name="manager", cwd=ROOT)
            children.append(manager)
            process.wait_until(lambda: (read_status(mdata).get("lastReconcile") or {}).get("ok")
                               and read_status(mdata).get("manager", {}).get("connected"),
                               120, 0.05, what="the fleet manager to start", child=manager)
            children.append(process.spawn(
                [sys.executable, "-m", "fleet.sim", "--broker", f"{MQTT_HOST}:{ports[MQTT_ID]}",
                 "--count", str(n_vehicles), "--manufacturer", "bench", "--serial-prefix", "agv",
                 "--state-interval", str(sample), "--map", str(map_file), "--vmax", str(v_max),
                 "--amax", str(a_max)], log_dir=logs, name="sim", cwd=ROOT))
            process.wait_until(lambda: len([v for v in read_status(mdata).get("vehicles", [])
                                            if v.get("manufacturer") == "bench" and v.get("readySeconds") is not None])
                               >= n_vehicles, 60 + 2.0 * n_vehicles, 0.1, what=f"{n_vehicles} vehicles to join",
                               child=manager)
            cb_token = plant.agents.agents["127.0.0.3"].state_dir / "token"
            planner = process.spawn([sys.executable, "-m", "fleet.planner", "--plant", plant_file, "--lotlan", jobs,
                                     "--data-dir", pdata, "--manager-data-dir", mdata, "--map", map_file,
                                     "--min-battery", "5",
                                     "--ngsi-url", f"http://127.0.0.3:{ports[CONTEXT_ID]}",
                                     "--ngsi-token-file", cb_token], log_dir=logs, name="planner", cwd=ROOT)
            children.append(planner)
            api = Api(pdata, "planner")
            process.wait_until(lambda: api.where().get("pid") == planner.pid, 60, 0.05,
                               what="the planner's API", child=planner)
            measured = _drive(api, planner, ManagerClient.for_data_dir(mdata), sample, deadline)
        finally:
            for child in reversed(children):
                process.stop(child)
    start, tasks = timeline(pdata / "journal.jsonl")
    return _figures(n_orders, n_vehicles, v_max, a_max, seed, the_map, all_orders, start, tasks, measured)


def _drive(api: Api, planner: process.Child, manager: ManagerClient, sample: float,
           deadline: float) -> dict[str, Any]:
    """Start the job, sample positions and the planner's RSS until every task ended."""
    cpu0 = cpu_seconds(planner.pid)
    status, body = api.call("POST", "/v1/jobs", {})
    if status != 201:
        raise RuntimeError(f"the planner refused the job: {status} {body}")
    paths: dict[str, list[list[float]]] = {}
    rss: list[float] = []
    began = time.time()
    last_poll = 0.0

    def step() -> bool:
        nonlocal last_poll
        now = time.time()
        for v in manager.vehicles():
            pos = (v.get("state") or {}).get("agvPosition") or {}
            if isinstance(pos.get("x"), (int, float)):
                track = paths.setdefault(v["vehicle"], [])
                point = [round(now - began, 2), round(pos["x"], 2), round(pos["y"], 2)]
                if not track or track[-1][1:] != point[1:]:
                    track.append(point)
        rss.append(rss_mib(planner.pid))
        if now - last_poll < 1.0:
            return False
        last_poll = now
        code, tasks = api.call("GET", "/v1/tasks")
        return code == 200 and bool(tasks["tasks"]) and all(
            t["state"] in ("FINISHED", "FAILED", "WITHDRAWN") for t in tasks["tasks"])

    process.wait_until(step, deadline, sample, what="every task to end", child=planner)
    status_text = Path(f"/proc/{planner.pid}/status").read_text()
    hwm = next(int(line.split()[1]) / 1024 for line in status_text.splitlines() if line.startswith("VmHWM:"))
    return {"began": began, "cpu_s": cpu_seconds(planner.pid) - cpu0, "rss_mib_max_sampled": max(rss),
            "rss_mib_peak": hwm, "paths": paths}


def _figures(n_orders: int, n_vehicles: int, v_max: float, a_max: float, seed: int, the_map: dict[str, Any],
             all_orders: list[Order], start: float, tasks: list[dict[str, Any]],
             measured: dict[str, Any]) -> dict[str, Any]:
    finished = [t for t in tasks if t["state"] == "FINISHED"]
    makespan = max(t["finished"] for t in finished) - start if finished else float("nan")
    best = ideal(all_orders, the_map, n_vehicles, v_max, a_max)
    assign_ms = [t["assign_ms"] for t in tasks if t.get("assign_ms") is not None]
    queued = [t["assigned"] - t["active"] for t in tasks if "assigned" in t and "active" in t]
    shift = measured["began"] - start  # samples are relative to the job's POST; the Gantt to the journal's job
    gantt = [{"id": t["lotlanTask"], "vehicle": t.get("vehicle", ""), "assigned": round(t["assigned"] - start, 3),
              "leg0_done": round(t["leg0_done"] - start, 3) if "leg0_done" in t else None,
              "finished": round(t["finished"] - start, 3) if "finished" in t else None, "state": t["state"]}
             for t in tasks if "assigned" in t]
    paths = {k: turning_points([[round(p[0] + shift, 2), p[1], p[2]] for p in v]) for k, v in measured["paths"].items()}
    rate = len(finished) / makespan * 60 if finished else 0.0
    loaded = [(t["finished"] - t["leg0_done"]) / best["loaded_leg_s"][t["lotlanTask"]]
              for t in finished if "leg0_done" in t]
    return {
        "orders": n_orders, "vehicles": n_vehicles, "v_max": v_max, "a_max": a_max, "seed": seed,
        "finished": len(finished), "failed": sum(1 for t in tasks if t["state"] == "FAILED"),
        "makespan_s": makespan, "orders_per_min": rate, "ideal": best,
        "vs_ideal": makespan / best["makespan_s"] if finished else None,
        "loaded_leg_vs_ideal": sum(loaded) / len(loaded) if loaded else None,
        "assign": summarize([ms / 1000 for ms in assign_ms]),
        "queued_active": summarize(queued),
        "planner_cpu_s": measured["cpu_s"], "planner_cpu_ms_per_order": measured["cpu_s"] / n_orders * 1000,
        "planner_rss_mib_max_sampled": measured["rss_mib_max_sampled"], "planner_rss_mib_peak": measured["rss_mib_peak"],
        "position_samples": sum(len(v) for v in measured["paths"].values()),
        "map": the_map, "gantt": gantt, "paths": paths,
    }


def goals(data: dict[str, Any]) -> list[dict[str, Any]]:
    """The issue's goals with the measured figure and a verdict (reported, never asserted)."""
    p99, ratio = data["assign"].get("p99"), data["vs_ideal"]
    return [
        {"goal": "assignment latency p99 (the planner's SPARQL choice)", "measured": f"{p99:.1f} ms" if p99 else "n/a",
         "target": "< 50 ms", "met": bool(p99 is not None and p99 < 50)},
        {"goal": f"{data['orders']} orders over {data['vehicles']} AGVs: makespan against the ideal",
         "measured": f"{ratio:.2f}x" if ratio else "n/a", "target": "≤ 1.10x", "met": bool(ratio and ratio <= 1.10)},
    ]


def to_markdown(data: dict[str, Any]) -> str:
    a, q = data["assign"], data["queued_active"]
    lines = [
        f"# fleet tasks: {data['orders']} LoTLan transport orders over {data['vehicles']} simulated VDA 5050 AGVs",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']} · vehicles: v_max {data['v_max']} m/s, "
        f"a_max {data['a_max']} m/s², pick/drop {ActionTimes().pick:g} s + {ActionTimes().drop:g} s.",
        "",
        "| finished | failed | makespan | orders/min | ideal orders/min | makespan vs ideal | assign p50 | assign p99 | "
        "ACTIVE before assigned p50 / p99 | planner CPU | CPU/order | planner RSS peak |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
        f"| {data['finished']}/{data['orders']} | {data['failed']} | {data['makespan_s']:.1f} s | "
        f"{data['orders_per_min']:.1f} | {data['ideal']['orders_per_min']:.1f} | {data['vs_ideal'] or float('nan'):.2f}x | "
        f"{a.get('p50', float('nan')):.1f} ms | {a.get('p99', float('nan')):.1f} ms | "
        f"{q.get('p50', float('nan')) / 1000:.1f} / {q.get('p99', float('nan')) / 1000:.1f} s | "
        f"{data['planner_cpu_s']:.1f} s | {data['planner_cpu_ms_per_order']:.0f} ms | {data['planner_rss_mib_peak']:.0f} MiB |",
        "",
        "Ideal: the sum of the orders' loaded travel times (trapezoid at v_max/a_max, straight line) plus "
        "pick and drop, over the number of vehicles; empty runs and turns are not in it. "
        f"The loaded leg alone (pickup done -> FINISHED: turn, drive, drop, the planner noticing) took "
        f"{data['loaded_leg_vs_ideal'] or float('nan'):.2f}x its ideal on average.",
        "",
        "| goal (issue 12) | measured | target | verdict |",
        "|---|---|---|---|",
    ]
    lines += [f"| {g['goal']} | {g['measured']} | {g['target']} | {'met' if g['met'] else '**not met**'} |"
              for g in data["goals"]]
    # the plots (fleet_tasks-paths.png, fleet_tasks-gantt.png) are placed by benchmarks/report.py
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--orders", type=int, default=200)
    parser.add_argument("--vehicles", type=int, default=20)
    parser.add_argument("--tiny", action="store_true", help="6 orders over 2 vehicles")
    parser.add_argument("--seed", type=int, default=12)
    parser.add_argument("--sample", type=float, default=0.2, help="seconds between position samples")
    parser.add_argument("--vmax", type=float, default=2.0, help="the vehicles' top speed, m/s")
    parser.add_argument("--amax", type=float, default=1.0, help="the vehicles' acceleration, m/s²")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.tiny:
        args.orders, args.vehicles = 6, 2
    if args.orders < 1 or args.vehicles < 1:
        parser.error(f"--orders and --vehicles must be >= 1, got {args.orders} and {args.vehicles}")
    info = machine()
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-tasks-") as tmp:
        data = run_fleet(Path(tmp), n_orders=args.orders, n_vehicles=args.vehicles, seed=args.seed,
                         sample=args.sample, v_max=args.vmax, a_max=args.amax)
    data = {"command": command_line("benchmarks.bench_fleet_tasks", argv), "machine": info, **data}
    data["goals"] = goals(data)
    write_results(args.out, "fleet_tasks", data, to_markdown(data))
    plots.fleet_paths(data, args.out / "fleet_tasks-paths.png")
    plots.fleet_gantt(data, args.out / "fleet_tasks-gantt.png")
    return 0 if data["finished"] == args.orders else 1


if __name__ == "__main__":
    raise SystemExit(main())

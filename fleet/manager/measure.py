"""Measures plug and play: from each vehicle's ``connection: ONLINE`` to "ready for tasks"
(its reconcile applied), for N simulated vehicles joining at once, and what the manager costs.

    python -m fleet.manager.measure --count 50 [--plant ontology/examples/agv-fleet.ttl] [--work DIR]

It copies the plant onto free ports, starts a local agent per machine and applies the plant
(``engine.local_plant``), starts ``python -m fleet.manager`` on it, then ``python -m fleet.sim
--count N``; it waits until the manager's status shows every vehicle with ``readySeconds``
(measured by the manager from the arrival of the vehicle's ONLINE), samples the manager's CPU time
and RSS from /proc, checks that a plan made afterwards is empty, and tears everything down.
Prints JSON. Linux only; needs the loopback addresses of the plant (127.0.0.2, ...).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from engine import process
from engine.local_plant import LocalPlant, copy_on_free_ports
from engine.pipeline import run_pipeline

ROOT = Path(__file__).resolve().parents[2]
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def _status(data: Path) -> dict[str, Any]:
    try:
        return json.loads((data / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def measure(count: int, plant_source: Path, work: Path, deadline: float) -> dict[str, Any]:
    work.mkdir(parents=True, exist_ok=True)
    plant_file = work / "plant.ttl"
    ports = copy_on_free_ports(plant_source, plant_file)
    data, logs = work / "fleet-data", work / "logs"
    manager = sim = None
    with LocalPlant.start([plant_file], work / "agents") as plant:
        try:
            if not plant.apply().ok:
                raise RuntimeError("the plant did not apply")
            manager = process.spawn([sys.executable, "-m", "fleet.manager", plant_file, "--data-dir", data,
                                     "--agents", plant.agents.agents_file], log_dir=logs, name="fleet-manager", cwd=ROOT)
            process.wait_until(lambda: (s := _status(data)).get("manager", {}).get("connected")
                               and (s.get("lastReconcile") or {}).get("ok"), 60.0, 0.05,
                               what="the fleet manager", child=manager)
            cpu0, began = cpu_seconds(manager.pid), time.monotonic()
            mqtt_port = ports.get("fleet-mqtt") or next(iter(ports.values()))
            sim = process.spawn([sys.executable, "-m", "fleet.sim", "--broker", f"127.0.0.2:{mqtt_port}",
                                 "--count", str(count), "--manufacturer", "measure", "--serial-prefix", "m-",
                                 "--state-interval", "5"], log_dir=logs, name="fleet-sim", cwd=ROOT)

            def all_ready() -> list[dict[str, Any]] | None:
                rows = [v for v in _status(data).get("vehicles", []) if v["manufacturer"] == "measure"]
                return rows if len(rows) == count and all(v["readySeconds"] is not None for v in rows) else None
            rows = process.wait_until(all_ready, deadline, 0.05, what=f"{count} vehicles ready", child=manager)
            took = time.monotonic() - began
            cpu, rss = cpu_seconds(manager.pid) - cpu0, rss_mib(manager.pid)
            ready = sorted(v["readySeconds"] for v in rows)
            runs = [line.split("reconcile: ", 1)[1][:80] for line in manager.log_path.read_text().splitlines()
                    if "reconcile: " in line][1:]
            files = [plant_file, *sorted((data / "discovered").glob("*.ttl"))]
            after = run_pipeline(files, plant.directory).plan
            return {"vehicles": count, "all_ready_s": round(took, 3),
                    "online_to_ready_s": {"min": ready[0], "median": statistics.median(ready), "max": ready[-1]},
                    "reconcile_runs": runs, "discovered_files": len(files) - 1,
                    "plan_after_empty": bool(after is not None and after.empty),
                    "manager_cpu_s": round(cpu, 2), "manager_rss_mib": round(rss, 1),
                    "manager_cpu_ms_per_vehicle": round(1000 * cpu / count, 1)}
        finally:
            if sim is not None:
                process.stop(sim, grace=15.0)
            if manager is not None:
                process.stop(manager, grace=15.0)
            files = [plant_file, *sorted((data / "discovered").glob("*.ttl"))]
            destroy = run_pipeline(files, plant.directory, destroy=True)
            if destroy.plan is not None and destroy.desired is not None and not destroy.plan.empty:
                from engine.apply import apply

                apply(destroy.plan, destroy.desired, plant.directory, destroy=True)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m fleet.manager.measure", description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=10)
    p.add_argument("--plant", type=Path, default=ROOT / "ontology" / "examples" / "agv-fleet.ttl")
    p.add_argument("--work", type=Path, default=None, help="working folder (default: a new temporary one)")
    p.add_argument("--deadline", type=float, default=300.0)
    args = p.parse_args(argv)
    if not 1 <= args.count <= 50:
        print(f"error: --count {args.count}: from 1 to 50 (the simulator's default map has 50 parking spots)",
              file=sys.stderr)
        return 2
    work = args.work or Path(tempfile.mkdtemp(prefix="plantkg-plug-and-play-"))
    print(json.dumps(measure(args.count, args.plant, work, args.deadline), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

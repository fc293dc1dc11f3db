"""Benchmark: AGVs joining a plant by plug and play, from ``connection: ONLINE`` to ready for tasks.

For each fleet size N (default 1, 10, 50): a fresh copy of ``ontology/examples/agv-fleet.ttl`` on
free ports is applied through local agents (Mosquitto, the context broker, the mqtt-ngsi bridge),
the fleet manager (``python -m fleet.manager``) starts on it, then ``python -m fleet.sim --count
N`` connects N simulated VDA 5050 vehicles at once. Measured:

- per vehicle, ``readySeconds`` from the manager's ``status.json``: from the ONLINE that made the
  vehicle known until the reconcile that applied its topics and bridge routes finished (its
  factsheet asked and received, the Turtle written, the plant validated, reasoned, planned and
  applied) — p50, p99, max;
- the wall time from starting the simulator until every vehicle is ready, and how many
  reconciles that took (joins close together share one);
- the fleet manager's CPU seconds and RSS growth per joined vehicle, and its CPU per vehicle per
  second of steady state afterwards (state messages every ``--state-interval`` s);
- checks: every vehicle discovered exactly once (one file each), and a plan of the plant with the
  discovered files has no changes afterwards.

Baseline, measured in the same run on the same Mosquitto and simulator: the *floor* of any plug
and play — a bare VDA 5050 master that answers a vehicle's ONLINE with a ``factsheetRequest`` and
times the factsheet's arrival. ``vs floor`` is the join p50 over that floor's p50: what deriving
and applying the vehicle's channels through the knowledge graph costs on top of merely learning
what the vehicle is.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from benchmarks.common import RESULTS, ROOT, command_line, cpu_seconds, machine, summarize, write_results
from engine import process
from engine.demo.local_plant import LocalPlant, copy_on_free_ports
from fleet.vda5050 import topics
from fleet.vda5050.headers import HeaderCounter
from fleet.vda5050.messages import Action, BlockingType, InstantActions

EXAMPLE = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
MQTT_BROKER_ID = "fleet-mqtt"
MQTT_HOST = "127.0.0.2"  # the example's Mosquitto machine
PAGE = os.sysconf("SC_PAGE_SIZE")



def rss_mib(pid: int) -> float:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * PAGE / 2**20


def read_status(data: Path) -> dict[str, Any]:
    try:
        return json.loads((data / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def mqtt_port(ports: dict[str, int]) -> int:
    return ports[MQTT_BROKER_ID]


def floor_run(port: int, logs: Path, repeats: int) -> list[float]:
    """ONLINE -> factsheet received, answered by a bare master, one fresh vehicle at a time."""
    seen: dict[tuple[str, str], float] = {}
    done: dict[tuple[str, str], float] = {}
    lock = threading.Lock()
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-floor-{os.getpid()}")

    def on_message(_c: mqtt.Client, _u: object, msg: mqtt.MQTTMessage) -> None:
        now = time.perf_counter()
        if msg.retain:
            return  # an older vehicle's retained state, not a join
        vt = topics.parse(msg.topic)
        key = (vt.manufacturer, vt.serial)
        if vt.subtopic.value == "connection":
            if json.loads(msg.payload).get("connectionState") != "ONLINE":
                return
            with lock:
                if key in seen:
                    return
                seen[key] = now
            header = HeaderCounter(key[0], key[1]).next("instantActions")
            body = InstantActions((Action("factsheetRequest", uuid.uuid4().hex, BlockingType.NONE),))
            client.publish(topics.topic(key[0], key[1], "instantActions"), json.dumps(body.to_json(header)), qos=0)
        elif vt.subtopic.value == "factsheet":
            with lock:
                if key in seen and key not in done:
                    done[key] = now

    client.on_message = on_message
    client.connect(MQTT_HOST, port)
    client.subscribe([(topics.subscription("connection"), 1), (topics.subscription("factsheet"), 0)])
    client.loop_start()
    try:
        for i in range(repeats):
            prefix = f"floor{i}x"
            sim = process.spawn([sys.executable, "-m", "fleet.sim", "--broker", f"{MQTT_HOST}:{port}",
                                 "--count", "1", "--manufacturer", "bench", "--serial-prefix", prefix],
                                log_dir=logs, name=f"floor-sim-{i}", cwd=ROOT)
            try:
                process.wait_until(lambda: len(done) > i, 30, 0.005, what="the factsheet", child=sim)
            finally:
                process.stop(sim)
    finally:
        client.loop_stop()
        client.disconnect()
    return [done[k] - seen[k] for k in done]


def write_map(path: Path, vehicles: int) -> Path:
    """A hall with a parking spot per vehicle (the default map has 50), 2 m apart in rows of 50."""
    rows = (vehicles + 49) // 50
    stations = [{"name": f"park-{i + 1}", "x": 2.0 + 2.0 * (i % 50), "y": 2.0 + 2.0 * (i // 50)}
                for i in range(vehicles)]
    stations.append({"name": "charger-1", "x": 1.0, "y": 1.0, "charger": True})
    path.write_text(json.dumps({"mapId": "bench-hall", "width": 104.0, "height": 4.0 + 2.0 * rows,
                                "stations": stations}))
    return path


def join_run(work: Path, count: int, state_interval: float, settle: float) -> dict[str, Any]:
    """One fleet size on a fresh plant: the manager, then ``count`` vehicles at once."""
    work.mkdir(parents=True, exist_ok=True)
    plant_file = work / "agv-fleet.ttl"
    ports = copy_on_free_ports(EXAMPLE, plant_file)
    data, logs = work / "fleet-data", work / "logs"
    with LocalPlant.start([plant_file], work / "plant") as plant:
        result = plant.apply()
        if not result.ok:
            raise RuntimeError(f"the plant did not apply: {result}")
        manager = process.spawn([sys.executable, "-m", "fleet.manager", plant_file, "--data-dir", data,
                                 "--agents", plant.agents.agents_file], log_dir=logs, name="manager", cwd=ROOT)
        sim: process.Child | None = None
        try:
            process.wait_until(lambda: (read_status(data).get("lastReconcile") or {}).get("ok")
                               and read_status(data).get("manager", {}).get("connected"),
                               120, 0.05, what="the fleet manager to start", child=manager)
            cpu0, rss0 = cpu_seconds(manager.pid), rss_mib(manager.pid)
            started = time.monotonic()
            sim = process.spawn([sys.executable, "-m", "fleet.sim", "--broker", f"{MQTT_HOST}:{mqtt_port(ports)}",
                                 "--count", str(count), "--manufacturer", "bench", "--serial-prefix", "join",
                                 "--rate", "1", "--state-interval", str(state_interval),
                                 "--map", str(write_map(work / "map.json", count))],
                                log_dir=logs, name="sim", cwd=ROOT)

            def ready() -> list[dict[str, Any]] | None:
                rows = [v for v in read_status(data).get("vehicles", [])
                        if v.get("manufacturer") == "bench" and v.get("readySeconds") is not None]
                return rows if len(rows) >= count else None

            rows = process.wait_until(ready, 60 + count * 2.0, 0.05, what=f"{count} vehicles ready", child=manager)
            wall = time.monotonic() - started
            cpu1, rss1 = cpu_seconds(manager.pid), rss_mib(manager.pid)
            reconciles = _reconciles(data, logs)
            end = time.monotonic() + settle
            process.wait_until(lambda: time.monotonic() >= end, settle + 5, 0.25, what="the steady-state window")
            cpu2 = cpu_seconds(manager.pid)
            files = sorted((data / "discovered").glob("*.ttl"))
            plant.files = [plant_file, *files]
            after = plant.plan()
        finally:
            if sim is not None:
                process.stop(sim)
            process.stop(manager)
    bench_files = [f for f in files if f.name.startswith("bench--")]
    return {
        "count": count,
        "ready": summarize([r["readySeconds"] for r in rows]),
        "wall_s": wall,
        "reconciles": reconciles,
        "discovered_files": len(bench_files),
        "distinct_vehicles": len({r["serial"] for r in rows}),
        "plan_after_empty": after.empty,
        "cpu_s_per_vehicle_join": (cpu1 - cpu0) / count,
        "rss_mib_before": rss0,
        "rss_mib_per_vehicle": (rss1 - rss0) / count,
        "cpu_ms_per_vehicle_s_steady": (cpu2 - cpu1) / settle / count * 1000,
    }


def _reconciles(data: Path, logs: Path) -> int | None:
    """How many reconciles the manager logged (its log says one line per run)."""
    try:
        text = (logs / "manager.log").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    return sum(1 for line in text.splitlines() if "reconcile" in line and ("applied" in line or "no changes" in line))


def to_markdown(data: dict[str, Any]) -> str:
    floor = data["floor"]["p50"]
    lines = [
        "# fleet join: connection ONLINE -> ready for tasks (plug and play)",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']} · floor (ONLINE -> factsheet "
        f"received by a bare VDA 5050 master, same broker, {data['floor']['n']} runs): "
        f"p50 {floor:.1f} ms, max {data['floor']['max']:.1f} ms.",
        "",
        "| vehicles | ready p50 | p99 | max | vs floor (p50) | all ready (wall) | discovered once | plan after | manager CPU/vehicle (join) | RSS/vehicle | steady CPU/vehicle |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in data["rows"]:
        ready = r["ready"]
        once = "yes" if r["distinct_vehicles"] == r["count"] == r["discovered_files"] else \
            f"no ({r['discovered_files']} files, {r['distinct_vehicles']} vehicles)"
        lines.append(
            f"| {r['count']} | {ready['p50']:.0f} ms | {ready['p99']:.0f} ms | {ready['max']:.0f} ms | "
            f"{ready['p50'] / floor:.1f}× | {r['wall_s']:.2f} s | {once} | "
            f"{'no changes' if r['plan_after_empty'] else 'CHANGES'} | {r['cpu_s_per_vehicle_join'] * 1000:.0f} ms | "
            f"{r['rss_mib_per_vehicle']:.2f} MiB | {r['cpu_ms_per_vehicle_s_steady']:.2f} ms/s |")
    lines += ["", "Goal (issue 11): < 1 s from ONLINE to ready for one vehicle, excluding any Kafka start."]
    one = next((r for r in data["rows"] if r["count"] == 1), None)
    if one is not None:
        met = one["ready"]["max"] < 1000
        lines.append(f"Measured for one vehicle: max {one['ready']['max']:.0f} ms — goal {'met' if met else 'NOT met'}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 10, 50])
    parser.add_argument("--floor-runs", type=int, default=5)
    parser.add_argument("--state-interval", type=float, default=5.0)
    parser.add_argument("--settle", type=float, default=10.0, help="seconds of steady state measured")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    info = machine()
    rows = []
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-fleet-") as tmp:
        work = Path(tmp)
        floor = _floor(work, args.floor_runs)
        for count in args.counts:
            run_dir = work / f"n{count}"
            rows.append(join_run(run_dir, count, args.state_interval, args.settle))
            shutil.rmtree(run_dir, ignore_errors=True)
    data = {"command": command_line("benchmarks.bench_fleet_join", argv), "machine": info,
            "floor": summarize(floor), "rows": rows}
    write_results(args.out, "fleet_join", data, to_markdown(data))
    return 0


def _floor(work: Path, repeats: int) -> list[float]:
    """The floor on a bare Mosquitto of the same plant (applied, no fleet manager running)."""
    plant_file = work / "floor" / "agv-fleet.ttl"
    plant_file.parent.mkdir(parents=True)
    ports = copy_on_free_ports(EXAMPLE, plant_file)
    with LocalPlant.start([plant_file], work / "floor" / "plant") as plant:
        if not plant.apply().ok:
            raise RuntimeError("the floor's plant did not apply")
        return floor_run(mqtt_port(ports), work / "floor" / "logs", repeats)


if __name__ == "__main__":
    raise SystemExit(main())

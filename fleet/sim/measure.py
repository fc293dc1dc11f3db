"""Measures what ``python -m fleet.sim`` costs: CPU % and RSS of the simulator process, and the
message rates it really achieves, while every vehicle drives laps.

    python -m fleet.sim.measure --broker 127.0.0.1:1883 --count 50 --rate 10 --state-interval 0.1 --duration 30

Needs a running MQTT broker (it measures the simulator, not the broker). It starts the simulator,
waits until every vehicle is ONLINE, sends each one an order of laps around its parking spot (so
the figures are for moving vehicles), lets it run ``--warmup`` s, then samples
``/proc/<pid>/stat`` (user+system time) and ``/proc/<pid>/status`` (VmRSS) every second for
``--duration`` s and counts the state/visualization messages a subscriber receives. Prints JSON.
Linux only (reads /proc).
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from fleet.sim import map as site_map
from fleet.vda5050 import topics
from fleet.vda5050.headers import HeaderCounter
from fleet.vda5050.messages import Edge, Node, NodePosition, Order

TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


def laps(x: float, y: float, map_id: str, count: int) -> Order:
    corners = [(x, y), (x + 1.0, y), (x + 1.0, y + 1.0), (x, y + 1.0)]
    points = [corners[i % 4] for i in range(4 * count + 1)]
    nodes = tuple(Node(f"c{i % 4}", 2 * i, True, (), NodePosition(px, py, map_id)) for i, (px, py) in enumerate(points))
    edges = tuple(Edge(f"e{i}", 2 * i + 1, nodes[i].node_id, nodes[i + 1].node_id) for i in range(len(nodes) - 1))
    return Order("laps", 0, nodes, edges)


def wait(predicate, deadline: float, what: str) -> None:
    end = time.monotonic() + deadline
    while not predicate():
        if time.monotonic() > end:
            raise SystemExit(f"timed out after {deadline} s waiting for {what}")
        time.sleep(0.05)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m fleet.sim.measure")
    p.add_argument("--broker", default="127.0.0.1:1883")
    p.add_argument("--count", type=int, default=50)
    p.add_argument("--rate", type=float, default=10.0)
    p.add_argument("--state-interval", type=float, default=0.1)
    p.add_argument("--tick", type=float, default=0.05)
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--warmup", type=float, default=3.0)
    p.add_argument("--manufacturer", default="bench")
    args = p.parse_args(argv)
    host, port = args.broker.rsplit(":", 1)

    counts: Counter[str] = Counter()
    online: set[str] = set()
    lock = threading.Lock()

    def on_message(_c, _u, m) -> None:
        parsed = topics.parse(m.topic)
        with lock:
            counts[parsed.subtopic.value] += 1
            if parsed.subtopic.value == "connection" and b'"ONLINE"' in m.payload:
                online.add(parsed.serial)

    sub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"fleet-measure-{os.getpid()}")
    sub.on_message = on_message
    sub.on_connect = lambda c, *_: c.subscribe(f"uagv/v2/{topics.check_level('manufacturer', args.manufacturer)}/+/+", qos=0)
    sub.connect(host, int(port))
    sub.loop_start()
    cmd = [sys.executable, "-m", "fleet.sim", "--broker", args.broker, "--count", str(args.count),
           "--manufacturer", args.manufacturer, "--serial-prefix", "b-", "--rate", str(args.rate),
           "--state-interval", str(args.state_interval), "--tick", str(args.tick)]
    sim = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)  # noqa: S603
    try:
        wait(lambda: len(online) >= args.count, 60, f"{args.count} vehicles ONLINE")
        site = site_map.default_map()
        # a 1 m side takes ~5 s with the default limits (turn + drive): enough laps to keep
        # driving through the run, not more (a state lists every node still ahead)
        n_laps = max(1, int((args.warmup + args.duration) / 20) + 1)
        for i, spot in enumerate(site.parking()[: args.count]):
            serial = f"b-{i + 1:04d}"
            message = laps(spot.x, spot.y, site.map_id, n_laps).to_json(HeaderCounter(args.manufacturer, serial).next("order"))
            sub.publish(topics.topic(args.manufacturer, serial, "order"), json.dumps(message), qos=0)
        time.sleep(args.warmup)  # measured tool, not a test: a fixed warm-up is the point
        with lock:
            before = Counter(counts)
        cpu0, t0 = cpu_seconds(sim.pid), time.monotonic()
        rss = []
        while time.monotonic() - t0 < args.duration:
            time.sleep(1.0)
            rss.append(rss_mib(sim.pid))
        cpu1, t1 = cpu_seconds(sim.pid), time.monotonic()
        with lock:
            window = counts - before
        elapsed = t1 - t0
        result = {
            "command": " ".join(cmd[1:]),
            "vehicles": args.count, "duration_s": round(elapsed, 1), "order_nodes": 4 * n_laps + 1,
            "cpu_percent_of_one_core": round(100 * (cpu1 - cpu0) / elapsed, 1),
            "rss_mib_max": round(max(rss), 1), "rss_mib_last": round(rss[-1], 1),
            "state_per_s": round(window["state"] / elapsed, 1),
            "visualization_per_s": round(window["visualization"] / elapsed, 1),
            "cpus": os.cpu_count(), "loadavg_1min": round(os.getloadavg()[0], 2),
        }
    finally:
        sim.send_signal(signal.SIGTERM)
        code = sim.wait(timeout=30)
        sub.disconnect()
        sub.loop_stop()
    result["sim_exit_code"] = code
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())

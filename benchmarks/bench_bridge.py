"""Benchmark: each bridge against the raw paths it joins, measured in the same run, on loopback.

Senders and receivers are processes of their own, written in C where one exists
(:mod:`benchmarks.bridge_load`: ``mosquitto_pub``/``mosquitto_sub``, a Kafka producer and a Kafka
reader that never waits for a batch), so the measuring clients are not what is measured.

Paths (QoS 1 / ``acks=all``, 100-byte payloads carrying their index and send time):

- ``raw-mqtt``: mosquitto_pub -> one Mosquitto -> mosquitto_sub;
- ``raw-kafka``: producer -> Kafka -> reader;
- ``mosquitto-bridge``: mosquitto_pub -> Mosquitto A -> A's own bridge (rendered by
  engine.drivers.mosquitto.runtime) -> Mosquitto B -> mosquitto_sub;
- ``mqtt-kafka``: mosquitto_pub -> Mosquitto -> bridge worker -> Kafka -> reader;
- ``kafka-mqtt``: producer -> Kafka -> bridge worker -> Mosquitto -> mosquitto_sub.

Two phases per path: ``max`` sends as fast as the sender takes the messages (sustained msg/s =
distinct messages received / time from first send to last receive) and ``paced`` sends at
``--paced-rate`` msg/s (default 10,000: half of issue 16's goal of 20,000) for end-to-end latency
p50/p99. Lost and duplicate counts for every run; the bridge worker's CPU time per message.
Results: ``benchmarks/results/bridge.{json,md}``.

Usage: ``python -m benchmarks.bench_bridge [--messages 60000] [--paced-rate 10000]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks import bridge_load as load
from benchmarks import bridge_rig as rig
from benchmarks.common import RESULTS, command_line, cpu_seconds, machine, percentile, write_results
from engine import process
from engine.bridge_worker.config import Direction, Route, WorkerConfig
from engine.drivers.mosquitto.runtime import MosquittoBridge, MosquittoBridgeTopic

PATHS = ("raw-mqtt", "raw-kafka", "mosquitto-bridge", "mqtt-kafka", "kafka-mqtt")
BRIDGES = ("mosquitto-bridge", "mqtt-kafka", "kafka-mqtt")
IDLE_LIMIT = 10.0              # seconds without a new message before a run is declared over
GOAL_RATE = 20_000             # issue 16: msg/s sustained by each bridge
GOAL_P99_MS = 20.0             # issue 16: p99 end to end at half the goal rate


@dataclass
class BenchPath:
    """A sender, the receiver at the other end, and the processes whose CPU a run reports."""

    feeder: load.Feeder
    arrivals: load.Arrivals
    cpu: dict[str, int] = field(default_factory=dict)   # name -> pid


def run(path: BenchPath, n: int, rate: float | None) -> dict[str, object]:
    """Send ``n`` messages (at ``rate`` per second, or as fast as the sender takes them); wait
    until all arrived or none came for IDLE_LIMIT s; measure."""
    cpu_before = {name: cpu_seconds(pid) for name, pid in path.cpu.items()}
    path.arrivals.read()
    duplicates_before = path.arrivals.duplicates
    first, start_ns, _ = path.feeder.send(n, rate)
    count, last_change = 0, time.monotonic()

    def finished() -> bool:
        nonlocal count, last_change
        new = sum(1 for i in path.arrivals.read() if first <= i < first + n)
        if new:
            count, last_change = count + new, time.monotonic()
        return count >= n or time.monotonic() - last_change > IDLE_LIMIT

    process.wait_until(finished, 900.0, 0.02, what="the run to end")
    got = [path.arrivals.first[i] for i in range(first, first + n) if i in path.arrivals.first]
    cpu = {name: cpu_seconds(pid) - cpu_before[name] for name, pid in path.cpu.items()}
    latencies = sorted((r - s) / 1e6 for s, r in got)
    elapsed = (max(r for _, r in got) - start_ns) / 1e9 if got else float("nan")
    return {"messages": n, "offered_rate": rate, "msgs_per_s": len(got) / elapsed if got else 0.0,
            "p50_ms": percentile(latencies, 50) if latencies else None,
            "p99_ms": percentile(latencies, 99) if latencies else None,
            "lost": n - len(got), "duplicates": path.arrivals.duplicates - duplicates_before,
            "cpu_us_per_msg": {name: round(seconds * 1e6 / max(1, len(got)), 1) for name, seconds in cpu.items()}}


def warm_up(name: str, path: BenchPath) -> None:
    """Probe until one message comes through (the subscription or assignment is live), then
    send 200: connections, caches and the bridge link are warm and nothing is lost."""
    def through() -> bool:
        path.feeder.send(1, None)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            if path.arrivals.read():
                return True
            time.sleep(0.01)  # polling a file the receiver writes
        return False

    process.wait_until(through, 60.0, 0.0, what=f"the {name} path to carry a message")
    result = run(path, 200, None)
    if result["lost"]:
        raise RuntimeError(f"{name}: warm-up lost {result['lost']} of 200 messages")


def measure(n: int, paced_rate: float, work: Path) -> dict[str, object]:
    from tests.integration.conftest import start_kafka  # the project's one-node Kafka starter

    stops: list[Callable[[], object]] = []
    try:
        kafka = start_kafka(work / "kafka")
        stops.append(lambda: process.stop(kafka.child, grace=30.0))
        mq = rig.Mosquitto(work / "mq").start()
        stops.append(mq.stop)
        remote = rig.Mosquitto(work / "mq-b").start()
        stops.append(remote.stop)
        bridged = rig.Mosquitto(work / "mq-a", bridges=(MosquittoBridge(
            "bench-bridge", "127.0.0.1", remote.port, (MosquittoBridgeTopic("bench/nb", "out", 1),)),)).start()
        stops.append(bridged.stop)
        bootstrap = kafka.bootstrap_servers
        rig.create_topics(bootstrap, ["bench.raw", "bench.m2k", "bench.k2m"], 1)
        cfg = WorkerConfig("bench", "127.0.0.1", mq.port, bootstrap,
                           (Route("bench/m2k", "bench.m2k", Direction.MQTT_TO_KAFKA),
                            Route("bench/k2m", "bench.k2m", Direction.KAFKA_TO_MQTT)), work / "worker")
        worker = rig.start_worker(cfg)
        stops.append(lambda: process.stop(worker))
        rig.wait_ready(cfg, worker)
        pids = {"mosquitto": mq.child.pid, "kafka": kafka.child.pid}  # type: ignore[union-attr]
        paths = build_paths(work, mq, bridged, remote, bootstrap, worker.pid, pids, stops)
        for name, path in paths.items():
            warm_up(name, path)
        rows = [{"path": name, "phase": "max", **run(path, n, None)} for name, path in paths.items()]
        rows += [{"path": name, "phase": "paced", **run(path, n, paced_rate)} for name, path in paths.items()]
    finally:
        for stop in reversed(stops):
            stop()
    add_ratios(rows)
    return {"benchmark": "bridge", "machine": machine(), "messages": n, "paced_rate": paced_rate,
            "goals": goals(rows, paced_rate),
            "command": command_line("benchmarks.bench_bridge", sys.argv[1:] if __name__ == "__main__" else None),
            "rows": rows}


def build_paths(work: Path, mq: rig.Mosquitto, bridged: rig.Mosquitto, remote: rig.Mosquitto,
                bootstrap: str, worker_pid: int, pids: dict[str, int],
                stops: list[Callable[[], object]]) -> dict[str, BenchPath]:
    def mqtt_out(broker: rig.Mosquitto, topic: str, name: str) -> load.Feeder:
        feeder = load.mqtt_publisher(broker.host, broker.port, topic, f"bench-pub-{name}", work / f"{name}.pub.log")
        stops.append(feeder.close)
        return feeder

    def mqtt_in(broker: rig.Mosquitto, topic: str, name: str) -> load.Arrivals:
        receiver = load.mqtt_subscriber(broker.host, broker.port, topic, f"bench-sub-{name}", work / f"{name}.in")
        stops.append(receiver.stop)
        return load.Arrivals(receiver.out)

    def kafka_out(topic: str, name: str) -> load.Feeder:
        feeder = load.kafka_producer(bootstrap, topic, work / f"{name}.producer.log")
        stops.append(feeder.close)
        return feeder

    def kafka_in(topic: str, name: str) -> load.Arrivals:
        receiver = load.kafka_reader(bootstrap, topic, work / f"{name}.in")
        stops.append(receiver.stop)
        return load.Arrivals(receiver.out)

    return {
        "raw-mqtt": BenchPath(mqtt_out(mq, "bench/raw", "raw-mqtt"), mqtt_in(mq, "bench/raw", "raw-mqtt"),
                              {"mosquitto": pids["mosquitto"]}),
        "raw-kafka": BenchPath(kafka_out("bench.raw", "raw-kafka"), kafka_in("bench.raw", "raw-kafka"),
                               {"kafka": pids["kafka"]}),
        "mosquitto-bridge": BenchPath(mqtt_out(bridged, "bench/nb", "mosquitto-bridge"),
                                      mqtt_in(remote, "bench/nb", "mosquitto-bridge"),
                                      {"mosquitto A": bridged.child.pid,  # type: ignore[union-attr]
                                       "mosquitto B": remote.child.pid}),  # type: ignore[union-attr]
        "mqtt-kafka": BenchPath(mqtt_out(mq, "bench/m2k", "mqtt-kafka"), kafka_in("bench.m2k", "mqtt-kafka"),
                                {"worker": worker_pid, **pids}),
        "kafka-mqtt": BenchPath(kafka_out("bench.k2m", "kafka-mqtt"), mqtt_in(mq, "bench/k2m", "kafka-mqtt"),
                                {"worker": worker_pid, **pids}),
    }


def add_ratios(rows: list[dict[str, object]]) -> None:
    """Throughput against the raw path of the bridge's source side, same phase."""
    raw = {(r["path"], r["phase"]): r for r in rows if str(r["path"]).startswith("raw-")}
    for row in rows:
        base = raw.get(("raw-kafka" if row["path"] in ("raw-kafka", "kafka-mqtt") else "raw-mqtt", row["phase"]))
        if base is None:
            continue
        row["throughput_vs_raw"] = float(row["msgs_per_s"]) / float(base["msgs_per_s"])  # type: ignore[arg-type]
        if row["p50_ms"] is not None and base["p50_ms"] is not None:
            row["p50_added_ms"] = float(row["p50_ms"]) - float(base["p50_ms"])  # type: ignore[arg-type]


def goals(rows: list[dict[str, object]], paced_rate: float) -> list[dict[str, object]]:
    """Issue 16's bridge goals, per bridge, as ``plantkg-bench report`` lists them: the sustained
    rate with nothing lost or duplicated (max phase), and p99 at the paced rate."""
    by = {(r["path"], r["phase"]): r for r in rows}
    out: list[dict[str, object]] = []
    for name in BRIDGES:
        top, paced = by.get((name, "max")), by.get((name, "paced"))
        if top is None or paced is None:
            continue
        rate = float(top["msgs_per_s"])  # type: ignore[arg-type]
        out.append({"goal": f"bridge {name}: sustained msg/s, nothing lost or duplicated",
                    "measured": f"{rate:,.0f} msg/s ({top.get('throughput_vs_raw', float('nan')):.2f}x raw), "
                                f"{top['lost']} lost, {top['duplicates']} duplicates",
                    "target": f">= {GOAL_RATE:,}, 0, 0",
                    "met": rate >= GOAL_RATE and top["lost"] == 0 and top["duplicates"] == 0})
        p99 = paced["p99_ms"]
        out.append({"goal": f"bridge {name}: p99 end to end at {paced_rate:,.0f} msg/s",
                    "measured": "-" if p99 is None else f"{p99:.1f} ms ({paced['lost']} lost)",
                    "target": f"< {GOAL_P99_MS:.0f} ms",
                    "met": p99 is not None and float(p99) < GOAL_P99_MS and paced["lost"] == 0})  # type: ignore[arg-type]
    return out


def to_markdown(data: dict[str, object]) -> str:
    def ms(v: object) -> str:
        return "-" if v is None else f"{v:.2f}"

    lines = ["# bridge: throughput and latency of each bridge against the raw paths (same run)", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · {data['messages']} messages "
             f"per run, QoS 1 (Kafka: acks=all), {load.PAYLOAD_SIZE}-byte payloads; senders and receivers "
             f"are processes of their own (mosquitto_pub/mosquitto_sub, a Kafka producer and a reader that do "
             f"not wait for batches); `paced` sends at {data['paced_rate']:.0f} msg/s", "",
             "| path | phase | offered msg/s | msg/s | vs raw | p50 ms | p99 ms | lost | duplicates | CPU µs/msg |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:  # type: ignore[union-attr]
        offered = "max" if r["offered_rate"] is None else f"{r['offered_rate']:.0f}"
        cpu = ", ".join(f"{k} {v:.0f}" for k, v in r.get("cpu_us_per_msg", {}).items())
        ratio = f"{r['throughput_vs_raw']:.2f}" if "throughput_vs_raw" in r else "-"
        lines.append(f"| {r['path']} | {r['phase']} | {offered} | {r['msgs_per_s']:.0f} | {ratio} | "
                     f"{ms(r['p50_ms'])} | {ms(r['p99_ms'])} | {r['lost']} | {r['duplicates']} | {cpu} |")
    lines += ["", "| goal (issue 16) | measured | target | verdict |", "|---|---|---|---|"]
    for g in data["goals"]:  # type: ignore[union-attr]
        lines.append(f"| {g['goal']} | {g['measured']} | {g['target']} | {'met' if g['met'] else 'not met'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="bridge throughput and latency benchmark")
    parser.add_argument("--messages", type=int, default=60_000)
    parser.add_argument("--paced-rate", type=float, default=GOAL_RATE / 2)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if not 0 < args.messages <= 60_000:
        parser.error("--messages must be 1..60000 (mosquitto_pub -l tracks at most 65535 in flight)")
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-bridge-") as tmp:
        data = measure(args.messages, args.paced_rate, Path(tmp))
    data["command"] = command_line("benchmarks.bench_bridge", argv)
    write_results(args.out, "bridge", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: MQTT -> NGSI-v2 through the bridge worker at QoS 1, against the real context broker.

For each case, same run, same machine (Mosquitto, ``python -m engine.context_broker`` with a token,
the worker, all on loopback):

- ``direct``: upserts of one entity sent one after the other over one keep-alive connection by the
  worker's own HTTP client (no MQTT): the most one of the worker's sending lanes can do;
- ``worker, T topics``: N QoS-1 messages ``{"seq": i}`` published as fast as the publisher goes,
  spread over T topics (T entities, so up to T of the worker's 4 lanes send at once); msg/s =
  N / (time from the first publish to the worker's ``forwarded`` counter reaching N).

Usage: ``python -m benchmarks.bench_bridge_ngsi [--messages 10000] [--topics 1 4]``.
Results: ``benchmarks/results/bridge_ngsi.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import paho.mqtt.client as mqtt

from benchmarks.bridge_rig import Mosquitto, start_worker, wait_ready
from benchmarks.common import RESULTS, command_line, machine, write_results
from benchmarks.context_broker_rig import ContextBroker
from engine import process
from engine.bridge_worker.ngsi_client import NgsiClient
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiRoute, NgsiWorkerConfig
from engine.bridge_worker.ngsi_mapping import upsert_body
from engine.bridge_worker.stats import read_stats


def direct(cb: ContextBroker, count: int) -> float:
    """Sequential upserts over one connection; returns requests per second."""
    client = NgsiClient(cb.url, cb.token_file)
    began = time.monotonic()
    for i in range(count):
        client.upsert(upsert_body("urn:bench:direct", "Bench", json.dumps({"seq": i}).encode(), time.time()))
    elapsed = time.monotonic() - began
    client.close()
    return count / elapsed


def through_worker(folder: Path, mosquitto: Mosquitto, cb: ContextBroker, count: int, topics: int) -> dict:
    names = [f"bench/ngsi/{t}" for t in range(topics)]
    routes = tuple(NgsiRoute(n, f"urn:bench:{t}", "Bench", NgsiDirection.MQTT_TO_NGSI)
                   for t, n in enumerate(names))
    cfg = NgsiWorkerConfig(f"bench-{topics}", mosquitto.host, mosquitto.port, cb.url, routes,
                           folder / "worker", token_file=cb.token_file, stats_interval=0.05)
    child = start_worker(cfg)  # type: ignore[arg-type]
    try:
        wait_ready(cfg, child)  # type: ignore[arg-type]
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5)
        client.max_inflight_messages_set(1000)
        client.connect(mosquitto.host, mosquitto.port)
        client.loop_start()
        began = time.monotonic()
        infos = [client.publish(names[i % topics], json.dumps({"seq": i}), qos=1) for i in range(count)]
        process.wait_until(lambda: (s := read_stats(cfg.state_dir)) is not None
                           and s.forwarded_mqtt_to_ngsi >= count, 600.0, 0.01,
                           what=f"{count} messages forwarded", child=child)
        elapsed = time.monotonic() - began
        for info in infos:
            info.wait_for_publish(10)
        client.disconnect()
        client.loop_stop()
        stats = read_stats(cfg.state_dir)
        assert stats is not None
        return {"topics": topics, "seconds": elapsed, "msg_per_s": count / elapsed,
                "retried": stats.retried, "refused": stats.refused}
    finally:
        process.stop(child)


def to_markdown(data: dict) -> str:
    lines = [
        "# MQTT -> NGSI-v2 through the bridge worker (QoS 1)", "",
        f"`{data['command']}` — {data['messages']} messages per case; machine: "
        f"{data['machine']['cpus']} CPUs, load {data['machine']['load_average'][0]:.1f} at start, "
        f"commit {data['machine']['commit']}.", "",
        "| case | msg/s | retried | refused |", "|---|---|---|---|",
        f"| direct upserts, one connection (no MQTT) | {data['direct_per_s']:.0f} | - | - |",
    ]
    for row in data["rows"]:
        lines.append(f"| worker, {row['topics']} topic(s) | {row['msg_per_s']:.0f} | {row['retried']} | "
                     f"{row['refused']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=10_000)
    parser.add_argument("--topics", type=int, nargs="+", default=[1, 4])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    info = machine()
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-ngsi-") as tmp:
        mosquitto = Mosquitto(Path(tmp) / "mosquitto").start()
        cb = ContextBroker(Path(tmp) / "context-broker").start()
        try:
            per_s = direct(cb, args.messages)
            rows = [through_worker(Path(tmp) / f"w{t}", mosquitto, cb, args.messages, t) for t in args.topics]
        finally:
            cb.stop()
            mosquitto.stop()
    data = {"command": command_line("benchmarks.bench_bridge_ngsi", argv), "machine": info,
            "messages": args.messages, "direct_per_s": per_s, "rows": rows}
    write_results(args.out, "bridge_ngsi", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

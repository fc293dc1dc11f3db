"""Benchmark: the first paper's Table 1 on loopback — deploying a Mosquitto broker bare vs through
plantkg, each until a QoS-1 publish of a small message is acknowledged.

- ``bare``: render a mosquitto.conf, spawn mosquitto, poll (every 0.5 ms) until a QoS-1 publish
  of 512 bytes is acknowledged (PUBACK), stop it. What a person does by hand, at best.
- ``plantkg``: with one agent already running (as on a real plant), ``apply`` a one-broker plant
  through the engine (load, validate, reason, derive, observe the agent over HTTP, plan, PUT to
  the agent, which spawns mosquitto and waits for its health check), then the same acknowledged
  publish; then ``destroy`` (not timed). The engine runs in-process, as the dashboard will run it;
  the CLI adds an interpreter start (~0.6 s) on top.
- ``plantkg-dispatch``: the same apply with the plan already made — only the agent round trip
  and broker start — to show where the time goes.

Runs are interleaved so drift hits all alike. Results: ``benchmarks/results/deploy.{json,md}``,
with min, max, mean, standard deviation, p50, p99 and the ratio of means to bare.

Usage: ``python -m benchmarks.bench_deploy [--runs 50]``
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import paho.mqtt.client as mqtt

from benchmarks.common import RESULTS, machine, write_results
from engine import netutil, process
from engine.agent.local import start_local_agents
from engine.agents_config import AgentDirectory
from engine.apply import apply
from engine.mosquitto_runtime import MosquittoConfig, default_run_as, mosquitto_command, render_mosquitto_conf
from engine.parts import mosquitto_binary
from engine.pipeline import run_pipeline

HOST = "127.0.0.2"
PAYLOAD = b"x" * 512

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://w3id.org/plantkg/examples/bench#> .
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "bench" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {port} ; pk:hasTopic :t .
:t a pk:Topic ; pk:id "t" ; pk:name "bench.t" ; pk:qos 1 .
:r a pk:Resource ; pk:id "r" ; pk:name "publisher" ; pk:sendsTo :mqtt ; pk:publishes :t .
"""


def acked_publish(host: str, port: int, deadline: float = 10.0) -> None:
    """Connect and publish PAYLOAD at QoS 1 until the PUBACK arrives, polling every 0.5 ms."""
    end = time.monotonic() + deadline
    while True:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
        try:
            client.connect(host, port)
            info = client.publish("bench.t", PAYLOAD, qos=1)
            while not info.is_published():
                if client.loop(timeout=0.0005) != mqtt.MQTT_ERR_SUCCESS:
                    raise ConnectionError("lost")
                if time.monotonic() > end:
                    raise TimeoutError("no PUBACK")
            client.disconnect()
            return
        except (ConnectionError, OSError):
            if time.monotonic() > end:
                raise TimeoutError(f"mosquitto on {host}:{port} never acknowledged") from None
            time.sleep(0.0005)  # poll interval of the readiness check (a deadline bounds it)


def bare(work: Path) -> float:
    port = netutil.free_port(HOST)
    conf = work / "bare.conf"
    conf.write_text(render_mosquitto_conf(MosquittoConfig(HOST, port, work / "bare.log", default_run_as())))
    start = time.perf_counter()
    child = process.spawn(mosquitto_command(mosquitto_binary(), conf), log_dir=work, name="bare")
    try:
        acked_publish(HOST, port)
        return time.perf_counter() - start
    finally:
        process.stop(child)


def through_plantkg(work: Path, directory: AgentDirectory, dispatch_only: bool) -> float:
    port = netutil.free_port(HOST)
    plant = work / "plant.ttl"
    plant.write_text(PLANT.format(host=HOST, port=port))
    prepared = run_pipeline([plant], directory) if dispatch_only else None
    start = time.perf_counter()
    result = prepared or run_pipeline([plant], directory)
    assert result.plan is not None and result.desired is not None
    outcome = apply(result.plan, result.desired, directory)
    assert outcome.ok, outcome
    acked_publish(HOST, port)
    elapsed = time.perf_counter() - start
    gone = run_pipeline([plant], directory, destroy=True)
    assert gone.plan is not None and gone.desired is not None
    assert apply(gone.plan, gone.desired, directory, destroy=True).ok
    return elapsed


def stats(xs: list[float]) -> dict[str, float]:
    ms = sorted(x * 1000 for x in xs)
    return {"n": len(ms), "min": ms[0], "max": ms[-1], "mean": statistics.fmean(ms),
            "stdev": statistics.stdev(ms) if len(ms) > 1 else 0.0,
            "p50": ms[len(ms) // 2], "p99": ms[min(len(ms) - 1, int(len(ms) * 0.99))]}


def measure(runs: int) -> dict[str, object]:
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-") as tmp:
        work = Path(tmp)
        agents = start_local_agents([HOST], work / "agents")
        try:
            directory = AgentDirectory.load(agents.agents_file)
            times: dict[str, list[float]] = {"bare": [], "plantkg": [], "plantkg-dispatch": []}
            through_plantkg(work, directory, False)  # warm-up: imports, JIT-free but caches
            for _ in range(runs):
                times["bare"].append(bare(work))
                times["plantkg"].append(through_plantkg(work, directory, False))
                times["plantkg-dispatch"].append(through_plantkg(work, directory, True))
        finally:
            agents.stop()
    table = {k: stats(v) for k, v in times.items()}
    base = table["bare"]["mean"]
    for row in table.values():
        row["ratio"] = row["mean"] / base
    return {"benchmark": "deploy", "machine": machine(), "runs": runs,
            "command": "python -m benchmarks.bench_deploy " + " ".join(sys.argv[1:]), "ms": table,
            "paper": {"bare_ms": 23.9, "tool_cable_ms": 80.1, "ratio": 3.35}}


def to_markdown(data: dict[str, object]) -> str:
    lines = ["# deploy: Mosquitto until the first QoS-1 PUBACK, bare vs through plantkg (Table 1)", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · {data['runs']} runs each, interleaved", "",
             "| path | min ms | max ms | mean ms | stdev ms | p50 ms | p99 ms | mean / bare |",
             "|---|---|---|---|---|---|---|---|"]
    for name, r in data["ms"].items():  # type: ignore[union-attr]
        lines.append(f"| {name} | {r['min']:.1f} | {r['max']:.1f} | {r['mean']:.1f} | {r['stdev']:.1f} | "
                     f"{r['p50']:.1f} | {r['p99']:.1f} | {r['ratio']:.2f} |")
    lines += ["", "The paper (its hardware, over cable): 23.9 ms bare, 80.1 ms through its tool (3.35x)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="deployment latency benchmark (Table 1)")
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = measure(args.runs)
    write_results(args.out, "deploy", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: the first paper's load test (its Fig. 12) and what the paper left open.

For each number of Mosquitto brokers N (default 1, 5, 10, 25, 50, 100), on one machine:

1. **Bring-up.** By hand (baseline), the fastest way: render N configs, spawn N mosquitto from 8
   threads, poll all at once (``benchmarks.mqtt_ready``: a non-blocking connect to every broker, a
   raw CONNECT as soon as one accepts, one select for all; a refusing one is tried again 0.25 ms
   later) until every one answers with a CONNACK; SIGTERM all, wake all (a connection to each port, opened at once), then wait for all (``engine.process.stop_each``). Through plantkg: write an N-broker plant
   (``benchmarks.synthetic.mosquitto_plant``, free ports) and run one ``apply`` against one local
   agent (load, validate, reason, derive, observe, plan, dispatch: one batch request, in which the
   agent starts every broker at once and waits for their health checks together); later one
   ``destroy`` (likewise one batch: every broker stopped at once). Both use the desired-state cache
   as ``plantkg apply``/``destroy`` do: a new plant is derived, the destroy of the plant just
   applied finds it in the cache. Both the same run, interleaved; the ratio is
   the figure. Also the resident memory (RSS) of each idle broker and of the agent holding N.
2. **Load.** With the N brokers up, bursts of M messages (default 100…500) sent as simultaneously
   as one thread can (``benchmarks.mqtt_burst``), ``spread`` and ``one-to-one``: per message the
   publish → PUBACK and publish → delivery latency; each cell repeated, so the spread between
   repeats says how much of a difference between cells is noise.
3. **Message size.** For some N, bursts of ``--size-messages`` messages of 100 B, 10 KB, 1 MB.
4. **TCP_NODELAY.** For some N (``--nagle-brokers``), the matrix (spread) against brokers spawned
   by hand with the agent's config, as is and with ``set_tcp_nodelay true``: a PUBACK held back by
   Nagle's algorithm until the client's delayed ACK (~40 ms on Linux) shows as a stall.
5. **Another broker.** One Kafka broker brought up by one apply, bursts of ``--kafka-messages``
   (produce → acknowledged with acks=all, produce → consumed; ``benchmarks.kafka_burst``) and the
   same message sizes; the JVM's RSS.

Results: ``benchmarks/results/load.{json,md,csv}`` (the CSV has one row per burst) and the plots
``load.png``, ``load-nodelay.png``, ``load-sizes.png``, ``load-bringup.png``.

Usage: ``python -m benchmarks.bench_load [--brokers 1 5 10 25 50 100] [--messages 100 200 300 400 500]
[--repeat 3] [--deploy-repeat 3] [--sizes 100 10000 1000000] [--size-brokers 1 10 100]``
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from confluent_kafka import KafkaException

from benchmarks import mqtt_ready, plots, synthetic
from benchmarks.bench_deploy import KAFKA_PLANT
from benchmarks.bridge_burst import BridgeBurstRig
from benchmarks.kafka_burst import KafkaRig
from benchmarks.common import RESULTS, command_line, machine, summarize, write_results
from benchmarks.mqtt_burst import MODES, BurstResult, BurstRig
from engine import netutil, process
from engine.agent.local import start_local_agents
from engine.agents_config import AgentDirectory
from engine.apply import apply
from engine.incremental.desired_cache import DesiredCache
from engine.drivers.mosquitto.runtime import MosquittoConfig, default_run_as, mosquitto_command, render_mosquitto_conf
from engine.parts import mosquitto_binary
from engine.pipeline import run_pipeline

HOST = "127.0.0.2"
READY_S = 60.0
SPAWN_THREADS = 8
#: One Mosquitto bridged to one Kafka on the same machine; the topic's name is valid for both. Both
#: are open (pk:allowAnonymous true; closed is the default): the bursts publish and read anonymously.
BRIDGE_PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://w3id.org/plantkg/examples/bench-bridge#> .
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "bench-mqtt" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {mqtt_port} ; pk:allowAnonymous true ; pk:hasTopic :t ; pk:bridgesTo :kafka .
:kafka a pk:Broker ; pk:id "kafka" ; pk:name "bench-kafka" ; pk:brokerType "kafka" ;
    pk:ip "{host}" ; pk:port {kafka_port} ; pk:allowAnonymous true ; pk:hasTopic :t .
:t a pk:Topic ; pk:id "t" ; pk:name "bench.bridge" ; pk:qos 1 ; pk:partitions 1 .
"""


def wait_all_ready(brokers: list[tuple[str, int]], deadline: float = READY_S) -> None:
    """Poll every pending broker at once (raw CONNECT, one select) until all answer a CONNACK."""
    mqtt_ready.wait_all_ready(brokers, deadline)


def _hand_confs(n: int, work: Path, nodelay: bool = True) -> tuple[list[int], list[Path]]:
    """n configs as the agent renders them, on free ports, each with persistence in a folder of its
    own (the agent's safe default: a broker stopped by hand saves its state as plantkg's do; without
    it the hand baseline skipped that write and the ratio compared two different brokers);
    ``nodelay=False`` turns Mosquitto's TCP_NODELAY back to its own default (off), which plantkg's
    rendering sets on."""
    ports = netutil.free_ports(n, HOST)
    confs = []
    for i, port in enumerate(ports):
        conf = work / f"hand-{i}.conf"
        data = work / f"hand-{i}-data"
        data.mkdir(exist_ok=True)
        text = render_mosquitto_conf(MosquittoConfig(HOST, port, work / f"hand-{i}.log", default_run_as(),
                                                     data_dir=data))
        if not nodelay:
            assert "set_tcp_nodelay true\n" in text, "the rendering no longer sets TCP_NODELAY"
            text = text.replace("set_tcp_nodelay true\n", "set_tcp_nodelay false\n")
        conf.write_text(text)
        confs.append(conf)
    return ports, confs


def _spawn_all(confs: list[Path], work: Path, children: list[process.Child]) -> None:
    """Spawn one mosquitto per config from ``SPAWN_THREADS`` threads: a spawn waits for its child
    to exec, and those waits overlap."""
    argvs = [mosquitto_command(mosquitto_binary(), conf) for conf in confs]
    with ThreadPoolExecutor(max_workers=SPAWN_THREADS) as pool:
        children.extend(pool.map(lambda i: process.spawn(argvs[i], log_dir=work, name=f"hand-{i}"),
                                 range(len(argvs))))


def by_hand(n: int, work: Path) -> tuple[float, float]:
    """The fastest way by hand: spawn n mosquitto in parallel, poll all at once until every one
    answers a CONNECT; then SIGTERM all, wake all (a connection to each port, all opened at once:
    Mosquitto 2.0 masks its signals while it waits in epoll up to 100 ms, and plantkg's agent wakes
    its brokers so too) and wait for all. Returns (up s, down s)."""
    ports, confs = _hand_confs(n, work)
    children: list[process.Child] = []
    try:
        start = time.perf_counter()
        _spawn_all(confs, work, children)
        wait_all_ready([(HOST, p) for p in ports])
        up = time.perf_counter() - start
        start = time.perf_counter()
        outcomes = process.stop_each(children, [10.0] * len(children),
                                     lambda: netutil.touch_all([(HOST, p) for p in ports]))
        down = time.perf_counter() - start
        failed = [o for o in outcomes if isinstance(o, Exception)]
        if failed:
            raise failed[0]
        return up, down
    finally:
        for child in children:
            process.stop(child)


def through_plantkg(plant: Path, directory: AgentDirectory, destroy: bool = False,
                    parallelism: int = 8, cache: DesiredCache | None = None) -> dict[str, float]:
    """One ``apply`` (or ``destroy``) of the plant: total seconds and the pipeline's stages.
    ``cache``: the desired-state cache, as ``plantkg apply``/``destroy`` use it (a destroy of the
    plant just applied finds it there; a new plant is derived)."""
    start = time.perf_counter()
    result = run_pipeline([plant], directory, destroy=destroy, cache=cache)
    assert result.plan is not None and result.desired is not None, "the load plant is invalid"
    planned = time.perf_counter()
    outcome = apply(result.plan, result.desired, directory, destroy=destroy, parallelism=parallelism)
    if not outcome.ok:
        problems = [f"{o.change.address}: {o.status.value}: {o.error}" for o in (*outcome.failed, *outcome.skipped)]
        problems += [f"{u.address}: {u.detail}" for u in outcome.unexpected]
        raise RuntimeError(f"{'destroy' if destroy else 'apply'} of {plant} did not converge "
                           f"({len(problems)} problem(s)): " + "; ".join(problems[:5]))
    end = time.perf_counter()
    return {"total": end - start, "pipeline": planned - start, "dispatch": end - planned,
            **{f"stage_{k}": v for k, v in result.timings.items()}}


def rss_kb(pid: int) -> int:
    """Resident memory of a process, from /proc (0 if it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def children_of(pid: int) -> list[int]:
    """Pids whose parent is ``pid``."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def file_costs(folder: Path, count: int = 300) -> dict[str, float]:
    """What this machine's file system charges for what an agent's broker start does to its state
    folder (3 folders made, 4 files written whole: spec.json, the rendered config, pid.json,
    topics.json; the log opened), measured in ``folder`` (where the agents keep their state):
    µs of wall and of this process's kernel CPU per folder made and per whole-file write
    (engine.whole_file.write_whole: a new file aside, then renamed). The by-hand baseline makes
    its folders and configs before its clock starts, so this is the part of the apply / hand
    ratio that is the file system's."""
    from engine.whole_file import write_whole  # noqa: PLC0415

    root = folder / "file-costs"
    root.mkdir(parents=True, exist_ok=True)
    out: dict[str, float] = {}
    for what, step in (("mkdir", lambda i: (root / f"d{i}").mkdir()),
                       ("write_whole", lambda i: write_whole(root / f"f{i}.json", '{"x": 1}\n'))):
        cpu, start = os.times(), time.perf_counter()
        for i in range(count):
            step(i)
        wall, sys_cpu = time.perf_counter() - start, os.times().system - cpu.system
        out[f"{what}_us"], out[f"{what}_sys_us"] = wall / count * 1e6, sys_cpu / count * 1e6
    shutil.rmtree(root)
    return out


def memory(agent_pid: int) -> dict[str, float]:
    brokers = [rss_kb(p) for p in children_of(agent_pid)]
    return {"agent_rss_mb": rss_kb(agent_pid) / 1024, "brokers": len(brokers),
            "broker_rss_mb_mean": statistics.fmean(brokers) / 1024 if brokers else 0.0,
            "broker_rss_mb_max": max(brokers, default=0) / 1024}


def _cell(results: list[BurstResult], study: str) -> dict[str, object]:
    acks = [x for r in results for x in r.ack_s]
    deliveries = [x for r in results for x in r.delivery_s]
    return {"study": study, "brokers": results[0].brokers, "messages": results[0].messages, "size": results[0].size,
            "mode": results[0].mode, "repeats": len(results), "lost": sum(r.lost for r in results),
            "send_ms": statistics.fmean(r.send_s for r in results) * 1000,
            "ack": summarize(acks), "delivery": summarize(deliveries),
            "ack_mean_of_repeats_stdev": _stdev([statistics.fmean(r.ack_s) * 1000 for r in results if r.ack_s]),
            "delivery_mean_of_repeats_stdev": _stdev([statistics.fmean(r.delivery_s) * 1000 for r in results
                                                      if r.delivery_s])}


def _stdev(xs: list[float]) -> float:
    return statistics.stdev(xs) if len(xs) > 1 else 0.0


def _bursts(rig: BurstRig, study: str, messages: list[int], sizes: list[int], modes: tuple[str, ...],
            repeat: int, raw: list[BurstResult]) -> list[dict[str, object]]:
    cells = []
    for size in sizes:
        for mode in modes:
            for m in messages:
                runs = [rig.burst(m, size, mode) for _ in range(repeat)]
                raw.extend(runs)
                cells.append(_cell(runs, study))
    return cells


def one_size(n: int, args: argparse.Namespace, work: Path, raw: list[BurstResult]) -> dict[str, object]:
    """Everything measured with N brokers (bring-up both ways, memory, load, sizes)."""
    agents = start_local_agents([HOST], work / f"agents-{n}")
    try:
        directory = AgentDirectory.load(agents.agents_file)
        agent_pid = agents.agents[HOST].child.pid
        idle_agent_mb = rss_kb(agent_pid) / 1024
        ups, downs, hand_ups, hand_downs = [], [], [], []
        cache = DesiredCache(work / f"desired-cache-{n}")  # as the command line's apply and destroy
        for r in range(args.deploy_repeat):  # interleaved, so drift hits both alike
            hand_up, hand_down = by_hand(n, work)
            hand_ups.append(hand_up)
            hand_downs.append(hand_down)
            ports = netutil.free_ports(n, HOST)
            plant = work / f"load-{n}-{r}.ttl"
            plant.write_text(synthetic.mosquitto_plant(HOST, ports))
            ups.append(through_plantkg(plant, directory, parallelism=args.apply_parallelism, cache=cache))
            if r < args.deploy_repeat - 1:
                downs.append(through_plantkg(plant, directory, destroy=True, parallelism=args.apply_parallelism,
                                             cache=cache))
        mem = memory(agent_pid)
        brokers = [(HOST, p) for p in ports]
        cells = []
        max_m = max([*args.messages, args.size_messages])
        with BurstRig(brokers, max_m) as rig:
            rig.burst(min(max_m, 50), 100, "spread")  # warm-up: first packets on fresh connections
            cells += _bursts(rig, "matrix", args.messages, [args.size], MODES, args.repeat, raw)
            if n in args.size_brokers:
                cells += _bursts(rig, "size", [args.size_messages], args.sizes, ("spread",), args.repeat, raw)
        downs.append(through_plantkg(plant, directory, destroy=True, parallelism=args.apply_parallelism,
                                     cache=cache))
    finally:
        agents.stop()
    up_s, hand_up_s = statistics.median(u["total"] for u in ups), statistics.median(hand_ups)
    down_s, hand_down_s = statistics.median(d["total"] for d in downs), statistics.median(hand_downs)
    return {"brokers": n, "bringup": {
        "hand_up_s": hand_up_s, "plantkg_up_s": up_s, "up_ratio": up_s / hand_up_s,
        "hand_down_s": hand_down_s, "plantkg_down_s": down_s, "down_ratio": down_s / hand_down_s,
        "plantkg_up_split_s": {k: statistics.median(u[k] for u in ups) for k in ups[0]},
        "plantkg_down_split_s": {k: statistics.median(d.get(k, 0.0) for d in downs) for k in downs[0]},
        "runs": {"hand_up_s": hand_ups, "plantkg_up_s": [u["total"] for u in ups],
                 "hand_down_s": hand_downs, "plantkg_down_s": [d["total"] for d in downs]}},
        "memory": {**mem, "agent_idle_rss_mb": idle_agent_mb}, "cells": cells}


def nagle_arm(n: int, args: argparse.Namespace, work: Path, raw: list[BurstResult]) -> list[dict[str, object]]:
    """The matrix (spread) against n brokers spawned by hand, with Mosquitto's default
    (``set_tcp_nodelay false``) and with plantkg's ``set_tcp_nodelay true``: do Nagle's algorithm
    and delayed ACKs explain stalls?"""
    cells = []
    for label, nodelay in (("tcp-default", False), ("tcp-nodelay", True)):
        ports, confs = _hand_confs(n, work, nodelay)
        children: list[process.Child] = []
        try:
            _spawn_all(confs, work, children)
            wait_all_ready([(HOST, p) for p in ports])
            with BurstRig([(HOST, p) for p in ports], 0) as rig:
                rig.burst(min(max(args.nagle_messages), 50), args.size, "spread")  # warm-up
                cells += _bursts(rig, label, args.nagle_messages, [args.size], ("spread",), args.repeat, raw)
        finally:
            for child in children:
                process.stop(child)
    return cells


def kafka_arm(args: argparse.Namespace, work: Path, raw: list[BurstResult]) -> dict[str, object]:
    """One Kafka broker through one apply; bursts of each size of ``--kafka-messages``, then sizes."""
    agents = start_local_agents([HOST], work / "agents-kafka")
    try:
        directory = AgentDirectory.load(agents.agents_file)
        port = netutil.free_port(HOST)
        plant = work / "kafka.ttl"
        plant.write_text(KAFKA_PLANT.format(host=HOST, port=port))
        up = through_plantkg(plant, directory)
        cells = []
        with KafkaRig(f"{HOST}:{port}", "bench.t") as rig:
            for study, sizes, counts in (("kafka", [args.size], args.kafka_messages),
                                         ("kafka-size", args.sizes, [args.size_messages])):
                for size in sizes:
                    for m in counts:
                        try:
                            runs = [rig.burst(m, size) for _ in range(args.repeat)]
                        except KafkaException as exc:  # e.g. 1 MB > the default message.max.bytes
                            cells.append({"study": study, "size": size, "messages": m, "refused": str(exc)})
                            continue
                        raw.extend(runs)
                        cells.append(_cell(runs, study))
        mem = memory(agents.agents[HOST].child.pid)
        down = through_plantkg(plant, directory, destroy=True)
    finally:
        agents.stop()
    return {"up_s": up["total"], "down_s": down["total"], "memory": mem, "cells": cells}


def bridge_arm(args: argparse.Namespace, work: Path, raw: list[BurstResult]) -> dict[str, object]:
    """One apply of a Mosquitto bridged to a Kafka (a bridge worker beside Mosquitto); bursts of
    each size of ``--bridge-messages`` published on Mosquitto and consumed from Kafka."""
    agents = start_local_agents([HOST], work / "agents-bridge")
    try:
        directory = AgentDirectory.load(agents.agents_file)
        mqtt_port, kafka_port = netutil.free_ports(2, HOST)
        plant = work / "bridge.ttl"
        plant.write_text(BRIDGE_PLANT.format(host=HOST, mqtt_port=mqtt_port, kafka_port=kafka_port))
        up = through_plantkg(plant, directory)
        cells = []
        with BridgeBurstRig(HOST, mqtt_port, f"{HOST}:{kafka_port}", "bench.bridge") as rig:
            for m in args.bridge_messages:
                runs = [rig.burst(m, args.size) for _ in range(args.repeat)]
                raw.extend(runs)
                cells.append(_cell(runs, "bridge"))
        down = through_plantkg(plant, directory, destroy=True)
    finally:
        agents.stop()
    return {"up_s": up["total"], "down_s": down["total"], "cells": cells}


def measure(args: argparse.Namespace, argv: list[str] | None) -> tuple[dict[str, object], list[BurstResult]]:
    info = machine()
    raw: list[BurstResult] = []
    rows = []
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-load-") as tmp:
        costs = file_costs(Path(tmp))
        for n in args.brokers:
            rows.append(one_size(n, args, Path(tmp), raw))
            print(f"{n} brokers: bring-up {rows[-1]['bringup']}", flush=True)
            if n in args.nagle_brokers:
                rows[-1]["cells"] += nagle_arm(n, args, Path(tmp), raw)
        kafka = kafka_arm(args, Path(tmp), raw) if args.kafka_messages else None
        bridge = bridge_arm(args, Path(tmp), raw) if args.bridge_messages else None
    return {"kafka": kafka, "bridge": bridge, "file_costs": costs, "benchmark": "load", "machine": info, "command": command_line("benchmarks.bench_load", argv),
            "repeat": args.repeat, "deploy_repeat": args.deploy_repeat, "size": args.size,
            "apply_parallelism": args.apply_parallelism,
            "paper": "Fig. 12: 1-100 brokers x 100-500 messages < 1 KB, one machine", "rows": rows}, raw


def write_csv(path: Path, raw: list[BurstResult]) -> None:
    """One row per burst: its shape, send time and the mean/p50/p99 of both latencies (ms)."""
    with path.open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["brokers", "messages", "size", "mode", "send_ms", "lost",
                      "ack_mean_ms", "ack_p50_ms", "ack_p99_ms", "delivery_mean_ms", "delivery_p50_ms",
                      "delivery_p99_ms"])
        for r in raw:
            a, d = summarize(list(r.ack_s)), summarize(list(r.delivery_s))
            out.writerow([r.brokers, r.messages, r.size, r.mode, f"{r.send_s * 1000:.3f}", r.lost,
                          *(f"{s.get(k, float('nan')):.3f}" for s in (a, d) for k in ("mean", "p50", "p99"))])


def to_markdown(data: dict[str, object]) -> str:
    rows = data["rows"]
    lines = ["# load: N Mosquitto brokers on one machine, brought up by one apply, then bursts of M messages "
             "(Fig. 12)", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · every cell {data['repeat']} bursts, "
             f"bring-up median of {data['deploy_repeat']}", "",
             "## Bring-up and memory", "",
             "| brokers | by hand up s | one apply up s | apply / hand | (of which pipeline s) | by hand down s "
             "| one destroy s | destroy / hand | RSS per idle broker MB | agent RSS MB (idle → N brokers) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:  # type: ignore[union-attr]
        b, m = r["bringup"], r["memory"]
        lines.append(f"| {r['brokers']} | {b['hand_up_s']:.3f} | {b['plantkg_up_s']:.3f} | **{b['up_ratio']:.2f}** | "
                     f"{b['plantkg_up_split_s']['pipeline']:.3f} | {b['hand_down_s']:.3f} | {b['plantkg_down_s']:.3f} | "
                     f"{b['down_ratio']:.2f} | {m['broker_rss_mb_mean']:.1f} | "
                     f"{m['agent_idle_rss_mb']:.0f} → {m['agent_rss_mb']:.0f} |")
    split = [(r["brokers"], r["bringup"].get("plantkg_up_split_s"), r["bringup"].get("plantkg_down_split_s"))
             for r in rows]  # type: ignore[union-attr]
    if any(up and down for _, up, down in split):
        lines += ["", "Where one apply's and one destroy's time goes (median s; pipeline = the stages before "
                  "dispatch, dispatch = the batch and the check):", ""]
        for n, up, down in split:
            if up and down:
                lines.append(f"- {n} brokers: apply " + ", ".join(f"{k.removeprefix('stage_')} {v:.3f}"
                                                                  for k, v in up.items() if k != "total")
                             + "; destroy " + ", ".join(f"{k.removeprefix('stage_')} {v:.3f}"
                                                       for k, v in down.items() if k != "total"))
    costs = data.get("file_costs")
    if isinstance(costs, dict):
        lines += ["", f"File system of the agents' state folder: making a folder {costs['mkdir_us']:.0f} µs "
                  f"({costs['mkdir_sys_us']:.0f} µs of it kernel CPU), writing a small file whole "
                  f"{costs['write_whole_us']:.0f} µs ({costs['write_whole_sys_us']:.0f}). An agent's broker start "
                  "makes 3 folders and writes 4 files whole before its broker runs (spec, config, pid, then "
                  "topics); the by-hand arm makes its folders and configs before its clock starts "
                  "(`file_costs` in bench_load.py)."]
    lines += ["", f"## Latency per message, ms ({data['size']} B payload, QoS 1)", "",
              "| mode | brokers | messages | send burst ms | ack mean | ack p50 | ack p99 | delivery mean | "
              "delivery p50 | delivery p99 | stdev of burst means (ack / delivery) | lost |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    cells = [c for r in rows for c in r["cells"]]  # type: ignore[union-attr]
    for c in sorted((c for c in cells if c["study"] == "matrix"), key=lambda c: (c["mode"], c["brokers"], c["messages"])):
        lines.append(_cell_line(c))
    nagle = [c for c in cells if c["study"].startswith("tcp-")]
    if nagle:
        lines += ["", "## TCP_NODELAY on the brokers (spread, brokers spawned by hand)", "",
                  "| broker sockets | brokers | messages | send burst ms | ack mean | ack p50 | ack p99 | delivery mean | "
                  "delivery p50 | delivery p99 | stdev of burst means (ack / delivery) | lost |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in sorted(nagle, key=lambda c: (c["brokers"], c["messages"], c["study"])):
            lines.append(_cell_line(c, first="study"))
    kafka = data.get("kafka")
    if kafka:
        lines += ["", "## Kafka (one broker, acks=all; ack = delivery report, delivery = consumed)", "",
                  f"One apply brought it up in {kafka['up_s']:.2f} s, one destroy took {kafka['down_s']:.2f} s; "
                  f"JVM RSS {kafka['memory']['broker_rss_mb_mean']:.0f} MB, agent {kafka['memory']['agent_rss_mb']:.0f} MB.",
                  "", "| study: size B | brokers | messages | send burst ms | ack mean | ack p50 | ack p99 | "
                  "delivery mean | delivery p50 | delivery p99 | stdev of burst means (ack / delivery) | lost |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in sorted(kafka["cells"], key=lambda c: (c["study"], c["size"], c["messages"])):
            if "refused" in c:
                lines.append(f"| {c['study']}: {c['size']} | 1 | {c['messages']} | refused by Kafka: {c['refused']} "
                             "||||||||")
            else:
                lines.append(_cell_line({**c, "label": f"{c['study']}: {c['size']}"}, first="label"))
    bridge = data.get("bridge")
    if bridge:
        lines += ["", "## MQTT → Kafka bridge (one Mosquitto, its bridge worker, one Kafka; ack = Mosquitto's "
                  "PUBACK, delivery = consumed from Kafka)", "",
                  f"One apply brought the three up in {bridge['up_s']:.2f} s, one destroy took {bridge['down_s']:.2f} s. "
                  "Compare with the one-broker rows of the matrix (delivery on the same Mosquitto) and the Kafka "
                  "table (produced to Kafka directly).", "",
                  "| path | brokers | messages | send burst ms | ack mean | ack p50 | ack p99 | delivery mean | "
                  "delivery p50 | delivery p99 | stdev of burst means (ack / delivery) | lost |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in sorted(bridge["cells"], key=lambda c: c["messages"]):
            lines.append(_cell_line({**c, "label": "MQTT → bridge → Kafka"}, first="label"))
    sized = [c for c in cells if c["study"] == "size"]
    if sized:
        lines += ["", "## Message size (spread)", "",
                  "| size B | brokers | messages | send burst ms | ack mean | ack p50 | ack p99 | delivery mean | "
                  "delivery p50 | delivery p99 | stdev of burst means (ack / delivery) | lost |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for c in sorted(sized, key=lambda c: (c["brokers"], c["size"])):
            lines.append(_cell_line(c, first="size"))
    return "\n".join(lines) + "\n"


def _cell_line(c: dict[str, object], first: str = "mode") -> str:
    a, d = c["ack"], c["delivery"]
    return (f"| {c[first]} | {c['brokers']} | {c['messages']} | {c['send_ms']:.1f} | {a['mean']:.1f} | {a['p50']:.1f} | "
            f"{a['p99']:.1f} | {d['mean']:.1f} | {d['p50']:.1f} | {d['p99']:.1f} | "
            f"{c['ack_mean_of_repeats_stdev']:.1f} / {c['delivery_mean_of_repeats_stdev']:.1f} | {c['lost']} |")


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="load test of N Mosquitto brokers (Fig. 12)")
    parser.add_argument("--brokers", type=int, nargs="+", default=[1, 5, 10, 25, 50, 100])
    parser.add_argument("--messages", type=int, nargs="+", default=[100, 200, 300, 400, 500])
    parser.add_argument("--repeat", type=int, default=3, help="bursts per cell")
    parser.add_argument("--deploy-repeat", type=int, default=3, help="bring-ups per broker count, each way")
    parser.add_argument("--size", type=int, default=100, help="payload bytes of the main matrix")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 10_000, 1_000_000])
    parser.add_argument("--size-brokers", type=int, nargs="*", default=[1, 10, 100])
    parser.add_argument("--size-messages", type=int, default=100)
    parser.add_argument("--kafka-messages", type=int, nargs="*", default=[100, 300, 500],
                        help="burst sizes against one Kafka broker (none: no Kafka arm)")
    parser.add_argument("--bridge-messages", type=int, nargs="*", default=[100, 300, 500],
                        help="burst sizes through an MQTT -> Kafka bridge (none: no bridge arm)")
    parser.add_argument("--apply-parallelism", type=int, default=8,
                        help="apply's parallel calls (engine.apply's default is 8)")
    parser.add_argument("--nagle-messages", type=int, nargs="+", default=[1, 10, 100, 500],
                        help="burst sizes of the TCP_NODELAY arm (small bursts show stalls best)")
    parser.add_argument("--nagle-brokers", type=int, nargs="*", default=[10],
                        help="broker counts also measured by hand with and without set_tcp_nodelay")
    parser.add_argument("--out", type=Path, default=RESULTS)
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    if args.size < 8 or min(args.sizes) < 8:
        raise SystemExit("payloads carry an 8-byte index: sizes must be >= 8")
    data, raw = measure(args, argv)
    write_results(args.out, "load", data, to_markdown(data))
    write_csv(args.out / "load.csv", raw)
    plots.load(data, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

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
- ``plantkg-warm``: the same apply by a long-running process that keeps its pipeline warm
  (``engine.incremental.warm.WarmPipeline``, as ``plantkg serve``'s reconcile loop and the fleet
  manager do): each run's plant differs from the last one only by the broker's port, a one-line
  edit the warm session follows (re-validates and re-reasons what it touches) instead of loading,
  validating and reasoning the plant afresh.
- ``plantkg-cli``: ``plantkg apply --yes`` of the same plant as a person types it, a whole process
  (interpreter start, imports, pipeline, apply) until it exits, then the same acknowledged
  publish; ``--cli-runs`` runs (default 10; the desired-state cache is emptied before each, so
  every run plans a plant it has not seen, as the in-process rows do). Issue 16: at most 10x bare.
- ``plantkg-cli-served``: the same command while a ``plantkg serve`` of that plant runs (started
  once, before the runs): the command hands its apply to the server over its control socket
  (engine.control) and prints what the server says; each run's plant differs from the last by the
  broker's port, an edit the server's warm pipeline follows. Two runs before are not counted: the
  server's cold start, and its first edit (which analyses the shapes' queries, once per cache
  folder: ``kg.sparql_deps`` keeps the analysis on disk). The command's stderr must say it ran in
  the server, else the run fails.
- ``plantkg-remote-<d>ms``: the same apply against an agent on an emulated remote machine (a
  network namespace behind a veth pair with ``tc netem`` delaying each packet ``--delay-ms`` each
  way, ``benchmarks.netns``); the publish crosses that link too. What the paper's "tool + cable"
  row corresponds to. Skipped, with the reason recorded, where netem is not available.
- ``plantkg-proxy-<d>ms``: the same through a user-space TCP forwarder delaying each direction
  ``--delay-ms`` (``benchmarks.delay_proxy``: orders to a second local agent, and the publish, go
  through it) — the delayed network where netem is missing, and a cross-check where it is not.
- ``kafka-bare`` / ``kafka-plantkg``: the same for one Kafka (KRaft) broker — render
  server.properties, format storage, start the JVM, create the topic, until a produce with
  acks=all is acknowledged; ``--kafka-runs`` runs (each takes seconds), interleaved likewise;
  ratio to ``kafka-bare``. The rendered broker does not auto-create topics (issue 13): bare
  creates ``bench.t`` with an AdminClient (what ``kafka-topics.sh --create`` does), plantkg's
  apply creates it because the plant declares it; neither path produces before the topic exists.

Runs are interleaved so drift hits all alike. Results: ``benchmarks/results/deploy.{json,md}``,
with min, max, mean, standard deviation, p50, p99 and the ratio of means to bare.

Usage: ``python -m benchmarks.bench_deploy [--runs 50] [--cli-runs 10] [--kafka-runs 10] [--delay-ms 5]``
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
from confluent_kafka import KafkaError, KafkaException, Producer
from confluent_kafka.admin import AdminClient, NewTopic

from benchmarks import netns
from benchmarks.delay_proxy import DelayProxy
from benchmarks.common import RESULTS, command_line, machine, summarize, write_results
from engine import netutil, parts, process
from engine.drivers.kafka import runtime as kafka_runtime
from engine.agent.local import start_local_agents
from engine.agents_config import AgentDirectory
from engine.apply import apply
from engine.drivers.mosquitto.runtime import MosquittoConfig, default_run_as, mosquitto_command, render_mosquitto_conf
from engine.parts import mosquitto_binary
from engine.incremental.warm import WarmPipeline
from engine.pipeline import Pipeline, run_pipeline

HOST = "127.0.0.2"
PROXIED_HOST = "127.0.0.3"
PAYLOAD = b"x" * 512

# The paper's deployment measure: an open broker (pk:allowAnonymous true; closed is the default),
# its readiness probe publishes anonymously, as the hand-run baseline does.
PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://w3id.org/plantkg/examples/bench#> .
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "bench" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {port} ; pk:allowAnonymous true ; pk:hasTopic :t .
:t a pk:Topic ; pk:id "t" ; pk:name "bench.t" ; pk:qos 1 .
:r a pk:Resource ; pk:id "r" ; pk:name "publisher" ; pk:sendsTo :mqtt ; pk:publishes :t .
"""

# Likewise an open Kafka (pk:allowAnonymous true; closed is the default): the readiness probe creates
# the topic and produces anonymously, as the hand-run baseline does.
KAFKA_PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://w3id.org/plantkg/examples/bench#> .
:kafka a pk:Broker ; pk:id "kafka" ; pk:name "bench-kafka" ; pk:brokerType "kafka" ;
    pk:ip "{host}" ; pk:port {port} ; pk:allowAnonymous true ; pk:hasTopic :t .
:t a pk:Topic ; pk:id "t" ; pk:name "bench.t" .
:r a pk:Resource ; pk:id "r" ; pk:name "producer" ; pk:sendsTo :kafka ; pk:publishes :t .
"""
KAFKA_READY_S = 120.0
BENCH_TOPIC = "bench.t"
# while the JVM starts: no controller / broker yet, or the request timed out
_NOT_READY = (KafkaError._TRANSPORT, KafkaError._TIMED_OUT, KafkaError.REQUEST_TIMED_OUT,
              KafkaError._ALL_BROKERS_DOWN, KafkaError.NOT_CONTROLLER)


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


def create_topic(host: str, port: int, deadline: float = KAFKA_READY_S) -> None:
    """Create BENCH_TOPIC (1 partition, 1 replica) on a starting broker, polling every 5 ms until
    it is created or already there: the broker does not auto-create it."""
    admin = AdminClient({"bootstrap.servers": f"{host}:{port}", "reconnect.backoff.ms": 5,
                         "reconnect.backoff.max.ms": 50, "log_level": 0})
    end = time.monotonic() + deadline
    while True:
        left = max(end - time.monotonic(), 0.1)
        future = admin.create_topics([NewTopic(BENCH_TOPIC, 1, 1)], request_timeout=left)[BENCH_TOPIC]
        try:
            future.result(timeout=left)
            return
        except KafkaException as exc:
            error = exc.args[0]
            if error.code() == KafkaError.TOPIC_ALREADY_EXISTS:
                return
            if not error.retriable() and error.code() not in _NOT_READY:
                raise
            if time.monotonic() > end:
                raise TimeoutError(f"Kafka on {host}:{port} never created {BENCH_TOPIC}: {error}") from None
        finally:
            del future  # its exception's traceback would keep the AdminClient alive
        time.sleep(0.005)  # poll interval of the readiness check (a deadline bounds it)


def acked_produce(host: str, port: int, deadline: float = KAFKA_READY_S) -> None:
    """Produce PAYLOAD with acks=all until Kafka acknowledges it (the client retries meanwhile).
    The topic must exist: the broker does not create it on demand."""
    producer = Producer({"bootstrap.servers": f"{host}:{port}", "acks": "all", "linger.ms": 0,
                         "reconnect.backoff.ms": 5, "reconnect.backoff.max.ms": 50, "retry.backoff.ms": 5,
                         "message.timeout.ms": int(deadline * 1000), "log_level": 0})
    errors: list[object] = []
    producer.produce(BENCH_TOPIC, PAYLOAD, on_delivery=lambda err, msg: errors.append(err))
    if producer.flush(deadline) != 0 or errors != [None]:
        raise TimeoutError(f"Kafka on {host}:{port} never acknowledged: {errors}")


def bare_kafka(work: Path) -> float:
    """What a person does by hand: write server.properties, format storage, start, create the
    topic, produce."""
    kafka, java = parts.kafka_parts(), parts.java_binary()
    port, controller = netutil.free_ports(2, HOST)
    broker_dir = work / f"kafka-bare-{port}"
    broker_dir.mkdir()
    cfg = kafka_runtime.KafkaNodeConfig(HOST, port, controller, broker_dir / "data")
    start = time.perf_counter()
    properties = broker_dir / "server.properties"
    properties.write_text(kafka_runtime.render_server_properties(cfg))
    kafka_runtime.format_storage(cfg, properties, broker_dir, kafka=kafka, java=java)
    child = process.spawn(kafka_runtime.broker_command(kafka, java, properties, broker_dir / "logs"),
                          log_dir=broker_dir, name="kafka")
    try:
        create_topic(HOST, port)
        acked_produce(HOST, port)
        return time.perf_counter() - start
    finally:
        process.stop(child, grace=30.0)


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


def through_plantkg(work: Path, directory: AgentDirectory, dispatch_only: bool, kind: str = "mosquitto",
                    host: str = HOST, publish_delay_s: float = 0.0,
                    stages: dict[str, list[float]] | None = None,
                    pipeline: Callable[..., Pipeline] = run_pipeline) -> float:
    """Apply a one-broker plant until its first acknowledged message; ``publish_delay_s``: the
    publish goes through a :class:`DelayProxy` delaying that much each way. ``stages`` gets the
    seconds of each pipeline stage, of apply (dispatch and check) and of the publish."""
    port = netutil.free_port(host) if host.startswith("127.") else 1883  # a fresh namespace has every port free
    plant = work / "plant.ttl"
    plant.write_text((KAFKA_PLANT if kind == "kafka" else PLANT).format(host=host, port=port))
    prepared = run_pipeline([plant], directory) if dispatch_only else None
    with DelayProxy(host, port, publish_delay_s) if publish_delay_s else nullcontext() as proxy:
        start = time.perf_counter()
        result = prepared or pipeline([plant], directory)
        assert result.plan is not None and result.desired is not None
        planned = time.perf_counter()
        outcome = apply(result.plan, result.desired, directory)
        assert outcome.ok, outcome
        applied = time.perf_counter()
        reach = ("127.0.0.1", proxy.port) if proxy else (host, port)
        (acked_produce if kind == "kafka" else acked_publish)(*reach)
        elapsed = time.perf_counter() - start
    if stages is not None:
        for name, seconds in [*result.timings.items(), ("apply", applied - planned),
                              ("publish", start + elapsed - applied)]:
            stages.setdefault(name, []).append(seconds)
    gone = run_pipeline([plant], directory, destroy=True)
    assert gone.plan is not None and gone.desired is not None
    assert apply(gone.plan, gone.desired, directory, destroy=True).ok
    return elapsed


PLANTKG = str(Path(sys.executable).parent / "plantkg")
SERVED_NOTE = "runs in plantkg serve"


def through_cli(work: Path, directory: AgentDirectory, agents_file: Path, served: Served | None = None) -> float:
    """``plantkg apply --yes`` of a one-broker plant as a whole process, until its first
    acknowledged message; alone, the desired-state cache is empty (a plant never seen); with
    ``served``, the plant is the served one and the command must have run in the server."""
    port = netutil.free_port(HOST)
    plant = served.plant if served else work / "plant-cli.ttl"
    plant.write_text(PLANT.format(host=HOST, port=port))
    if served:
        env = served.env
    else:
        cache = work / "cli-cache"
        shutil.rmtree(cache, ignore_errors=True)
        env = {**os.environ, "PLANTKG_CACHE_DIR": str(cache)}
    argv = [PLANTKG, "apply", "--yes", "--agents", str(agents_file), str(plant)]
    start = time.perf_counter()
    done = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=120, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"plantkg apply exited {done.returncode}: {done.stderr[-2000:]}")
    if (SERVED_NOTE in done.stderr) != (served is not None):
        raise RuntimeError(f"plantkg apply {'did not run' if served else 'ran'} in plantkg serve: {done.stderr[-2000:]}")
    acked_publish(HOST, port)
    elapsed = time.perf_counter() - start
    gone = run_pipeline([plant], directory, destroy=True)
    assert gone.plan is not None and gone.desired is not None
    assert apply(gone.plan, gone.desired, directory, destroy=True).ok
    return elapsed


@dataclass(frozen=True)
class Served:
    """A running ``plantkg serve`` of ``plant`` and the environment its commands run with."""

    plant: Path
    env: dict[str, str]


@contextmanager
def served_plant(work: Path, agents_file: Path) -> Iterator[Served]:
    """``plantkg serve`` of a one-broker plant, its control socket open (engine.control), until left."""
    short = Path(tempfile.mkdtemp(prefix="pkb-", dir="/tmp"))  # a socket path stays under ~100 bytes
    env = {**os.environ, "PLANTKG_RUN_DIR": str(short / "run"), "XDG_STATE_HOME": str(work / "served-state"),
           "PLANTKG_CACHE_DIR": str(work / "served-cache")}
    plant = work / "plant-served.ttl"
    plant.write_text(PLANT.format(host=HOST, port=netutil.free_port(HOST)))
    log = work / "serve.log"
    with log.open("w") as out:
        server = subprocess.Popen([PLANTKG, "serve", str(plant), "--agents", str(agents_file), "--listen",
                                   f"127.0.0.1:{netutil.free_port()}", "--observe-interval", "3600"],
                                  env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        process.wait_until(lambda: "runs here, warm" in log.read_text() or server.poll() is not None, 60,
                           what="plantkg serve's control socket")
        if server.poll() is not None or "runs here, warm" not in log.read_text():
            raise RuntimeError(f"plantkg serve did not open its control socket: {log.read_text()[-2000:]}")
        yield Served(plant, env)
    finally:
        server.terminate()
        server.wait(60)
        shutil.rmtree(short, ignore_errors=True)


@dataclass(frozen=True)
class Remote:
    """An agent reached over a delayed network: which row it fills and how to reach it."""

    row: str
    directory: AgentDirectory
    host: str
    publish_delay_s: float = 0.0


def _netem_remote(stack: ExitStack, work: Path, delay_ms: float) -> Remote | str:
    """An agent in a network namespace behind a netem-delayed link, or why there is none."""
    try:
        link = stack.enter_context(netns.delayed_link(delay_ms))
    except netns.LinkUnavailable as exc:
        return str(exc)
    agent = stack.enter_context(netns.remote_agent(link, work))
    return Remote(f"plantkg-remote-{delay_ms:g}ms", AgentDirectory.load(agent.agents_file), link.remote_ip)


def _proxy_remote(stack: ExitStack, work: Path, delay_ms: float) -> Remote:
    """A second local agent whose orders (and publishes) go through a user-space delay proxy."""
    agents = start_local_agents([PROXIED_HOST], work / "proxied")
    stack.callback(agents.stop)
    agent = agents.agents[PROXIED_HOST]
    host, port = agent.url.removeprefix("http://").rsplit(":", 1)
    proxy = stack.enter_context(DelayProxy(host, int(port), delay_ms / 1000))
    agents_file = work / "agents-proxied.toml"
    agents_file.write_text(f'[agents."{PROXIED_HOST}"]\nurl = "http://127.0.0.1:{proxy.port}"\n'
                           f'token_file = "{agent.state_dir / "token"}"\n')
    os.chmod(agents_file, 0o600)
    return Remote(f"plantkg-proxy-{delay_ms:g}ms", AgentDirectory.load(agents_file), PROXIED_HOST, delay_ms / 1000)


def measure(runs: int, kafka_runs: int = 0, delay_ms: float | None = None, cli_runs: int = 0) -> dict[str, object]:
    info = machine()
    times: dict[str, list[float]] = {"bare": [], "plantkg": [], "plantkg-dispatch": [], "plantkg-warm": []}
    stages: dict[str, list[float]] = {}  # where the plantkg row's time goes
    warm_stages: dict[str, list[float]] = {}
    warm = WarmPipeline()
    remotes: list[Remote] = []
    remote_note = ""
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-") as tmp, ExitStack() as stack:
        work = Path(tmp)
        agents = start_local_agents([HOST], work / "agents")
        stack.callback(agents.stop)
        directory = AgentDirectory.load(agents.agents_file)
        if delay_ms is not None:
            netem = _netem_remote(stack, work, delay_ms)
            if isinstance(netem, str):
                remote_note = f"not measured: the delayed link is not available here ({netem})"
            else:
                remotes.append(netem)
            if delay_ms > 0:
                remotes.append(_proxy_remote(stack, work, delay_ms))
        for remote in remotes:
            times[remote.row] = []
            through_plantkg(work, remote.directory, False, host=remote.host,
                            publish_delay_s=remote.publish_delay_s)  # warm-up of that agent
        through_plantkg(work, directory, False)  # warm-up: imports, JIT-free but caches
        through_plantkg(work, directory, False, pipeline=warm)  # the warm session's start
        for _ in range(runs):
            times["bare"].append(bare(work))
            times["plantkg"].append(through_plantkg(work, directory, False, stages=stages))
            times["plantkg-dispatch"].append(through_plantkg(work, directory, True))
            times["plantkg-warm"].append(through_plantkg(work, directory, False, stages=warm_stages, pipeline=warm))
            for remote in remotes:
                times[remote.row].append(through_plantkg(work, remote.directory, False, host=remote.host,
                                                         publish_delay_s=remote.publish_delay_s))
        if cli_runs:
            times["plantkg-cli"] = []
            through_cli(work, directory, agents.agents_file)  # warm-up: the file cache of the imports
            times["plantkg-cli-served"] = []
            served = stack.enter_context(served_plant(work, agents.agents_file))
            # warm-up: the server's cold start, then its first edit, which analyses the shapes'
            # queries once per cache folder (kg.sparql_deps, kept on disk: ~2 s, once ever for a user)
            through_cli(work, directory, agents.agents_file, served)
            through_cli(work, directory, agents.agents_file, served)
        for _ in range(cli_runs):  # interleaved with bare runs of their own
            times["bare"].append(bare(work))
            times["plantkg-cli"].append(through_cli(work, directory, agents.agents_file))
            times["plantkg-cli-served"].append(through_cli(work, directory, agents.agents_file, served))
        if kafka_runs:
            times.update({"kafka-bare": [], "kafka-plantkg": []})
        for _ in range(kafka_runs):
            times["kafka-bare"].append(bare_kafka(work))
            times["kafka-plantkg"].append(through_plantkg(work, directory, False, kind="kafka"))
    table = {k: summarize(v) for k, v in times.items()}
    for name, row in table.items():
        row["ratio"] = row["mean"] / table["kafka-bare" if name.startswith("kafka") else "bare"]["mean"]
    return {"benchmark": "deploy", "machine": info, "runs": runs, "kafka_runs": kafka_runs, "cli_runs": cli_runs,
            "delay_ms": delay_ms, "remote_note": remote_note, "ms": table,
            "plantkg_stages_ms": {k: statistics.median(v) * 1000 for k, v in stages.items()},
            "plantkg_warm_stages_ms": {k: statistics.median(v) * 1000 for k, v in warm_stages.items()},
            "warm_calls": dict(warm.stats),
            "paper": {"bare_ms": 23.9, "tool_cable_ms": 80.1, "ratio": 3.35}}


def to_markdown(data: dict[str, object]) -> str:
    lines = ["# deploy: a broker until its first acknowledged message, bare vs through plantkg (Table 1)", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · Mosquitto {data['runs']} runs each, "
             f"`plantkg apply` as a process {data.get('cli_runs', 0)} runs, "
             f"Kafka {data.get('kafka_runs', 0)} runs each (a run takes seconds), interleaved", "",
             "| path | runs | min ms | max ms | mean ms | stdev ms | p50 ms | p99 ms | mean / bare |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, r in data["ms"].items():  # type: ignore[union-attr]
        lines.append(f"| {name} | {r['n']} | {r['min']:.1f} | {r['max']:.1f} | {r['mean']:.1f} | {r['stdev']:.1f} | "
                     f"{r['p50']:.1f} | {r['p99']:.1f} | {r['ratio']:.2f} |")
    if data.get("remote_note"):
        lines.append(f"| plantkg-remote-{data['delay_ms']:g}ms | 0 | {data['remote_note']} |||||||")
    parts = data.get("plantkg_stages_ms") or {}
    if parts:
        lines += ["", "Where the `plantkg` row's time goes (median ms of its runs): "
                  + ", ".join(f"{k} {v:.1f}" for k, v in parts.items()) + "."]
    warm = data.get("plantkg_warm_stages_ms") or {}
    if warm:
        lines += ["", "Where the `plantkg-warm` row's time goes (median ms; the session's stages, then apply "
                  "and publish): " + ", ".join(f"{k} {v:.1f}" for k, v in warm.items())
                  + f". Calls of the warm pipeline: {data.get('warm_calls')} (one cold start before the runs)."]
    lines += ["", "The paper (its hardware, over cable): 23.9 ms bare, 80.1 ms through its tool (3.35x). "
              "Kafka rows are divided by kafka-bare, the others by bare."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="deployment latency benchmark (Table 1)")
    parser.add_argument("--runs", type=int, default=50)
    parser.add_argument("--cli-runs", type=int, default=10,
                        help="runs of `plantkg apply` as a whole process (0: no such row)")
    parser.add_argument("--kafka-runs", type=int, default=10)
    parser.add_argument("--delay-ms", type=float, default=5.0,
                        help="one-way delay of the emulated remote link (netem); a negative value skips the row")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = measure(args.runs, args.kafka_runs, args.delay_ms if args.delay_ms >= 0 else None, args.cli_runs)
    data["command"] = command_line("benchmarks.bench_deploy", argv)
    write_results(args.out, "deploy", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

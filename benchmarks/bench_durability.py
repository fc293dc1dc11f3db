"""Benchmark: what each fault loses with plantkg's settings, and what Mosquitto's save policies cost.

What may not be lost is what a publisher got an acknowledgement for. Publishers and receivers are
processes of their own (:mod:`benchmarks.bridge_load`): a paho publisher writing the index of
every message PUBACKed to it, ``mosquitto_sub`` with a persistent session, a Kafka reader.

Part 1, per save policy of the brokers (``pk:persistEvery``; ``default`` is none, which plantkg
renders as a save every :data:`DEFAULT_SAVE_SECONDS` s, plus the save signal its agent sends every
:data:`SAVE_TICK_SECONDS` s while the broker reads anything, run here by the agent's own
:class:`engine.agent.save_tick.SaveTicker`; ``tick:S`` saves only when told, every S seconds), on a
Mosquitto bridge A -> B:

- ``msg/s``: ``--messages`` sent as fast as ``mosquitto_pub`` takes them, distinct messages
  received on B / time from first send to last receive, and its ratio to the unsafe setting
  ``1000000`` (saved in practice only on a clean stop): the cost of the policy;
- ``target killed``: ``--stream`` messages at ``--rate``, B SIGKILLed when a third arrived and
  started again on the same folder: acknowledged messages never received, duplicates, whether a
  persistent session made before the stream was still there; once with B's subscriber connected,
  once with it offline during the stream (what B holds for it lives in memory until B saves).
  The run is over when every acknowledged message arrived or a marker published on A after the
  stream's last PUBACK did (the bridge forwards in order: what is still missing then is lost).

Part 2, with the default policy, a stream through each plantkg path with one fault mid-stream
(the faulty process SIGKILLed and started again, as its agent would):

- ``mqtt-kafka``: the bridge worker; the Kafka broker; the worker and then, one second later,
  the source Mosquitto (the double fault: what Mosquitto queued for the absent worker);
- ``kafka-mqtt``: the worker; the target Mosquitto.

Part 3 (with part 1): the double fault for each policy.

Usage: ``python -m benchmarks.bench_durability [--messages 20000] [--stream 15000] [--rate 3000]
[--policies 1000000 default 10 100 1] [--parts 1 2 3]``. Results: ``benchmarks/results/durability.{json,md}``.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from benchmarks import bridge_load as load
from benchmarks import bridge_rig as rig
from benchmarks.common import RESULTS, command_line, machine, write_results
from engine import process
from engine.bridge_worker.config import Direction, Route, WorkerConfig
from engine.agent.save_tick import SaveTicker
from engine.drivers.mosquitto.runtime import (BRIDGE_RESTART_TIMEOUT, DEFAULT_SAVE_SECONDS, SAVE_TICK_SECONDS,
                                              MosquittoBridge, MosquittoBridgeTopic)

TOPIC = "bench/durability"
PROBE_TOPIC = "bench/probe"
UNSAFE = "1000000"  # the largest pk:persistEvery: saved in practice only on a clean stop
SUPERVISOR_TICK = 0.1  # BrokerManager's default tick
IDLE = BRIDGE_RESTART_TIMEOUT[1] + 10.0  # seconds without news before a stream is declared over


@dataclass(frozen=True)
class Policy:
    """A save policy: ``default`` (none set: Mosquitto's save by time, and its agent's save signal
    every :data:`SAVE_TICK_SECONDS` s while it reads anything), N changes (``pk:persistEvery N``),
    or ``tick:S``: saved only when told, every S seconds (the agent's save signal at another
    period, with no save by time)."""

    name: str
    every: int | None
    tick: float | None = None

    @classmethod
    def parse(cls, text: str) -> Policy:
        if text == "default":
            return cls(text, None, SAVE_TICK_SECONDS)
        if text.startswith("tick:"):
            return cls(text, int(UNSAFE), float(text.split(":", 1)[1]))
        return cls(text, int(text))

    def broker(self, folder: Path, bridges: tuple[MosquittoBridge, ...] = ()) -> rig.Mosquitto:
        return rig.Mosquitto(folder, bridges=bridges, persist_every=self.every).start()

    def saver(self, brokers: list[rig.Mosquitto]) -> Callable[[], None]:
        """Send ``brokers`` their save signals as an agent does (engine.agent.save_tick: the same
        code), for the policies with a tick; returns the function that stops it."""
        if self.tick is None:
            return lambda: None
        stop, tickers = threading.Event(), [SaveTicker(self.tick) for _ in brokers]

        def tick() -> None:
            while not stop.wait(SUPERVISOR_TICK):  # the agent's supervisor loop
                for broker, ticker in zip(brokers, tickers):
                    child = broker.child
                    if child is not None and child.running():
                        ticker.step(child.pid, signal.SIGUSR1, time.monotonic())

        thread = threading.Thread(target=tick, daemon=True)
        thread.start()
        return lambda: (stop.set(), thread.join(5))  # type: ignore[func-returns-value]


# --- sessions ---------------------------------------------------------------------------------

def plant_session(port: int, client_id: str) -> None:
    """Create a persistent session with one subscription (on a topic nobody publishes, so nothing
    queues for it) and leave."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
    granted = threading.Event()
    client.on_subscribe = lambda *_: granted.set()
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        client.subscribe(PROBE_TOPIC, 1)
        process.wait_until(granted.is_set, 10, 0.01, what="the probe's SUBACK")
    finally:
        client.loop_stop()
        client.disconnect()


def session_present(port: int, client_id: str) -> bool:
    """Connect as ``client_id`` without cleaning its session: did the broker still have it?"""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
    flags: list[bool] = []
    client.on_connect = lambda _c, _u, f, *_: flags.append(bool(f.session_present))
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        process.wait_until(lambda: flags, 10, 0.01, what="CONNACK")
    finally:
        client.loop_stop()
        client.disconnect()
    return flags[0]


def publish_marker(port: int) -> bytes:
    """Publish one QoS 1 message on :data:`TOPIC` that no receiver counts (no index in it), once
    the broker acknowledged it; returns its payload. Sent to a bridge's source after the stream's
    last PUBACK, it queues behind every message of the stream, and the bridge forwards in order:
    when it reached the receiver, whatever of the stream has not is not coming."""
    payload = f"drained-{uuid.uuid4().hex}"
    # mosquitto_pub exits once its QoS 1 message is acknowledged
    subprocess.run([load.need("mosquitto_pub"), "-h", "127.0.0.1", "-p", str(port), "-t", TOPIC, "-q", "1",
                    "-m", payload], check=True, capture_output=True, timeout=30)
    return payload.encode()


def received(arrivals: load.Arrivals, payload: bytes) -> bool:
    """Whether the receiver's file holds ``payload`` (a marker: :class:`bridge_load.Arrivals`
    skips it)."""
    try:
        return payload in arrivals.path.read_bytes()
    except FileNotFoundError:
        return False


# --- one stream -------------------------------------------------------------------------------

def until_done_or_idle(arrivals: load.Arrivals, done: Callable[[], bool]) -> None:
    """Wait until ``done()``, or until nothing new arrived for IDLE s (the rest is missing)."""
    last, last_count = time.monotonic(), -1

    def over() -> bool:
        nonlocal last, last_count
        arrivals.read()
        if len(arrivals.first) != last_count:
            last, last_count = time.monotonic(), len(arrivals.first)
        return done() or time.monotonic() - last > IDLE

    process.wait_until(over, 900, 0.05, what="the stream to end")


def stream(work: Path, pub_port: int, count: int, rate: float, arrivals: load.Arrivals,
           fault: Callable[[], None] | None, mqtt_topic: str = TOPIC) -> dict[str, object]:
    """Publish ``count`` messages at ``rate`` on ``pub_port``; when a third arrived, run ``fault``;
    wait until every acknowledged message arrived or nothing came for IDLE s."""
    acked_file = work / f"acked-{uuid.uuid4().hex[:6]}"
    arrivals.read()
    base = len(arrivals.first)
    publisher = load.acked_publisher("127.0.0.1", pub_port, mqtt_topic, count, rate, acked_file)
    try:
        if fault is not None:
            process.wait_until(lambda: arrivals.read() is not None and len(arrivals.first) - base >= count // 3,
                               120, 0.005, what="a third of the stream")
            fault()

        def done() -> bool:
            acked = load.read_acked(acked_file)
            return publisher.poll() is not None and len(acked) == count and acked <= set(arrivals.first)
        until_done_or_idle(arrivals, done)
    finally:
        if publisher.poll() is None:
            publisher.terminate()
            publisher.wait(10)
    acked = load.read_acked(acked_file)
    got = set(arrivals.first)
    return {"sent": count, "acked": len(acked), "missing": len(acked - got),
            "duplicates": arrivals.duplicates}


# --- part 1: save policies on a Mosquitto bridge ----------------------------------------------

def bridge_pair(work: Path, policy: Policy, stops: list[Callable[[], object]]) -> tuple[rig.Mosquitto, rig.Mosquitto]:
    target = policy.broker(work / "b")
    stops.append(target.stop)
    bridge = MosquittoBridge("bench.a.b", target.host, target.port, (MosquittoBridgeTopic(TOPIC, "out", 1),))
    source = policy.broker(work / "a", (bridge,))
    stops += [source.stop, policy.saver([source, target])]
    return source, target


def subscriber(broker: rig.Mosquitto, name: str, work: Path, stops: list[Callable[[], object]]) -> load.Arrivals:
    """A persistent ``mosquitto_sub`` on ``broker``, once a probe published there reached it."""
    receiver = load.mqtt_subscriber(broker.host, broker.port, TOPIC, name, work / f"{name}.in", persistent=True)
    stops.append(receiver.stop)
    arrivals = load.Arrivals(receiver.out)
    probe = load.mqtt_publisher(broker.host, broker.port, TOPIC, f"{name}-probe", work / f"{name}.probe.log")
    try:
        def through() -> bool:
            probe.send(1, None)
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                if arrivals.read():
                    return True
                time.sleep(0.01)  # polling the receiver's file
            return False
        process.wait_until(through, 60, 0.0, what=f"{name} to receive")
    finally:
        probe.close()
    return arrivals


COST_CAP = 60.0   # seconds a throughput run may take: a slow policy's rate is clear by then


def policy_cost(work: Path, policy: Policy, n: int) -> dict[str, object]:
    """``n`` messages as fast as mosquitto_pub sends them across the bridge: distinct messages
    received per second (over at most COST_CAP s)."""
    stops: list[Callable[[], object]] = []
    try:
        source, target = bridge_pair(work, policy, stops)
        arrivals = subscriber(target, "cost-sub", work, stops)
        feeder = load.mqtt_publisher(source.host, source.port, TOPIC, "cost-pub", work / "cost-pub.log")
        stops.append(feeder.proc.kill)  # what it still holds is not measured
        arrivals.read()
        first, start_ns, _ = feeder.send(n, None)
        cap = time.monotonic() + COST_CAP
        until_done_or_idle(arrivals, lambda: time.monotonic() > cap
                           or all(i in arrivals.first for i in range(first, first + n)))
        got = [arrivals.first[i][1] for i in range(first, first + n) if i in arrivals.first]
        seconds = (max(got) - start_ns) / 1e9 if got else float("nan")
        return {"received": len(got), "missing": n - len(got), "seconds": seconds,
                "capped": len(got) < n and time.monotonic() > cap,
                "msg_per_s": len(got) / seconds if got else 0.0}
    finally:
        for stop in reversed(stops):
            stop()


def policy_costs(work: Path, policies: list[Policy], n: int, repeats: int) -> dict[str, dict[str, object]]:
    """Each policy's throughput ``repeats`` times, the order reversed every other round (the
    machine's load drifts): the median run of each, and every rate."""
    runs: dict[str, list[dict[str, object]]] = {p.name: [] for p in policies}
    for r in range(repeats):
        for i, policy in enumerate(policies if r % 2 == 0 else list(reversed(policies))):
            runs[policy.name].append(policy_cost(work / f"cost-{r}-{i}", policy, n))
    out = {}
    for name, results in runs.items():
        ordered = sorted(results, key=lambda x: float(x["msg_per_s"]))  # type: ignore[arg-type]
        out[name] = {**ordered[len(ordered) // 2], "rates": [round(float(x["msg_per_s"])) for x in results]}  # type: ignore[arg-type]
    return out


def policy_target_killed(work: Path, policy: Policy, count: int, rate: float,
                         offline: bool) -> dict[str, object]:
    """B SIGKILLed mid-stream and started again. ``offline``: its subscriber's persistent session
    is disconnected during the stream, so everything B acknowledged waits in B's memory for it
    until B saves (the window Mosquitto cannot close); it connects again after the restart."""
    stops: list[Callable[[], object]] = []
    try:
        source, target = bridge_pair(work, policy, stops)
        saved_before = rig.mtime(target.folder / "data" / "mosquitto.db")
        plant_session(target.port, "probe-session")
        if policy.every is None:
            # The claim measured is "a session outlives a SIGKILL once the 1-2 s save window
            # after it was made has passed": wait for that save (the tiny test's stream is over
            # in well under a second, and on a loaded machine its kill could come first).
            process.wait_until(lambda: rig.mtime(target.folder / "data" / "mosquitto.db") != saved_before,
                               4 * DEFAULT_SAVE_SECONDS + 5, 0.02, what="the target's first save after the probe")
        name = "offline-sub" if offline else "kill-sub"
        arrivals = subscriber(target, name, work, stops)
        receiver_stop = stops.pop()
        if offline:
            receiver_stop()   # its session stays on B and queues the stream
        acked_file = work / "acked"
        publisher = load.acked_publisher("127.0.0.1", source.port, TOPIC, count, rate, acked_file)
        try:
            if offline:
                process.wait_until(lambda: len(load.read_acked(acked_file)) >= count // 3, 120, 0.005,
                                   what="a third of the stream acknowledged")
            else:
                process.wait_until(lambda: arrivals.read() is not None and len(arrivals.first) > count // 3,
                                   120, 0.005, what="a third of the stream")
            target.kill()
            target.start()
            process.wait_until(lambda: publisher.poll() is not None, 600, 0.05, what="every PUBACK")
        finally:
            if publisher.poll() is None:
                publisher.terminate()
                publisher.wait(10)
        if offline:  # connect again: what B kept for the session arrives now
            receiver = load.mqtt_subscriber(target.host, target.port, TOPIC, name, work / f"{name}.in",
                                            persistent=True, append=True)
            stops.append(receiver.stop)
        else:
            stops.append(receiver_stop)
        acked = load.read_acked(acked_file)
        # Over when every acknowledged message arrived, or the marker sent after them did (what
        # B lost is not coming); without the marker a loss meant waiting IDLE seconds for nothing.
        marker = publish_marker(source.port)
        until_done_or_idle(arrivals, lambda: acked <= set(arrivals.first) or received(arrivals, marker))
        arrivals.read()
        return {"sent": count, "acked": len(acked), "missing": len(acked - set(arrivals.first)),
                "duplicates": arrivals.duplicates,
                "session_present": session_present(target.port, "probe-session")}
    finally:
        for stop in reversed(stops):
            stop()


# --- part 2: plantkg's paths with the default policy ------------------------------------------

class WorkerRig:
    """Kafka, one Mosquitto and a bridge worker carrying ``bench/durability`` <-> ``durability``."""

    def __init__(self, work: Path, direction: Direction, policy: Policy = Policy("default", None)) -> None:
        from tests.integration.conftest import start_kafka  # the project's one-node Kafka starter

        self.work, self.stops = work, []  # type: ignore[var-annotated]
        self.kafka = start_kafka(work / "kafka")
        self.kafka_child: object = self.kafka.child
        self.stops.append(lambda: process.stop(self.kafka_child, grace=30.0) if self.kafka_child else None)
        self.mq = policy.broker(work / "mq")
        self.stops += [self.mq.stop, policy.saver([self.mq])]
        rig.create_topics(self.kafka.bootstrap_servers, ["durability"], 1)
        self.cfg = WorkerConfig("durability", "127.0.0.1", self.mq.port, self.kafka.bootstrap_servers,
                                (Route(TOPIC, "durability", direction),), work / "worker")
        self.worker: process.Child | None = None
        self.start_worker()
        self.stops.append(self.stop_worker)

    def start_worker(self) -> None:
        self.worker = rig.start_worker(self.cfg)
        rig.wait_ready(self.cfg, self.worker, 120)

    def stop_worker(self) -> None:
        if self.worker is not None:
            process.stop(self.worker)
            self.worker = None

    def kill_worker(self) -> None:
        assert self.worker is not None
        rig.kill_group(self.worker)
        self.worker = None

    def kill_kafka(self) -> None:
        rig.kill_group(self.kafka_child)  # type: ignore[arg-type]
        self.kafka_child = rig.respawn_kafka(self.kafka.config, self.kafka.broker_dir)

    def close(self) -> None:
        for stop in reversed(self.stops):
            stop()


def mqtt_to_kafka(work: Path, fault: str, count: int, rate: float,
                  policy: Policy = Policy("default", None)) -> dict[str, object]:
    r = WorkerRig(work, Direction.MQTT_TO_KAFKA, policy)
    try:
        reader = load.kafka_reader(r.kafka.bootstrap_servers, "durability", work / "kafka.in")
        r.stops.append(reader.stop)
        arrivals = load.Arrivals(reader.out)

        def double() -> None:
            r.kill_worker()
            time.sleep(1.0)  # the fault as specified: the source dies one second after the worker
            r.mq.kill()
            r.mq.start()
            r.start_worker()

        faults = {"worker": lambda: (r.kill_worker(), r.start_worker()), "kafka": r.kill_kafka, DOUBLE: double}
        result = stream(work, r.mq.port, count, rate, arrivals, faults[fault])
        return result
    finally:
        r.close()


def kafka_to_mqtt(work: Path, fault: str, count: int, rate: float) -> dict[str, object]:
    r = WorkerRig(work, Direction.KAFKA_TO_MQTT)
    try:
        arrivals = subscriber(r.mq, "k2m-sub", work, r.stops)
        feeder_done: dict[str, object] = {}
        producer = load.kafka_producer(r.kafka.bootstrap_servers, "durability", work / "producer.log")
        base = len(arrivals.first)

        def send() -> None:
            feeder_done["first"], _, _ = producer.send(count, rate)
            feeder_done["code"] = producer.close()
        sender = threading.Thread(target=send, daemon=True)
        sender.start()
        process.wait_until(lambda: arrivals.read() is not None and len(arrivals.first) - base >= count // 3,
                           120, 0.005, what="a third of the stream")
        if fault == "worker":
            r.kill_worker()
            r.start_worker()
        else:
            r.mq.kill()
            r.mq.start()
        sender.join(300)
        first = int(feeder_done.get("first", 0))  # type: ignore[call-overload]
        until_done_or_idle(arrivals, lambda: sum(1 for i in arrivals.first if i >= first) >= count)
        got = {i for i in arrivals.first if first <= i < first + count}
        # the producer exits 0 only when Kafka acknowledged every record: all of them count
        acked = count if feeder_done.get("code") == 0 else None
        return {"sent": count, "acked": acked, "missing": count - len(got), "duplicates": arrivals.duplicates}
    finally:
        r.close()


DOUBLE = "worker, then source Mosquitto 1 s later"
PATH_FAULTS = [("mqtt-kafka", "worker"), ("mqtt-kafka", "kafka"), ("mqtt-kafka", DOUBLE),
               ("kafka-mqtt", "worker"), ("kafka-mqtt", "target Mosquitto")]


# --- report -----------------------------------------------------------------------------------

def goals(policies: list[dict[str, object]], faults: list[dict[str, object]]) -> list[dict[str, object]]:
    """Issue 16's durability goals for the default settings, as ``plantkg-bench report`` lists them."""
    out: list[dict[str, object]] = []
    by = {r["policy"]: r for r in policies}
    default, unsafe = by.get("default"), by.get(UNSAFE)
    if default is not None:
        k, o = default["killed"], default["killed_offline"]  # type: ignore[index]
        out.append({"goal": "default save policy: killed Mosquitto bridge target, subscriber connected",
                    "measured": f"{k['missing']} missing of {k['acked']}", "target": "0 missing",
                    "met": k["missing"] == 0})
        out.append({"goal": "default save policy: killed Mosquitto bridge target, its subscriber offline "
                            "(what it queued lives in memory until a save)",
                    "measured": f"{o['missing']} missing of {o['acked']}", "target": "0 missing",
                    "met": o["missing"] == 0})
        out.append({"goal": "default save policy: persistent sessions present after a SIGKILL",
                    "measured": "yes" if k["session_present"] and o["session_present"] else "no",
                    "target": "yes", "met": bool(k["session_present"] and o["session_present"])})
        if unsafe is not None:
            ratio = default["cost"]["msg_per_s"] / unsafe["cost"]["msg_per_s"]  # type: ignore[index]
            out.append({"goal": f"default save policy: throughput vs {UNSAFE} (unsafe), bridge at full speed",
                        "measured": f"{ratio:.2f}x", "target": ">= 0.90x", "met": ratio >= 0.9})
    for f in faults:
        out.append({"goal": f"default settings, {f['path']}: SIGKILL of the {f['fault']}",
                    "measured": f"{f['missing']} missing of {f['acked']}, {f['duplicates']} duplicates",
                    "target": "0 missing", "met": f["missing"] == 0})
    return out


def to_markdown(data: dict[str, object]) -> str:
    lines = [
        "# durability: what each fault loses, and what Mosquitto's save policies cost",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']}. Missing = messages the "
        "publisher got a PUBACK for (Kafka: a delivery report) that never arrived. Each fault is a "
        "SIGKILL of the process when a third of the stream arrived, then a start on the same folder.",
        "",
    ]
    rows = data.get("policies") or []
    if rows:
        base = next((r["cost"]["msg_per_s"] for r in rows if r["policy"] == UNSAFE), rows[0]["cost"]["msg_per_s"])  # type: ignore[index]
        lines += [
            f"## Save policies on a Mosquitto bridge A -> B ({data['messages']} messages as fast as "
            f"mosquitto_pub sends them, median of {data['repeats']} runs in alternating order, at most "
            f"{COST_CAP:.0f} s each; the kill: {data['stream']} messages at {data['rate']:.0f} msg/s)",
            "",
            f"`default` is no pk:persistEvery: `autosave_interval {DEFAULT_SAVE_SECONDS}` (Mosquitto saves when "
            f"its clock's whole second is more than {DEFAULT_SAVE_SECONDS} past the last save's) and the agent's "
            f"save signal (SIGUSR1) every {SAVE_TICK_SECONDS} s while the broker reads anything "
            "(engine.agent.save_tick). A number N: a save after every N changes. `tick:S`: only the save "
            f"signal, every S s. Ratio against `{UNSAFE}`.",
            "",
            "| save policy | msg/s, no kill | vs " + UNSAFE + " | target killed: missing of acked (duplicates) "
            "| same, subscriber offline | sessions present after the kill | MQTT -> Kafka: worker, then "
            "source Mosquitto killed 1 s later |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in rows:  # type: ignore[union-attr]
            c, k, o = r["cost"], r["killed"], r["killed_offline"]
            d = r.get("double_fault")
            present = "yes" if k["session_present"] and o["session_present"] else "no"
            double = "-" if d is None else f"{d['missing']} of {d['acked']} ({d['duplicates']})"
            lines.append(f"| {r['policy']} | {c['msg_per_s']:.0f}{' (capped)' if c.get('capped') else ''} | "
                         f"{c['msg_per_s'] / base:.2f} | "
                         f"{k['missing']} of {k['acked']} ({k['duplicates']}) | "
                         f"{o['missing']} of {o['acked']} ({o['duplicates']}) | {present} | {double} |")
        lines.append("")
    faults = data.get("faults") or []
    if faults:
        lines += [f"## plantkg's paths, default save policy ({data['stream']} messages at {data['rate']:.0f} msg/s)", "",
                  "| path | fault | missing of acked | duplicates |", "|---|---|---|---|"]
        for f in faults:  # type: ignore[union-attr]
            acked = "?" if f["acked"] is None else f["acked"]
            lines.append(f"| {f['path']} | {f['fault']} | {f['missing']} of {acked} | {f['duplicates']} |")
        lines.append("")
    lines += ["| goal (issue 16) | measured | target | verdict |", "|---|---|---|---|"]
    for g in data["goals"]:  # type: ignore[union-attr]
        lines.append(f"| {g['goal']} | {g['measured']} | {g['target']} | {'met' if g['met'] else 'not met'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=20_000, help="per throughput run (at most 60000)")
    parser.add_argument("--stream", type=int, default=15_000, help="messages per fault run")
    parser.add_argument("--rate", type=float, default=3000.0, help="msg/s of the fault runs")
    parser.add_argument("--repeats", type=int, default=3, help="throughput runs per policy")
    parser.add_argument("--policies", nargs="*", default=[UNSAFE, "default", "10", "100", "1"])
    parser.add_argument("--parts", nargs="+", type=int, choices=(1, 2, 3), default=[1, 2, 3],
                        help="1: policies on a Mosquitto bridge; 2: plantkg's paths with the default "
                             "policy; 3 (with 1): the double fault per policy")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    info = machine()
    policies, faults = [], []
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-durability-") as tmp:
        if 1 in args.parts:
            chosen = [Policy.parse(p) for p in args.policies]
            costs = policy_costs(Path(tmp) / "costs", chosen, args.messages, args.repeats)
            for i, policy in enumerate(chosen):
                folder = Path(tmp) / f"p{i}"
                policies.append({"policy": policy.name, "cost": costs[policy.name],
                                 "killed": policy_target_killed(folder / "kill", policy, args.stream,
                                                                args.rate, offline=False),
                                 "killed_offline": policy_target_killed(folder / "offline", policy,
                                                                        args.stream, args.rate, offline=True)})
                if 3 in args.parts:
                    policies[-1]["double_fault"] = mqtt_to_kafka(folder / "double", DOUBLE, args.stream,
                                                                 args.rate, policy)
        if 2 in args.parts:
            for i, (path, fault) in enumerate(PATH_FAULTS):
                run = mqtt_to_kafka if path == "mqtt-kafka" else kafka_to_mqtt
                faults.append({"path": path, "fault": fault,
                               **run(Path(tmp) / f"f{i}", fault, args.stream, args.rate)})
    data = {"command": command_line("benchmarks.bench_durability", argv), "machine": info,
            "messages": args.messages, "repeats": args.repeats, "stream": args.stream, "rate": args.rate,
            "policies": policies, "faults": faults, "goals": goals(policies, faults)}
    write_results(args.out, "durability", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

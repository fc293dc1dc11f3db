"""Benchmark: what broker users and ACLs cost a Mosquitto (issue 13), against the same Mosquitto
open to anonymous clients, in the same run.

Issue 13 asks for "the cost of TLS and ACLs … with and without, same run; goal ≤ 15% throughput
cost". TLS is not built yet and bridges at a closed broker are refused by the plan, so this
measures what exists: two Mosquitto brokers rendered by the real driver
(:class:`engine.drivers.mosquitto.driver.MosquittoDriver`, files 0600 as the agent writes them) on free
loopback ports, both up for the whole run:

- ``open``: no users (``allow_anonymous true``, no password or ACL file);
- ``closed``: ``BrokerSpec.users`` = a publisher that may write ``bench/t`` and a subscriber that
  may read it, passwords from ``file:`` references in a temp dir (0600). Mosquitto then checks the
  password at CONNECT and consults the ACL on every publish and every delivery. Before measuring,
  the run checks that it refuses an anonymous client (and fails otherwise).

Per broker and repeat (the order alternates between repeats, so drift of the shared machine
falls on both alike): N QoS-1 messages from one paho publisher with at most ``--window`` in
flight, to one QoS-1 subscriber; publish → PUBACK latency (p50, p99), end-to-end throughput
(distinct messages delivered / time from the first publish to the last delivery), and missing
messages (must be 0). A short warm-up per broker precedes the repeats and is not counted.
Reported: medians over the repeats, and closed / open ratios of throughput and p99.

The clients are Python (paho), on the same 2 cores as the brokers: the client side is likely the
bottleneck, so the ratio bounds what users and ACLs cost a plant's Python clients, not Mosquitto's
own ceiling.

Usage: ``python -m benchmarks.bench_security [--messages 20000] [--repeats 3] [--window 100] [--tiny]``.
Results: ``benchmarks/results/security.{json,md}``.
"""

from __future__ import annotations

import argparse
import secrets
import statistics
import tempfile
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from benchmarks.common import RESULTS, command_line, machine, percentile, write_results
from engine import netutil, process
from engine.agent.folder import RENDERED_MODE, write_atomic
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.model import BrokerSpec, BrokerUser

HOST = "127.0.0.1"
TOPIC = "bench/t"
GOAL_COST = 0.15  # issue 13: at most 15% throughput cost
ARMS = ("open", "closed")


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str


@dataclass
class Broker:
    """A Mosquitto rendered by the driver and run by :mod:`engine.process`."""

    spec: BrokerSpec
    folder: Path
    child: process.Child | None = None

    def start(self, driver: MosquittoDriver) -> Broker:
        files = driver.render_config(self.spec, self.folder)
        driver.prepare(self.spec, self.folder)
        for name, text in files.items():
            write_atomic(self.folder / name, text, RENDERED_MODE)
        self.child = process.spawn(driver.command(self.spec, self.folder), log_dir=self.folder, name="mosquitto")
        process.wait_until(lambda: driver.health(self.spec, 1.0), driver.start_deadline, 0.02,
                           what=f"mosquitto {self.spec.id} on {HOST}:{self.spec.port}", child=self.child)
        return self

    def stop(self) -> None:
        if self.child is not None:
            process.stop(self.child)
            self.child = None


def brokers(folder: Path) -> tuple[Broker, Broker, Credentials, Credentials]:
    """The open and the closed broker's specs (not started), and the closed one's publisher and
    subscriber, whose passwords are in 0600 files under ``folder/secrets``."""
    secret_dir = folder / "secrets"
    secret_dir.mkdir(parents=True, exist_ok=True)
    secret_dir.chmod(0o700)
    creds = {}
    for name in ("bench-pub", "bench-sub"):
        password = secrets.token_urlsafe(16)
        write_atomic(secret_dir / name, password + "\n", 0o600)
        creds[name] = Credentials(name, password)
    users = (BrokerUser("bench-pub", f"file:{secret_dir / 'bench-pub'}", write=(TOPIC,)),
             BrokerUser("bench-sub", f"file:{secret_dir / 'bench-sub'}", read=(TOPIC,)))

    def spec(arm: str, with_users: tuple[BrokerUser, ...]) -> BrokerSpec:
        return BrokerSpec(id=f"bench-{arm}", iri=f"https://example.org/bench#{arm}", name=arm, kind="mosquitto",
                          host=HOST, port=netutil.free_port(HOST), users=with_users)

    return (Broker(spec("open", ()), folder / "open"), Broker(spec("closed", users), folder / "closed"),
            creds["bench-pub"], creds["bench-sub"])


def closing_lines(folder: Path) -> list[str]:
    """The lines of the closed broker's rendered ``mosquitto.conf`` that close it (an error if
    one is missing: the run would measure an open broker twice)."""
    keys = {ln.split(" ", 1)[0]: ln for ln in (folder / "mosquitto.conf").read_text().splitlines() if ln.strip()}
    lines = [keys.get(k, f"(no {k})") for k in ("allow_anonymous", "password_file", "acl_file")]
    if lines[0] != "allow_anonymous false" or any(ln.startswith("(no ") for ln in lines):
        raise RuntimeError(f"the closed broker's mosquitto.conf in {folder} does not close it: {lines}")
    return lines


def connack(port: int, creds: Credentials | None) -> str:
    """The CONNACK reason (paho's name) a client gets from the broker on ``port``."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-probe-{uuid.uuid4().hex[:8]}")
    if creds is not None:
        client.username_pw_set(creds.user, creds.password)
    answers: list[str] = []
    client.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
    client.connect(HOST, port, keepalive=10)
    client.loop_start()
    try:
        return process.wait_until(lambda: answers[0] if answers else None, 10.0, what=f"a CONNACK on {port}")
    finally:
        client.disconnect()
        client.loop_stop()


def _client(port: int, creds: Credentials | None, role: str) -> tuple[mqtt.Client, list[str]]:
    """A paho client (not connected yet) and the list its CONNACK reasons go to."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-{role}-{uuid.uuid4().hex[:8]}")
    if creds is not None:
        client.username_pw_set(creds.user, creds.password)
    answers: list[str] = []
    client.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
    return client, answers


def _admitted(port: int, answers: list[str], role: str) -> bool:
    if answers and answers[0] != "Success":
        raise RuntimeError(f"the broker on port {port} refused the {role}: {answers[0]}")
    return bool(answers)


def one_run(port: int, count: int, window: int, pub: Credentials | None, sub: Credentials | None) -> dict[str, Any]:
    """``count`` QoS-1 messages, at most ``window`` unacknowledged, to one subscriber."""
    got: list[int] = []
    last = [0.0]
    subscriber, sub_up = _client(port, sub, "sub")
    granted: list[int] = []
    subscriber.on_subscribe = lambda _c, _u, _mid, codes, _p: granted.extend(c.value for c in codes)

    def on_message(_c: object, _u: object, msg: mqtt.MQTTMessage) -> None:
        got.append(int(msg.payload))
        last[0] = time.perf_counter()

    subscriber.on_message = on_message
    publisher, pub_up = _client(port, pub, "pub")
    publisher.max_inflight_messages_set(window)
    publisher.max_queued_messages_set(0)
    acks: list[tuple[int, float]] = []
    room = threading.BoundedSemaphore(window)

    def on_publish(_c: object, _u: object, mid: int, _reason: object, _p: object) -> None:
        acks.append((mid, time.perf_counter()))
        room.release()

    publisher.on_publish = on_publish
    subscriber.connect(HOST, port, keepalive=30)
    subscriber.loop_start()
    publisher.connect(HOST, port, keepalive=30)
    publisher.loop_start()
    try:
        process.wait_until(lambda: _admitted(port, sub_up, "subscriber") and _admitted(port, pub_up, "publisher"),
                           10.0, 0.005, what=f"both clients admitted on {port}")
        subscriber.subscribe(TOPIC, 1)
        process.wait_until(lambda: granted, 10.0, 0.005, what=f"the SUBACK on {port}")
        if granted[0] != 1:
            raise RuntimeError(f"the subscriber's QoS-1 subscription to {TOPIC} on port {port} got {granted[0]:#x}")
        sent: list[tuple[int, float]] = []
        start = time.perf_counter()
        for n in range(count):
            if not room.acquire(timeout=30):
                raise RuntimeError(f"no PUBACK for 30 s on port {port} after {n} messages")
            t = time.perf_counter()
            info = publisher.publish(TOPIC, str(n).encode(), qos=1)
            if info.rc != mqtt.MQTT_ERR_SUCCESS:
                raise RuntimeError(f"publish {n} on port {port} failed: {mqtt.error_string(info.rc)}")
            sent.append((info.mid, t))
        process.wait_until(lambda: len(acks) >= count, 60.0, 0.005, what=f"every PUBACK on {port}")
        # done when every message arrived, or nothing arrived for 5 s (the rest counts as missing)
        process.wait_until(lambda: len(set(got)) >= count or time.perf_counter() - max(last[0], start) > 5.0,
                           60.0 + count / 100, 0.01, what=f"the deliveries on {port}")
    finally:
        for client in (publisher, subscriber):
            client.disconnect()
            client.loop_stop()
    distinct = len(set(got))
    seconds = last[0] - start
    latencies = pair_latencies(sent, list(acks))
    return {"messages": count, "received": distinct, "missing": count - distinct,
            "duplicates": len(got) - distinct, "seconds": seconds,
            "msg_per_s": distinct / seconds if distinct and seconds > 0 else 0.0,
            "puback_ms": latency_summary(latencies)}


def pair_latencies(sent: list[tuple[int, float]], acks: list[tuple[int, float]]) -> list[float]:
    """Seconds from each publish to its PUBACK. Message ids are reused once acknowledged (and wrap
    at 65535), so the k-th send of an id pairs with the k-th PUBACK of that id."""
    by_mid: dict[int, list[float]] = {}
    for mid, t in acks:
        by_mid.setdefault(mid, []).append(t)
    seen: dict[int, int] = {}
    out = []
    for mid, t in sent:
        k = seen.get(mid, 0)
        seen[mid] = k + 1
        if k < len(by_mid.get(mid, ())):
            out.append(by_mid[mid][k] - t)
    return out


def latency_summary(seconds: list[float]) -> dict[str, float]:
    ms = sorted(x * 1000 for x in seconds)
    if not ms:
        return {"n": 0}
    return {"n": len(ms), "p50": percentile(ms, 50), "p99": percentile(ms, 99), "max": ms[-1]}


def medians(runs: list[dict[str, Any]]) -> dict[str, float]:
    return {"msg_per_s": statistics.median(r["msg_per_s"] for r in runs),
            "p50_ms": statistics.median(r["puback_ms"]["p50"] for r in runs),
            "p99_ms": statistics.median(r["puback_ms"]["p99"] for r in runs),
            "missing": sum(r["missing"] for r in runs)}


def _ratio(closed: float, open_: float) -> float | None:
    """closed / open, or None when the open baseline measured nothing (then the run has failed)."""
    return closed / open_ if open_ else None


def _fmt(ratio: float | None) -> str:
    return "n/a" if ratio is None else f"{ratio:.3f}"


def goals(data: dict[str, Any]) -> list[dict[str, Any]]:
    ratio = data["ratios"]["throughput_closed_over_open"]
    if ratio is None:
        return [{"goal": "ACL throughput cost (Mosquitto with users and ACLs vs open, same run)",
                 "measured": "n/a (no open baseline)", "target": f"≤ {GOAL_COST * 100:.0f}%", "met": False}]
    cost = 1 - ratio
    return [{"goal": "ACL throughput cost (Mosquitto with users and ACLs vs open, same run)",
             "measured": f"{cost * 100:+.1f}% (closed/open = {ratio:.3f})",
             "target": f"≤ {GOAL_COST * 100:.0f}%", "met": cost <= GOAL_COST}]


def to_markdown(data: dict[str, Any]) -> str:
    med, ratios = data["medians"], data["ratios"]
    lines = [
        "# security: a Mosquitto with users and ACLs against the same Mosquitto open",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']}",
        "",
        f"{data['messages']} QoS-1 messages per run, one publisher (at most {data['window']} in flight) → "
        f"`{TOPIC}` → one QoS-1 subscriber; {data['repeats']} repeats per broker, order alternating; medians. "
        "`closed`: anonymous refused (checked), password check at CONNECT, ACL on every publish and delivery. "
        "TLS: not built yet, not measured.",
        "",
        "| broker | msg/s delivered | publish → PUBACK p50 ms | p99 ms | missing |",
        "|---|---|---|---|---|",
    ]
    for arm in ARMS:
        m = med[arm]
        lines.append(f"| {arm} | {m['msg_per_s']:.0f} | {m['p50_ms']:.2f} | {m['p99_ms']:.2f} | {m['missing']} |")
    lines += ["", f"Closed / open: throughput {_fmt(ratios['throughput_closed_over_open'])}, "
              f"p99 {_fmt(ratios['p99_closed_over_open'])}, p50 {_fmt(ratios['p50_closed_over_open'])}. "
              "Per repeat (throughput closed/open): "
              + ", ".join(_fmt(r) for r in ratios["throughput_per_repeat"]) + ".", ""]
    for g in data["goals"]:
        lines.append(f"Goal: {g['goal']}: {g['measured']}, target {g['target']}: "
                     f"{'met' if g['met'] else '**not met**'}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--window", type=int, default=100, help="most QoS-1 messages in flight (default 100)")
    parser.add_argument("--warmup", type=int, default=1000, help="uncounted messages per broker first")
    parser.add_argument("--tiny", action="store_true", help="300 messages, 2 repeats: seconds")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.tiny:
        args.messages, args.repeats, args.warmup, args.window = 300, 2, 50, 50
    for name in ("messages", "repeats", "window"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be at least 1 (got {getattr(args, name)})")
    if args.warmup < 0:
        parser.error(f"--warmup must be at least 0 (got {args.warmup})")
    info = machine()
    runs: dict[str, list[dict[str, Any]]] = {arm: [] for arm in ARMS}
    driver = MosquittoDriver()
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-security-") as tmp:
        open_b, closed_b, pub, sub = brokers(Path(tmp))
        started: list[Broker] = []
        try:
            for b in (open_b, closed_b):
                started.append(b.start(driver))
            closed_conf = closing_lines(closed_b.folder)
            refused = connack(closed_b.spec.port, None)
            if refused == "Success":
                raise RuntimeError("the closed broker admitted an anonymous client: nothing to measure")
            creds = {"open": (None, None), "closed": (pub, sub)}
            ports = {"open": open_b.spec.port, "closed": closed_b.spec.port}
            for arm in ARMS:
                if args.warmup:
                    one_run(ports[arm], args.warmup, args.window, *creds[arm])
            for r in range(args.repeats):
                for arm in (ARMS if r % 2 == 0 else ARMS[::-1]):
                    runs[arm].append(one_run(ports[arm], args.messages, args.window, *creds[arm]))
        finally:
            for b in started:
                b.stop()
    med = {arm: medians(runs[arm]) for arm in ARMS}
    data: dict[str, Any] = {
        "command": command_line("benchmarks.bench_security", argv), "machine": info,
        "messages": args.messages, "repeats": args.repeats, "window": args.window, "warmup": args.warmup,
        "anonymous_on_closed": refused, "closed_conf": closed_conf, "runs": runs, "medians": med,
        "ratios": {"throughput_closed_over_open": _ratio(med["closed"]["msg_per_s"], med["open"]["msg_per_s"]),
                   "p99_closed_over_open": _ratio(med["closed"]["p99_ms"], med["open"]["p99_ms"]),
                   "p50_closed_over_open": _ratio(med["closed"]["p50_ms"], med["open"]["p50_ms"]),
                   "throughput_per_repeat": [_ratio(c["msg_per_s"], o["msg_per_s"])
                                             for o, c in zip(runs["open"], runs["closed"])]},
    }
    data["goals"] = goals(data)
    write_results(args.out, "security", data, to_markdown(data))
    missing = med["open"]["missing"] + med["closed"]["missing"]
    if missing:
        print(f"{missing} message(s) missing: the figures above do not count them")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

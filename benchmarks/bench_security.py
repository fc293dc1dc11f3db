"""Benchmark: what broker users, ACLs and TLS cost a Mosquitto and a Mosquitto bridge (issue 13),
against the same brokers open and plain, in the same run.

Issue 13 asks for "the cost of TLS and ACLs … bridge throughput and publish→PUBACK p99 with and
without, same run; goal ≤ 15% throughput cost". Five Mosquitto brokers rendered by the real driver
(:class:`engine.drivers.mosquitto.driver.MosquittoDriver`, files 0600 as the agent writes them, a
plant CA and a principal key in the run's temp dir), on free loopback ports, all up for the whole
run, measured as five arms:

- ``open``: no users (``allow_anonymous true``, no users file), plain MQTT;
- ``closed``: ``BrokerSpec.users`` = a publisher that may write ``bench/t`` and a subscriber that
  may read it, passwords from ``file:`` references (0600): Mosquitto checks the password at
  CONNECT and the users file's ACLs (dynamic security plugin) on every publish and delivery;
- ``closed-tls``: the same, and its listener speaks TLS only (``pk:tls``: a plant-CA certificate);
  the clients verify it against the CA;
- ``bridge-open``: a publisher on an open broker, Mosquitto's bridge to a second open broker, the
  subscriber there (plain, anonymous: plantkg before issue 13);
- ``bridge-closed-tls``: the same through two closed TLS brokers: the publisher and subscriber log
  in over TLS, the bridge logs in to the remote as its principal over TLS (``bridge_cafile``).

Before measuring, the run checks that each closed broker refuses an anonymous client (and fails
otherwise). Per arm and repeat (the order rotates between repeats, so drift of the shared machine
falls on all alike): N QoS-1 messages from one publisher with at most ``--window`` in flight,
to one QoS-1 subscriber; publish → PUBACK latency (p50, p99), end-to-end throughput (distinct
messages delivered / time from the first publish to the last delivery), missing messages
(must be 0), and the CPU (user + system, from /proc) of the arm's brokers and of its two clients
per delivered message. A short warm-up per arm precedes the repeats and is not counted. Reported:
medians over the repeats, and ratios to the plain open arm of the same path (single broker,
bridge).

Why the CPU columns: on a 2-core machine the brokers and the load generator share the cores, so
throughput is CPU-bound and a run of 20k messages (under a second) varied 0.4–1.8× between
repeats. The defaults are 100k messages and 5 repeats; the CPU per message of the brokers says what
TLS and ACLs cost them, independent of how the scheduler shared the cores in that run.

The clients are the Go load generator (``tools/loadgen``, built by ``make setup``; the run refuses
without it): publisher and subscriber each in its own process, so the client side no longer runs
in Python on the brokers' cores (they still share the machine's 2 cores; each run records the
clients' CPU per message). The anonymous-refusal probe stays a paho client (it measures nothing).

Usage: ``python -m benchmarks.bench_security [--messages 100000] [--repeats 5] [--window 100] [--tiny]``.
Results: ``benchmarks/results/security.{json,md}``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import secrets
import statistics
import tempfile
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator
from unittest import mock

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from benchmarks import loadgen
from benchmarks.common import RESULTS, command_line, cpu_seconds, machine, percentile, write_results
from engine import netutil, process
from engine.agent.folder import RENDERED_MODE, write_atomic
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.model import BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec, BrokerSpec, BrokerUser
from engine.security import ca, principal_key, principals

HOST = "127.0.0.1"
TOPIC = "bench/t"
GOAL_COST = 0.15  # issue 13: at most 15% throughput cost
ARMS = ("open", "closed", "closed-tls", "bridge-open", "bridge-closed-tls")
#: arm -> the plain open arm of the same path, its baseline
BASELINE = {"closed": "open", "closed-tls": "open", "bridge-closed-tls": "bridge-open"}
#: arm -> the brokers its messages cross (their CPU is the arm's broker CPU)
ARM_BROKERS = {"open": ("open",), "closed": ("closed",), "closed-tls": ("closed-tls",),
               "bridge-open": ("bridge-open-a", "bridge-open-b"),
               "bridge-closed-tls": ("bridge-tls-a", "bridge-tls-b")}


@dataclass(frozen=True)
class Credentials:
    user: str
    password: str


@dataclass(frozen=True)
class Client:
    """How a bench client reaches its broker: port, login, TLS (the plant CA's certificate)."""

    port: int
    creds: Credentials | None = None
    ca_file: Path | None = None


@dataclass
class Broker:
    """A Mosquitto rendered by the driver and run by :mod:`engine.process`."""

    spec: BrokerSpec
    folder: Path
    child: process.Child | None = None
    bridges: tuple[BridgeSpec, ...] = ()

    def start(self, driver: MosquittoDriver) -> Broker:
        files = driver.render_config(self.spec, self.folder, self.bridges)
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


@contextlib.contextmanager
def own_secrets(folder: Path) -> Iterator[None]:
    """Point plantkg at a principal key and a plant CA in `folder` for the block, never the user's.

    The environment is restored as it was when the block ends, however it ends.
    """
    with mock.patch.dict(os.environ, {principal_key.KEY_ENV: str(folder / "principal-key"),
                                      ca.CA_ENV: str(folder / "ca")}):
        yield


def brokers(folder: Path) -> tuple[dict[str, Broker], Credentials, Credentials]:
    """The brokers of every arm (not started), and the closed ones' publisher and subscriber, whose
    passwords are in 0600 files under ``folder/secrets``."""
    secret_dir = folder / "secrets"
    secret_dir.mkdir(parents=True, exist_ok=True)
    secret_dir.chmod(0o700)
    creds = {}
    for name in ("bench-pub", "bench-sub"):
        password = secrets.token_urlsafe(16)
        write_atomic(secret_dir / name, password + "\n", 0o600)
        creds[name] = Credentials(name, password)
    pub_user = BrokerUser("bench-pub", f"file:{secret_dir / 'bench-pub'}", write=(TOPIC,))
    sub_user = BrokerUser("bench-sub", f"file:{secret_dir / 'bench-sub'}", read=(TOPIC,))

    def spec(name: str, users: tuple[BrokerUser, ...] = (), tls: bool = False) -> BrokerSpec:
        return BrokerSpec(id=f"bench-{name}", iri=f"https://example.org/bench#{name}", name=name,
                          kind="mosquitto", host=HOST, port=netutil.free_port(HOST), users=users,
                          allow_anonymous=None if not users else False, tls=tls)

    out = {"open": spec("open"), "closed": spec("closed", (pub_user, sub_user)),
           "closed-tls": spec("closed-tls", (pub_user, sub_user), tls=True),
           "bridge-open-a": spec("bridge-open-a"), "bridge-open-b": spec("bridge-open-b"),
           "bridge-tls-a": spec("bridge-tls-a", (pub_user,), tls=True)}
    principal = BrokerUser(principals.bridge_principal("bench-bridge-tls-a", "bench-bridge-tls-b"),
                           principals.PRINCIPAL_REF, write=(TOPIC,))
    out["bridge-tls-b"] = spec("bridge-tls-b", (sub_user, principal), tls=True)

    def bridge(a: BrokerSpec, b: BrokerSpec) -> BridgeSpec:
        return BridgeSpec(local=BridgeEnd(a.id, a.kind, a.host, a.port, tls=a.tls),
                          remote=BridgeEnd(b.id, b.kind, b.host, b.port, tls=b.tls),
                          mechanism=BridgeMechanism.MOSQUITTO,
                          routes=(BridgeRoute(TOPIC, BridgeDirection.OUT, 1),))

    found = {name: Broker(s, folder / name) for name, s in out.items()}
    for a, b in (("bridge-open-a", "bridge-open-b"), ("bridge-tls-a", "bridge-tls-b")):
        found[a].bridges = (bridge(out[a], out[b]),)
    return found, creds["bench-pub"], creds["bench-sub"]


def clients(found: dict[str, Broker], pub: Credentials, sub: Credentials,
            ca_file: Path) -> dict[str, tuple[Client, Client]]:
    """arm -> (publisher, subscriber)."""
    port = {name: b.spec.port for name, b in found.items()}
    return {
        "open": (Client(port["open"]), Client(port["open"])),
        "closed": (Client(port["closed"], pub), Client(port["closed"], sub)),
        "closed-tls": (Client(port["closed-tls"], pub, ca_file), Client(port["closed-tls"], sub, ca_file)),
        "bridge-open": (Client(port["bridge-open-a"]), Client(port["bridge-open-b"])),
        "bridge-closed-tls": (Client(port["bridge-tls-a"], pub, ca_file),
                              Client(port["bridge-tls-b"], sub, ca_file)),
    }


def bridge_up(broker: Broker) -> bool:
    """The bridge of ``broker`` reports itself connected (its retained $SYS state, read as the
    agent reads it)."""
    return all(MosquittoDriver().bridge_states(broker.spec, broker.bridges, 2.0).values()) \
        and bool(broker.bridges)


def closing_lines(folder: Path) -> list[str]:
    """The lines of the closed broker's rendered ``mosquitto.conf`` that close it (an error if
    one is missing: the run would measure an open broker twice)."""
    keys = {ln.split(" ", 1)[0]: ln for ln in (folder / "mosquitto.conf").read_text().splitlines()
            if ln.strip() and not ln.startswith("connection")}
    lines = [keys.get(k, f"(no {k})") for k in ("allow_anonymous", "plugin", "plugin_opt_config_file")]
    if lines[0] != "allow_anonymous false" or any(ln.startswith("(no ") for ln in lines):
        raise RuntimeError(f"the closed broker's mosquitto.conf in {folder} does not close it: {lines}")
    return lines


def connack(target: Client) -> str:
    """The CONNACK reason (paho's name) a client gets from the broker on ``target.port``."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-probe-{uuid.uuid4().hex[:8]}")
    _secure(client, target)
    port = target.port
    answers: list[str] = []
    client.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
    client.connect(HOST, port, keepalive=10)
    client.loop_start()
    try:
        return process.wait_until(lambda: answers[0] if answers else None, 10.0, what=f"a CONNACK on {port}")
    finally:
        client.disconnect()
        client.loop_stop()


def _secure(client: mqtt.Client, target: Client) -> None:
    if target.ca_file is not None:
        client.tls_set(ca_certs=str(target.ca_file))
    if target.creds is not None:
        client.username_pw_set(target.creds.user, target.creds.password)


def _client(target: Client, role: str) -> tuple[mqtt.Client, list[str]]:
    """A paho client (not connected yet) and the list its CONNACK reasons go to."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"bench-{role}-{uuid.uuid4().hex[:8]}")
    _secure(client, target)
    answers: list[str] = []
    client.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
    return client, answers


def _admitted(port: int, answers: list[str], role: str) -> bool:
    if answers and answers[0] != "Success":
        raise RuntimeError(f"the broker on port {port} refused the {role}: {answers[0]}")
    return bool(answers)


def _target(client: Client) -> loadgen.Target:
    creds = client.creds
    return loadgen.Target(f"{HOST}:{client.port}", creds.user if creds else None,
                          creds.password if creds else None, client.ca_file)


def one_run(pub: Client, sub: Client, count: int, window: int, broker_pids: tuple[int, ...] = ()) -> dict[str, Any]:
    """``count`` QoS-1 messages, at most ``window`` unacknowledged, to one subscriber (on the
    same broker, or on the far side of a bridge): the Go load generator's ``mqtt-sub`` and
    ``mqtt-pub``, each in its own process, the publisher started once the subscriber holds its
    SUBACK. The subscriber stops at ``count`` distinct messages, or 5 s after the last new one (the
    rest counts as missing). The CPU the brokers of ``broker_pids`` used meanwhile is recorded
    (user + system, all threads, from /proc)."""
    deadline = 60.0 + count / 100
    broker_cpu0 = sum(cpu_seconds(pid) for pid in broker_pids)
    receiver = loadgen.start("mqtt-sub", _target(sub), TOPIC, count, deadline, ("--idle", "5s"))
    try:
        sent = loadgen.publish(_target(pub), TOPIC, count, window, deadline)
    except BaseException:
        receiver.stop()
        raise
    got = receiver.result(deadline + 30.0)
    broker_cpu = sum(cpu_seconds(pid) for pid in broker_pids) - broker_cpu0
    if sent.error or sent.acked != count:
        raise RuntimeError(f"the publisher on port {pub.port} got {sent.acked}/{count} PUBACKs: {sent.error}")
    seconds = (got.last_ns - sent.start_ns) / 1e9 if got.last_ns and sent.start_ns else 0.0
    return {"messages": count, "received": got.received, "missing": got.missing,
            "duplicates": got.duplicates, "seconds": seconds,
            "msg_per_s": got.received / seconds if got.received and seconds > 0 else 0.0,
            "puback_ms": {"n": sent.acked, "p50": sent.p50_ms, "p99": sent.p99_ms, "max": sent.max_ms},
            "end_to_end_ms": {"p50": got.p50_ms, "p99": got.p99_ms, "max": got.max_ms},
            "client_cpu_s": {"publisher": sent.cpu_s, "subscriber": got.cpu_s},
            "broker_cpu_s": broker_cpu}


def latency_summary(seconds: list[float]) -> dict[str, float]:
    ms = sorted(x * 1000 for x in seconds)
    if not ms:
        return {"n": 0}
    return {"n": len(ms), "p50": percentile(ms, 50), "p99": percentile(ms, 99), "max": ms[-1]}


def _per_msg_us(seconds: float, run: dict[str, Any]) -> float:
    return 1e6 * seconds / max(run["received"], 1)


def _client_cpu(run: dict[str, Any]) -> float:
    return run["client_cpu_s"]["publisher"] + run["client_cpu_s"]["subscriber"]


def medians(runs: list[dict[str, Any]]) -> dict[str, float]:
    return {"msg_per_s": statistics.median(r["msg_per_s"] for r in runs),
            "p50_ms": statistics.median(r["puback_ms"]["p50"] for r in runs),
            "p99_ms": statistics.median(r["puback_ms"]["p99"] for r in runs),
            "missing": sum(r["missing"] for r in runs),
            # the load generator's own CPU (publisher + subscriber) per delivered message, µs
            "client_cpu_us_per_msg": statistics.median(_per_msg_us(_client_cpu(r), r) for r in runs),
            # the arm's brokers' CPU per delivered message, µs, and everything's (brokers + clients)
            "broker_cpu_us_per_msg": statistics.median(_per_msg_us(r["broker_cpu_s"], r) for r in runs),
            "total_cpu_us_per_msg": statistics.median(_per_msg_us(r["broker_cpu_s"] + _client_cpu(r), r)
                                                      for r in runs)}


def _ratio(value: float, base: float) -> float | None:
    """value / base, or None when the baseline measured nothing (then the run has failed)."""
    return value / base if base else None


def _fmt(ratio: float | None) -> str:
    return "n/a" if ratio is None else f"{ratio:.3f}"


GOAL_NAMES = {"closed": "ACL throughput cost (a Mosquitto with users and ACLs vs open, same run)",
              "closed-tls": "TLS + ACL throughput cost (one Mosquitto, vs open and plain, same run)",
              "bridge-closed-tls": "TLS + ACL bridge throughput cost (two closed TLS Mosquittos and "
                                   "their bridge, vs open and plain, same run)"}


def goals(data: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for arm, name in GOAL_NAMES.items():
        ratio = data["ratios"][arm]["throughput"]
        if ratio is None:
            out.append({"goal": name, "measured": "n/a (no baseline)", "target": f"≤ {GOAL_COST * 100:.0f}%",
                        "met": False})
            continue
        cost = 1 - ratio
        out.append({"goal": name, "measured": f"{cost * 100:+.1f}% ({arm}/{BASELINE[arm]} = {ratio:.3f})",
                    "target": f"≤ {GOAL_COST * 100:.0f}%", "met": ratio >= 1 - GOAL_COST})  # not cost <= 0.15: 1 - 0.85 > 0.15 in floats
    return out


def to_markdown(data: dict[str, Any]) -> str:
    med, ratios = data["medians"], data["ratios"]
    lines = [
        "# security: users, ACLs and TLS on a Mosquitto and a bridge, against the same open and plain",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']}",
        "",
        f"{data['messages']} QoS-1 messages per run, one publisher (at most {data['window']} in flight) → "
        f"`{TOPIC}` → one QoS-1 subscriber (on the same broker, or on the far side of a Mosquitto bridge); "
        f"{data['repeats']} repeats per arm, order rotating; medians. `closed`: anonymous refused (checked), "
        "password check at CONNECT, ACL (dynamic security plugin) on every publish and delivery. `tls`: the "
        "listener speaks TLS only, clients (and the bridge) verify a plant-CA certificate. Clients: the Go load "
        "generator (`tools/loadgen`), publisher and subscriber each in its own process; client CPU is theirs "
        "(user + system) per delivered message.",
        "",
        "| arm | msg/s delivered | publish → PUBACK p50 ms | p99 ms | missing | broker CPU µs/msg | "
        "client CPU µs/msg | throughput vs baseline | p99 vs baseline | broker CPU vs baseline | "
        "all CPU vs baseline |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for arm in ARMS:
        m, r = med[arm], ratios.get(arm)
        lines.append(f"| {arm} | {m['msg_per_s']:.0f} | {m['p50_ms']:.2f} | {m['p99_ms']:.2f} | {m['missing']} | "
                     + f"{m['broker_cpu_us_per_msg']:.1f} | {m['client_cpu_us_per_msg']:.0f} | "
                     + (f"{_fmt(r['throughput'])} | {_fmt(r['p99'])} | {_fmt(r['broker_cpu'])} | "
                        f"{_fmt(r['total_cpu'])} |" if r else "baseline | baseline | baseline | baseline |"))
    lines += ["", "Per repeat (throughput vs baseline): "
              + "; ".join(f"{arm}: " + ", ".join(_fmt(x) for x in ratios[arm]["throughput_per_repeat"])
                          for arm in BASELINE) + ".", ""]
    cpu = [med[arm]["client_cpu_us_per_msg"] for arm in ARMS]
    cores = med["open"]["client_cpu_us_per_msg"] * med["open"]["msg_per_s"] / 1e6
    lines += [f"Client side: the load generator (publisher + subscriber processes) used {min(cpu):.0f}–{max(cpu):.0f} µs "
              f"of CPU per delivered message (medians per arm), i.e. {cores:.2f} of a core at the open arm's rate, "
              f"on the same {data['machine'].get('cpus', '?')} cores as the brokers: the ratios include that share.",
              ""]
    for g in data["goals"]:
        lines.append(f"Goal: {g['goal']}: {g['measured']}, target {g['target']}: "
                     f"{'met' if g['met'] else '**not met**'}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--window", type=int, default=100, help="most QoS-1 messages in flight (default 100)")
    parser.add_argument("--warmup", type=int, default=1000, help="uncounted messages per arm first")
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
    loadgen.binary()  # refuse before starting brokers when the load generator is not built
    info = machine()
    runs: dict[str, list[dict[str, Any]]] = {arm: [] for arm in ARMS}
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix="plantkg-bench-security-"))
        stack.enter_context(own_secrets(Path(tmp)))
        driver = MosquittoDriver()
        found, pub, sub = brokers(Path(tmp))
        started: list[Broker] = []
        try:
            for name in ("open", "closed", "closed-tls", "bridge-open-b", "bridge-tls-b",
                         "bridge-open-a", "bridge-tls-a"):  # remotes first: the bridges connect at once
                started.append(found[name].start(driver))
            ca_file = ca.ca_cert_file()
            targets = clients(found, pub, sub, ca_file)
            closed_conf = {name: closing_lines(found[name].folder)
                           for name in ("closed", "closed-tls", "bridge-tls-a", "bridge-tls-b")}
            refused = {name: connack(Client(found[name].spec.port, None, ca_file if found[name].spec.tls else None))
                       for name in closed_conf}
            if "Success" in refused.values():
                raise RuntimeError(f"a closed broker admitted an anonymous client ({refused}): nothing to measure")
            for name in ("bridge-open-a", "bridge-tls-a"):
                process.wait_until(lambda b=found[name]: bridge_up(b), 30.0, 0.1,
                                   what=f"the bridge of {name} to connect")
            pids = {arm: tuple(found[name].child.pid for name in ARM_BROKERS[arm] if found[name].child)
                    for arm in ARMS}
            for arm in ARMS:
                if args.warmup:
                    one_run(*targets[arm], args.warmup, args.window)
            for r in range(args.repeats):
                order = ARMS[r % len(ARMS):] + ARMS[:r % len(ARMS)]
                for arm in order:
                    runs[arm].append(one_run(*targets[arm], args.messages, args.window, pids[arm]))
        finally:
            for b in started:
                b.stop()
    med = {arm: medians(runs[arm]) for arm in ARMS}
    ratios = {arm: {"throughput": _ratio(med[arm]["msg_per_s"], med[base]["msg_per_s"]),
                    "p99": _ratio(med[arm]["p99_ms"], med[base]["p99_ms"]),
                    "p50": _ratio(med[arm]["p50_ms"], med[base]["p50_ms"]),
                    "broker_cpu": _ratio(med[arm]["broker_cpu_us_per_msg"], med[base]["broker_cpu_us_per_msg"]),
                    "total_cpu": _ratio(med[arm]["total_cpu_us_per_msg"], med[base]["total_cpu_us_per_msg"]),
                    "throughput_per_repeat": [_ratio(a["msg_per_s"], b["msg_per_s"])
                                              for a, b in zip(runs[arm], runs[base])]}
              for arm, base in BASELINE.items()}
    data: dict[str, Any] = {
        "command": command_line("benchmarks.bench_security", argv), "machine": info,
        "messages": args.messages, "repeats": args.repeats, "window": args.window, "warmup": args.warmup,
        "anonymous_on_closed": refused, "closed_conf": closed_conf, "runs": runs, "medians": med,
        "ratios": ratios,
    }
    data["goals"] = goals(data)
    write_results(args.out, "security", data, to_markdown(data))
    missing = sum(m["missing"] for m in med.values())
    if missing:
        print(f"{missing} message(s) missing: the figures above do not count them")
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

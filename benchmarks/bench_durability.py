"""Benchmark: what a Mosquitto bridge target loses when killed with SIGKILL, per save policy.

Mosquitto keeps sessions, subscriptions and queued messages in memory and saves them after every
``pk:persistEvery`` N changes (plantkg's default: ``DEFAULT_PERSIST_EVERY``, 10). The baseline is
the unsafe setting a plant can choose for speed, ``1000000`` (saved in practice only on a clean
stop, like Mosquitto's own time-based save). For each policy, same run, same machine:

- ``msg/s``: QoS-1 messages per second from a publisher on broker A, across A's own bridge, to a
  persistent subscriber on broker B (distinct messages received / time from first send to last
  receive), and its ratio to the unsafe baseline;
- after a SIGKILL of B once a third of the messages arrived, and B started again on the same
  folder: how many messages the subscriber never received (``missing``) and received twice.

Usage: ``python -m benchmarks.bench_durability [--messages 10000] [--policies 1000000 default 100 1]``.
Results: ``benchmarks/results/durability.{json,md}``.
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
import uuid
from pathlib import Path

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from benchmarks.bridge_rig import Mosquitto
from benchmarks.common import RESULTS, command_line, machine, write_results
from engine import process
from engine.drivers.mosquitto.runtime import BRIDGE_RESTART_TIMEOUT, DEFAULT_PERSIST_EVERY, MosquittoBridge, MosquittoBridgeTopic

TOPIC = "bench/durability"
UNSAFE = "1000000"  # the largest pk:persistEvery: saved in practice only on a clean stop


class Subscriber:
    """Persistent QoS-1 subscriber that resubscribes on every connect."""

    def __init__(self, port: int) -> None:
        self.got: list[int] = []
        self.last = time.monotonic()
        self._lock = threading.Lock()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"sub-{uuid.uuid4().hex[:8]}",
                                  clean_session=False)
        self.client.reconnect_delay_set(0.1, 1)
        subscribed = threading.Event()
        self.client.on_connect = lambda c, *_: c.subscribe(TOPIC, 1)
        self.client.on_subscribe = lambda *_: subscribed.set()
        self.client.on_message = self._on_message
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        process.wait_until(subscribed.is_set, 10, 0.01, what="SUBACK")

    def _on_message(self, _c: object, _u: object, msg: mqtt.MQTTMessage) -> None:
        with self._lock:
            self.got.append(int(msg.payload))
            self.last = time.monotonic()

    def distinct(self) -> int:
        with self._lock:
            return len(set(self.got))

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


def publish(port: int, count: int, on_each: object = None) -> None:
    pub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"pub-{uuid.uuid4().hex[:8]}")
    pub.max_inflight_messages_set(1000)
    pub.max_queued_messages_set(0)
    pub.connect("127.0.0.1", port)
    pub.loop_start()
    try:
        for info in [pub.publish(TOPIC, str(n).encode(), qos=1) for n in range(count)]:
            info.wait_for_publish(timeout=60)
    finally:
        pub.loop_stop()
        pub.disconnect()


def one_run(folder: Path, count: int, every: int | None, kill: bool) -> dict[str, object]:
    target = Mosquitto(folder / "b", persist_every=every).start()
    bridge = MosquittoBridge("bench.a.b", target.host, target.port,
                             (MosquittoBridgeTopic(TOPIC, "out", 1),))
    source = Mosquitto(folder / "a", bridges=(bridge,)).start()
    sink = Subscriber(target.port)
    try:
        process.wait_until(lambda: _bridged(source.port, sink), 30, 0.05, what="the bridge to connect")
        sink.got.clear()
        start = time.monotonic()
        killer = threading.Thread(target=_kill_at_a_third, args=(target, sink, count)) if kill else None
        if killer:
            killer.start()
        publish(source.port, count)
        quiet_since = start
        if killer:
            killer.join(60)
            target.start()
            quiet_since = time.monotonic()
        # done when everything arrived, or when nothing arrived for longer than the source's bridge
        # may wait before it reconnects (its backoff cap): a shorter wait counts as "missing" what
        # the bridge would still deliver
        idle = BRIDGE_RESTART_TIMEOUT[1] + 5.0
        process.wait_until(lambda: sink.distinct() >= count
                           or time.monotonic() - max(sink.last, quiet_since) > idle,
                           180, 0.05, what="the stream to end")
        seconds = sink.last - start
        distinct = sink.distinct()
        return {"received": distinct, "missing": count - distinct,
                "duplicates": len(sink.got) - distinct, "seconds": seconds,
                "msg_per_s": distinct / seconds if seconds > 0 else None}
    finally:
        sink.close()
        source.stop()
        target.stop()


def _bridged(port: int, sink: Subscriber) -> bool:
    """Publish one probe (-1) and see it arrive."""
    pub = mqtt.Client(CallbackAPIVersion.VERSION2)
    pub.connect("127.0.0.1", port)
    pub.loop_start()
    pub.publish(TOPIC, b"-1", qos=1).wait_for_publish(5)
    pub.loop_stop()
    pub.disconnect()
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        if -1 in sink.got:
            return True
        time.sleep(0.01)
    return False


def _kill_at_a_third(target: Mosquitto, sink: Subscriber, count: int) -> None:
    process.wait_until(lambda: sink.distinct() >= count // 3, 60, 0.001, what="a third of the stream")
    target.kill()


def to_markdown(data: dict[str, object]) -> str:
    rows = data["rows"]  # type: ignore[index]
    base_policy = UNSAFE if any(r["policy"] == UNSAFE for r in rows) else rows[0]["policy"]  # type: ignore[index]
    base = next(r["throughput"]["msg_per_s"] for r in rows if r["policy"] == base_policy)  # type: ignore[index]
    lines = [
        "# durability: a Mosquitto bridge target killed with SIGKILL, per save policy",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']} · {data['messages']} QoS-1 "
        "messages A -> A's bridge -> B -> persistent subscriber on B; the kill comes when a third "
        "arrived, then B starts again on the same folder.",
        "",
        f"Baseline of the ratio: `{base_policy}`. `default` is no pk:persistEvery, which plantkg renders "
        f"as a save every {DEFAULT_PERSIST_EVERY} changes.",
        "",
        f"| save policy (pk:persistEvery) | msg/s, no kill | vs {base_policy} | missing after SIGKILL | duplicates |",
        "|---|---|---|---|---|",
    ]
    for r in rows:  # type: ignore[union-attr]
        t, k = r["throughput"], r["killed"]
        rate = t["msg_per_s"]
        lines.append(f"| {r['policy']} | {rate:.0f} | {rate / base:.2f} | {k['missing']} | {k['duplicates']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--messages", type=int, default=10_000)
    parser.add_argument("--policies", nargs="+", default=[UNSAFE, "default", "100", "1"])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    info = machine()
    rows = []
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-durability-") as tmp:
        for i, policy in enumerate(args.policies):
            every = None if policy == "default" else int(policy)
            rows.append({
                "policy": policy,
                "throughput": one_run(Path(tmp) / f"{i}-plain", args.messages, every, kill=False),
                "killed": one_run(Path(tmp) / f"{i}-killed", args.messages, every, kill=True),
            })
    data = {"command": command_line("benchmarks.bench_durability", argv), "machine": info,
            "messages": args.messages, "rows": rows}
    write_results(args.out, "durability", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

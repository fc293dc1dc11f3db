"""Benchmark: bridges against the raw MQTT path, measured in the same run, on loopback.

Paths (each: one publisher, one subscriber, QoS 1, 100-byte payloads carrying their index and
send time):

- ``raw``: paho publisher -> one Mosquitto -> paho subscriber;
- ``mosquitto-bridge``: publisher -> Mosquitto A -> A's own bridge (rendered by
  engine.drivers.mosquitto.runtime) -> Mosquitto B -> subscriber;
- ``mqtt-kafka``: publisher -> Mosquitto -> bridge worker -> Kafka -> confluent consumer;
- ``kafka-mqtt``: confluent producer -> Kafka -> bridge worker -> Mosquitto -> subscriber.

Two phases per path: ``max`` sends as fast as the sender can (sustained msg/s = distinct messages
received / time from first send to last receive) and ``paced`` sends at half the raw path's
``max`` rate (end-to-end latency p50/p99 at a load every path should sustain). Lost and
duplicate counts for every run. Results: ``benchmarks/results/bridge.{json,md}``.

Usage: ``python -m benchmarks.bench_bridge [--messages 20000]``
"""

from __future__ import annotations

import argparse
import struct
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
from confluent_kafka import Consumer, Producer, TopicPartition
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from benchmarks import bridge_rig as rig
from benchmarks.common import RESULTS, machine, write_results
from engine import process
from engine.bridge_worker.config import Direction, Route, WorkerConfig
from engine.errors import WaitTimeoutError
from engine.drivers.mosquitto.runtime import MosquittoBridge, MosquittoBridgeTopic

PAYLOAD_SIZE = 100
HEADER = struct.Struct("!QQ")  # index, send time (ns since the epoch)
PATHS = ("raw", "mosquitto-bridge", "mqtt-kafka", "kafka-mqtt")
IDLE_LIMIT = 10.0              # seconds without a new message before a run is declared over


def message(index: int) -> bytes:
    return HEADER.pack(index, time.time_ns()).ljust(PAYLOAD_SIZE, b".")


class Receiver:
    """Arrival times by message index (first arrival) and the duplicate count."""

    def __init__(self) -> None:
        self.first: dict[int, tuple[int, int]] = {}   # index -> (sent ns, received ns)
        self.duplicates = 0
        self.lock = threading.Lock()

    def got(self, data: bytes) -> None:
        now = time.time_ns()
        index, sent = HEADER.unpack_from(data)
        with self.lock:
            if index in self.first:
                self.duplicates += 1
            else:
                self.first[index] = (sent, now)

    def reset(self) -> None:
        with self.lock:
            self.first, self.duplicates = {}, 0


def mqtt_client(port: int, client_id: str) -> mqtt.Client:
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5)
    client.max_inflight_messages_set(1000)
    client.max_queued_messages_set(0)
    client.connect("127.0.0.1", port, properties=Properties(PacketTypes.CONNECT))
    client.loop_start()
    return client


def mqtt_receiver(port: int, topic: str, receiver: Receiver) -> mqtt.Client:
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-sub-{port}-{topic}",
                         protocol=mqtt.MQTTv5)
    client.on_message = lambda _c, _u, msg: receiver.got(msg.payload)
    granted = threading.Event()
    client.on_subscribe = lambda *_: granted.set()
    client.connect("127.0.0.1", port)
    client.subscribe(topic, qos=1)
    client.loop_start()
    process.wait_until(granted.is_set, 10.0, what=f"subscription to {topic}")
    return client


class KafkaReceiver:
    """Reads one partition from its current end in a thread."""

    def __init__(self, bootstrap: str, topic: str, receiver: Receiver) -> None:
        self.consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": "bench-reader",
                                  "enable.auto.commit": False, "fetch.wait.max.ms": 10})
        end = self.consumer.get_watermark_offsets(TopicPartition(topic, 0), timeout=10)[1]
        self.consumer.assign([TopicPartition(topic, 0, end)])  # resolved now: nothing later skipped
        self.receiver, self.done = receiver, threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.done.is_set():
            for msg in self.consumer.consume(1000, timeout=0.05):
                if not msg.error():
                    self.receiver.got(msg.value())

    def close(self) -> None:
        self.done.set()
        self.thread.join()
        self.consumer.close()


@dataclass
class Path_:
    """A sender and the receiver at the other end."""

    send: Callable[[bytes], None]
    flush: Callable[[], None]
    receiver: Receiver


def run(path: Path_, n: int, rate: float | None) -> dict[str, float | int | None]:
    """Send ``n`` messages (at ``rate`` per second, or as fast as possible) and measure."""
    path.receiver.reset()
    pause = threading.Event()
    start = time.monotonic()
    start_ns = time.time_ns()
    for i in range(n):
        if rate:
            ahead = start + i / rate - time.monotonic()
            if ahead > 0.001:
                pause.wait(ahead)  # pacing the sender
        path.send(message(i))
    path.flush()
    last_count, last_change = -1, time.monotonic()

    def finished() -> bool:
        nonlocal last_count, last_change
        count = len(path.receiver.first)
        if count != last_count:
            last_count, last_change = count, time.monotonic()
        return count >= n or time.monotonic() - last_change > IDLE_LIMIT

    process.wait_until(finished, 600.0, 0.01, what="the run to end")
    with path.receiver.lock:
        times = sorted(path.receiver.first.values(), key=lambda t: t[1])
        duplicates = path.receiver.duplicates
    latencies = sorted((r - s) / 1e6 for s, r in times)
    elapsed = (times[-1][1] - start_ns) / 1e9 if times else float("nan")
    return {"messages": n, "offered_rate": rate, "msgs_per_s": len(times) / elapsed if times else 0.0,
            "p50_ms": latencies[len(latencies) // 2] if latencies else None,
            "p99_ms": latencies[min(len(latencies) - 1, int(len(latencies) * 0.99))] if latencies else None,
            "lost": n - len(times), "duplicates": duplicates}


def mqtt_sender(port: int, topic: str) -> tuple[Callable[[bytes], None], Callable[[], None], mqtt.Client]:
    client = mqtt_client(port, f"bench-pub-{port}-{topic}")
    infos: list[mqtt.MQTTMessageInfo] = []

    def send(data: bytes) -> None:
        infos.append(client.publish(topic, data, qos=1))

    def flush() -> None:
        for info in infos:
            info.wait_for_publish(60)
        infos.clear()

    return send, flush, client


def kafka_sender(bootstrap: str, topic: str) -> tuple[Callable[[bytes], None], Callable[[], None], Producer]:
    producer = Producer({"bootstrap.servers": bootstrap, "enable.idempotence": True, "acks": "all",
                         "linger.ms": 1})

    def send(data: bytes) -> None:
        while True:
            try:
                producer.produce(topic, data)
                break
            except BufferError:
                producer.poll(0.01)
        producer.poll(0)

    return send, lambda: producer.flush(60), producer


def measure(n: int, fraction: float, work: Path) -> dict[str, object]:
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
        rig.create_topics(kafka.bootstrap_servers, ["bench.m2k", "bench.k2m"], 1)
        cfg = WorkerConfig("bench", "127.0.0.1", mq.port, kafka.bootstrap_servers,
                           (Route("bench/m2k", "bench.m2k", Direction.MQTT_TO_KAFKA),
                            Route("bench/k2m", "bench.k2m", Direction.KAFKA_TO_MQTT)), work / "worker")
        worker = rig.start_worker(cfg)
        stops.append(lambda: process.stop(worker))
        rig.wait_ready(cfg, worker)
        paths = build_paths(mq, bridged, remote, kafka.bootstrap_servers, stops)
        for name, path in paths.items():  # warm-up: connections, JIT-free caches, the bridge link
            warm = run(path, 200, None)
            if warm["lost"]:
                raise RuntimeError(f"{name}: warm-up lost {warm['lost']} of 200 messages")
        rows = [{"path": name, "phase": "max", **run(path, n, None)} for name, path in paths.items()]
        paced = round(fraction * float(rows[0]["msgs_per_s"]))  # type: ignore[arg-type]
        rows += [{"path": name, "phase": "paced", **run(path, n, paced)} for name, path in paths.items()]
    finally:
        for stop in reversed(stops):
            stop()
    add_ratios(rows)
    return {"benchmark": "bridge", "machine": machine(), "messages": n, "paced_fraction": fraction,
            "command": "python -m benchmarks.bench_bridge " + " ".join(sys.argv[1:]), "rows": rows}


def build_paths(mq: rig.Mosquitto, bridged: rig.Mosquitto, remote: rig.Mosquitto, bootstrap: str,
                stops: list[Callable[[], object]]) -> dict[str, Path_]:
    paths: dict[str, Path_] = {}
    for name, pub_port, sub_port, topic in (("raw", mq.port, mq.port, "bench/raw"),
                                            ("mosquitto-bridge", bridged.port, remote.port, "bench/nb")):
        receiver = Receiver()
        sub = mqtt_receiver(sub_port, topic, receiver)
        send, flush, pub = mqtt_sender(pub_port, topic)
        stops += [sub.loop_stop, pub.loop_stop]
        paths[name] = Path_(send, flush, receiver)
    receiver = Receiver()
    reader = KafkaReceiver(bootstrap, "bench.m2k", receiver)
    stops.append(reader.close)
    send, flush, pub = mqtt_sender(mq.port, "bench/m2k")
    stops.append(pub.loop_stop)
    paths["mqtt-kafka"] = Path_(send, flush, receiver)
    receiver = Receiver()
    sub = mqtt_receiver(mq.port, "bench/k2m", receiver)
    stops.append(sub.loop_stop)
    ksend, kflush, _producer = kafka_sender(bootstrap, "bench.k2m")
    paths["kafka-mqtt"] = Path_(ksend, kflush, receiver)
    return paths


def add_ratios(rows: list[dict[str, object]]) -> None:
    raw = {r["phase"]: r for r in rows if r["path"] == "raw"}
    for row in rows:
        base = raw[row["phase"]]
        row["throughput_vs_raw"] = float(row["msgs_per_s"]) / float(base["msgs_per_s"])  # type: ignore[arg-type]
        if row["p50_ms"] is not None and base["p50_ms"] is not None:
            row["p50_added_ms"] = float(row["p50_ms"]) - float(base["p50_ms"])  # type: ignore[arg-type]


def to_markdown(data: dict[str, object]) -> str:
    lines = ["# bridge: throughput and latency of each bridge against the raw MQTT path (same run)", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · {data['messages']} messages "
             f"per run, QoS 1, {PAYLOAD_SIZE}-byte payloads; `paced` sends at "
             f"{data['paced_fraction']:.0%} of the raw path's `max` rate", "",
             "| path | phase | offered msg/s | msg/s | vs raw | p50 ms | p99 ms | p50 added ms | lost | duplicates |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["rows"]:  # type: ignore[union-attr]
        def ms(v: object) -> str:
            return "-" if v is None else f"{v:.2f}"
        offered = "max" if r["offered_rate"] is None else str(r["offered_rate"])
        lines.append(f"| {r['path']} | {r['phase']} | {offered} | {r['msgs_per_s']:.0f} | "
                     f"{r['throughput_vs_raw']:.2f} | {ms(r['p50_ms'])} | {ms(r['p99_ms'])} | "
                     f"{ms(r.get('p50_added_ms'))} | {r['lost']} | {r['duplicates']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="bridge throughput and latency benchmark")
    parser.add_argument("--messages", type=int, default=20_000)
    parser.add_argument("--paced-fraction", type=float, default=0.5)
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-bridge-") as tmp:
        data = measure(args.messages, args.paced_fraction, Path(tmp))
    write_results(args.out, "bridge", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

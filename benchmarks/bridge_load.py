"""Senders and receivers of the bridge benchmark, each in a process of its own, so what is measured
is the path and not the measuring client (issue 16: a paho publisher and subscriber in one Python
process topped out near 2k msg/s, and a receiver calling ``consume(1000, timeout=0.05)`` added up
to 50 ms to every latency).

- MQTT out: ``mosquitto_pub -l`` (C, libmosquitto; Debian's mosquitto-clients), one process per
  path kept for the whole benchmark, QoS 1 with up to 1000 messages in flight. It sends each line
  of its standard input as one message; :class:`Feeder` writes those lines, each stamped with the
  time it was written, at a set rate or as fast as the pipe takes them.
- MQTT in: ``mosquitto_sub -F '%U %p'`` (C): one line per message, the receive time (ns since the
  epoch, taken by mosquitto_sub as it prints) then the payload, flushed per message into a file.
- Kafka out: ``python -m benchmarks.bridge_load kafka-write`` (below), a confluent-kafka
  (librdkafka) producer in its own process, idempotent, ``acks=all``, fed by a :class:`Feeder`
  like mosquitto_pub: it produces each line as soon as it is read. (Debian's ``kcat -P`` 1.7.1
  holds the last lines of its input until more arrives, which kcat fixed after 1.7.1.)
- Kafka in: ``python -m benchmarks.bridge_load kafka-read`` (below), a confluent-kafka consumer
  in its own process that never waits for a batch to fill: ``poll`` returns at the first record,
  then ``consume(timeout=0)`` takes what else is there; each record is written with the time it
  was handed over.

A payload is one line: ``<index> <send ns> `` padded to :data:`PAYLOAD_SIZE` bytes. A receiver's
file is read with :class:`Arrivals`, which keeps the first arrival of each index and counts
duplicates; indexes grow across runs, so a late message of one run never counts in the next.

``mosquitto_pub -l`` has one limit to respect: after the end of its input it waits for the PUBACK
of the last message id it sent, and ids wrap at 65535, so more than 65535 messages still queued in
it at the end would stop it early. The feeders here never close a publisher with more than a
run's worth queued.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

PAYLOAD_SIZE = 100          # bytes of a message (the line without its newline)
MQTT_INFLIGHT = 1000        # QoS-1 messages mosquitto_pub keeps unacknowledged (Mosquitto's max_inflight)
CHUNK = 64                  # lines written at once when the feeder is behind or unpaced


def line(index: int, sent_ns: int) -> bytes:
    head = f"{index} {sent_ns} "
    return (head + "." * (PAYLOAD_SIZE - len(head)) + "\n").encode()


def parse_payload(payload: bytes) -> tuple[int, int]:
    """(index, send ns) of a payload written by :func:`line`."""
    index, sent, _rest = payload.split(b" ", 2)
    return int(index), int(sent)


def need(binary: str) -> str:
    path = shutil.which(binary)
    if path is None:
        raise RuntimeError(f"{binary} is not installed: run scripts/setup.sh (it installs "
                           "mosquitto-clients)")
    return path


class Feeder:
    """Writes payload lines into a sender's standard input."""

    def __init__(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdin is not None
        self.proc = proc
        self.fd = proc.stdin.fileno()
        self.next_index = 0

    def send(self, count: int, rate: float | None) -> tuple[int, int, int]:
        """Write ``count`` lines, at ``rate`` per second or as fast as the pipe takes them;
        returns (first index, first send ns, time the last line was written in ns)."""
        first = self.next_index
        began_ns = time.time_ns()
        start = time.monotonic()
        pause = threading.Event()
        sent = 0
        while sent < count:
            if rate:
                due = min(count, int((time.monotonic() - start) * rate) + 1)
                if due <= sent:
                    pause.wait((sent - (time.monotonic() - start) * rate) / rate)  # pacing the sender
                    continue
                batch = min(due - sent, CHUNK)
            else:
                batch = min(count - sent, CHUNK)
            now = time.time_ns()
            data = b"".join(line(self.next_index + i, now) for i in range(batch))
            self._write(data)
            self.next_index += batch
            sent += batch
        return first, began_ns, time.time_ns()

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view):]

    def close(self, timeout: float = 120.0) -> int:
        """End the input; the sender flushes what it holds and exits (its exit code)."""
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        try:
            return self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


def mqtt_publisher(host: str, port: int, topic: str, client_id: str, log: Path) -> Feeder:
    argv = [need("mosquitto_pub"), "-h", host, "-p", str(port), "-t", topic, "-q", "1",
            "-M", str(MQTT_INFLIGHT), "--nodelay", "-i", client_id, "-l"]
    return Feeder(_spawn(argv, log, stdin=subprocess.PIPE))


def kafka_producer(bootstrap: str, topic: str, log: Path, partition: int = 0) -> Feeder:
    argv = [sys.executable, "-m", "benchmarks.bridge_load", "kafka-write", "--bootstrap", bootstrap,
            "--topic", topic, "--partition", str(partition)]
    return Feeder(_spawn(argv, log, stdin=subprocess.PIPE, cwd=Path(__file__).resolve().parent.parent))


@dataclass
class Receiver:
    """A receiving process writing ``<recv ns or s.ns> <payload>`` lines into ``out``."""

    proc: subprocess.Popen[bytes]
    out: Path

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def mqtt_subscriber(host: str, port: int, topic: str, client_id: str, out: Path,
                    persistent: bool = False, append: bool = False) -> Receiver:
    """``persistent``: a session that outlives the connection (``-c``), so messages published
    while the subscriber reconnects wait for it on the broker. ``append``: add to ``out`` (a
    subscriber coming back) instead of starting it anew."""
    argv = [need("mosquitto_sub"), "-h", host, "-p", str(port), "-t", topic, "-q", "1",
            "--nodelay", "-i", client_id, "-F", "%U %p", *(["-c"] if persistent else [])]
    return Receiver(_spawn(argv, out, stdout_to_log=True, append=append), out)


def kafka_reader(bootstrap: str, topic: str, out: Path, partitions: int = 1) -> Receiver:
    """The reader process, once it is assigned to the partitions' current ends."""
    argv = [sys.executable, "-m", "benchmarks.bridge_load", "kafka-read", "--bootstrap", bootstrap,
            "--topic", topic, "--partitions", str(partitions), "--out", str(out)]
    ready = out.with_suffix(".ready")
    proc = _spawn(argv, out.with_suffix(".log"), cwd=Path(__file__).resolve().parent.parent)
    end = time.monotonic() + 60
    while not ready.exists():  # written by the reader once its positions are resolved
        if proc.poll() is not None or time.monotonic() > end:
            proc.kill()
            raise RuntimeError(f"the Kafka reader of {topic} did not start: {out.with_suffix('.log')}")
        threading.Event().wait(0.02)  # polling a file another process writes
    return Receiver(proc, out)


def _spawn(argv: list[str], log: Path, stdin: int | None = subprocess.DEVNULL,
           stdout_to_log: bool = False, cwd: Path | None = None, append: bool = False) -> subprocess.Popen[bytes]:
    log.parent.mkdir(parents=True, exist_ok=True)
    with open(log, "ab" if append else "wb") as out:
        err = open(log.with_suffix(log.suffix + ".err"), "wb") if stdout_to_log else subprocess.STDOUT
        try:
            return subprocess.Popen(argv, stdin=stdin, stdout=out, stderr=err, cwd=cwd,
                                    start_new_session=True)
        finally:
            if stdout_to_log:
                err.close()  # type: ignore[union-attr]


@dataclass
class Arrivals:
    """The first arrival of each index in a receiver's file, read as it grows."""

    path: Path
    first: dict[int, tuple[int, int]] = field(default_factory=dict)  # index -> (sent ns, received ns)
    duplicates: int = 0
    _offset: int = 0
    _partial: bytes = b""

    def read(self) -> list[int]:
        """Take in what the file gained; return the indexes that arrived for the first time."""
        try:
            with open(self.path, "rb") as f:
                f.seek(self._offset)
                data = f.read()
        except FileNotFoundError:
            return []
        self._offset += len(data)
        data = self._partial + data
        lines = data.split(b"\n")
        self._partial = lines.pop()
        new: list[int] = []
        for raw in lines:
            if not raw:
                continue
            stamp, payload = raw.split(b" ", 1)
            received = int(stamp.replace(b".", b"")) if b"." in stamp else int(stamp)
            try:
                index, sent = parse_payload(payload)
            except ValueError:
                continue  # not one of ours (a probe written by a test)
            if index in self.first:
                self.duplicates += 1
            else:
                self.first[index] = (sent, received)
                new.append(index)
        return new



def _kafka_read(bootstrap: str, topic: str, partitions: int, out: Path) -> int:
    from confluent_kafka import Consumer, TopicPartition  # noqa: PLC0415 - only in this process

    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"bench-reader-{os.getpid()}",
                         "enable.auto.commit": False, "fetch.wait.max.ms": 5, "log_level": 0})
    tps = []
    for p in range(partitions):
        end = consumer.get_watermark_offsets(TopicPartition(topic, p), timeout=30)[1]
        tps.append(TopicPartition(topic, p, end))  # resolved now: nothing produced later is skipped
    consumer.assign(tps)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with open(out, "wb") as f:
        out.with_suffix(".ready").write_text("ready\n")
        while not stop.is_set():
            first = consumer.poll(0.1)  # returns at the first record: no batch to wait for
            if first is None:
                continue
            batch = [first, *consumer.consume(10_000, timeout=0)]
            now = b"%d " % time.time_ns()
            f.write(b"".join(now + m.value() + b"\n" for m in batch if not m.error() and m.value()))
            f.flush()
    consumer.close()
    return 0


def _kafka_write(bootstrap: str, topic: str, partition: int) -> int:
    """Produce each line of standard input (without its newline) as soon as it is read; at the
    end of the input, wait for every delivery report."""
    from confluent_kafka import Producer  # noqa: PLC0415 - only in this process

    producer = Producer({"bootstrap.servers": bootstrap, "enable.idempotence": True, "acks": "all",
                         "linger.ms": 1, "log_level": 0})
    failed = 0

    def report(err: object, _msg: object) -> None:
        nonlocal failed
        failed += err is not None

    fd = sys.stdin.fileno()
    partial = b""
    while True:
        data = os.read(fd, 1 << 16)  # whatever the pipe holds now, at most 64 KiB
        if not data:
            break
        lines = (partial + data).split(b"\n")
        partial = lines.pop()
        for value in lines:
            while True:
                try:
                    producer.produce(topic, value, partition=partition, on_delivery=report)
                    break
                except BufferError:
                    producer.poll(0.01)
        producer.poll(0)
    left = producer.flush(120)
    return 1 if failed or left else 0


def acked_publisher(host: str, port: int, topic: str, count: int, rate: float, out: Path) -> subprocess.Popen[bytes]:
    """A paho publisher process that sends ``count`` QoS-1 messages at ``rate`` msg/s and writes
    the index of each message the broker acknowledged to ``out``: what a fault may not lose is what
    a publisher got a PUBACK for (mosquitto_pub cannot tell which). It reconnects by itself and
    exits once every message is acknowledged."""
    argv = [sys.executable, "-m", "benchmarks.bridge_load", "mqtt-pub", "--host", host, "--port", str(port),
            "--topic", topic, "--count", str(count), "--rate", str(rate), "--out", str(out)]
    return _spawn(argv, out.with_suffix(".log"), cwd=Path(__file__).resolve().parent.parent)


def read_acked(path: Path) -> set[int]:
    try:
        return {int(x) for x in path.read_bytes().split()}
    except FileNotFoundError:
        return set()


def _mqtt_pub(host: str, port: int, topic: str, count: int, rate: float, out: Path) -> int:
    import paho.mqtt.client as mqtt  # noqa: PLC0415 - only in this process

    pending: dict[int, int] = {}      # mid -> index, for messages in flight
    early: set[int] = set()           # mids acknowledged before publish() returned their index
    lock = threading.Lock()           # never held while calling paho: its callback holds paho's lock
    done = threading.Event()
    written = 0
    with open(out, "wb") as f:
        def record(index: int) -> None:  # the caller holds lock
            nonlocal written
            f.write(b"%d\n" % index)
            written += 1
            if written % 200 == 0 or written == count:
                f.flush()
            if written == count:
                done.set()

        def on_publish(_c: object, _u: object, mid: int, *_rest: object) -> None:
            with lock:
                index = pending.pop(mid, None)
                if index is None:
                    early.add(mid)
                else:
                    record(index)

        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-acked-{os.getpid()}",
                             clean_session=False)
        client.max_inflight_messages_set(1000)
        client.max_queued_messages_set(0)
        client.reconnect_delay_set(0.1, 1)
        client.on_publish = on_publish
        client.connect(host, port)
        client.loop_start()
        start = time.monotonic()
        pause = threading.Event()
        for i in range(count):
            ahead = start + i / rate - time.monotonic()
            if ahead > 0.002:
                pause.wait(ahead)  # pacing the sender
            mid = client.publish(topic, line(i, time.time_ns())[:-1], qos=1).mid
            with lock:
                if mid in early:
                    early.discard(mid)
                    record(i)
                else:
                    pending[mid] = i
        done.wait(600)
        with lock:
            f.flush()
        client.loop_stop()
        client.disconnect()
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="bridge benchmark helper processes")
    sub = parser.add_subparsers(dest="command", required=True)
    read = sub.add_parser("kafka-read", help="write each record of a topic with its receive time")
    read.add_argument("--bootstrap", required=True)
    read.add_argument("--topic", required=True)
    read.add_argument("--partitions", type=int, default=1)
    read.add_argument("--out", type=Path, required=True)
    write = sub.add_parser("kafka-write", help="produce each line of standard input")
    write.add_argument("--bootstrap", required=True)
    write.add_argument("--topic", required=True)
    write.add_argument("--partition", type=int, default=0)
    pub = sub.add_parser("mqtt-pub", help="publish paced QoS-1 messages, write the acknowledged indexes")
    pub.add_argument("--host", required=True)
    pub.add_argument("--port", type=int, required=True)
    pub.add_argument("--topic", required=True)
    pub.add_argument("--count", type=int, required=True)
    pub.add_argument("--rate", type=float, required=True)
    pub.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    if args.command == "mqtt-pub":
        return _mqtt_pub(args.host, args.port, args.topic, args.count, args.rate, args.out)
    if args.command == "kafka-write":
        return _kafka_write(args.bootstrap, args.topic, args.partition)
    return _kafka_read(args.bootstrap, args.topic, args.partitions, args.out)


if __name__ == "__main__":
    sys.exit(main())

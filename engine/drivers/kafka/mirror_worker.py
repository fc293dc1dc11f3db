"""``python -m engine.drivers.kafka.mirror_worker <worker.json>``: one MirrorMaker 2, watched.

The agent runs this like a bridge worker (engine.agent.workers: one supervised process per bridge,
restarted with backoff when it exits). It renders ``mm2.properties`` next to ``worker.json``
(and, when an end is closed, ``mm2-login.properties``, mode 0600, the one file of the folder with
plantkg's password besides the 0600 ``password_file`` the agent wrote; mm2.properties refers to
it: engine.drivers.kafka.mirror),
starts MirrorMaker 2 (:mod:`engine.drivers.kafka.mirror`) as its child — in its process group, so
the agent's stop ends both, and with a parent-death signal, so a killed worker leaves no JVM —
and every ``interval`` seconds measures the mirror against both clusters into ``stats.json``
(engine.bridge_worker.stats, mechanism ``kafka-mirror``):

- ``lag``: records of the mirrored topics the source has and the target has not yet, summed per
  partition as ``max(0, source end offset - target end offset)``. Exact while MirrorMaker 2 is the
  only writer of those topics on the target and both started empty (plantkg creates them there);
  a producer of the same topic on the target would hide lag, never invent it.
- ``forwarded``: the records the target's mirrored topics hold (the sum of their end offsets):
  all copied by MirrorMaker 2 under the same condition as ``lag``, and cumulative across restarts
  of this worker (a count taken from its first answer undercounted everything copied before the
  clusters first answered it, 0 in one loaded run).
- ``ready``: MirrorMaker 2 runs and both clusters answered the last measure.

It exits with MirrorMaker's exit code when MirrorMaker exits (the agent restarts it), 0 after
SIGTERM/SIGINT, 2 for a config it cannot use.
"""

from __future__ import annotations

import collections
import ctypes
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from confluent_kafka import Consumer, KafkaException, TopicPartition

from engine import parts
from engine.bridge_worker.stats import WorkerStats, write_stats
from engine.drivers.kafka.mirror import (
    DEFAULT_HEAP,
    MirrorConfig,
    mirror_command,
    render_login_properties,
    render_mm2_properties,
)
from engine.errors import ConfigValueError
from engine.security.kafka_client import login_settings
from engine.whole_file import write_whole

PROPERTIES_FILE = "mm2.properties"
LOGIN_FILE = "mm2-login.properties"
MECHANISM = "kafka-mirror"
EXIT_BAD_CONFIG = 2
_PR_SET_PDEATHSIG = 1
_END_FLAGS = ("source_closed", "target_closed", "source_tls", "target_tls")

log = logging.getLogger("engine.drivers.kafka.mirror_worker")


@dataclass(frozen=True)
class MirrorWorkerConfig:
    """What ``worker.json`` holds for a mirror (written by the agent, engine.agent.workers)."""

    bridge_id: str
    mirror: MirrorConfig
    state_dir: Path
    heap: str = DEFAULT_HEAP
    interval: float = 2.0
    password_file: Path | None = None  # plantkg's Kafka password (0600), when an end is closed
    ca_file: Path | None = None        # the plant CA's certificate, when an end speaks TLS

    def to_json(self) -> str:
        return json.dumps({
            "mechanism": MECHANISM, "bridge_id": self.bridge_id,
            "source": list(self.mirror.source), "target": list(self.mirror.target),
            "topics": list(self.mirror.topics), "replication": self.mirror.replication,
            "state_dir": str(self.state_dir), "heap": self.heap, "interval": self.interval,
            # only what is on: an open, plain mirror's worker.json (and so its config hash) reads as before
            **{name: True for name in _END_FLAGS if getattr(self.mirror, name)},
            **({"password_file": str(self.password_file)} if self.password_file is not None else {}),
            **({"ca_file": str(self.ca_file)} if self.ca_file is not None else {}),
        }, indent=2, sort_keys=True) + "\n"

    def password(self) -> str | None:
        """plantkg's password from ``password_file`` (None when no end is closed)."""
        if not self.mirror.closed:
            return None
        if self.password_file is None:
            raise ConfigValueError("password_file", None, "a mirror with a closed end needs plantkg's password file")
        try:
            return self.password_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigValueError("password_file", str(self.password_file),
                                   f"cannot be read ({exc.strerror})") from None

    @classmethod
    def from_json(cls, text: str) -> MirrorWorkerConfig:
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise ConfigValueError("worker.json", text[:80], f"not JSON: {exc}") from None
        if not isinstance(data, dict) or data.get("mechanism") != MECHANISM:
            raise ConfigValueError("mechanism", data.get("mechanism") if isinstance(data, dict) else data,
                                   f"expected {MECHANISM!r}")
        try:
            mirror = MirrorConfig(tuple(data["source"]), tuple(data["target"]), tuple(data["topics"]),
                                  int(data["replication"]), *(data.get(name, False) for name in _END_FLAGS))
            bridge_id, state_dir = str(data["bridge_id"]), Path(str(data["state_dir"]))
            heap, interval = str(data.get("heap", DEFAULT_HEAP)), float(data.get("interval", 2.0))
            password_file = None if data.get("password_file") is None else Path(str(data["password_file"]))
            ca_file = None if data.get("ca_file") is None else Path(str(data["ca_file"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigValueError("worker.json", str(exc), "a mirror worker config field is missing or mistyped") from None
        if not 0.1 <= interval <= 60:
            raise ConfigValueError("interval", interval, "must be in 0.1..60 seconds")
        return cls(bridge_id, mirror, state_dir, heap, interval, password_file, ca_file)


def is_mirror_config(text: str) -> bool:
    try:
        data = json.loads(text)
    except ValueError:
        return False
    return isinstance(data, dict) and data.get("mechanism") == MECHANISM


class Offsets:
    """End offsets of the mirrored topics on one cluster (a group-less consumer's watermarks)."""

    def __init__(self, bootstrap: tuple[str, ...], topics: tuple[str, ...], password: str | None = None,
                 ca_file: Path | None = None) -> None:
        """``password``: plantkg's, to log in at a closed Kafka (None: an open one); ``ca_file``:
        the plant CA's certificate at a TLS Kafka (None: a plain one)."""
        self.topics = topics
        self.consumer = Consumer({"bootstrap.servers": ",".join(bootstrap), "group.id": "plantkg-mirror-probe",
                                  "enable.auto.commit": False, "log_level": 0, **login_settings(password, ca_file)})

    def ends(self, timeout: float) -> dict[tuple[str, int], int]:
        """(topic, partition) -> end offset; raises KafkaException when the cluster does not answer."""
        metadata = self.consumer.list_topics(timeout=timeout)
        out = {}
        for topic in self.topics:
            found = metadata.topics.get(topic)
            if found is None or found.error is not None:
                continue
            for partition in found.partitions:
                _low, high = self.consumer.get_watermark_offsets(TopicPartition(topic, partition),
                                                                 timeout=timeout, cached=False)
                out[(topic, partition)] = high
        return out

    def close(self) -> None:
        self.consumer.close()


def lag_of(source: dict[tuple[str, int], int], target: dict[tuple[str, int], int]) -> int:
    """Records on the source not yet on the target, per partition (see the module docstring)."""
    return sum(max(0, end - target.get(tp, 0)) for tp, end in source.items())


class MirrorWorker:
    """Runs MirrorMaker 2 and writes its stats until stopped or until MirrorMaker exits."""

    def __init__(self, cfg: MirrorWorkerConfig) -> None:
        self.cfg = cfg
        self.stop_event = threading.Event()
        self.child: subprocess.Popen[bytes] | None = None
        self.rates: collections.deque[tuple[float, int]] = collections.deque(maxlen=64)

    def run(self) -> int:
        cfg = self.cfg
        properties = cfg.state_dir / PROPERTIES_FILE
        login = cfg.state_dir / LOGIN_FILE
        try:
            password = cfg.password()
            if password is not None:
                write_whole(login, render_login_properties(password), mode=0o600)
            else:
                login.unlink(missing_ok=True)
            write_whole(properties, render_mm2_properties(cfg.mirror, login if password else None, cfg.ca_file),
                        mode=0o600)
        except ConfigValueError as exc:
            log.error("cannot render %s: %s", PROPERTIES_FILE, exc)
            return EXIT_BAD_CONFIG
        argv = mirror_command(parts.kafka_parts(), parts.java_binary(), properties, cfg.state_dir / "logs", cfg.heap)
        self.child = subprocess.Popen(argv, stdin=subprocess.DEVNULL, cwd=cfg.state_dir,  # noqa: S603 - argv list
                                      preexec_fn=_die_with_parent)
        log.info("MirrorMaker 2 started, pid %d: %s -> %s, topics %s", self.child.pid,
                 ",".join(cfg.mirror.source), ",".join(cfg.mirror.target), ",".join(cfg.mirror.topics))
        m = cfg.mirror
        source = Offsets(m.source, m.topics, password if m.source_closed else None, cfg.ca_file if m.source_tls else None)
        target = Offsets(m.target, m.topics, password if m.target_closed else None, cfg.ca_file if m.target_tls else None)
        try:
            while not self.stop_event.is_set():
                code = self.child.poll()
                if code is not None:
                    log.error("MirrorMaker 2 exited with code %d", code)
                    self._write(False, None, self._last(), f"MirrorMaker 2 exited with code {code}")
                    return code or 1
                try:
                    ends_t = target.ends(5.0)
                    ends_s = source.ends(5.0)
                except KafkaException as exc:
                    self._write(False, None, self._last(), f"cluster not answering: {exc}")
                else:
                    self._write(True, lag_of(ends_s, ends_t), sum(ends_t.values()), None)
                self.stop_event.wait(cfg.interval)
            return 0
        finally:
            self._stop_child()
            source.close()
            target.close()

    def _last(self) -> int:
        return self.rates[-1][1] if self.rates else 0

    def _write(self, connected: bool, lag: int | None, forwarded: int, error: str | None) -> None:
        now = time.monotonic()
        self.rates.append((now, forwarded))
        old = next((r for r in self.rates if now - r[0] <= 10.0), self.rates[0])
        rate = (forwarded - old[1]) / (now - old[0]) if now > old[0] else 0.0
        alive = self.child is not None and self.child.poll() is None
        write_stats(self.cfg.state_dir, WorkerStats(
            bridge_id=self.cfg.bridge_id, pid=os.getpid(), ready=alive and connected,
            mqtt_connected=False, kafka_connected=connected, forwarded_mqtt_to_kafka=0,
            forwarded_kafka_to_mqtt=0, retried=0, last_error=error, updated_at=time.time(),
            mechanism=MECHANISM, forwarded_per_s=max(0.0, rate), forwarded_kafka_to_kafka=forwarded,
            lag=lag))

    def _stop_child(self) -> None:
        if self.child is None or self.child.poll() is not None:
            return
        self.child.terminate()
        try:
            self.child.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.child.kill()
            self.child.wait()


def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Linux prctl(PR_SET_PDEATHSIG, SIGTERM): the JVM gets SIGTERM when this worker dies."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m engine.drivers.kafka.mirror_worker <worker.json>", file=sys.stderr)
        return EXIT_BAD_CONFIG
    try:
        cfg = MirrorWorkerConfig.from_json(Path(args[0]).read_text(encoding="utf-8"))
    except (OSError, ConfigValueError) as exc:
        print(f"mirror worker: {args[0]}: {exc}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    logging.basicConfig(stream=sys.stderr, level=logging.INFO,
                        format=f"%(asctime)s mirror {cfg.bridge_id} %(levelname)s: %(message)s")
    worker = MirrorWorker(cfg)

    def stop(_signum: int, _frame: Any) -> None:
        worker.stop_event.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    return worker.run()


if __name__ == "__main__":
    sys.exit(main())

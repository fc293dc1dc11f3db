"""Real brokers and bridge workers on loopback, for the bridge benchmark and the bridge tests.

- :class:`Mosquitto`: one broker rendered by :mod:`engine.drivers.mosquitto.runtime` (so it has the
  settings plantkg deploys: persistence, large queues), which can be SIGKILLed and started again
  with the same config and data folder.
- :func:`respawn_kafka`: start a stopped or killed Kafka node again from its rendered
  ``server.properties`` (same ports, same data).
- :func:`start_worker`: write ``worker.json`` and run ``python -m engine.bridge_worker`` on it.
"""

from __future__ import annotations

import os
import signal
import sys
from dataclasses import dataclass, field
from pathlib import Path

from confluent_kafka.admin import AdminClient, NewTopic

from engine import netutil, parts, process
from engine.drivers.kafka import runtime as kafka_runtime
from engine.bridge_worker.config import WorkerConfig
from engine.bridge_worker.stats import WorkerStats, read_stats
from engine.drivers.mosquitto.runtime import MosquittoBridge, MosquittoConfig, default_run_as, mosquitto_command, render_mosquitto_conf


@dataclass
class Mosquitto:
    """A Mosquitto broker in ``folder`` (conf, data, log), started by :meth:`start`."""

    folder: Path
    host: str = "127.0.0.1"
    port: int = 0
    bridges: tuple[MosquittoBridge, ...] = ()
    persist_every: int | None = None
    child: process.Child | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.port = self.port or netutil.free_port(self.host)
        (self.folder / "data").mkdir(parents=True, exist_ok=True)
        cfg = MosquittoConfig(self.host, self.port, self.folder / "mosquitto.log", default_run_as(),
                              data_dir=self.folder / "data", bridges=self.bridges,
                              persist_every=self.persist_every)
        (self.folder / "mosquitto.conf").write_text(render_mosquitto_conf(cfg), encoding="utf-8")

    def start(self) -> Mosquitto:
        argv = mosquitto_command(parts.mosquitto_binary(), self.folder / "mosquitto.conf")
        self.child = process.spawn(argv, log_dir=self.folder, name="mosquitto-out")
        process.wait_until(lambda: netutil.port_open(self.host, self.port), 10.0, 0.01,
                           what=f"mosquitto on {self.host}:{self.port}", child=self.child)
        return self

    def save(self) -> None:
        """Make Mosquitto write its in-memory database (sessions, queues) to disk now (SIGUSR1)."""
        assert self.child is not None
        before = mtime(self.folder / "data" / "mosquitto.db")
        os.kill(self.child.pid, signal.SIGUSR1)
        process.wait_until(lambda: mtime(self.folder / "data" / "mosquitto.db") != before, 10.0,
                           what="mosquitto to save its database")

    def kill(self) -> None:
        """SIGKILL: what Mosquitto held only in memory is gone."""
        assert self.child is not None
        kill_group(self.child)
        self.child = None

    def stop(self) -> None:
        if self.child is not None:
            process.stop(self.child)
            self.child = None


def mtime(path: Path) -> int | None:
    """The file's modification time in ns (None while it does not exist): a save shows as a change."""
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return None


def kill_group(child: process.Child) -> None:
    """SIGKILL a child's whole process group and reap it."""
    os.killpg(child.pid, signal.SIGKILL)
    child.popen.wait()
    process.wait_until(lambda: not child.group_alive(), 10.0, 0.01, what=f"{child.name} to die")


def respawn_kafka(config: kafka_runtime.KafkaNodeConfig, broker_dir: Path) -> process.Child:
    """Run the Kafka node of ``broker_dir`` again (already formatted: same cluster, same data)."""
    argv = kafka_runtime.broker_command(parts.kafka_parts(), parts.java_binary(),
                                        broker_dir / "server.properties", logs_dir=broker_dir / "logs")
    child = process.spawn(argv, log_dir=broker_dir / "logs", name="kafka")
    try:
        process.wait_until(lambda: netutil.port_open(config.host, config.port), 90.0, 0.1,
                           what=f"Kafka to listen on {config.host}:{config.port}", child=child)
    except BaseException:
        process.stop(child)
        raise
    return child


def create_topics(bootstrap: str, names: list[str], partitions: int = 1, timeout: float = 60.0) -> None:
    """Create Kafka topics (replication 1) and wait until they exist."""
    admin = AdminClient({"bootstrap.servers": bootstrap})
    futures = admin.create_topics([NewTopic(n, num_partitions=partitions, replication_factor=1) for n in names])
    for future in futures.values():
        future.result(timeout=timeout)
    process.wait_until(lambda: set(names) <= set(admin.list_topics(timeout=5).topics), timeout,
                       0.1, what=f"Kafka topics {names}")


def start_worker(cfg: WorkerConfig, name: str = "worker") -> process.Child:
    """Write ``<state_dir>/worker.json`` and run the worker on it (logs in ``<state_dir>/<name>.log``)."""
    cfg.state_dir.mkdir(parents=True, exist_ok=True)
    path = cfg.state_dir / "worker.json"
    path.write_text(cfg.to_json(), encoding="utf-8")
    return process.spawn([sys.executable, "-m", "engine.bridge_worker", str(path)],
                         log_dir=cfg.state_dir, name=name, cwd=parts.repo_root())


def wait_ready(cfg: WorkerConfig, child: process.Child, deadline: float = 60.0) -> WorkerStats:
    """Poll the worker's stats until it says ready (it fails fast if the worker exits)."""
    def ready() -> WorkerStats | None:
        stats = read_stats(cfg.state_dir)
        return stats if stats is not None and stats.pid == child.pid and stats.ready else None

    return process.wait_until(ready, deadline, 0.05, what=f"bridge worker {cfg.bridge_id} to be ready",
                              child=child)

"""What every bridge worker does around its forwarding halves: start them, write ``stats.json``
when its health changes (and every ``stats_interval`` s) with counters that go on from the last
run's file and the forwarding rate of the last ~10 s (:mod:`engine.bridge_worker.rate`), run a
probe of the remote side in a thread of its own, and on a stop let the halves finish what is in
flight before the MQTT link disconnects.

A worker (:class:`engine.bridge_worker.worker.Worker` for Kafka,
:class:`engine.bridge_worker.ngsi_worker.NgsiWorker` for NGSI-v2) says which halves it has, how
its health reads as a stats snapshot, how it probes the remote, and what one pass of its main
thread does (Kafka -> MQTT polls Kafka there; the NGSI worker only waits).
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import replace
from typing import Any, Protocol

from engine.bridge_worker.mqtt_link import MqttLink
from engine.bridge_worker.rate import Sample, add_sample, rate
from engine.bridge_worker.stats import WorkerStats, read_stats, write_stats

log = logging.getLogger("plantkg.bridge")

STOP_GRACE = 10.0  # seconds a stop waits for writes and PUBACKs in flight
TICK = 0.05        # seconds between passes of the main thread


class Startable(Protocol):
    def start(self) -> None: ...


class Half(Startable, Protocol):
    """A forwarding half: started once, stopped with a deadline for what is in flight."""

    def stop(self, deadline: float) -> None: ...


class BridgeLoop(ABC):
    """The run loop shared by the bridge workers; subclasses set ``cfg``, ``health``, ``link``."""

    cfg: Any
    health: Any
    link: MqttLink

    def __init__(self) -> None:
        self.stopping = threading.Event()
        self._probe = threading.Thread(target=self.probe, name="remote-probe", daemon=True)
        self._samples: tuple[Sample, ...] = ()  # the forwarded counter over the last WINDOW s

    @abstractmethod
    def halves(self) -> Sequence[Half]:
        """The forwarding halves this worker's routes need (started in this order)."""

    def watchers(self) -> Sequence[Startable]:
        """Threads started with the halves that end by themselves on :attr:`stopping`
        (their ``stop`` is not called); none by default."""
        return ()

    @abstractmethod
    def snapshot(self) -> WorkerStats:
        """The stats snapshot of :attr:`health` for ``stats.json``."""

    @abstractmethod
    def probe(self) -> None:
        """Probe the remote side until :attr:`stopping` is set (runs in its own thread)."""

    @abstractmethod
    def stopped_line(self) -> str:
        """The log line of a finished stop (what was forwarded)."""

    def step(self) -> None:
        """One pass of the main thread; by default only waits."""
        self.stopping.wait(TICK)

    def run(self) -> None:
        """Forward until :attr:`stopping` is set, then stop cleanly."""
        self.cfg.state_dir.mkdir(parents=True, exist_ok=True)
        self.health.carry_on_from(read_stats(self.cfg.state_dir))
        self._write_stats()
        for half in (*self.halves(), *self.watchers()):
            half.start()
        self.link.start()
        self._probe.start()
        next_stats = 0.0
        while not self.stopping.is_set():
            self.step()
            now = time.monotonic()
            if now >= next_stats or self.health.changed.is_set():
                self.health.changed.clear()
                self._write_stats()
                next_stats = now + self.cfg.stats_interval
        self._shutdown()

    def _shutdown(self) -> None:
        log.info("stopping")
        self._write_stats()
        deadline = time.monotonic() + STOP_GRACE
        for half in self.halves():
            half.stop(deadline)
        self.link.stop()
        self._write_stats()
        log.info("%s", self.stopped_line())

    def _write_stats(self) -> None:
        stats = self.snapshot()
        self._samples = add_sample(self._samples, time.monotonic(), stats.forwarded)
        stats = replace(stats, forwarded_per_s=round(rate(self._samples), 3))
        try:
            write_stats(self.cfg.state_dir, stats)
        except OSError as exc:
            log.warning("cannot write stats: %s", exc)

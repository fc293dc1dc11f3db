"""The agent's brokers: declarative PUT/DELETE, supervision, and re-adoption after a restart.

:class:`BrokerManager` owns ``<state-dir>/brokers/`` (one :class:`~engine.agent.folder.BrokerFolder`
per broker) and is what the HTTP layer calls. Its rules:

- ``put(spec)`` is idempotent. A broker already running with the same *essence* (the driver says
  which fields need a restart) and the same rendered config is left alone; anything else is
  stopped, re-rendered, started, and the call returns once the driver's health check passes (or
  raises when the driver's start deadline passes).
- A supervision thread notices a broker that exits on its own, marks it CRASHED and restarts it
  with exponential backoff (``backoff_base`` doubling up to ``backoff_cap``); ``restarts`` and
  ``last_error`` show in its status. The backoff resets after ``stable_after`` s of health.
- ``open()`` re-adopts brokers an earlier agent left running (pid, start time and command line
  must match, see :mod:`engine.agent.procs`), stops strays, and starts brokers whose process is
  gone: every folder with a ``spec.json`` is a broker that should run — unless the operator
  stopped it.
- ``stop``/``start``/``restart`` are the operator's verbs (:mod:`engine.agent.held`): ``stop``
  writes the broker's ``stopped.json`` and stops its process; the broker then reports
  STOPPED_BY_OPERATOR, keeps its folder (spec, config, data), and nothing starts it (supervisor,
  re-adoption, PUT) until ``start`` or ``restart``; ``restart`` is a stop and a start (a new pid).

Many brokers at once (``put_many``, ``delete_many``: a batch) are ordered and awaited by
:mod:`engine.agent.bring_up`, through the steps the manager hands it; so is the wait of every
single PUT and start.

Locking: each broker has an operation lock held for a whole PUT/DELETE/topic call (the supervisor
only ``try``-locks it, so it never waits behind a slow start); ``self._lock`` guards the broker
table and every field update, so a GET reads a consistent snapshot without waiting for a PUT.
"""

from __future__ import annotations

import logging
import shutil
import threading
import time
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from collections.abc import Sequence
from typing import Any

from engine import netutil, process
from engine.agent import bring_up
from engine.agent.folder import BrokerFolder, PidRecord
from engine.agent.held import Held, clear_held, read_held, write_held
from engine.agent.owners import Owners, claim
from engine.agent.procs import (
    AdoptedProcess,
    BrokerProcess,
    SpawnedProcess,
    log_end,
    mentions,
    proc_info,
    processes_of,
    raise_first,
    started_at,
    stop_foreign,
    stop_together,
)
from engine.agent.save_tick import SaveTicker
from engine.agent.supervision import backoff, start_supervisor
from engine.agent.wire import BROKER_ID
from engine.drivers.base import LOGS_DIR, BridgeCarrier, Driver, PeriodicSave, Waking, config_hash, log_file
from engine.drivers.registry import DriverRegistry
from engine.errors import (
    BrokerUnavailableError,
    DriverError,
    EngineError,
    UnknownDriverError,
)
from engine.model import (
    BridgeSpec,
    BridgeStatus,
    BrokerSpec,
    BrokerStatus,
    ObservedBridge,
    ObservedBroker,
    ObservedTopic,
    TopicSpec,
)

log = logging.getLogger(__name__)

BROKERS_DIR = "brokers"
REMOVED_DIR = "removed"


class BrokerNotFoundError(EngineError):
    """No broker with this id on this agent (HTTP 404)."""

    def __init__(self, broker_id: str) -> None:
        super().__init__(f"no broker {broker_id!r} on this agent",
                         hint="PUT /v1/brokers/<id> first")
        self.broker_id = broker_id


class BridgeConflictError(EngineError):
    """A bridge PUT whose local end is not the broker this agent runs under that id (HTTP 409)."""


class BrokerNotRunningError(EngineError):
    """The broker failed or is stopped; a topic cannot be changed on it now (HTTP 409)."""


class BrokerHeldError(BrokerNotRunningError):
    """The operator stopped the broker; nothing that would start it is done until it is started
    again (HTTP 409)."""

    def __init__(self, broker_id: str, doing: str) -> None:
        super().__init__(f"broker {broker_id!r} is stopped by the operator; {doing} would start it",
                         hint=f"`plantkg start {broker_id}` (POST /v1/brokers/{broker_id}/start) "
                              "first")
        self.broker_id = broker_id


@dataclass(eq=False)
class _Broker:
    spec: BrokerSpec
    driver: Driver | None                 # None: no driver for the stored kind any more
    folder: BrokerFolder
    op: threading.Lock = field(default_factory=threading.Lock)
    proc: BrokerProcess | None = None
    status: BrokerStatus = BrokerStatus.STOPPED
    restarts: int = 0
    last_error: str | None = None
    config_hash: str | None = None
    essence: dict[str, Any] | None = None  # of the running process
    failures: int = 0                      # consecutive crashes, for the backoff
    next_start: float | None = None        # monotonic time the supervisor (re)starts it
    healthy_since: float | None = None
    deleted: bool = False
    owners: Owners | None = None           # owner.json: the broker's, its topics', its bridges'
    held: Held | None = None               # stopped.json: the operator stopped it
    saves: SaveTicker | None = None        # the save signals sent to it (PeriodicSave drivers)

    def record(self) -> Owners:
        if self.owners is None:
            self.owners = Owners.read(self.folder.path)
        return self.owners


class BrokerManager:
    """All brokers of one agent; thread-safe."""

    def __init__(
        self,
        state_dir: Path,
        registry: DriverRegistry,
        *,
        backoff_base: float = 1.0,
        backoff_cap: float = 30.0,
        stable_after: float = 30.0,
        tick: float = 0.1,
    ) -> None:
        self.state_dir = state_dir
        self.registry = registry
        self.backoff_base = backoff_base
        self.backoff_cap = backoff_cap
        self.stable_after = stable_after
        self.tick = tick
        self._lock = threading.Lock()
        self._brokers: dict[str, _Broker] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        # What a batch may do to the brokers (engine.agent.bring_up orders the steps and waits).
        self._steps = bring_up.Steps[_Broker](
            registry=registry, claim=self._claim, held=self._held, begin=self._put_begin,
            observe=self._observe, update=self._update, stop=self._stop_procs, remove=self._remove)

    @property
    def brokers_dir(self) -> Path:
        return self.state_dir / BROKERS_DIR

    # --- life cycle ------------------------------------------------------------------------

    def open(self) -> BrokerManager:
        """Load the broker folders, re-adopt or schedule their processes, start supervising."""
        self.brokers_dir.mkdir(parents=True, exist_ok=True)
        for path in sorted(self.brokers_dir.iterdir()):
            if path.is_dir() and BROKER_ID.fullmatch(path.name):
                try:
                    self._load(path)
                except EngineError as exc:
                    log.error("broker folder %s ignored: %s", path, exc)
        self._thread = start_supervisor("plantkg-supervisor", self._stop, self.tick, self._all,
                                        self._supervise_one, lambda b: f"broker {b.spec.id}")
        return self

    def close(self, *, stop_brokers: bool = False) -> None:
        """Stop supervising; with ``stop_brokers`` also stop every broker (specs stay, so the next
        agent starts them again). They are stopped together, each with its own outcome
        (:meth:`_stop_procs`: N brokers take about as long as one, and one that will not stop
        leaves none of the others running); then each failure is logged and the first (by id)
        raised."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if not stop_brokers:
            return
        brokers = sorted(self._all(), key=lambda b: b.spec.id)  # the locks in id order, as a batch
        for b in brokers:
            b.op.acquire()
        try:
            errors = self._stop_procs([b for b in brokers if b.proc is not None and not b.deleted])
        finally:
            for b in brokers:
                b.op.release()
        raise_first(errors, "broker", log)

    # --- API -------------------------------------------------------------------------------

    def list(self) -> list[ObservedBroker]:
        return [self._observe(b) for b in sorted(self._all(), key=lambda b: b.spec.id)]

    def get(self, broker_id: str) -> ObservedBroker | None:
        with self._lock:
            b = self._brokers.get(broker_id)
        return self._observe(b) if b is not None else None

    def put(self, spec: BrokerSpec, owner: str | None = None) -> ObservedBroker:
        """Make broker ``spec.id`` run as ``spec``; return it once healthy. ``owner``: the plant
        that owns it (refused if another one does; None keeps the recorded owner)."""
        (result,) = self.put_many([(spec, owner)])
        if isinstance(result, Exception):
            raise result
        return result

    def put_many(self, requests: Sequence[tuple[BrokerSpec, str | None]]) -> list[ObservedBroker | Exception]:
        """:meth:`put` for many brokers (distinct ids) at once: each is checked, rendered and
        spawned (from a few threads: a spawn waits for its child's exec), then all are awaited in
        one polling loop, not a thread each (:func:`engine.agent.bring_up.put_many`). Each gets its
        own answer or error, in order; one that fails to start fails alone, as its single PUT
        would."""
        return bring_up.put_many(self._steps, requests)

    def _put_begin(self, b: _Broker, spec: BrokerSpec, owner: str | None) -> bool:
        """The part of a PUT before its wait (``b``'s operation lock held): True if the broker must
        now be awaited, False if it runs as asked already."""
        driver = self.registry.get(spec.kind)
        owner = claim(b.record().owner, owner, f"broker {spec.id!r}")
        if b.held is not None:
            raise BrokerHeldError(spec.id, "a PUT")
        if self._unchanged(b, spec, driver):
            if b.spec != spec:
                b.folder.write_spec(spec)
                self._update(b, spec=spec)
            b.record().set_owner(owner)
            return b.status is not BrokerStatus.RUNNING
        if b.proc is not None:
            self._stop_proc(b)
        if b.spec.kind != spec.kind:
            self._retire_folder(b)
            b.owners = Owners(b.folder.path)  # a new broker: its topics and bridges went
        b.folder.path.mkdir(parents=True, exist_ok=True)
        b.folder.write_spec(spec)
        b.record().set_owner(owner)
        self._update(b, spec=spec, driver=driver, failures=0, next_start=None, last_error=None)
        try:
            self._start(b, restart=False)
        except Exception as exc:
            self._update(b, status=BrokerStatus.FAILED, last_error=f"start failed: {exc}")
            raise
        return True

    def delete(self, broker_id: str, owner: str | None = None) -> None:
        """Stop the broker and move its folder to ``<state-dir>/removed/`` (idempotent); refused
        if ``owner`` is given and another plant owns the broker."""
        (error,) = self.delete_many([(broker_id, owner)])
        if error is not None:
            raise error

    def delete_many(self, requests: Sequence[tuple[str, str | None]]) -> list[Exception | None]:
        """:meth:`delete` for many brokers (distinct ids) at once: every process is sent SIGTERM,
        then all are waited for, then the folders are moved away
        (:func:`engine.agent.bring_up.delete_many`). Each gets its own error (None: deleted), in
        order."""
        return bring_up.delete_many(self._steps, requests)

    def put_topic(self, topic: TopicSpec, owner: str | None = None) -> ObservedTopic:
        """Create or alter a topic; an implicit-topics driver (MQTT) only validates, and the agent
        records the topic in topics.json. ``owner``: as for :meth:`put` (the broker's owner, if
        any, must be the same)."""
        b = self._existing(topic.broker_id)
        try:
            record = b.record()
            claim(record.owner, owner, f"broker {b.spec.id!r}")
            owner = claim(record.topics.get(topic.name), owner, f"topic {topic.name!r}")
            driver = self._topic_driver(b)
            observed = driver.ensure_topic(b.spec, topic)
            if driver.implicit_topics:
                kept = [t for t in b.folder.read_topics() if t.name != observed.name]
                b.folder.write_topics([*kept, replace(observed, owner=None)])
            record.set_topic(topic.name, owner)
            return replace(observed, owner=owner)
        finally:
            b.op.release()

    def delete_topic(self, broker_id: str, name: str, owner: str | None = None) -> None:
        try:
            b = self._existing(broker_id)
        except BrokerNotFoundError:
            return
        try:
            record = b.record()
            claim(record.topics.get(name), owner, f"topic {name!r}")
            driver = self._topic_driver(b)
            driver.delete_topic(b.spec, name)
            if driver.implicit_topics:
                b.folder.write_topics([t for t in b.folder.read_topics() if t.name != name])
            record.set_topic(name, None)
        finally:
            b.op.release()

    def set_owner(self, broker_id: str, owner: str, bridges: list[str] | None = None) -> ObservedBroker:
        """Import: record ``owner`` for the broker, and for every topic and native bridge on it that
        nobody owns (refused if another plant owns the broker). Nothing runs differently."""
        b = self._existing(broker_id)
        try:
            record = b.record()
            claim(record.owner, owner, f"broker {broker_id!r}")
            record.owner = owner
            record.topics = {**{t: owner for t in self._topic_names(b)}, **record.topics}
            bridges = b.folder.read_bridges() if b.folder.path.exists() else ()
            record.bridges = {**{x.remote.id: owner for x in bridges}, **record.bridges}
            record.write()
        finally:
            b.op.release()
        return self._observe(b)

    def _topic_names(self, b: _Broker) -> list[str]:
        if b.driver is not None and b.driver.implicit_topics:
            return [t.name for t in b.folder.read_topics()]
        if b.driver is not None and b.status is BrokerStatus.RUNNING:
            try:
                return [t.name for t in b.driver.observe_topics(b.spec)]
            except DriverError as exc:
                log.warning("topics of broker %s not observed: %s", b.spec.id, exc)
        return []

    # --- the operator's verbs ------------------------------------------------------------------

    def stop(self, broker_id: str) -> ObservedBroker:
        """Stop the broker and keep it stopped (spec, config and data kept) until :meth:`start`;
        idempotent. The flag is written first: a crash in between leaves it stopped."""
        b = self._existing(broker_id)
        try:
            if b.held is None:
                held = write_held(b.folder.path, self._live_topics(b))
                if b.proc is not None:
                    self._stop_proc(b)
                self._update(b, held=held, status=BrokerStatus.STOPPED_BY_OPERATOR, failures=0,
                             next_start=None, healthy_since=None)
                log.info("broker %s stopped by the operator", broker_id)
        finally:
            b.op.release()
        return self._observe(b)

    def start(self, broker_id: str) -> ObservedBroker:
        """Start a broker the operator stopped (or one that is down) with its stored spec and
        config; return it once healthy. A running broker is left alone."""
        b = self._existing(broker_id)
        try:
            if b.driver is None:
                raise BrokerNotRunningError(f"broker {broker_id!r} cannot be started: "
                                            f"{b.last_error}", hint="install its driver")
            if b.proc is not None and b.proc.alive():
                if b.status is not BrokerStatus.RUNNING:
                    self._wait_healthy(b)
                return self._observe(b)
            self._start_now(b)
        finally:
            b.op.release()
        return self._observe(b)

    def restart(self, broker_id: str) -> ObservedBroker:
        """Stop the broker (gracefully, its data kept) and start it again: a new process."""
        b = self._existing(broker_id)
        try:
            if b.driver is None:
                raise BrokerNotRunningError(f"broker {broker_id!r} cannot be restarted: "
                                            f"{b.last_error}", hint="install its driver")
            if b.proc is not None:
                self._stop_proc(b)
            self._start_now(b)
        finally:
            b.op.release()
        return self._observe(b)

    def _start_now(self, b: _Broker) -> None:
        """Spawn (the operation lock held), clear the operator's flag, wait until healthy."""
        self._update(b, failures=0, next_start=None, last_error=None)
        try:
            self._start(b, restart=False)
        except Exception as exc:
            self._update(b, status=BrokerStatus.FAILED if b.held is None
                         else BrokerStatus.STOPPED_BY_OPERATOR, last_error=f"start failed: {exc}")
            raise
        clear_held(b.folder.path)
        self._update(b, held=None)
        self._wait_healthy(b)

    def _live_topics(self, b: _Broker) -> list[ObservedTopic]:
        """The topics a running broker reports now (kept in the flag while it is stopped)."""
        if b.driver is None or b.driver.implicit_topics or b.status is not BrokerStatus.RUNNING:
            return []
        try:
            return b.driver.observe_topics(b.spec)
        except DriverError as exc:
            log.warning("topics of broker %s not observed before its stop: %s", b.spec.id, exc)
            return []

    # --- native bridges (carried in the broker's own config) ---------------------------------

    def put_native_bridge(self, bridge: BridgeSpec, owner: str | None = None) -> ObservedBridge:
        """Render ``bridge`` into its local broker's config; restart that broker (only) if the
        rendered config changed. The remote may be down: the broker keeps reconnecting."""
        b = self._existing(bridge.local.id)
        try:
            record = b.record()
            claim(record.owner, owner, f"broker {b.spec.id!r}")
            owner = claim(record.bridges.get(bridge.remote.id), owner, bridge.address)
            if b.held is not None:
                raise BrokerHeldError(b.spec.id, f"changing {bridge.address}")
            if (b.spec.host, b.spec.port) != (bridge.local.host, bridge.local.port):
                raise BridgeConflictError(
                    f"{bridge.address}: its local end {bridge.local.host}:{bridge.local.port} is "
                    f"not broker {b.spec.id!r} here ({b.spec.host}:{b.spec.port})",
                    hint="PUT the broker first, then its bridges")
            kept = tuple(x for x in b.folder.read_bridges() if x.address != bridge.address)
            self._rerender(b, tuple(sorted((*kept, bridge), key=lambda x: x.address)))
            record.set_bridge(bridge.remote.id, owner)
        finally:
            b.op.release()
        return next(o for o in self.native_bridges() if o.spec.address == bridge.address)

    def delete_native_bridge(self, local_id: str, remote_id: str, owner: str | None = None) -> bool:
        """Remove the bridge from its broker's config (restarting it); False if not carried."""
        try:
            b = self._existing(local_id)
        except BrokerNotFoundError:
            return False
        try:
            bridges = b.folder.read_bridges()
            kept = tuple(x for x in bridges if x.remote.id != remote_id)
            if kept == bridges:
                return False
            record = b.record()
            claim(record.bridges.get(remote_id), owner, f"bridge.{local_id}.{remote_id}")
            if b.held is not None:
                raise BrokerHeldError(local_id, f"removing bridge.{local_id}.{remote_id}")
            self._rerender(b, kept)
            record.set_bridge(remote_id, None)
            return True
        finally:
            b.op.release()

    def native_bridges(self) -> list[ObservedBridge]:
        """Every native bridge, with its state as the running broker reports it."""
        out: list[ObservedBridge] = []
        for b in sorted(self._all(), key=lambda b: b.spec.id):
            bridges = b.folder.read_bridges() if b.folder.path.exists() else ()
            if not bridges:
                continue
            driver, status = b.driver, b.status
            states: dict[str, bool] = {}
            if status is BrokerStatus.RUNNING and isinstance(driver, BridgeCarrier):
                states = driver.bridge_states(b.spec, bridges, 0.5)
            owners = b.record().bridges
            for bridge in bridges:
                out.append(ObservedBridge(
                    spec=bridge, status=_native_status(status, states.get(bridge.address)),
                    last_error=None if states.get(bridge.address) else b.last_error,
                    owner=owners.get(bridge.remote.id)))
        return out

    def _rerender(self, b: _Broker, bridges: tuple[BridgeSpec, ...]) -> None:
        """Validate the new rendering first (nothing changes on a refusal), then store the bridges
        and restart the broker if its config changed."""
        assert b.driver is not None
        files = b.driver.render_config(b.spec, b.folder.path, bridges)
        b.folder.write_bridges(bridges)
        if b.proc is not None and b.proc.alive() and config_hash(files) == b.config_hash:
            return
        if b.proc is not None:
            self._stop_proc(b)
        self._update(b, failures=0, next_start=None, last_error=None)
        self._start(b, restart=False)
        self._wait_healthy(b)

    # --- helpers for the API ---------------------------------------------------------------

    def _all(self) -> list[_Broker]:
        with self._lock:
            return list(self._brokers.values())

    def _update(self, b: _Broker, **changes: Any) -> None:
        with self._lock:
            for name, value in changes.items():
                setattr(b, name, value)

    def _claim(self, spec: BrokerSpec, driver: Driver) -> _Broker:
        """The broker's record (created if new) with its operation lock held."""
        while True:
            with self._lock:
                b = self._brokers.get(spec.id)
                if b is None:
                    b = _Broker(spec, driver, BrokerFolder(self.brokers_dir / spec.id))
                    self._brokers[spec.id] = b
            b.op.acquire()
            if not b.deleted:
                return b
            b.op.release()

    def _existing(self, broker_id: str) -> _Broker:
        """A known broker with its operation lock held, else BrokerNotFoundError."""
        b = self._held(broker_id)
        if b is None:
            raise BrokerNotFoundError(broker_id)
        return b

    def _held(self, broker_id: str) -> _Broker | None:
        """A known broker with its operation lock held, else None."""
        with self._lock:
            b = self._brokers.get(broker_id)
        if b is None:
            return None
        b.op.acquire()
        if b.deleted:
            b.op.release()
            return None
        return b

    def _remove(self, b: _Broker) -> None:
        """A stopped broker gone (its lock held): its folder moved away, then out of the table."""
        self._retire_folder(b)
        with self._lock:
            b.deleted = True
            self._brokers.pop(b.spec.id, None)

    def _unchanged(self, b: _Broker, spec: BrokerSpec, driver: Driver) -> bool:
        """Running (or starting) with the same essence and the same rendered files."""
        if b.proc is None or not b.proc.alive() or b.driver is not driver:
            return False
        if b.essence != driver.essence(spec):
            return False
        try:
            return config_hash(driver.render_config(spec, b.folder.path, b.folder.read_bridges())) \
                == b.config_hash
        except EngineError:
            return False

    def _topic_driver(self, b: _Broker) -> Driver:
        """The broker's driver, if its topics can be changed now (always for implicit topics)."""
        if b.driver is not None and b.driver.implicit_topics:
            return b.driver
        self._require_running(b)
        assert b.driver is not None
        return b.driver

    def _require_running(self, b: _Broker) -> None:
        if b.status is BrokerStatus.RUNNING and b.proc is not None and b.proc.alive():
            return
        if b.held is not None:
            raise BrokerHeldError(b.spec.id, "changing its topics")
        where = f"broker {b.spec.id!r} is {b.status.value}"
        if b.status in (BrokerStatus.STARTING, BrokerStatus.CRASHED):
            raise BrokerUnavailableError(f"{where}; the agent is (re)starting it",
                                         hint="try again in a few seconds")
        raise BrokerNotRunningError(
            f"{where}" + (f": {b.last_error}" if b.last_error else ""),
            hint="PUT the broker again to start it",
        )

    def _observe(self, b: _Broker) -> ObservedBroker:
        record = b.record()
        with self._lock:
            spec, driver, proc, status = b.spec, b.driver, b.proc, b.status
            observed = ObservedBroker(
                spec=spec, status=status, pid=proc.pid if proc else None,
                started_at=started_at(proc.start_ticks) if proc else None,
                restarts=b.restarts, config_hash=b.config_hash, last_error=b.last_error,
                owner=record.owner,
            )
            held = b.held
        renewal = getattr(driver, "tls_renewal", None)  # drivers with TLS listeners (Mosquitto)
        if renewal is not None and spec.tls:
            observed = replace(observed, tls_renew=renewal(spec, b.folder.path))
        topics: list[ObservedTopic] = []
        if driver is not None and driver.implicit_topics:
            topics = b.folder.read_topics()
        elif held is not None:
            topics = list(held.topics)
        elif driver is not None and status is BrokerStatus.RUNNING:
            try:
                topics = driver.observe_topics(spec)
            except DriverError as exc:
                log.warning("topics of broker %s not observed: %s", spec.id, exc)
        owners = dict(record.topics)
        return replace(observed, topics=tuple(sorted(
            (replace(t, owner=owners.get(t.name)) for t in topics), key=lambda t: t.name)))

    # --- processes -------------------------------------------------------------------------

    def _start(self, b: _Broker, *, restart: bool) -> None:
        """Prepare, render, spawn; status STARTING (the caller or the supervisor waits)."""
        driver, spec, path = b.driver, b.spec, b.folder.path
        assert driver is not None
        (path / LOGS_DIR).mkdir(parents=True, exist_ok=True)
        driver.prepare(spec, path)
        files = driver.render_config(spec, path, b.folder.read_bridges())
        b.folder.write_rendered(files)
        argv = driver.command(spec, path)
        child = process.spawn(argv, log_dir=path / LOGS_DIR, name=driver.kind, cwd=path)
        proc = SpawnedProcess(child)
        restarts = b.restarts + (1 if restart else 0)
        digest, essence = config_hash(files), driver.essence(spec)
        try:
            b.folder.write_pid(PidRecord(pid=proc.pid, start_ticks=proc.start_ticks,
                                         argv=tuple(argv), restarts=restarts, config_hash=digest,
                                         essence=essence))
        except BaseException:
            proc.stop(driver.stop_grace)  # untracked, it would run unsupervised
            raise
        self._update(b, proc=proc, status=BrokerStatus.STARTING, restarts=restarts,
                     config_hash=digest, essence=essence, next_start=None, healthy_since=None)
        log.info("broker %s (%s) started, pid %d", spec.id, driver.kind, proc.pid)

    def _wait_healthy(self, b: _Broker) -> None:
        """Return once the spawned broker is healthy; else its error (engine.agent.bring_up)."""
        (error,) = bring_up.wait_all_healthy([b], self._update)
        if error is not None:
            raise error

    def _stop_proc(self, b: _Broker) -> None:
        error = self._stop_procs([b]).get(b.spec.id)
        if error is not None:
            raise error

    def _stop_procs(self, brokers: list[_Broker]) -> dict[str, Exception]:
        """Stop the brokers' processes together (SIGTERM to all, then wait for all: N take as long
        as the slowest); each stopped one STOPPED without its pid.json; the errors by broker id."""
        procs = [b.proc for b in brokers]
        assert all(p is not None for p in procs)
        grace = [b.driver.stop_grace if b.driver is not None else 30.0 for b in brokers]
        wakes = [b.driver.wake_address(b.spec) for b in brokers if isinstance(b.driver, Waking)]

        def wake_all() -> None:  # drivers whose broker acts on SIGTERM only when its loop wakes
            netutil.touch_all(wakes)

        failed = stop_together(procs, grace, wake_all if wakes else None)  # type: ignore[arg-type]
        errors: dict[str, Exception] = {}
        for b, error in zip(brokers, failed):
            if error is not None:
                errors[b.spec.id] = error
                continue
            try:
                b.folder.remove_pid()
            except OSError as exc:
                errors[b.spec.id] = exc
                continue
            self._update(b, proc=None, status=BrokerStatus.STOPPED, healthy_since=None, next_start=None)
            log.info("broker %s stopped", b.spec.id)
        return errors

    def _retire_folder(self, b: _Broker) -> None:
        """Move the folder to removed/<id>.<UTC time> (logs and data kept for a post-mortem)."""
        if not b.folder.path.exists():
            return
        stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ")
        target = self.state_dir / REMOVED_DIR / f"{b.spec.id}.{stamp}"
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(b.folder.path), str(target))
        b.folder.forget()

    # --- re-adoption -----------------------------------------------------------------------

    def _load(self, path: Path) -> None:
        folder = BrokerFolder(path)
        spec = folder.read_spec()
        if spec is None or spec.id != path.name:
            return
        try:
            driver: Driver | None = self.registry.get(spec.kind)
        except UnknownDriverError as exc:
            self._brokers[spec.id] = _Broker(spec, None, folder, status=BrokerStatus.FAILED,
                                             last_error=exc.message)
            return
        assert driver is not None
        b = _Broker(spec, driver, folder, held=read_held(path))
        pid = folder.read_pid()
        adopted = None
        if pid is not None and b.held is not None:
            b.restarts = pid.restarts  # its process (if any) is a stray: the operator stopped it
        elif pid is not None:
            info = proc_info(pid.pid)
            if info is not None and info.start_ticks == pid.start_ticks \
                    and mentions(info, path, pid.argv[0]):
                adopted = AdoptedProcess(info, log_file(path, driver.kind))
            b.restarts = pid.restarts
        program = pid.argv[0] if pid is not None else None
        if program is None:
            try:
                program = driver.command(spec, path)[0]
            except EngineError:
                program = None
        for stray in processes_of(path, program) if program else []:
            if adopted is None or stray.pid != adopted.pid:
                log.warning("stopping stray process %d of broker %s: %s", stray.pid, spec.id,
                            " ".join(stray.argv))
                stop_foreign(stray, driver.stop_grace)
        if b.held is not None:
            folder.remove_pid()
            b.status = BrokerStatus.STOPPED_BY_OPERATOR
            log.info("broker %s stays stopped by the operator", spec.id)
        elif adopted is not None and pid is not None:
            b.proc, b.config_hash, b.essence = adopted, pid.config_hash, pid.essence
            b.status = BrokerStatus.RUNNING if driver.health(spec, 1.0) else BrokerStatus.STARTING
            if b.status is BrokerStatus.RUNNING:
                b.healthy_since = time.monotonic()
            log.info("broker %s re-adopted (pid %d, %s)", spec.id, adopted.pid, b.status.value)
        elif pid is not None:
            b.status = BrokerStatus.CRASHED
            b.last_error = f"process {pid.pid} was gone when the agent started"
            b.next_start = time.monotonic()
        else:
            b.next_start = time.monotonic()
        self._brokers[spec.id] = b

    # --- supervision -----------------------------------------------------------------------

    def _supervise_one(self, b: _Broker) -> None:
        if not b.deleted and b.driver is not None:
            self._supervise(b)

    def _backoff(self, failures: int) -> float:
        return backoff(self.backoff_base, self.backoff_cap, failures)

    def _supervise(self, b: _Broker) -> None:
        now = time.monotonic()
        assert b.driver is not None
        if b.proc is not None:
            if not b.proc.alive():
                code = b.proc.exit_code()
                failures = b.failures + 1
                delay = self._backoff(failures)
                when = datetime.now(timezone.utc).isoformat(timespec="seconds")
                error = (f"exited unexpectedly at {when}"
                         + (f" with code {code}" if code is not None else "")
                         + f"; restart in {delay:.1f} s. Log ends with:\n"
                         + log_end(b.proc))
                self._update(b, proc=None, status=BrokerStatus.CRASHED, failures=failures,
                             next_start=now + delay, last_error=error, healthy_since=None)
                log.warning("broker %s %s", b.spec.id, error)
            elif b.status is BrokerStatus.STARTING:
                if b.driver.health(b.spec, 0.5):
                    self._update(b, status=BrokerStatus.RUNNING, healthy_since=now)
            else:
                if b.failures and b.healthy_since is not None and now - b.healthy_since >= self.stable_after:
                    self._update(b, failures=0)
                self._tick_save(b, now)
            return
        if b.next_start is not None and now >= b.next_start:
            try:
                self._start(b, restart=b.status is BrokerStatus.CRASHED)
            except Exception as exc:  # noqa: BLE001 - reported in the status, retried
                failures = b.failures + 1
                delay = self._backoff(failures)
                self._update(b, status=BrokerStatus.CRASHED, failures=failures,
                             next_start=now + delay,
                             last_error=f"restart failed: {exc}; next try in {delay:.1f} s")
                log.warning("broker %s: restart failed: %s", b.spec.id, exc)


    @staticmethod
    def _tick_save(b: _Broker, now: float) -> None:
        """Send a running broker its driver's save signal when due (engine.agent.save_tick)."""
        save = b.driver.save_signal(b.spec) if isinstance(b.driver, PeriodicSave) else None
        if save is None or b.proc is None or b.status is not BrokerStatus.RUNNING:
            return
        if b.saves is None or b.saves.every != save.every:
            b.saves = SaveTicker(save.every)
        b.saves.step(b.proc.pid, save.signal, now)


def _native_status(broker: BrokerStatus, connected: bool | None) -> BridgeStatus:
    """A native bridge runs when its broker runs and reports the connection up."""
    if broker is BrokerStatus.RUNNING:
        return BridgeStatus.RUNNING if connected else BridgeStatus.CONNECTING
    return {BrokerStatus.STARTING: BridgeStatus.CONNECTING, BrokerStatus.CRASHED: BridgeStatus.CRASHED,
            BrokerStatus.FAILED: BridgeStatus.FAILED}.get(broker, BridgeStatus.STOPPED)

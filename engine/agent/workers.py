"""The agent's bridge workers: one supervised process per MQTT <-> Kafka, MQTT <-> NGSI or
Kafka -> Kafka bridge it carries (the last a MirrorMaker 2 watched by
``python -m engine.drivers.kafka.mirror_worker``, which reports its lag).

A worker bridge lives in ``<state-dir>/bridges/<local>--<remote>/``::

    spec.json     the BridgeSpec last PUT (its presence means "this worker should run")
    worker.json   the worker's configuration (engine.bridge_worker.config.WorkerConfig, or
                  engine.bridge_worker.ngsi_config.NgsiWorkerConfig for mechanism mqtt-ngsi, or
                  engine.drivers.kafka.mirror_worker.MirrorWorkerConfig for kafka-mirror)
    remote.token  mqtt-ngsi: the context broker's write token (the token of the agent that runs
                  it); mqtt-kafka to a closed Kafka, kafka-mirror with a closed end: plantkg's
                  password there, derived from the principal key (engine.security.kafka_client)
                  when the spec says the Kafka end is ``closed`` (no token travels for it); mode
                  0600; absent when every Kafka end is open
    pid.json      pid, start time, argv, restarts, config hash (as for brokers)
    stats.json    what the worker reports: readiness, counters, forwarding rate, last error
    logs/bridge.log

The rules are the broker manager's (:mod:`engine.agent.manager`), kept small: ``put`` is
idempotent (same config and a live process: nothing to do; else restart the worker), a supervisor
thread restarts a worker that exits with exponential backoff, and ``open`` re-adopts workers an
earlier agent left running (pid, start time and command line must match). A worker whose remote is
down keeps running and reconnecting: it shows as CONNECTING, not as failed.

The remote token is a transport detail, never part of the spec: it is not in spec.json, in what
the agent answers or in its log. A changed token restarts the worker (it is part of the config
hash). Deleting an mqtt-ngsi bridge stops its worker, then runs ``python -m engine.bridge_worker
--remove worker.json`` once to delete the bridge's subscriptions on the context broker (bounded;
if the context broker is away they stay, and a later worker of the same bridge removes them).
"""

from __future__ import annotations

import logging
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

from engine import process
from engine.security import kafka_client
from engine.agent.folder import SPEC_FILE, BrokerFolder, PidRecord, write_atomic
from engine.agent.owners import Owners, claim
from engine.agent.procs import (
    AdoptedProcess,
    BrokerProcess,
    SpawnedProcess,
    mentions,
    proc_info,
    processes_of,
    started_at,
    stop_foreign,
    raise_first,
    stop_together,
)
from engine.agent.supervision import backoff, start_supervisor
from engine.agent.wire import bridge_spec_from_json
from engine.bridge_worker.config import Direction, KeyMode, Route, WorkerConfig
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiRoute, NgsiWorkerConfig
from engine.bridge_worker.stats import read_stats
from engine.drivers.base import LOGS_DIR, config_hash
from engine.drivers.kafka.mirror import MirrorConfig
from engine.drivers.kafka.mirror_worker import MirrorWorkerConfig
from engine.errors import ConfigValueError, EngineError
from engine.security import ca, principals
from engine.security.mqtt_client import USER_KINDS
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeSpec,
    BridgeStatus,
    ObservedBridge,
    to_dict,
)
from engine.values import host_in_url

log = logging.getLogger(__name__)

WORKERS_DIR = "bridges"
REMOVED_DIR = "removed"
WORKER_FILE = "worker.json"
TOKEN_FILE = "remote.token"
#: Seconds the removal of an mqtt-ngsi bridge's subscriptions may take at delete.
REMOVE_TIMEOUT = 15.0
WORKER_MECHANISMS = (BridgeMechanism.WORKER, BridgeMechanism.NGSI, BridgeMechanism.MIRROR)
LOG_NAME = "bridge"
#: The module the agent runs for a Kafka -> Kafka bridge (a watched MirrorMaker 2).
MIRROR_MODULE = "engine.drivers.kafka.mirror_worker"
STOP_GRACE = 10.0
#: A worker that has not rewritten stats.json for this long is reported as not ready.
STALE_STATS = 5.0


def folder_name(local_id: str, remote_id: str) -> str:
    return f"{local_id}--{remote_id}"


def worker_config(spec: BridgeSpec, state_dir: Path) -> WorkerConfig:
    """The worker's configuration for ``spec`` (local: the MQTT broker, remote: Kafka). The worker
    subscribes and publishes at QoS 1 at most: a QoS 2 topic is bridged at least once."""
    routes: list[Route] = []
    for r in spec.routes:
        qos, key = min(r.qos, 1), KeyMode(r.key)
        if r.direction in (BridgeDirection.OUT, BridgeDirection.BOTH):
            routes.append(Route(r.topic, r.topic, Direction.MQTT_TO_KAFKA, qos, key))
        if r.direction in (BridgeDirection.IN, BridgeDirection.BOTH):
            routes.append(Route(r.topic, r.topic, Direction.KAFKA_TO_MQTT, qos, key))
    return WorkerConfig(
        bridge_id=folder_name(spec.local.id, spec.remote.id),
        mqtt_host=spec.local.host, mqtt_port=spec.local.port,
        kafka_bootstrap=",".join(_bootstrap(spec.remote)),
        routes=tuple(routes), state_dir=state_dir, mqtt_username=_mqtt_login(spec),
        mqtt_ca_file=_mqtt_ca(spec), kafka_ca_file=ca.ca_cert_file() if spec.remote.tls else None,
    )


def ngsi_worker_config(spec: BridgeSpec, state_dir: Path, token_file: Path | None) -> NgsiWorkerConfig:
    """The NGSI worker's configuration for ``spec`` (local: the MQTT broker, remote: the context
    broker). Each route is one topic and its entity (``entity_id``/``entity_type``, filled by
    derive); ``out`` writes the entity from MQTT, ``in`` subscribes it to MQTT."""
    routes: list[NgsiRoute] = []
    for i, r in enumerate(spec.routes):
        entity_id, entity_type = getattr(r, "entity_id", None), getattr(r, "entity_type", None)
        if entity_id is None:
            raise ConfigValueError(f"routes[{i}].entity_id", None,
                                   f"an mqtt-ngsi route needs the NGSI entity of topic {r.topic!r}")
        qos, entity_type = min(r.qos, 1), entity_type or "Thing"
        if r.direction in (BridgeDirection.OUT, BridgeDirection.BOTH):
            routes.append(NgsiRoute(r.topic, entity_id, entity_type, NgsiDirection.MQTT_TO_NGSI, qos))
        if r.direction in (BridgeDirection.IN, BridgeDirection.BOTH):
            routes.append(NgsiRoute(r.topic, entity_id, entity_type, NgsiDirection.NGSI_TO_MQTT, qos))
    return NgsiWorkerConfig(
        bridge_id=folder_name(spec.local.id, spec.remote.id),
        mqtt_host=spec.local.host, mqtt_port=spec.local.port,
        ngsi_url=f"{'https' if spec.remote.tls else 'http'}://{host_in_url(spec.remote.host)}:{spec.remote.port}",
        routes=tuple(routes), state_dir=state_dir, token_file=token_file,
        mqtt_username=_mqtt_login(spec), mqtt_ca_file=_mqtt_ca(spec),
        ngsi_ca_file=ca.ca_cert_file() if spec.remote.tls else None,  # a pk:tls context broker
        notify_username=_notify_login(spec, routes),
    )


def _notify_login(spec: BridgeSpec, routes: list[NgsiRoute]) -> str | None:
    """The principal the context broker publishes the bridge's notifications as, where plantkg
    renders users and the bridge brings entities back (engine.derived.access makes it a user there)."""
    if _mqtt_login(spec) is None or not any(r.direction is NgsiDirection.NGSI_TO_MQTT for r in routes):
        return None
    return principals.notify_principal(spec.local.id, spec.remote.id)


def _mqtt_ca(spec: BridgeSpec) -> Path | None:
    """The plant CA's certificate when the worker's MQTT broker speaks TLS."""
    return ca.ca_cert_file() if spec.local.tls else None


def _mqtt_login(spec: BridgeSpec) -> str | None:
    """The worker's principal on its MQTT broker where plantkg renders users (engine.derived.access
    makes it a user there), else None (anonymous)."""
    if spec.local.kind not in USER_KINDS:
        return None
    return principals.bridge_principal(spec.local.id, spec.remote.id)


def mirror_config(spec: BridgeSpec, state_dir: Path) -> MirrorWorkerConfig:
    """A MirrorMaker 2's configuration (local: the target Kafka, which carries it; remote: the
    source). Its own topics take the target's replication factor: one per broker, at most 3."""
    target = _bootstrap(spec.local)
    closed = spec.local.closed or spec.remote.closed  # plantkg logs in there: its password file
    return MirrorWorkerConfig(
        bridge_id=folder_name(spec.local.id, spec.remote.id),
        mirror=MirrorConfig(source=_bootstrap(spec.remote), target=target,
                            topics=tuple(r.topic for r in spec.routes), replication=min(3, len(target)),
                            source_closed=spec.remote.closed, target_closed=spec.local.closed,
                            source_tls=spec.remote.tls, target_tls=spec.local.tls),
        state_dir=state_dir, password_file=state_dir / TOKEN_FILE if closed else None,
        ca_file=ca.ca_cert_file() if spec.local.tls or spec.remote.tls else None,
    )


def _bootstrap(end: BridgeEnd) -> tuple[str, ...]:
    """``host:port`` of every broker of a Kafka end (a cluster lists them; else the one)."""
    return end.bootstrap or (f"{host_in_url(end.host)}:{end.port}",)


def _config_text(spec: BridgeSpec, folder: Path, remote_token: str | None) -> str:
    if spec.mechanism is BridgeMechanism.MIRROR:
        if remote_token is not None:
            raise ConfigValueError("remote_token", "(hidden)", "only an mqtt-ngsi bridge takes a remote token")
        if any(r.direction is not BridgeDirection.IN for r in spec.routes):
            raise ConfigValueError("routes", [r.direction.value for r in spec.routes],
                                   "a kafka-mirror bridge copies into its carrier only (direction in)")
        return mirror_config(spec, folder).to_json()
    if spec.mechanism is BridgeMechanism.NGSI:
        token_file = folder / TOKEN_FILE if remote_token is not None else None
        return ngsi_worker_config(spec, folder, token_file).to_json()
    if remote_token is not None:
        raise ConfigValueError("remote_token", "(hidden)", "only an mqtt-ngsi bridge takes a remote token")
    cfg = worker_config(spec, folder)
    if spec.remote.closed:  # a closed Kafka: the worker's clients log in as plantkg
        cfg = replace(cfg, kafka_password_file=folder / TOKEN_FILE)
    return cfg.to_json()


def _logs_in_to_kafka(spec: BridgeSpec) -> bool:
    """The bridge's process logs in to a closed Kafka as plantkg: a worker's remote, either end of
    a mirror."""
    if spec.mechanism is BridgeMechanism.MIRROR:
        return spec.local.closed or spec.remote.closed
    return spec.mechanism is BridgeMechanism.WORKER and spec.remote.closed


def _digest(folder: Path) -> str:
    """The config hash of a worker folder: worker.json and the token (so a new token restarts)."""
    files = {WORKER_FILE: (folder / WORKER_FILE).read_text(encoding="utf-8")}
    token = folder / TOKEN_FILE
    if token.exists():
        files[TOKEN_FILE] = token.read_text(encoding="utf-8")
    return config_hash(files)


class WorkerFolder(BrokerFolder):
    """A worker bridge's folder: a BrokerFolder whose spec.json holds a BridgeSpec."""

    def read_bridge(self) -> BridgeSpec | None:
        return self.read_parsed(SPEC_FILE, bridge_spec_from_json,
                                "PUT the bridge again, or delete its folder")

    def write_bridge(self, spec: BridgeSpec) -> None:
        self.write_json(SPEC_FILE, to_dict(spec))


@dataclass(eq=False)
class _Worker:
    spec: BridgeSpec
    folder: WorkerFolder
    op: threading.Lock = field(default_factory=threading.Lock)
    proc: BrokerProcess | None = None
    config_hash: str | None = None
    status: BridgeStatus = BridgeStatus.STOPPED
    restarts: int = 0
    failures: int = 0
    next_start: float | None = None
    last_error: str | None = None
    owners: Owners | None = None  # owner.json: the plant that owns the bridge

    def record(self) -> Owners:
        if self.owners is None:
            self.owners = Owners.read(self.folder.path)
        return self.owners


class WorkerManager:
    """All bridge workers of one agent; thread-safe."""

    def __init__(self, state_dir: Path, *, python: str = sys.executable, backoff_base: float = 1.0,
                 backoff_cap: float = 30.0, tick: float = 0.1) -> None:
        self.state_dir = state_dir
        self.python = python
        self.backoff_base, self.backoff_cap, self.tick = backoff_base, backoff_cap, tick
        self._lock = threading.Lock()
        self._workers: dict[str, _Worker] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def workers_dir(self) -> Path:
        return self.state_dir / WORKERS_DIR

    # --- life cycle ------------------------------------------------------------------------

    def open(self) -> WorkerManager:
        self.workers_dir.mkdir(parents=True, exist_ok=True)
        for path in sorted(p for p in self.workers_dir.iterdir() if p.is_dir()):
            try:
                self._load(path)
            except EngineError as exc:
                log.error("bridge folder %s ignored: %s", path, exc)
        self._thread = start_supervisor("plantkg-workers", self._stop, self.tick, self._all,
                                        self._supervise, lambda w: f"bridge worker {w.spec.address}")
        return self

    def close(self, *, stop_workers: bool = False) -> None:
        """Stop supervising; with ``stop_workers`` also stop every worker, together (SIGTERM to
        all, then wait: :func:`~engine.agent.procs.stop_together`), each with its own outcome, so
        one that will not stop leaves none of the others running; then each failure is logged and
        the first (by folder name) raised."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if not stop_workers:
            return
        workers = sorted(self._all(), key=lambda w: w.folder.path.name)  # the locks in one order
        for w in workers:
            w.op.acquire()
        errors: dict[str, Exception] = {}
        try:
            running = [w for w in workers if w.proc is not None]
            failed = stop_together([w.proc for w in running], [STOP_GRACE] * len(running))  # type: ignore[misc]
            for w, error in zip(running, failed):
                if error is None:
                    try:
                        w.folder.remove_pid()
                    except OSError as exc:
                        error = exc
                if error is not None:
                    errors[w.folder.path.name] = error
                    continue
                self._set(w, proc=None, status=BridgeStatus.STOPPED, next_start=None)
        finally:
            for w in workers:
                w.op.release()
        raise_first(errors, "bridge worker", log)

    # --- API -------------------------------------------------------------------------------

    def put(self, spec: BridgeSpec, remote_token: str | None = None,
            owner: str | None = None) -> ObservedBridge:
        """Make the worker of ``spec`` run with its configuration (restarted if it changed).
        ``remote_token``: the context broker's write token (mqtt-ngsi only; None: it is open).
        ``owner``: the plant that owns the bridge (refused if another one does)."""
        if spec.mechanism not in WORKER_MECHANISMS:
            raise EngineError(f"{spec.address} is not a worker bridge", hint="a bug in the agent")
        key = folder_name(spec.local.id, spec.remote.id)
        folder = WorkerFolder(self.workers_dir / key)
        text = _config_text(spec, folder.path, remote_token)  # refuses bad values before anything changes
        with self._lock:
            w = self._workers.setdefault(key, _Worker(spec, folder))
        if _logs_in_to_kafka(spec):
            remote_token = kafka_client.password()  # plantkg's on a closed Kafka, from the principal key
        with w.op:
            owner = claim(w.record().owner, owner, spec.address)
            files = {WORKER_FILE: text}
            if remote_token is not None:
                files[TOKEN_FILE] = remote_token
            digest = config_hash(files)
            if w.proc is not None and w.proc.alive() and w.config_hash == digest:
                if w.spec != spec:
                    w.folder.write_bridge(spec)
                    w.spec = spec
                w.record().set_owner(owner)
                return self._observe(w)
            self._stop_proc(w)
            folder.path.mkdir(parents=True, exist_ok=True)
            folder.write_bridge(spec)
            if remote_token is not None:
                write_atomic(folder.path / TOKEN_FILE, remote_token, mode=0o600)
            else:
                (folder.path / TOKEN_FILE).unlink(missing_ok=True)
            folder.write_rendered({WORKER_FILE: text})
            w.record().set_owner(owner)
            self._set(w, spec=spec, failures=0, last_error=None)
            self._start(w, restart=False)
            return self._observe(w)

    def delete(self, local_id: str, remote_id: str, owner: str | None = None) -> bool:
        """Stop the worker and retire its folder; False if there was none. Refused if ``owner``
        is given and another plant owns the bridge."""
        key = folder_name(local_id, remote_id)
        with self._lock:
            w = self._workers.get(key)
        if w is None:
            return False
        claim(w.record().owner, owner, w.spec.address)
        with self._lock:
            if self._workers.get(key) is not w:
                return False
            self._workers.pop(key)
        with w.op:
            self._stop_proc(w)
            if w.spec.mechanism is BridgeMechanism.NGSI and (w.folder.path / WORKER_FILE).exists():
                self._remove_subscriptions(w)
            (w.folder.path / TOKEN_FILE).unlink(missing_ok=True)
            if w.folder.path.exists():
                stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%S.%fZ")
                target = self.state_dir / REMOVED_DIR / f"bridge.{key}.{stamp}"
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(str(w.folder.path), str(target))
        return True

    def _remove_subscriptions(self, w: _Worker) -> None:
        """Delete the bridge's subscriptions on the context broker (see the module docstring)."""
        argv = [self.python, "-m", "engine.bridge_worker", "--remove", str(w.folder.path / WORKER_FILE)]
        try:
            done = subprocess.run(argv, cwd=w.folder.path, capture_output=True, text=True,
                                  timeout=REMOVE_TIMEOUT, check=False)
        except subprocess.TimeoutExpired:
            log.warning("bridge %s: removing its context broker subscriptions took more than %.0f s; "
                        "a later worker of this bridge removes them", w.spec.address, REMOVE_TIMEOUT)
            return
        if done.returncode != 0:
            log.warning("bridge %s: its context broker subscriptions stay (a later worker of this "
                        "bridge removes them): %s", w.spec.address, done.stderr.strip()[-500:])

    def list(self) -> list[ObservedBridge]:
        return [self._observe(w) for w in sorted(self._all(), key=lambda w: w.spec.address)]

    def set_owner(self, local_id: str, owner: str) -> None:
        """Import: record ``owner`` for every worker bridge of broker ``local_id`` nobody owns."""
        for w in self._all():
            if w.spec.local.id == local_id:
                with w.op:
                    if w.record().owner is None and w.folder.path.exists():
                        w.record().set_owner(owner)

    # --- processes -------------------------------------------------------------------------

    def _all(self) -> list[_Worker]:
        with self._lock:
            return list(self._workers.values())

    def _set(self, w: _Worker, **changes: object) -> None:
        with self._lock:
            for name, value in changes.items():
                setattr(w, name, value)

    def _argv(self, w: _Worker) -> list[str]:
        module = MIRROR_MODULE if w.spec.mechanism is BridgeMechanism.MIRROR else "engine.bridge_worker"
        return [self.python, "-m", module, str(w.folder.path / WORKER_FILE)]

    def _start(self, w: _Worker, *, restart: bool) -> None:
        argv = self._argv(w)
        digest = _digest(w.folder.path)
        child = process.spawn(argv, log_dir=w.folder.path / LOGS_DIR, name=LOG_NAME, cwd=w.folder.path)
        proc = SpawnedProcess(child)
        restarts = w.restarts + (1 if restart else 0)
        try:
            w.folder.write_pid(PidRecord(pid=proc.pid, start_ticks=proc.start_ticks, argv=tuple(argv),
                                         restarts=restarts, config_hash=digest))
        except BaseException:
            proc.stop(STOP_GRACE)
            raise
        self._set(w, proc=proc, config_hash=digest, restarts=restarts, next_start=None,
                  status=BridgeStatus.CONNECTING)
        log.info("bridge worker %s started, pid %d", w.spec.address, proc.pid)

    def _stop_proc(self, w: _Worker) -> None:
        if w.proc is not None:
            w.proc.stop(STOP_GRACE)
            w.folder.remove_pid()
        self._set(w, proc=None, status=BridgeStatus.STOPPED, next_start=None)

    def _observe(self, w: _Worker) -> ObservedBridge:
        with self._lock:
            spec, proc, status = w.spec, w.proc, w.status
            restarts, last_error = w.restarts, w.last_error
        stats = read_stats(w.folder.path) if w.folder.path.exists() else None
        alive = proc is not None and proc.alive()
        mine = alive and stats is not None and proc is not None and stats.pid == proc.pid
        fresh = mine and time.time() - stats.updated_at < STALE_STATS  # type: ignore[union-attr]
        if alive:
            status = BridgeStatus.RUNNING if fresh and stats.ready else BridgeStatus.CONNECTING  # type: ignore[union-attr]
        error = last_error or (stats.last_error if stats is not None else None)
        return ObservedBridge(
            spec=spec, status=status, pid=proc.pid if proc is not None else None,
            started_at=started_at(proc.start_ticks) if proc is not None else None,
            restarts=restarts,
            forwarded=stats.forwarded if stats is not None else None,
            retried=stats.retried if stats is not None else None,
            last_error=error,
            refused=stats.refused if stats is not None and stats.mechanism == "mqtt-ngsi" else None,
            owner=w.record().owner,
            # the last rate of the live worker (even a stale file's: a hung stats writer need not
            # mean a quiet bridge); a worker that is gone forwards nothing
            forwarded_per_s=None if stats is None else stats.forwarded_per_s if mine else 0.0,
            lag=stats.lag if stats is not None and mine else None,
        )

    # --- re-adoption and supervision ------------------------------------------------------

    def _load(self, path: Path) -> None:
        folder = WorkerFolder(path)
        spec = folder.read_bridge()
        if spec is None or not (path / WORKER_FILE).is_file():
            return
        w = _Worker(spec, folder)
        pid = folder.read_pid()
        if pid is not None:
            info = proc_info(pid.pid)
            if info is not None and info.start_ticks == pid.start_ticks \
                    and mentions(info, path, pid.argv[0]):
                w.proc = AdoptedProcess(info, path / LOGS_DIR / f"{LOG_NAME}.log")
                w.config_hash, w.status = pid.config_hash, BridgeStatus.CONNECTING
            w.restarts = pid.restarts
        for stray in processes_of(path, self.python):
            if w.proc is None or stray.pid != w.proc.pid:
                log.warning("stopping stray bridge worker %d in %s", stray.pid, path)
                stop_foreign(stray, STOP_GRACE)
        if w.proc is None:
            w.next_start = time.monotonic()
            if pid is not None:
                w.status, w.last_error = BridgeStatus.CRASHED, f"process {pid.pid} was gone when the agent started"
        self._workers[path.name] = w

    def _supervise(self, w: _Worker) -> None:
        now = time.monotonic()
        if w.proc is not None and not w.proc.alive():
            code = w.proc.exit_code()
            failures = w.failures + 1
            delay = backoff(self.backoff_base, self.backoff_cap, failures)
            tail = "\n".join(w.proc.log_tail().strip().splitlines()[-8:])
            error = (f"worker exited" + (f" with code {code}" if code is not None else "")
                     + f"; restart in {delay:.1f} s. Log ends with:\n{tail}")
            self._set(w, proc=None, status=BridgeStatus.CRASHED, failures=failures,
                      next_start=now + delay, last_error=error)
            log.warning("bridge %s: %s", w.spec.address, error)
        elif w.proc is None and w.next_start is not None and now >= w.next_start:
            self._start(w, restart=w.status is BridgeStatus.CRASHED)
            self._set(w, last_error=None)

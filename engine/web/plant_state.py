"""The plant a ``plantkg serve`` process keeps: its files, graph, observed state, plan — and apply.

:class:`PlantState` owns one immutable :class:`Snapshot` at a time and replaces it whole, so a
request reads one consistent version (``version`` numbers them; the API sends it as an ETag).
A watcher thread re-reads the files when their size or mtime changes (load → validate → reason
→ derive, then observe → plan) and asks the agents again every ``observe_interval`` seconds.
Apply runs in a thread of its own, only on request (or after each re-read with ``auto_apply``),
and only the plan the person saw: the caller names the plan's fingerprint and a different current
plan is refused. A file that cannot be loaded leaves the last good plant shown, with the error,
and nothing can be applied until it is fixed.

Paths may be folders (every ``*.ttl`` inside, engine.reconcile_loop.plant_files): a file added to a
watched folder is a change. With ``auto_apply``, :meth:`PlantState.start` also runs a
:class:`~engine.reconcile_loop.ReconcileLoop` on the same paths: it applies what the plant
requires after a change and, every ``observe_interval``, puts back what drifted (a broker deleted
behind plantkg's back); its last run is in the snapshot (``reconcile``). Every apply, the loop's or
a person's, holds one lock, so two never run at once; all of them touch only the plant's own
things (its owner, or ``owner``).
"""

from __future__ import annotations

import hashlib
import json
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import click

from engine.agents_config import AgentDirectory
from engine.apply import ApplyEvent, apply
from engine.cli.progress import result_lines
from engine.errors import EngineError
from engine.context_view import ContextView, agent_tokens, context_sources, write_context
from engine.model import DesiredState, ObservedBroker, ObservedState, Plan
from engine.observed import observe, write_observed
from engine.pipeline import run_pipeline
from engine.plan import plan as make_plan
from engine.reconcile_loop import LoopRun, ReconcileLoop, plant_files
from engine.render.plan import plan_json
from engine.web import views
from engine.web.rwlock import ReadWriteLock
from kg.errors import PlantKGError
from kg.load import PlantGraph
from kg.query import run_query
from kg.validate import ValidationReport

_RESOURCES = """SELECT ?id ?name ?bid WHERE {
  ?r pk:sendsTo ?b ; pk:id ?id . ?b pk:id ?bid . OPTIONAL { ?r pk:name ?name } } ORDER BY ?id ?bid"""
_MAX_PROGRESS = 200


class ApplyRefused(EngineError):
    """Apply was asked for a plan that is not the current one, or while another apply runs."""


@dataclass(frozen=True)
class ApplyJob:
    """The last apply: ``state`` is idle, running, done (converged) or failed."""

    state: str = "idle"
    fingerprint: str | None = None
    started_at: float | None = None
    finished_at: float | None = None
    progress: tuple[str, ...] = ()
    summary: tuple[str, ...] = ()
    by: str = ""


@dataclass(frozen=True)
class Snapshot:
    """One consistent view of the plant; later fields are None when a stage did not run."""

    version: int = 0
    files: tuple[str, ...] = ()
    loaded_at: float | None = None
    observed_at: float | None = None
    plant: PlantGraph | None = None
    report: ValidationReport | None = None
    desired: DesiredState | None = None
    observed: ObservedState | None = None
    plan: Plan | None = None
    fingerprint: str | None = None
    error: str | None = None
    resources: tuple[views.ResourceLink, ...] = ()
    agent_urls: tuple[tuple[str, str], ...] = ()
    context: ContextView | None = None
    apply: ApplyJob = field(default_factory=ApplyJob)
    reconcile: LoopRun | None = None       # the reconcile loop's last run (auto-apply)

    @cached_property
    def status(self) -> dict[str, Any]:
        """The dashboard's status document (made once per snapshot)."""
        brokers = views.broker_rows(self.desired, self.observed)
        bridges = views.bridge_rows(self.desired, self.observed)
        return {
            "version": self.version, "files": list(self.files), "loaded_at": self.loaded_at,
            "observed_at": self.observed_at, "error": self.error,
            "validation": views.report_summary(self.report),
            "machines": views.machine_rows(brokers, self.observed, dict(self.agent_urls)),
            "brokers": brokers, **views.topic_section(self.desired, self.observed),
            "bridges": bridges,
            "context": views.context_summary(self.context),
            "graph": views.graph_elements(brokers, bridges, self.resources),
            "plan": views.plan_summary(self.plan, self.fingerprint),
            "apply": {"state": self.apply.state, "fingerprint": self.apply.fingerprint,
                      "started_at": self.apply.started_at, "finished_at": self.apply.finished_at,
                      "progress": list(self.apply.progress), "summary": list(self.apply.summary)},
            "reconcile": None if self.reconcile is None else {
                "trigger": self.reconcile.trigger, "started_at": self.reconcile.started_at,
                "finished_at": self.reconcile.finished_at, "summary": dict(self.reconcile.summary),
                "applied": self.reconcile.applied, "converged": self.reconcile.converged,
                "foreign": self.reconcile.foreign, "error": self.reconcile.error},
        }


    @cached_property
    def status_json(self) -> bytes:
        return json.dumps(self.status, separators=(",", ":")).encode()


def plan_fingerprint(plan: Plan) -> str:
    """A short digest naming one plan (what a person saw and agreed to)."""
    return hashlib.sha256(plan_json(plan, indent=None).encode()).hexdigest()[:16]


def _signature(files: tuple[str, ...]) -> tuple[tuple[int, int] | None, ...]:
    out = []
    for name in files:
        try:
            st = Path(name).stat()
            out.append((st.st_mtime_ns, st.st_size))
        except OSError:
            out.append(None)
    return tuple(out)


class PlantState:
    """Holds the current :class:`Snapshot`; see the module docstring."""

    def __init__(self, files: list[str], agents_file: Path | None = None, *, auto_apply: bool = False,
                 observe_interval: float = 5.0, poll_interval: float = 0.5,
                 directory_loader: Callable[[Path | None], AgentDirectory] = AgentDirectory.load,
                 observe_fn: Callable[[AgentDirectory, Iterable[str]], ObservedState] = observe,
                 owner: str | None = None) -> None:
        self.paths = tuple(str(Path(f)) for f in files)
        self.owner = owner
        self.agents_file = agents_file
        self.auto_apply = auto_apply
        self.observe_interval = observe_interval
        self.poll_interval = poll_interval
        self.store_lock = ReadWriteLock()
        self._load_directory = directory_loader
        self._observe_fn = observe_fn
        self._snap = Snapshot(files=self.files)
        self._publish_lock = threading.Lock()
        self._work_lock = threading.Lock()     # one reload or refresh at a time
        self._apply_lock = threading.Lock()    # one apply at a time: a person's or the loop's
        self._loop: ReconcileLoop | None = None
        self._signature: tuple[Any, ...] | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    @property
    def snapshot(self) -> Snapshot:
        return self._snap

    @property
    def files(self) -> tuple[str, ...]:
        """The plant files now: the files given, and every ``*.ttl`` in the folders given."""
        return tuple(str(p) for p in plant_files(self.paths))

    @property
    def apply_lock(self) -> threading.Lock:
        """Held by every apply of this process (a person's, the loop's, a command's through the
        control socket, engine.control.server): two never run at once."""
        return self._apply_lock

    @property
    def loop(self) -> ReconcileLoop | None:
        """The reconcile loop (auto-apply, once started)."""
        return self._loop

    def _publish(self, **changes: Any) -> Snapshot:
        with self._publish_lock:
            self._snap = replace(self._snap, version=self._snap.version + 1, **changes)
            return self._snap

    # ------------------------------------------------------------------------------ reading

    def reload(self) -> Snapshot:
        """Re-read the files (and then the agents); auto-apply afterwards if asked to."""
        with self._work_lock:
            files = self.files
            self._signature = _signature(files)
            try:
                result = run_pipeline(files, None, observe=False, owner=self.owner)
            except PlantKGError as exc:
                return self._publish(error=f"the files cannot be loaded: {exc}", plan=None, fingerprint=None)
            plant = result.plant
            assert plant is not None
            resources = tuple(views.ResourceLink(r[0].value, r[1].value if r[1] else "", r[2].value)
                              for r in run_query(plant, _RESOURCES).rows)
            observed = self._observe(plant, result.desired) if result.desired is not None else {
                "observed": None, "plan": None, "fingerprint": None, "error": None}
            snap = self._publish(plant=plant, report=result.report, desired=result.desired,
                                 loaded_at=time.time(), resources=resources, files=files, **observed)
        if self.auto_apply and snap.plan is not None and not snap.plan.empty and snap.plan.applicable:
            try:
                self.start_apply(snap.fingerprint, by="auto-apply")
            except ApplyRefused:
                pass  # an apply is running; the next re-read applies what is left
        return self._snap

    def refresh(self) -> Snapshot:
        """Ask the agents again and plan again (the files are not re-read)."""
        with self._work_lock:
            snap = self._snap
            if snap.desired is None or snap.plant is None:
                return snap
            return self._publish(**self._observe(snap.plant, snap.desired))

    def _observe(self, plant: PlantGraph, desired: DesiredState) -> dict[str, Any]:
        """Ask the agents, write the observed graph, plan: the snapshot fields that change."""
        try:
            directory = self._load_directory(self.agents_file)
            hosts = {b.host for b in desired.brokers} | set(directory.hosts)
            observed = self._observe_fn(directory, hosts)
        except PlantKGError as exc:
            return {"error": f"the agents cannot be asked: {exc}", "observed": None, "plan": None,
                    "fingerprint": None, "observed_at": time.time()}
        with self.store_lock.writing():
            write_observed(plant, observed)
            context = write_context(plant, context_sources(plant, agent_tokens(desired.brokers, directory.token_for)))
        plan = make_plan(desired, observed)
        return {"observed": observed, "plan": plan, "fingerprint": plan_fingerprint(plan), "error": None,
                "observed_at": time.time(), "context": context, "agent_urls": tuple((h, directory.url_for(h)) for h in sorted(hosts))}

    def tick(self) -> None:
        """One look of the watcher: re-read changed files, or re-observe when it is time."""
        if _signature(self.files) != self._signature:
            self.reload()
            if self._loop is not None:
                self._loop.poke()
            return
        last = self._snap.observed_at
        if last is None or time.time() - last >= self.observe_interval:
            self.refresh()

    # ------------------------------------------------------------------------------ applying

    def broker_verb(self, broker_id: str, verb: str) -> ObservedBroker:
        """The operator's ``stop``/``start``/``restart`` of a broker an agent reports (its agent
        does it; data and config kept, see docs/operating.md); then the agents are asked again.
        Raises :class:`ApplyRefused` for a broker no agent reports, DispatchError if the agent
        refuses or does not answer."""
        if verb not in ("stop", "start", "restart"):
            raise ApplyRefused(f"{verb!r} is not one of stop, start, restart")
        snap = self._snap
        have = snap.observed.broker(broker_id) if snap.observed is not None else None
        if have is None:
            raise ApplyRefused(f"no agent reports broker {broker_id!r}",
                               hint="refresh, and pick a broker of the brokers table")
        directory = self._load_directory(self.agents_file)
        with self._apply_lock:  # not in the middle of an apply (or of the loop's)
            after = directory.client_for(have.spec.host).broker_verb(broker_id, verb)
        self.refresh()
        return after

    def start_apply(self, fingerprint: str | None, *, by: str = "") -> ApplyJob:
        """Start applying the current plan if its fingerprint is ``fingerprint``."""
        with self._publish_lock:
            snap = self._snap
            if snap.apply.state == "running":
                raise ApplyRefused("an apply is already running", hint="wait for it to finish")
            if snap.plan is None or snap.desired is None or fingerprint != snap.fingerprint:
                raise ApplyRefused("the plan changed since it was shown (or there is none)",
                                   hint="look at the current plan, then apply it")
            if not snap.plan.applicable:
                raise ApplyRefused("this plan cannot be applied (refusals or unreachable agents)",
                                   hint="change the plant or start the agents, then plan again")
            job = ApplyJob("running", fingerprint, time.time(), by=by)
            self._snap = replace(snap, version=snap.version + 1, apply=job)
        thread = threading.Thread(target=self._run_apply, args=(snap.plan, snap.desired),
                                  name="plantkg-web-apply", daemon=True)
        self._threads.append(thread)
        thread.start()
        return job

    def _run_apply(self, plan: Plan, desired: DesiredState) -> None:
        def on_event(event: ApplyEvent) -> None:
            line = f"{event.kind.value} {event.address}" + (f": {event.message}" if event.message else "")
            job = self._snap.apply
            self._publish(apply=replace(job, progress=(job.progress + (line,))[-_MAX_PROGRESS:]))

        try:
            directory = self._load_directory(self.agents_file)
            with self._apply_lock:
                result = apply(plan, desired, directory, on_event=on_event)
            summary = tuple(click.unstyle(line) for line in result_lines(result))
            state = "done" if result.ok else "failed"
        except PlantKGError as exc:
            summary, state = (f"Apply failed: {exc}",), "failed"
        except Exception as exc:  # noqa: BLE001 - an apply must never stay "running" forever
            summary, state = (f"Apply failed with an internal error: {exc!r}",), "failed"
        # Ask the agents again first and publish their answer with the job's end in one snapshot:
        # whoever sees "done" sees the brokers the apply made (not the status from before it).
        with self._work_lock:
            snap = self._snap
            seen = self._observe(snap.plant, snap.desired) if snap.desired is not None and snap.plant is not None else {}
            self._publish(apply=replace(snap.apply, state=state, finished_at=time.time(), summary=summary), **seen)

    # ------------------------------------------------------------------------------ watcher

    def start(self) -> None:
        """Load once now, then watch in a thread until :meth:`close`; with auto-apply, start the
        reconcile loop too."""
        self.reload()
        thread = threading.Thread(target=self._watch, name="plantkg-web-watch", daemon=True)
        self._threads.append(thread)
        thread.start()
        if self.auto_apply:
            self._start_loop()

    def _start_loop(self) -> None:
        try:
            directory = self._load_directory(self.agents_file)
        except PlantKGError as exc:
            self._publish(error=f"auto-apply cannot start: {exc}")
            return
        self._loop = ReconcileLoop(self.paths, directory, owner=self.owner,
                                   interval=self.observe_interval, apply_lock=self._apply_lock,
                                   on_run=self._loop_ran).start()

    def _loop_ran(self, run: LoopRun) -> None:
        self._publish(reconcile=run)
        if run.applied:
            self.refresh()

    def _watch(self) -> None:
        while not self._stop.wait(self.poll_interval):
            try:
                self.tick()
            except Exception as exc:  # noqa: BLE001 - keep watching; the error is shown on the page
                self._publish(error=f"internal error while refreshing: {exc!r}")

    def close(self, timeout: float = 60.0) -> None:
        """Stop the watcher and the reconcile loop, and wait for a running apply to finish."""
        self._stop.set()
        if self._loop is not None:
            self._loop.stop(timeout)
        for thread in self._threads:
            thread.join(timeout)

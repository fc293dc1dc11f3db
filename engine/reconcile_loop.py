"""Continuous reconciliation: keep applying what the plant's files require, and put back drift.

Plug and play (a vehicle joins, the fleet manager writes it into the graph as a file) needs more
than ``plantkg apply`` run by a person: :class:`ReconcileLoop` watches plant files *and folders*
(every ``*.ttl`` inside, recursively, hidden files skipped) and

- runs load → validate → reason → derive → observe → plan → apply when the files' *content*
  changed (a SHA-256 over names and bytes; a touched file with the same bytes is no change, a
  rewritten one with a kept mtime is), or when it is :meth:`~ReconcileLoop.poke`\\ d (the fleet
  manager after writing a discovered vehicle). Pokes within ``debounce`` seconds make one run;
- every ``interval`` seconds observes the agents again and applies the plan of the last valid
  plant, so a broker or bridge deleted or broken behind plantkg's back comes back;
- never runs two applies at once (one run at a time, each holding ``apply_lock`` from its
  observation to its apply's check; share the lock with whoever else applies, e.g. the
  dashboard's Apply button);
- never applies an invalid plant: the last valid one stays in force (what runs keeps running) and
  :attr:`~ReconcileLoop.status` says why the files are not applied;
- touches only its own plant's things: every plan and every agent call names the owner (the
  ``owner`` given, else the plant's own, engine.owner), and a plant without an owner is refused;
- reports each run as a frozen :class:`LoopRun` (time, trigger, plan summary, error).

Time is the caller's: tests give a short ``interval``; nothing here sleeps without a stop event.
"""

from __future__ import annotations

import hashlib
import logging
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine.agents_config import AgentDirectory
from engine.apply import ApplyResult, apply
from engine.model import DesiredState, ObservedState, Plan
from engine.observed import observe
from engine.incremental.warm import WarmPipeline
from engine.pipeline import Pipeline
from engine.plan import plan as make_plan
from engine.render.plan import summary_counts
from kg.errors import PlantKGError

log = logging.getLogger(__name__)

PLANT_SUFFIX = ".ttl"


class Trigger:
    """Why a run happened (plain strings: they are shown and logged as they are)."""

    START = "start"
    CHANGE = "change"
    POKE = "poke"
    DRIFT = "drift"
    MANUAL = "manual"


@dataclass(frozen=True)
class LoopRun:
    """One run of the loop. ``summary`` counts the plan's changes (create/update/replace/delete);
    ``applied``: changes were dispatched; ``converged``: the plant runs as planned afterwards;
    ``error``: why nothing (or not everything) was applied — None when all is well."""

    trigger: str
    started_at: float
    finished_at: float
    digest: str | None = None
    summary: Mapping[str, int] = field(default_factory=dict)
    applied: bool = False
    converged: bool = False
    foreign: int = 0
    error: str | None = None


@dataclass(frozen=True)
class LoopStatus:
    """What the loop enforces and how its last run went. ``invalid``: why the current files are
    not applied (None: they are what is enforced); ``digest``: the content of the plant in force."""

    owner: str | None
    files: tuple[str, ...]
    digest: str | None
    runs: int
    last: LoopRun | None
    invalid: str | None = None
    running: bool = False


def plant_files(paths: Iterable[Path | str]) -> list[Path]:
    """The plant files of ``paths``: files as given, folders as every ``*.ttl`` inside (sorted,
    recursively, names starting with ``.`` skipped: a writer's temporary files)."""
    out: list[Path] = []
    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            out.extend(sorted(p for p in path.rglob(f"*{PLANT_SUFFIX}")
                              if p.is_file() and not any(part.startswith(".")
                                                         for part in p.relative_to(path).parts)))
        else:
            out.append(path)
    return out


def content_digest(files: Iterable[Path]) -> str:
    """SHA-256 over each file's name and bytes (a missing file counts as its own content)."""
    h = hashlib.sha256()
    for path in files:
        h.update(str(path).encode() + b"\0")
        try:
            h.update(path.read_bytes())
        except OSError as exc:
            h.update(f"unreadable: {exc.strerror}".encode())
        h.update(b"\0")
    return h.hexdigest()


def _signature(paths: Iterable[Path | str]) -> tuple[Any, ...]:
    """Cheap change detector between two content hashes: names, sizes and mtimes."""
    out: list[Any] = []
    for path in plant_files(paths):
        try:
            st = path.stat()
            out.append((str(path), st.st_size, st.st_mtime_ns))
        except OSError:
            out.append((str(path), None))
    return tuple(out)


class ReconcileLoop:
    """See the module docstring. ``start()`` runs it in a thread; ``run_once()`` runs it now."""

    def __init__(
        self,
        paths: Iterable[Path | str],
        directory: AgentDirectory,
        *,
        owner: str | None = None,
        interval: float = 5.0,
        debounce: float = 0.1,
        poll: float = 0.25,
        prune: bool = False,
        apply_lock: threading.Lock | None = None,
        on_run: Callable[[LoopRun], None] | None = None,
        pipeline: Callable[..., Pipeline] | None = None,
        apply_fn: Callable[..., ApplyResult] = apply,
        observe_fn: Callable[[AgentDirectory, Iterable[str]], ObservedState] = observe,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.paths = tuple(str(p) for p in paths)
        if not self.paths:
            raise ValueError("a reconcile loop needs at least one plant file or folder")
        self.directory = directory
        self.owner = owner
        self.interval = interval
        self.debounce = debounce
        self.poll = poll
        self.prune = prune
        self.apply_lock = apply_lock or threading.Lock()
        self._on_run = on_run
        # the loop's own warm pipeline (engine.incremental.warm): a run re-plans from the edit
        self._pipeline = pipeline if pipeline is not None else WarmPipeline()
        self._apply, self._observe = apply_fn, observe_fn
        self._clock = clock
        self._run_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._poked_at: float | None = None
        self._thread: threading.Thread | None = None
        # the plant in force (last valid one) and what was last seen
        self._desired: DesiredState | None = None
        self._digest: str | None = None
        self._seen_digest: str | None = None
        self._signature: tuple[Any, ...] | None = None
        self._invalid: str | None = None
        self._runs = 0
        self._last: LoopRun | None = None
        self._next_observe = 0.0

    # ------------------------------------------------------------------------------ public

    @property
    def status(self) -> LoopStatus:
        with self._state_lock:
            return LoopStatus(
                owner=self._desired.owner if self._desired is not None else self.owner,
                files=tuple(str(p) for p in plant_files(self.paths)), digest=self._digest,
                runs=self._runs, last=self._last, invalid=self._invalid,
                running=self._thread is not None and self._thread.is_alive())

    @property
    def last_run(self) -> LoopRun | None:
        with self._state_lock:
            return self._last

    @property
    def desired(self) -> DesiredState | None:
        """The plant in force (the last valid one), or None before the first."""
        with self._state_lock:
            return self._desired

    def poke(self) -> None:
        """Re-read the plant soon (after ``debounce`` seconds without another poke)."""
        with self._state_lock:
            self._poked_at = time.monotonic()
        self._wake.set()

    def start(self) -> ReconcileLoop:
        """Run once now (in the thread), then watch until :meth:`stop`."""
        if self._thread is not None:
            raise RuntimeError("the reconcile loop runs already")
        self._thread = threading.Thread(target=self._main, name="plantkg-reconcile", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 60.0) -> None:
        """Stop watching; a run in progress finishes first (up to ``timeout`` seconds)."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def run_once(self, trigger: str = Trigger.MANUAL) -> LoopRun:
        """Re-read the files if their content changed, observe, plan, apply; one at a time."""
        with self._run_lock:
            started = self._clock()
            try:
                with self.apply_lock:  # observe, plan and apply with no other apply in between
                    run = self._run(trigger, started)
            except Exception as exc:  # noqa: BLE001 - the loop must outlive a bug; it is reported
                log.exception("reconcile run failed")
                run = LoopRun(trigger, started, self._clock(), self._digest,
                              error=f"internal error: {type(exc).__name__}: {exc}")
            with self._state_lock:
                self._runs += 1
                self._last = run
                self._next_observe = time.monotonic() + self.interval
            if run.error:
                log.warning("reconcile (%s): %s", trigger, run.error)
            if self._on_run is not None:
                self._on_run(run)
            return run

    # ------------------------------------------------------------------------------ a run

    def _run(self, trigger: str, started: float) -> LoopRun:
        files = plant_files(self.paths)
        digest = content_digest(files)
        observed: ObservedState | None = None
        plan: Plan | None = None
        if digest != self._seen_digest:
            self._seen_digest = digest
            result, problem = self._read(files)
            if problem is not None:
                with self._state_lock:
                    self._invalid = problem
            else:
                assert result is not None and result.desired is not None
                with self._state_lock:
                    self._desired, self._digest, self._invalid = result.desired, digest, None
                observed, plan = result.observed, result.plan
        desired = self.desired
        if desired is None:
            return LoopRun(trigger, started, self._clock(), None,
                           error=self._invalid or "no valid plant yet")
        if plan is None:
            observed = self._observe(self.directory, _hosts(desired, self.directory))
            plan = make_plan(desired, observed, prune=self.prune)
        return self._dispatch(trigger, started, desired, plan)

    def _read(self, files: list[Path]) -> tuple[Pipeline | None, str | None]:
        """The pipeline's result for ``files``, or why they cannot be applied."""
        try:
            result = self._pipeline(files, self.directory, owner=self.owner, prune=self.prune)
        except PlantKGError as exc:
            return None, f"the plant files cannot be used: {exc}"
        if not result.valid:
            shown = [f"{r.focus}" + (f" {r.path}" if r.path else "") + f": {r.message}"
                     for r in result.report.results if r.severity.endswith("Violation")][:5]
            return None, ("the plant has violations; the last valid plant stays in force: "
                          + "; ".join(shown))
        assert result.desired is not None
        if result.desired.owner is None:
            return None, ("the plant has no owner, and an automatic loop touches only its own "
                          'plant\'s things: give its owl:Ontology header an IRI or pk:plantName '
                          '"name", or give the loop an owner')
        if result.plan is None:
            return None, "the agents were not asked (no agents directory)"
        return result, None

    def _dispatch(self, trigger: str, started: float, desired: DesiredState, plan: Plan) -> LoopRun:
        summary, foreign = summary_counts(plan), len(plan.foreign)
        done = dict(trigger=trigger, started_at=started, digest=self._digest, summary=summary,
                    foreign=foreign)
        if not plan.applicable:
            why = [f"{r.address}: {r.reason}" for r in plan.refusals]
            why += [f"the agent of {h} did not answer" for h in plan.unreachable]
            return LoopRun(**done, finished_at=self._clock(),
                           error="the plan cannot be applied: " + "; ".join(why))
        if plan.empty:
            return LoopRun(**done, finished_at=self._clock(), converged=True)
        result = self._apply(plan, desired, self.directory, prune=self.prune)
        problems = [f"{o.change.address}: {o.error}" for o in result.failed]
        problems += [f"{u.address}: {u.detail}" for u in result.unexpected]
        return LoopRun(**done, finished_at=self._clock(), applied=True, converged=result.ok,
                       error="; ".join(problems) or None)

    # ------------------------------------------------------------------------------ watching

    def _main(self) -> None:
        self.run_once(Trigger.START)
        self._signature = _signature(self.paths)
        while not self._stop.is_set():
            trigger = self._next_trigger()
            if trigger is not None and not self._stop.is_set():
                self.run_once(trigger)

    def _next_trigger(self) -> str | None:
        """Wait for a poke, a change of the files or the next observation; None: nothing yet."""
        with self._state_lock:
            wait = min(self.poll, max(0.0, self._next_observe - time.monotonic()))
        self._wake.wait(wait)
        self._wake.clear()
        if self._stop.is_set():
            return None
        if self._poked():
            return Trigger.POKE
        signature = _signature(self.paths)
        if signature != self._signature:
            self._signature = signature
            if content_digest(plant_files(self.paths)) != self._seen_digest:
                return Trigger.CHANGE
        with self._state_lock:
            due = time.monotonic() >= self._next_observe
        return Trigger.DRIFT if due else None

    def _poked(self) -> bool:
        """True once the pokes have settled: ``debounce`` s without a new one (at most 1 s)."""
        with self._state_lock:
            first = self._poked_at
        if first is None:
            return False
        began = time.monotonic()
        while not self._stop.is_set():
            with self._state_lock:
                last = self._poked_at
            assert last is not None
            quiet = last + self.debounce - time.monotonic()
            if quiet <= 0 or time.monotonic() - began >= max(1.0, self.debounce):
                break
            self._stop.wait(quiet)
        with self._state_lock:
            self._poked_at = None
        self._signature = _signature(self.paths)
        return True


def _hosts(desired: DesiredState, directory: AgentDirectory) -> set[str]:
    return {b.host for b in desired.brokers} | set(directory.hosts)

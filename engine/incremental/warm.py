"""A warm pipeline for long-running processes: ``run_pipeline``'s answer, from what changed.

``plantkg apply`` runs once and starts cold; a process that runs for days and re-plans the same
plant again and again (the fleet manager after each vehicle that joins, the reconcile loop of
``plantkg serve``) should not load, validate, reason and derive the whole plant each time.
:class:`WarmPipeline` is a drop-in for :func:`engine.pipeline.run_pipeline` that keeps one
:class:`~engine.incremental.replan.ReplanSession` per process: each call hands it the plant's files
as they are now (a folder's new vehicle file is an added file), it re-validates the focus nodes the
edit can reach, re-reasons from the changed facts and derives again the brokers they touch, then
observes the agents and plans as ``run_pipeline`` does. ``tests/unit/test_incremental.py`` holds
the session to the full run, edit by edit and file by file.

What it does not keep warm, it does cold, exactly as ``run_pipeline``: the first call, the call
after one that raised (the session is then spent), a plant whose owner the caller names because
the plant's own declaration is ambiguous, and a destroy plan. It never writes the observed state
into the session's store (``run_pipeline`` does, for the SPARQL endpoint): the store stays the
plant's. Calls are serialised (one session, one lock).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

from engine.agents_config import AgentDirectory
from engine.incremental.replan import ReplanSession
from engine.observed import observe as observe_agents
from engine.owner import OwnerError, check_owner_name
from engine.pipeline import Pipeline, run_pipeline
from engine.plan import plan as make_plan


class WarmPipeline:
    """See the module docstring; ``stats`` counts the calls done warm and cold."""

    def __init__(self) -> None:
        self._session: ReplanSession | None = None
        self._lock = threading.Lock()
        self.stats = {"warm": 0, "cold": 0}

    def __call__(self, files: Iterable[Path | str], directory: AgentDirectory | None = None, *,
                 observe: bool = True, owner: str | None = None, prune: bool = False,
                 destroy: bool = False) -> Pipeline:
        files = [Path(f) for f in files]
        if destroy:  # rare, and it must see what runs exactly as a cold run would
            return run_pipeline(files, directory, observe=observe, owner=owner, prune=prune, destroy=True)
        with self._lock:
            try:
                result = self._refresh(files)
            except OwnerError:
                if owner is None:
                    raise
                self.stats["cold"] += 1  # the caller names the owner the plant cannot
                return run_pipeline(files, directory, observe=observe, owner=owner, prune=prune)
        desired = result.desired
        if desired is not None and owner is not None:
            desired = replace(desired, owner=check_owner_name(owner))
        out = Pipeline(result.plant, result.report, desired=desired, inferences=result.inferences,
                       timings=dict(result.timings))
        if not out.valid or desired is None or not observe or directory is None:
            return out
        start = time.perf_counter()
        out.observed = observe_agents(directory, out.hosts | set(directory.hosts))
        out.timings["observe"] = time.perf_counter() - start
        start = time.perf_counter()
        out.plan = make_plan(desired, out.observed, prune=prune)
        out.timings["plan"] = time.perf_counter() - start
        return out

    def _refresh(self, files: list[Path]) -> Pipeline:
        """The session's state for ``files``: started on the first call, brought up to date after."""
        session = self._session
        try:
            if session is None:
                session = ReplanSession(files)
                self.stats["cold"] += 1
            else:
                session.refresh(files=files)
                self.stats["warm"] += 1
        except BaseException:
            self._session = None  # spent: the next call starts afresh
            raise
        self._session = session
        return session.result

"""The stages from plant files to a plan, as one function the CLI and the dashboard share.

load → validate → reason → derive → observe → (observed graph) → plan. Each stage is the plain
function of its module; this one only strings them together, times them, and stops early:
an invalid plant stops after ``validate`` (``Pipeline.valid`` is False, nothing else is run and
no agent is asked), ``observe=False`` stops after ``derive`` (no network).

The desired state carries the plant's owner (engine.owner: its ``pk:plantName``, else its ontology
IRI, unless the caller names one), so the plan touches only what the plant owns.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from engine.agents_config import AgentDirectory
from engine.derive import derive
from engine.incremental.desired_cache import DesiredCache
from engine.model import DesiredState, ObservedState, Plan
from engine.observed import observe as observe_agents
from engine.observed import write_observed
from engine.owner import OwnerError, check_owner_name, plant_owner
from engine.plan import destroy_plan, plan as make_plan
from engine.reasoning.reason import reason
from kg.load import PlantGraph, load_plant
from kg.validate import ValidationReport, validate


@dataclass
class Pipeline:
    """What the stages produced; later fields are None when an earlier stage stopped the run."""

    plant: PlantGraph | None  # None when the desired state came from the cache
    report: ValidationReport
    desired: DesiredState | None = None
    observed: ObservedState | None = None
    plan: Plan | None = None
    inferences: Any = None
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def valid(self) -> bool:
        return self.report.conforms

    @property
    def hosts(self) -> set[str]:
        return {b.host for b in self.desired.brokers} if self.desired else set()


@contextmanager
def _timed(timings: dict[str, float], stage: str) -> Iterator[None]:
    start = time.perf_counter()
    try:
        yield
    finally:
        timings[stage] = time.perf_counter() - start


def run_pipeline(
    files: Iterable[Path | str],
    directory: AgentDirectory | None = None,
    *,
    observe: bool = True,
    destroy: bool = False,
    reason_engine: str = "auto",
    validate_engine: str = "auto",
    cache: DesiredCache | None = None,
    owner: str | None = None,
    prune: bool = False,
) -> Pipeline:
    """Run the stages on plant ``files``; ``destroy`` plans the removal of what the plant runs.

    With ``cache``, a valid plant whose files did not change since it was last derived skips
    load/validate/reason/derive (``Pipeline.plant`` is then None and no observed graph is written).
    ``owner``: the plant's owner (default: the plant's own, engine.owner); ``prune``: the plan
    also deletes what nobody owns.
    """
    files = list(files)
    timings: dict[str, float] = {}
    key, hit = None, None
    if cache is not None:
        with _timed(timings, "cache"):
            try:
                key = cache.key(files, reason_engine=reason_engine, validate_engine=validate_engine)
            except OSError:  # a FILE that is missing, unreadable or a folder: no cache; load says which
                key = None
            hit = cache.get(key) if key is not None else None
    if hit is not None:
        result = Pipeline(None, hit[1], desired=hit[0], timings=timings)
        desired = hit[0]
    else:
        with _timed(timings, "load"):
            plant = load_plant(files)
        with _timed(timings, "validate"):
            report = validate(plant, engine=validate_engine)  # type: ignore[arg-type]
        result = Pipeline(plant, report, timings=timings)
        if not report.conforms:
            return result
        try:
            own: str | None = plant_owner(plant)
        except OwnerError:
            if owner is None:
                raise
            own, cache = None, None  # the caller names the owner; never cache an unknown one
        desired = replace(derive_desired(plant, result, reason_engine), owner=own)
        result.desired = desired
        if cache is not None and key is not None:
            cache.put(key, desired, report)
    if owner is not None:
        desired = replace(desired, owner=check_owner_name(owner))
        result.desired = desired
    if not observe or directory is None:
        return result
    with _timed(timings, "observe"):
        result.observed = observe_agents(directory, result.hosts | set(directory.hosts))
        if result.plant is not None:
            write_observed(result.plant, result.observed)
    with _timed(timings, "plan"):
        result.plan = (destroy_plan(desired, result.observed) if destroy
                       else make_plan(desired, result.observed, prune=prune))
    return result


def derive_desired(plant: PlantGraph, result: Pipeline, reason_engine: str = "auto") -> DesiredState:
    """Reason (inferred facts into the store), then derive the desired state."""
    with _timed(result.timings, "reason"):
        result.inferences = reason(plant, engine=reason_engine)  # type: ignore[arg-type]
    with _timed(result.timings, "derive"):
        return derive(plant)

"""One reconcile of the plant: pipeline (validate, reason, derive, observe, plan), then apply.

The one seam between the fleet manager and the engine's flow, kept in this small module so the
engine's own reconcile loop (engine/reconcile_loop.py) can take its place later. It returns a
:class:`StepResult` (frozen, plain data) and never raises for a plant that is merely invalid or
for agents that fail: those are results the manager logs and writes to its status.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from engine.agents_config import AgentDirectory
from engine.apply import RetryPolicy, apply
from engine.pipeline import Pipeline, run_pipeline
from kg.errors import PlantKGError

#: Short retries: the manager reconciles again on the next change or drift, it does not wait 5 min.
RETRIES = RetryPolicy(attempts=4, base=0.2, cap=2.0, deadline=20.0)


@dataclass(frozen=True)
class Violation:
    file: str | None
    focus: str
    message: str


@dataclass(frozen=True)
class StepResult:
    valid: bool
    violations: tuple[Violation, ...] = ()
    changes: int = 0            # changes the plan had
    ok: bool = False            # valid, applied, and the plan made again afterwards is empty
    problems: tuple[str, ...] = ()
    seconds: float = 0.0

    def summary(self) -> str:
        if not self.valid:
            return f"invalid plant ({len(self.violations)} violation(s)), nothing applied"
        if self.ok:
            return f"{self.changes} change(s) applied in {self.seconds:.2f} s" if self.changes else "no changes"
        return "not converged: " + "; ".join(self.problems[:5])


def check(files: Iterable[Path | str]) -> StepResult:
    """Validate (and reason, derive) only: no agent is asked."""
    began = time.perf_counter()
    try:
        result = run_pipeline(list(files), None, observe=False)
    except PlantKGError as exc:
        return StepResult(False, (Violation(None, "", str(exc)),), seconds=time.perf_counter() - began)
    return StepResult(result.valid, _violations(result), ok=result.valid, seconds=time.perf_counter() - began)


def reconcile(files: Iterable[Path | str], directory: AgentDirectory,
              pipeline: Callable[..., Pipeline] = run_pipeline) -> StepResult:
    """Make what runs match ``files``: validate, plan against the agents, apply, check.
    ``pipeline``: the manager's warm one (engine.incremental.warm), so a join re-plans from the
    vehicles' edit, not from scratch; ``run_pipeline`` (cold) by default."""
    began = time.perf_counter()
    try:
        result = pipeline(list(files), directory)
    except PlantKGError as exc:  # a file that does not parse: the plant cannot be read
        return StepResult(False, (Violation(None, "", str(exc)),), seconds=time.perf_counter() - began)
    if not result.valid:
        return StepResult(False, _violations(result), seconds=time.perf_counter() - began)
    plan, desired = result.plan, result.desired
    assert plan is not None and desired is not None
    if not plan.applicable:
        why = tuple(f"{r.address}: {r.reason}" for r in plan.refusals)
        why += tuple(f"the agent of {h} did not answer" for h in plan.unreachable)
        return StepResult(True, changes=len(plan.pending), problems=why, seconds=time.perf_counter() - began)
    if plan.empty:
        return StepResult(True, ok=True, seconds=time.perf_counter() - began)
    try:
        outcome = apply(plan, desired, directory, retries=RETRIES)
    except PlantKGError as exc:
        return StepResult(True, changes=len(plan.pending), problems=(str(exc),),
                          seconds=time.perf_counter() - began)
    problems = tuple(f"{o.change.address}: {o.error}" for o in outcome.failed)
    problems += tuple(f"{u.address}: {u.detail}" for u in outcome.unexpected)
    return StepResult(True, changes=len(plan.pending), ok=outcome.ok, problems=problems,
                      seconds=time.perf_counter() - began)


def _violations(result: object) -> tuple[Violation, ...]:
    report = getattr(result, "report")
    return tuple(Violation(v.file, v.focus, v.message) for v in report.violations)

"""What ``apply`` and ``destroy`` did, as JSON-able data for programs (``--format json``).

Typed values: numbers as numbers, booleans as booleans, ``null`` where there is nothing. The
document carries the plan that was applied (:func:`engine.render.plan.plan_dict`), one entry per
change with its outcome, what the agents did unexpectedly, and what the plan made afterwards
still lists (``stillToDo``): the same facts as the text summary, for a pipeline or a CI job.
"""

from __future__ import annotations

import json
from typing import Any

from engine.apply import ApplyResult
from engine.model import Plan
from engine.render.plan import plan_dict

FORMAT_VERSION = 1


def result_dict(result: ApplyResult, *, verb: str) -> dict[str, Any]:
    """``verb`` is ``apply`` or ``destroy``."""
    return {
        "format_version": FORMAT_VERSION,
        "verb": verb,
        "ok": result.ok,
        "converged": result.converged,
        "seconds": round(result.seconds, 3),
        "counts": {"changed": len(result.changed), "failed": len(result.failed),
                   "skipped": len(result.skipped)},
        "outcomes": [{"address": o.change.address, "action": o.change.action.value,
                      "status": o.status.value, "seconds": round(o.seconds, 3),
                      "attempts": o.attempts, "error": o.error} for o in result.outcomes],
        "unexpected": [{"address": u.address, "detail": u.detail} for u in result.unexpected],
        "stillToDo": ([c.address for c in result.after.pending]
                      if result.after is not None and not result.after.empty else []),
        "plan": plan_dict(result.plan),
    }


def nothing_done_dict(plan: Plan, *, verb: str) -> dict[str, Any]:
    """The document when there was nothing to change (an empty, applicable plan)."""
    return {"format_version": FORMAT_VERSION, "verb": verb, "ok": True, "converged": True,
            "seconds": 0.0, "counts": {"changed": 0, "failed": 0, "skipped": 0}, "outcomes": [],
            "unexpected": [], "stillToDo": [], "plan": plan_dict(plan)}


def to_json(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, ensure_ascii=False)


__all__ = ["nothing_done_dict", "result_dict", "to_json"]

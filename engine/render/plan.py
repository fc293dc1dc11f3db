"""A plan for people (``render_plan``) and for programs (``plan_dict`` / ``plan_json``).

The text follows Terraform's: one block per change with a sign (``+`` create, ``~`` update,
``-/+`` replace, ``-`` delete) and the fields that differ as ``before → after``; refusals and hosts
whose agent did not answer after; a summary line last. No-op changes are not shown.
"""

from __future__ import annotations

import json
from collections import Counter
from typing import Any, Mapping

import click

from engine.model import Action, Change, Plan, to_dict
from engine.plan import REPLACE_FIELDS

SIGNS: Mapping[Action, str] = {
    Action.CREATE: "+",
    Action.UPDATE: "~",
    Action.REPLACE: "-/+",
    Action.DELETE: "-",
    Action.NOOP: " ",
}
COLORS: Mapping[Action, str] = {
    Action.CREATE: "green",
    Action.UPDATE: "yellow",
    Action.REPLACE: "magenta",
    Action.DELETE: "red",
    Action.NOOP: "white",
}
NO_CHANGES = "No changes. The plant matches its description."
#: Fields not worth a line of their own in a diff (they name the object already in its address).
_QUIET = frozenset({"id", "broker_id"})


def summary_counts(plan: Plan) -> dict[str, int]:
    """How many changes of each kind the plan holds (Terraform's summary)."""
    counts = Counter(c.action for c in plan.pending)
    return {
        "create": counts[Action.CREATE],
        "update": counts[Action.UPDATE],
        "replace": counts[Action.REPLACE],
        "delete": counts[Action.DELETE],
    }


def summary_line(plan: Plan) -> str:
    """``Plan: N to create, ...`` or the no-changes sentence."""
    if plan.empty and plan.applicable:
        return NO_CHANGES
    n = summary_counts(plan)
    return (f"Plan: {n['create']} to create, {n['update']} to update, {n['replace']} to replace, "
            f"{n['delete']} to destroy.")


def render_plan(plan: Plan, *, color: bool = False) -> str:
    """The plan as text; ``color`` adds ANSI colours (for a terminal)."""
    def paint(text: str, action: Action, bold: bool = False) -> str:
        return click.style(text, fg=COLORS[action], bold=bold) if color else text

    lines: list[str] = []
    if plan.pending:
        lines.append("plantkg will perform these actions:")
        lines.append("")
        for change in plan.pending:
            lines.extend(_change_block(change, paint))
    if plan.refusals:
        lines.append(paint("Refused (the brokers cannot make these changes):", Action.DELETE, True))
        for refusal in plan.refusals:
            lines.append(f"  ! {refusal.address}: {refusal.reason}")
        lines.append("")
    if plan.foreign:
        lines.append(paint("Foreign (other plants' or nobody's; left alone):", Action.NOOP, True))
        for item in plan.foreign:
            whose = f"owned by {item.owner}" if item.owner else "owned by nobody (--prune deletes it)"
            lines.append(f"  = {item.address}: {whose}")
        lines.append("")
    if plan.warnings:
        lines.append(click.style("Warnings:", fg="yellow", bold=True) if color else "Warnings:")
        for warning in plan.warnings:
            lines.append(f"  ! {warning}")
        lines.append("")
    if plan.unreachable:
        lines.append(paint("Agents that did not answer (what runs there is unknown):",
                           Action.DELETE, True))
        for host in plan.unreachable:
            lines.append(f"  ! {host}")
        lines.append("")
    lines.append(summary_line(plan))
    if not plan.applicable:
        lines.append("This plan cannot be applied: " + _why_not(plan))
    return "\n".join(lines)


def _why_not(plan: Plan) -> str:
    parts = []
    if plan.refusals:
        parts.append(f"{len(plan.refusals)} change(s) refused — change the plant so the broker can "
                     "make them")
    if plan.unreachable:
        parts.append(f"{len(plan.unreachable)} agent(s) unreachable — start `plantkg agent` there, "
                     "or fix the agents file")
    return "; ".join(parts) + "."


def _change_block(change: Change, paint: Any) -> list[str]:
    sign = SIGNS[change.action]
    verb = "must be replaced" if change.action is Action.REPLACE else f"will be {_past(change.action)}"
    head = paint(f"  {sign} {change.address}", change.action, True) + f" {verb}"
    lines = [head]
    if change.reason:
        lines.append(f"      # {change.reason}")
    for line in _field_lines(change):
        lines.append("      " + line)
    lines.append("")
    return lines


def _past(action: Action) -> str:
    return {Action.CREATE: "created", Action.UPDATE: "updated", Action.DELETE: "destroyed"}.get(
        action, action.value)


def _field_lines(change: Change) -> list[str]:
    before, after = change.before or {}, change.after or {}
    # An optional field the plant leaves unset (None) is not listed when created or destroyed.
    if change.action is Action.CREATE:
        return [f"+ {k} = {_show(v)}" for k, v in after.items() if k not in _QUIET and v is not None]
    if change.action is Action.DELETE:
        return [f"- {k} = {_show(v)}" for k, v in before.items() if k not in _QUIET and v is not None]
    out = []
    for key in after:
        old, new = before.get(key), after.get(key)
        if old != new:
            note = "   # forces replacement" if (change.action is Action.REPLACE
                                                 and change.address.startswith("broker.")
                                                 and key in REPLACE_FIELDS) else ""
            out.append(f"~ {key}: {_show(old)} → {_show(new)}{note}")
    return out


def _show(value: Any) -> str:
    return json.dumps(value, ensure_ascii=False) if value is not None else "(none)"


def plan_dict(plan: Plan) -> dict[str, Any]:
    """The plan as JSON-able data (no-ops included, so every object is accounted for)."""
    return {
        "format_version": 1,
        "applicable": plan.applicable,
        "empty": plan.empty,
        "summary": summary_counts(plan),
        "changes": [to_dict(c) for c in plan.changes],
        "refusals": [to_dict(r) for r in plan.refusals],
        "unreachable": list(plan.unreachable),
        "foreign": [to_dict(f) for f in plan.foreign],
        "warnings": list(plan.warnings),
    }


def plan_json(plan: Plan, *, indent: int | None = 2) -> str:
    """:func:`plan_dict` as a JSON document."""
    return json.dumps(plan_dict(plan), indent=indent, ensure_ascii=False)

"""A checked LoTLan program as text and JSON: for screens, logs and golden-file tests.

``expression_text`` writes an expression back in LoTLan syntax with every nested binary operation
in parentheses, so the grouping the parser chose is visible (``!a == b`` comes back as
``!a == b``, ``a or b and c`` as ``a or (b and c)``). ``program_json`` is a plain-data summary
(names, resolved steps and locations, conditions as text) in source order.
"""

from __future__ import annotations

from fleet.lotlan.model import (
    And,
    Compare,
    Const,
    Expr,
    Not,
    Or,
    Program,
    Ref,
    StepUse,
    TaskAttribute,
)


def expression_text(expr: Expr | None) -> str | None:
    if expr is None:
        return None
    if isinstance(expr, Ref):
        return expr.name
    if isinstance(expr, TaskAttribute):
        return f"{expr.task}.{expr.attribute}"
    if isinstance(expr, Const):
        if isinstance(expr.value, str):
            return f'"{expr.value}"'
        return str(expr.value)
    if isinstance(expr, Not):
        return "!" + _nested(expr.operand)
    op = {And: "and", Or: "or"}.get(type(expr)) or expr.op  # type: ignore[union-attr]
    return f"{_nested(expr.left)} {op} {_nested(expr.right)}"  # type: ignore[union-attr]


def _nested(expr: Expr) -> str:
    text = expression_text(expr) or ""
    return f"({text})" if isinstance(expr, (And, Or, Compare)) else text


def _use(use: StepUse) -> dict[str, object]:
    return {"step": use.step.name, "location": use.step.location.name,
            "arguments": dict(use.bound_parameters)}


def program_json(program: Program) -> dict[str, object]:
    """Plain data: every instance, step and task with its resolved references."""
    return {
        "locations": {loc.name: {"name": loc.physical_name, "type": loc.type} for loc in program.locations},
        "events": {e.name: {"name": e.physical_name, "type": e.type} for e in program.events},
        "times": {t.name: t.timing for t in program.times},
        "constraints": {c.name: c.type for c in program.constraints},
        "steps": {
            s.name: {"location": s.location.name, "triggered_by": expression_text(s.triggered_by),
                     "finished_by": expression_text(s.finished_by), "on_done": list(s.on_done),
                     "parameters": list(s.parameters)}
            for s in program.steps
        },
        "tasks": {
            t.name: {"from": _use(t.pickup), "to": _use(t.delivery),
                     "triggered_by": expression_text(t.triggered_by),
                     "finished_by": expression_text(t.finished_by), "on_done": list(t.on_done),
                     "repeat": t.repeat, "constraints": expression_text(t.constraints)}
            for t in program.tasks
        },
        "start_tasks": [t.name for t in program.start_tasks()],
    }

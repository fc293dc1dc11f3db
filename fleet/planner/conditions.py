"""TriggeredBy / FinishedBy evaluated: a LoTLan expression against the events fired and the tasks
done.

``events`` maps an Event's name to the value it was last fired with *inside the condition's
window* (fired after the task or leg began waiting, see fleet/planner/model.py): an Event not
fired there is unknown. A condition that is an Event alone holds when its value is true; a
comparison with an unknown side is false; ``task.IsDone`` holds when a task of that LoTLan name
finished in the same job. No expression is ever an error here: fleet.lotlan checked them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fleet.lotlan.model import And, Compare, Const, Expr, Not, Or, Ref, TaskAttribute

_OPS = {"==": lambda a, b: a == b, "!=": lambda a, b: a != b, "<": lambda a, b: a < b,
        "<=": lambda a, b: a <= b, ">": lambda a, b: a > b, ">=": lambda a, b: a >= b}


def _value(expr: Expr, events: Mapping[str, Any], done: frozenset[str]) -> Any:
    if isinstance(expr, Const):
        return expr.value
    if isinstance(expr, Ref):
        return events.get(expr.name)
    if isinstance(expr, TaskAttribute):
        return expr.task in done if expr.attribute == "IsDone" else None
    return holds(expr, events, done)


def holds(expr: Expr | None, events: Mapping[str, Any], done: frozenset[str] = frozenset()) -> bool:
    """True when ``expr`` holds (None, no condition, always holds)."""
    if expr is None:
        return True
    if isinstance(expr, Not):
        return not holds(expr.operand, events, done)
    if isinstance(expr, And):
        return holds(expr.left, events, done) and holds(expr.right, events, done)
    if isinstance(expr, Or):
        return holds(expr.left, events, done) or holds(expr.right, events, done)
    if isinstance(expr, Compare):
        left, right = _value(expr.left, events, done), _value(expr.right, events, done)
        if left is None or right is None:
            return False
        try:
            return bool(_OPS[expr.op](left, right))
        except TypeError:  # "abc" < 5: never true
            return False
    value = _value(expr, events, done)
    return value is True or (isinstance(value, str) and value.lower() == "true")

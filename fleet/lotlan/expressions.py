"""Check and resolve the expressions of TriggeredBy, FinishedBy and Constraints.

Names are resolved to what they refer to (an Event, a Time, a Constraint, or ``task.IsDone``)
and the result must be usable as a condition. The rules, and where they differ from the authors'
lotlan-scheduler (which checks only the top of an expression and accepts names it does not know
inside ``and``/``or`` in some places while refusing ``(a or b)`` in others):

- a condition (the whole expression, each side of ``and``/``or``, the operand of ``!``) is an
  Event of type Boolean, a Time, ``task.IsDone``, ``True``/``False`` (also ``true``/``false``, as
  the authors accept), a comparison, or a parenthesised condition;
- a comparison (``== != < <= > >=``) compares Events, Constraints, literals or conditions;
- in TriggeredBy/FinishedBy names are Events or Times; in Constraints names are Constraints;
- every name must be defined (an unknown name is an error, with the definition to add).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable
from dataclasses import replace

from fleet.lotlan.model import (
    And,
    Compare,
    Const,
    Constraint,
    Event,
    Expr,
    Not,
    Or,
    Pos,
    Ref,
    RefKind,
    TaskAttribute,
    Time,
)

TASK_ATTRIBUTES = ("IsDone",)


class ExprChecker:
    """Resolves names and checks conditions; errors go to ``error(at, message)``."""

    def __init__(self, error: Callable[[Pos, str], None], declared: dict, instances: dict,
                 tasks: set[str], broken: frozenset) -> None:
        self.error = error
        self.declared = declared      # name -> InstanceDecl (for the template of a wrong kind)
        self.instances = instances    # name -> Location/Event/Time/Constraint that checked out
        self.tasks = tasks
        self.broken = broken

    def condition(self, statement) -> Expr | None:
        """TriggeredBy/FinishedBy: a condition over Events, Times and tasks."""
        if statement is None:
            return None
        expr = self._resolve(statement.value, statement.keyword, constraints=False)
        if expr is not None:
            self._boolean(expr, statement.keyword)
        return expr

    def constraints(self, statement) -> Expr | None:
        """Constraints: a condition over Constraint instances (e.g. costs <= 100)."""
        if statement is None:
            return None
        expr = self._resolve(statement.value, statement.keyword, constraints=True)
        if expr is not None:
            self._boolean(expr, statement.keyword)
        return expr

    # ---- names -----------------------------------------------------------------------------------

    def _resolve(self, expr: Expr, keyword: str, constraints: bool) -> Expr | None:
        """The expression with names resolved; None if a name is unusable (reported)."""
        if isinstance(expr, Ref):
            return self._ref(expr, keyword, constraints)
        if isinstance(expr, TaskAttribute):
            return self._task_attribute(expr, keyword, constraints)
        if isinstance(expr, Not):
            operand = self._resolve(expr.operand, keyword, constraints)
            return None if operand is None else replace(expr, operand=operand)
        if isinstance(expr, (And, Or, Compare)):
            left = self._resolve(expr.left, keyword, constraints)
            right = self._resolve(expr.right, keyword, constraints)
            return None if left is None or right is None else replace(expr, left=left, right=right)
        return expr

    def _ref(self, ref: Ref, keyword: str, constraints: bool) -> Expr | None:
        if ref.name in ("true", "false"):
            return Const(ref.name == "true", ref.at)
        found = self.instances.get(ref.name)
        wanted = "a Constraint" if constraints else "an Event or a Time"
        if found is None:
            if ref.name in self.declared:
                return None  # the instance itself has errors, reported there
            if ("instance", ref.name) not in self.broken:
                define = "Constraint" if constraints else "Event"
                known = [n for n, v in self.instances.items() if isinstance(v, (Constraint,) if constraints
                                                                               else (Event, Time))]
                close = difflib.get_close_matches(ref.name, known, 1, 0.8)
                hint = f" (did you mean '{close[0]}'?)" if close else ""
                if ref.name in self.tasks and not constraints:
                    hint = f" (to wait for task {ref.name}, write {ref.name}.IsDone)"
                self.error(ref.at, f"unknown name '{ref.name}' in {keyword}: define {define} {ref.name} "
                           f"or correct the name{hint}; {keyword} names {wanted}")
            return None
        kind = {Event: RefKind.EVENT, Time: RefKind.TIME, Constraint: RefKind.CONSTRAINT}.get(type(found))
        allowed = (RefKind.CONSTRAINT,) if constraints else (RefKind.EVENT, RefKind.TIME)
        if kind not in allowed:
            template = type(found).__name__
            article = "an" if template[0] in "AEIOU" else "a"
            self.error(ref.at, f"'{ref.name}' is {article} {template}; {keyword} names {wanted}")
            return None
        return replace(ref, kind=kind)

    def _task_attribute(self, expr: TaskAttribute, keyword: str, constraints: bool) -> Expr | None:
        ok = True
        if constraints:
            self.error(expr.at, f"{keyword} cannot use a task's state ('{expr.task}.{expr.attribute}'): "
                       "name Constraints")
            return None
        if expr.task not in self.tasks and ("task", expr.task) not in self.broken:
            self.error(expr.at, f"unknown task '{expr.task}' in '{expr.task}.{expr.attribute}': define Task "
                       f"{expr.task} or correct the name")
            ok = False
        if expr.attribute not in TASK_ATTRIBUTES:
            self.error(expr.at, f"a task has no state '{expr.attribute}': write '{expr.task}.IsDone'")
            ok = False
        return expr if ok else None

    # ---- conditions ------------------------------------------------------------------------------

    def _boolean(self, expr: Expr, keyword: str) -> None:
        """Report the parts of a condition that are not conditions."""
        if isinstance(expr, (And, Or)):
            self._boolean(expr.left, keyword)
            self._boolean(expr.right, keyword)
        elif isinstance(expr, Not):
            self._boolean(expr.operand, keyword)
        elif isinstance(expr, Ref):
            found = self.instances[expr.name]
            if isinstance(found, Event) and found.type != "Boolean":
                self.error(expr.at, f"event '{expr.name}' has type {found.type or '(empty)'}, so it is no "
                           f"condition by itself: compare it, e.g. {expr.name} == 5, or give it "
                           'type = "Boolean"')
            elif isinstance(found, Constraint):
                self.error(expr.at, f"constraint '{expr.name}' is no condition by itself: compare it, "
                           f"e.g. {expr.name} <= 100")
        elif isinstance(expr, Const) and not isinstance(expr.value, bool):
            self.error(expr.at, f"{expr.value!r} is no condition: compare it with an event "
                       "(e.g. sensor == 5) or use True/False")

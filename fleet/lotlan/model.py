"""What a checked LoTLan program says, as frozen dataclasses: the task planner's input.

A :class:`Program` holds the instances of the four LoTLan primitives (``Location``, ``Event``,
``Time``, ``Constraint``), the ``TransportOrderStep`` blocks and the ``Task`` blocks, each in
source order and each with the position it was written at (``at``), so that later stages (the
task planner) can point back into the file. Steps and tasks are resolved: a step carries its
:class:`Location`, a task carries its pickup and delivery steps with their arguments. ``OnDone``
names tasks (the chains may be cyclic in the source, so they stay names; a checked program has
none that never ends). ``TriggeredBy``, ``FinishedBy`` and ``Constraints`` are expression trees
whose names are resolved to the kind of instance (or task) they refer to.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Union


@dataclass(frozen=True)
class Pos:
    """A position in a LoTLan file: 1-based line and column."""

    line: int
    column: int


# ---- expressions ---------------------------------------------------------------------------------

Literal = Union[bool, int, float, str]


class RefKind(enum.Enum):
    """What a name in an expression refers to."""

    EVENT = "Event"
    TIME = "Time"
    CONSTRAINT = "Constraint"
    UNRESOLVED = "unresolved"  # only in the parser's output; a checked program has none


@dataclass(frozen=True)
class Ref:
    """An instance named in an expression: ``buttonPressed``."""

    name: str
    at: Pos
    kind: RefKind = RefKind.UNRESOLVED


@dataclass(frozen=True)
class TaskAttribute:
    """A task's state named in an expression: ``helloTask.IsDone``."""

    task: str
    attribute: str
    at: Pos


@dataclass(frozen=True)
class Const:
    """A literal: ``True``, ``5``, ``42.5``, ``"abc"`` (quotes removed)."""

    value: Literal
    at: Pos


@dataclass(frozen=True)
class Not:
    operand: Expr
    at: Pos


@dataclass(frozen=True)
class And:
    left: Expr
    right: Expr
    at: Pos


@dataclass(frozen=True)
class Or:
    left: Expr
    right: Expr
    at: Pos


@dataclass(frozen=True)
class Compare:
    """``left op right`` with op one of ``< <= > >= == !=``."""

    op: str
    left: Expr
    right: Expr
    at: Pos


Expr = Union[Ref, TaskAttribute, Const, Not, And, Or, Compare]


def expression_names(expr: Expr) -> tuple[Ref | TaskAttribute, ...]:
    """Every name in an expression, left to right."""
    if isinstance(expr, (Ref, TaskAttribute)):
        return (expr,)
    if isinstance(expr, Not):
        return expression_names(expr.operand)
    if isinstance(expr, (And, Or, Compare)):
        return expression_names(expr.left) + expression_names(expr.right)
    return ()


# ---- instances of the primitives -----------------------------------------------------------------


@dataclass(frozen=True)
class Location:
    """``Location goodsPallet`` with ``name`` (the physical name) and ``type`` (the carrier)."""

    name: str
    physical_name: str
    type: str
    at: Pos


@dataclass(frozen=True)
class Event:
    """``Event buttonPressed`` with ``name`` (the physical signal) and ``type`` (Boolean, ...)."""

    name: str
    physical_name: str
    type: str
    at: Pos


@dataclass(frozen=True)
class Time:
    """``Time morning`` with ``timing`` in cron format."""

    name: str
    timing: str
    at: Pos


@dataclass(frozen=True)
class Constraint:
    """``Constraint costs`` with ``type``."""

    name: str
    type: str
    at: Pos


# ---- steps, tasks, program -----------------------------------------------------------------------


@dataclass(frozen=True)
class TransportOrderStep:
    """Where to go (``Location``) and what starts and ends the step there."""

    name: str
    location: Location
    triggered_by: Expr | None
    finished_by: Expr | None
    on_done: tuple[str, ...]
    parameters: tuple[str, ...]
    at: Pos


@dataclass(frozen=True)
class StepUse:
    """A step as a task uses it in ``From``/``To``, with the values of the step's Parameters."""

    step: TransportOrderStep
    arguments: tuple[Literal, ...]
    at: Pos

    @property
    def bound_parameters(self) -> tuple[tuple[str, Literal], ...]:
        return tuple(zip(self.step.parameters, self.arguments))


@dataclass(frozen=True)
class Task:
    """One transport (pickup then delivery) with its triggers, follow-ups and repetitions."""

    name: str
    pickup: StepUse
    delivery: StepUse
    triggered_by: Expr | None
    finished_by: Expr | None
    on_done: tuple[str, ...]
    repeat: int  # how many times the transport runs; 1 when the task has no Repeat
    constraints: Expr | None
    at: Pos


@dataclass(frozen=True)
class Program:
    """A checked LoTLan file; every tuple is in source order and names are unique per kind."""

    file: str
    locations: tuple[Location, ...]
    events: tuple[Event, ...]
    times: tuple[Time, ...]
    constraints: tuple[Constraint, ...]
    steps: tuple[TransportOrderStep, ...]
    tasks: tuple[Task, ...]

    def task(self, name: str) -> Task:
        """The task called ``name`` (KeyError when there is none)."""
        for task in self.tasks:
            if task.name == name:
                return task
        raise KeyError(name)

    def start_tasks(self) -> tuple[Task, ...]:
        """Tasks no OnDone (of a task or of a step) starts: the roots of the material flows."""
        followed = {n for t in self.tasks for n in t.on_done}
        followed |= {n for s in self.steps for n in s.on_done}
        return tuple(t for t in self.tasks if t.name not in followed)

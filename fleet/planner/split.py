"""The paper's Fig. 5 as a pure function: a list of motions and actions -> sub-tasks.

A sub-task is a run of motions followed by a run of actions. The paper: "in a task there cannot
be an action followed by a movement ... the task must be split in smaller sub-tasks"; and a wait
action ends a task. So :func:`split` starts a new sub-task at every motion that follows an action
and after every wait action. Items keep their order; nothing is dropped or reordered.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Union

WAIT = "wait"


@dataclass(frozen=True)
class Motion:
    """Drive to a station (``step``: the LoTLan TransportOrderStep that names it)."""

    station: str
    x: float
    y: float
    step: str = ""


@dataclass(frozen=True)
class Act:
    """Run an action where the vehicle stands (pick, drop, wait, ...)."""

    action: str
    step: str = ""


Item = Union[Motion, Act]


def split(items: tuple[Item, ...]) -> tuple[tuple[Item, ...], ...]:
    """Sub-tasks of motions-then-actions; a wait action ends its sub-task."""
    subtasks: list[tuple[Item, ...]] = []
    current: list[Item] = []
    acted = False
    for item in items:
        if isinstance(item, Motion) and acted:
            subtasks.append(tuple(current))
            current, acted = [], False
        current.append(item)
        if isinstance(item, Act):
            acted = True
            if item.action == WAIT:
                subtasks.append(tuple(current))
                current, acted = [], False
    if current:
        subtasks.append(tuple(current))
    return tuple(subtasks)


def well_formed(subtask: tuple[Item, ...]) -> bool:
    """True when no action is followed by a motion and a wait, if any, is the last item."""
    acted = False
    for i, item in enumerate(subtask):
        if isinstance(item, Motion) and acted:
            return False
        if isinstance(item, Act):
            acted = True
            if item.action == WAIT and i != len(subtask) - 1:
                return False
    return True

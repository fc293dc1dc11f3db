"""Task and sub-task states with every allowed transition, as data.

A task follows openTCS's transport-order lifecycle: ``RAW`` (created, its TriggeredBy not yet
true) -> ``ACTIVE`` (may be given to a vehicle) -> ``ASSIGNED`` (a vehicle chosen, nothing sent
yet) -> ``BEING_PROCESSED`` (an order was sent) -> ``FINISHED``; or ``FAILED`` (an action failed),
or ``WITHDRAWN`` (an operator took it back). A vehicle lost mid-task sends the task back to
``ACTIVE`` (re-assigned; finished sub-tasks stay finished).

A sub-task (:class:`LegState`, one leg of the transport: drive to a station, then act there):
``READY`` -> ``SENT`` (order sent) -> ``ACTED`` (its actions finished, waiting for FinishedBy) ->
``DONE``; ``SENT`` -> ``DONE`` when the step has no FinishedBy; ``SENT`` -> ``READY`` when its
vehicle is lost; ``SENT`` -> ``FAILED`` when an action failed.
"""

from __future__ import annotations

import enum

from fleet.planner.errors import TransitionError


class TaskState(enum.Enum):
    RAW = "RAW"
    ACTIVE = "ACTIVE"
    ASSIGNED = "ASSIGNED"
    BEING_PROCESSED = "BEING_PROCESSED"
    FINISHED = "FINISHED"
    FAILED = "FAILED"
    WITHDRAWN = "WITHDRAWN"

    @property
    def final(self) -> bool:
        return self in (TaskState.FINISHED, TaskState.FAILED, TaskState.WITHDRAWN)


class LegState(enum.Enum):
    READY = "READY"
    SENT = "SENT"
    ACTED = "ACTED"
    DONE = "DONE"
    FAILED = "FAILED"


T, L = TaskState, LegState

TASK_TRANSITIONS: dict[TaskState, frozenset[TaskState]] = {
    T.RAW: frozenset({T.ACTIVE, T.WITHDRAWN}),
    T.ACTIVE: frozenset({T.ASSIGNED, T.WITHDRAWN, T.FAILED}),
    T.ASSIGNED: frozenset({T.BEING_PROCESSED, T.ACTIVE, T.WITHDRAWN, T.FAILED, T.FINISHED}),
    T.BEING_PROCESSED: frozenset({T.FINISHED, T.FAILED, T.ACTIVE, T.WITHDRAWN}),
    T.FINISHED: frozenset(),
    T.FAILED: frozenset(),
    T.WITHDRAWN: frozenset(),
}

LEG_TRANSITIONS: dict[LegState, frozenset[LegState]] = {
    L.READY: frozenset({L.SENT}),
    L.SENT: frozenset({L.ACTED, L.DONE, L.FAILED, L.READY}),
    L.ACTED: frozenset({L.DONE}),
    L.DONE: frozenset(),
    L.FAILED: frozenset(),
}


def check_task(task_id: str, old: TaskState, new: TaskState) -> None:
    if new not in TASK_TRANSITIONS[old]:
        allowed = ", ".join(sorted(s.value for s in TASK_TRANSITIONS[old])) or "none (final)"
        raise TransitionError(f"task {task_id}: {old.value} -> {new.value} is not allowed "
                              f"(from {old.value}: {allowed})")


def check_leg(task_id: str, index: int, old: LegState, new: LegState) -> None:
    if new not in LEG_TRANSITIONS[old]:
        allowed = ", ".join(sorted(s.value for s in LEG_TRANSITIONS[old])) or "none (final)"
        raise TransitionError(f"task {task_id} sub-task {index}: {old.value} -> {new.value} is not allowed "
                              f"(from {old.value}: {allowed})")

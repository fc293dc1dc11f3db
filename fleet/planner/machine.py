"""The planner's transitions, pure: (task, what is known now) -> the task's next states.

:func:`advance` applies every transition that the conditions allow, one at a time, and returns
each intermediate task with a note (so the journal gets one record per transition) and the orders
to send. Every state change goes through :func:`fleet.planner.states.check_task` /
``check_leg``; a change the tables do not allow raises :class:`TransitionError` (a bug, never a
vehicle's or an operator's fault). The other entry points are the decisions taken outside:
:func:`assign` (the SPARQL query chose a vehicle), :func:`vehicle_lost`, :func:`withdraw`.

Tracking a sent leg (VDA 5050): the vehicle's state names the leg's ``orderId`` and every action
of the leg (action ids ``<orderId>-<station>-<i>``, fleet/manager/orders.py) is FINISHED -> the
leg's actions are done; any FAILED -> the leg and the task fail. Paper channels (fleet/planner/
paper.py): the leg is a task ``<orderId>``; its wait action finished (``finished_task_id``) -> done;
an item of the leg (fleet/planner/paperids.py) in the status's errors -> failed.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from fleet.lotlan.model import Expr
from fleet.planner import conditions, paperids
from fleet.planner.model import Leg, Task
from fleet.planner.states import LegState, TaskState, check_leg, check_task


@dataclass(frozen=True)
class Rules:
    """The LoTLan conditions of one task: its own, and each leg's (its step's) TriggeredBy/FinishedBy."""

    triggered_by: Expr | None = None
    finished_by: Expr | None = None
    legs: tuple[tuple[Expr | None, Expr | None], ...] = ()

    def leg(self, index: int) -> tuple[Expr | None, Expr | None]:
        return self.legs[index] if index < len(self.legs) else (None, None)


@dataclass(frozen=True)
class VehicleView:
    """What the planner knows of one vehicle now (its last VDA 5050 state and availability)."""

    key: str  # manufacturer/serial as in its topics
    online: bool
    order_id: str = ""
    last_node_id: str = ""
    actions: tuple[tuple[str, str], ...] = ()  # (actionId, actionStatus)
    paper: bool = False  # a paper-channel vehicle: order_id is a paper task id (fleet/planner/paperids.py)
    ended: bool = False  # paper channels: the task ``order_id`` has ended (its wait action finished)


@dataclass(frozen=True)
class Now:
    """What :func:`advance` may look at: events (a window function: name -> value of the events
    fired after a sequence number), the event counter, LoTLan tasks done per job, vehicles."""

    event_seq: int
    events_after: Callable[[int], Mapping[str, Any]]
    done: Mapping[str, frozenset[str]]
    vehicles: Mapping[str, VehicleView]
    at: str = ""


@dataclass(frozen=True)
class SendOrder:
    task_id: str
    leg: int
    vehicle: str
    order_id: str
    station: str
    x: float
    y: float
    actions: tuple[str, ...]


Step = tuple[Task, str]  # a task after one transition, and what happened


def set_task(task: Task, new: TaskState, reason: str, at: str, **changes: Any) -> Task:
    check_task(task.id, task.state, new)
    return replace(task, state=new, reason=reason, updated=at, **changes)


def set_leg(task: Task, leg: Leg, new: LegState, at: str, **changes: Any) -> Task:
    check_leg(task.id, leg.index, leg.state, new)
    return replace(task.with_leg(replace(leg, state=new, **changes)), updated=at)


def assign(task: Task, vehicle: str, reason: str, at: str = "") -> Task:
    return set_task(task, TaskState.ASSIGNED, reason, at, vehicle=vehicle)


def withdraw(task: Task, reason: str, at: str = "") -> Task:
    leg = task.current
    if leg is not None and leg.state is LegState.SENT:
        task = set_leg(task, leg, LegState.READY, at)
    return set_task(task, TaskState.WITHDRAWN, reason, at, vehicle="")


def vehicle_lost(task: Task, reason: str, at: str = "") -> Task:
    """The task's vehicle went away: the leg under way is to be done again by another vehicle;
    legs already DONE (or ACTED: their actions finished) stay so."""
    leg = task.current
    if leg is not None and leg.state is LegState.SENT:
        task = set_leg(task, leg, LegState.READY, at, order_id="")
    return set_task(task, TaskState.ACTIVE, reason, at, vehicle="")


def order_id(task: Task, leg: Leg) -> str:
    return f"{task.id}-{leg.index}-{leg.attempt + 1}"


def leg_progress(leg: Leg, view: VehicleView | None) -> str:
    """"finished", "failed" or "" (still under way / no news) for a SENT leg."""
    if view is None:
        return ""
    if view.paper:
        mine = paperids.item_ids(leg.order_id, len(leg.actions))  # the ids are the order's own
        if any(status == "FAILED" and item in mine for item, status in view.actions):
            return "failed"
        return "finished" if view.ended and view.order_id == paperids.task_uuid(leg.order_id) else ""
    if view.order_id != leg.order_id:
        return ""
    prefix = f"{leg.order_id}-{leg.station}-"
    mine = [status for action_id, status in view.actions if action_id.startswith(prefix)]
    if any(status == "FAILED" for status in mine):
        return "failed"
    if len(mine) == len(leg.actions) and mine and all(status == "FINISHED" for status in mine):
        return "finished"
    if not leg.actions and view.last_node_id == leg.station:
        return "finished"
    return ""


def _one(task: Task, rules: Rules, now: Now) -> tuple[Task, str, SendOrder | None] | None:
    """The next transition of ``task``, if any."""
    at = now.at
    done = now.done.get(task.job, frozenset())
    if task.state is TaskState.RAW:
        if conditions.holds(rules.triggered_by, now.events_after(task.armed), done):
            return set_task(task, TaskState.ACTIVE, "triggered", at), "RAW -> ACTIVE", None
        return None
    if task.state not in (TaskState.ASSIGNED, TaskState.BEING_PROCESSED):
        return None
    leg = task.current
    if leg is None:
        if conditions.holds(rules.finished_by, now.events_after(task.armed), done):
            return set_task(task, TaskState.FINISHED, "every sub-task done", at), "-> FINISHED", None
        return None
    trigger, finish = rules.leg(leg.index)
    if leg.state is LegState.READY:
        if not conditions.holds(trigger, now.events_after(leg.armed), done):
            return None
        oid = order_id(task, leg)
        moved = set_leg(task, leg, LegState.SENT, at, order_id=oid, attempt=leg.attempt + 1, vehicle=task.vehicle)
        if task.state is TaskState.ASSIGNED:
            moved = set_task(moved, TaskState.BEING_PROCESSED, f"order {oid} sent", at)
        send = SendOrder(task.id, leg.index, task.vehicle, oid, leg.station, leg.x, leg.y, leg.actions)
        return moved, f"sub-task {leg.index} READY -> SENT ({oid} to {task.vehicle})", send
    if leg.state is LegState.SENT:
        progress = leg_progress(leg, now.vehicles.get(task.vehicle))
        if progress == "failed":
            failed = set_leg(task, leg, LegState.FAILED, at)
            return (set_task(failed, TaskState.FAILED, f"an action of {leg.order_id} FAILED on {task.vehicle}", at),
                    f"sub-task {leg.index} SENT -> FAILED", None)
        if progress == "finished":
            if finish is None:
                return _leg_done(set_leg(task, leg, LegState.DONE, at), leg.index, now), \
                    f"sub-task {leg.index} SENT -> DONE", None
            return set_leg(task, leg, LegState.ACTED, at, armed=now.event_seq), \
                f"sub-task {leg.index} SENT -> ACTED (waiting for its FinishedBy)", None
        return None
    if leg.state is LegState.ACTED and conditions.holds(finish, now.events_after(leg.armed), done):
        return _leg_done(set_leg(task, leg, LegState.DONE, at), leg.index, now), \
            f"sub-task {leg.index} ACTED -> DONE", None
    return None


def _leg_done(task: Task, index: int, now: Now) -> Task:
    """Arm the next leg's window (its TriggeredBy counts events from now), or the task's FinishedBy."""
    nxt = task.current
    if nxt is None:
        return replace(task, armed=now.event_seq)
    return task.with_leg(replace(nxt, armed=now.event_seq))


def advance(task: Task, rules: Rules, now: Now, limit: int = 32) -> tuple[list[Step], list[SendOrder]]:
    """Every transition the conditions allow now, in order, and the orders they send."""
    steps: list[Step] = []
    sends: list[SendOrder] = []
    for _ in range(limit):
        nxt = _one(task, rules, now)
        if nxt is None:
            break
        task, note, send = nxt
        steps.append((task, note))
        if send is not None:
            sends.append(send)
    return steps, sends

"""A planned task and its sub-tasks (legs) as frozen dataclasses, with their JSON form (journal,
API, NGSI entity).

A :class:`Task` is one run of a LoTLan transport (``lotlan_task`` in job ``job``, run ``run`` of
its Repeat) for one vehicle at a time. Its :class:`Leg` s are the sub-tasks of Fig. 5 (fleet/
planner/split.py): drive to a station, then act there (``pick`` at the pickup, ``drop`` at the
delivery). ``armed`` is the event sequence number from which a condition counts events: an
operator's "Loaded" counts for the leg that waits for it only when pressed after the leg began
waiting. ``order_id`` is what was sent for the leg (deterministic: ``<task>-<leg>-<attempt>``, so
a resend after a restart is the same order and the vehicle ignores a duplicate). ``purpose`` is
``job`` for a LoTLan task, ``park`` / ``charge`` for a task the planner made itself (fleet/planner/
idle.py: back to the waiting area, to a charger); those have no LoTLan task (``lotlan_task`` "").
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from fleet.planner.states import LegState, TaskState


@dataclass(frozen=True)
class Leg:
    index: int
    step: str  # the LoTLan TransportOrderStep of its station
    station: str
    x: float
    y: float
    actions: tuple[str, ...]  # abstract: pick, drop, wait
    state: LegState = LegState.READY
    armed: int = 0
    attempt: int = 0
    order_id: str = ""
    vehicle: str = ""  # who sent / finished it

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "step": self.step, "station": self.station, "x": self.x, "y": self.y,
                "actions": list(self.actions), "state": self.state.value, "armed": self.armed,
                "attempt": self.attempt, "orderId": self.order_id, "vehicle": self.vehicle}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Leg:
        return cls(int(d["index"]), str(d["step"]), str(d["station"]), float(d["x"]), float(d["y"]),
                   tuple(d["actions"]), LegState(d["state"]), int(d["armed"]), int(d["attempt"]),
                   str(d["orderId"]), str(d["vehicle"]))


@dataclass(frozen=True)
class Task:
    id: str
    job: str
    lotlan_task: str
    run: int  # 1..repeat
    repeat: int
    legs: tuple[Leg, ...]
    state: TaskState = TaskState.RAW
    vehicle: str = ""  # "manufacturer/serial" while ASSIGNED or BEING_PROCESSED
    armed: int = 0  # events counted by the task's TriggeredBy / FinishedBy from here
    reason: str = ""  # why it is in its state (for people; never drives a decision)
    created: str = ""
    updated: str = ""
    purpose: str = "job"  # job | park | charge

    @property
    def service(self) -> bool:
        """A task the planner made itself (waiting area, charger): it never holds a vehicle from a job."""
        return self.purpose != "job"

    @property
    def current(self) -> Leg | None:
        """The first leg not yet DONE (None when all are)."""
        return next((leg for leg in self.legs if leg.state is not LegState.DONE), None)

    def with_leg(self, leg: Leg) -> Task:
        return replace(self, legs=tuple(leg if other.index == leg.index else other for other in self.legs))

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "job": self.job, "lotlanTask": self.lotlan_task, "run": self.run,
                "repeat": self.repeat, "state": self.state.value, "vehicle": self.vehicle, "armed": self.armed,
                "reason": self.reason, "created": self.created, "updated": self.updated,
                "purpose": self.purpose, "legs": [leg.to_json() for leg in self.legs]}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Task:
        return cls(str(d["id"]), str(d["job"]), str(d["lotlanTask"]), int(d["run"]), int(d["repeat"]),
                   tuple(Leg.from_json(leg) for leg in d["legs"]), TaskState(d["state"]), str(d["vehicle"]),
                   int(d["armed"]), str(d["reason"]), str(d.get("created", "")), str(d.get("updated", "")),
                   str(d.get("purpose", "job")))

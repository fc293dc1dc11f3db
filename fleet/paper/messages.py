"""Frozen messages of the paper's channels, with ``from_json`` (checked) and ``to_json`` (wire form).

``from_json`` runs the package's JSON schema (:func:`fleet.paper.schemas.check`) and then the
rules a schema cannot say, each naming the field path and value:

- motion item: the velocity and acceleration limits on x and theta are > 0 (a differential-drive
  vehicle could not drive or turn otherwise; y is ignored by it), the motion area has an area, and
  the point lies inside it (on its border counts as inside);
- the others: the schema is the whole rule.

``to_json`` writes the same field names (the paper's, snake_case), leaving unset optional fields
out. Headers are ``{"seq", "stamp", "frame_id"}`` as in ROS's std_msgs/Header, which the paper's
messages carry: :class:`HeaderCounter` gives each outgoing message one, counted per channel.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass, field
from typing import Any

from fleet.paper import geometry
from fleet.paper.errors import MessageError
from fleet.paper.schemas import Kind, check

Json = dict[str, Any]


def iso_stamp(epoch: float) -> str:
    whole = time.gmtime(epoch)
    return time.strftime("%Y-%m-%dT%H:%M:%S", whole) + f".{int(epoch % 1 * 1000):03d}Z"


@dataclass(frozen=True)
class Header:
    seq: int
    stamp: str
    frame_id: str

    @classmethod
    def from_json(cls, data: Json) -> Header:
        return cls(int(data["seq"]), data["stamp"], data["frame_id"])

    def to_json(self) -> Json:
        return {"seq": self.seq, "stamp": self.stamp, "frame_id": self.frame_id}


class HeaderCounter:
    """Headers for one sender: ``seq`` counted per channel from 0, the clock injected."""

    def __init__(self, frame_id: str, clock: Any = time.time) -> None:
        self.frame_id = frame_id
        self._clock = clock
        self._seq: dict[str, int] = {}

    def next(self, channel: str) -> Header:
        seq = self._seq.get(channel, 0)
        self._seq[channel] = seq + 1
        return Header(seq, iso_stamp(self._clock()), self.frame_id)


def _axes(values: Any) -> tuple[float, float, float]:
    return (float(values[0]), float(values[1]), float(values[2]))


@dataclass(frozen=True)
class MotionItem:
    header: Header
    point_id: str
    task_id: str
    motion_id: str
    point: tuple[float, ...]  # (x, y) or (x, y, theta)
    max_velocity: tuple[float, float, float]
    max_acceleration: tuple[float, float, float]
    motion_area: tuple[tuple[float, float], ...]
    sequence: int

    @property
    def theta(self) -> float | None:
        return self.point[2] if len(self.point) == 3 else None

    @classmethod
    def from_json(cls, data: Json) -> MotionItem:
        check(Kind.MOTION_ITEM, data)
        name = Kind.MOTION_ITEM.value
        for key in ("max_velocity", "max_acceleration"):
            for axis, label in ((0, "x"), (2, "theta")):
                if not data[key][axis] > 0:
                    raise MessageError(name, f"{key}/{axis}", data[key][axis],
                                       f"the {label} limit must be > 0: a differential-drive vehicle could not "
                                       f"{'drive' if axis == 0 else 'turn'} (y is the axis it ignores)")
        area = tuple((float(x), float(y)) for x, y in data["motion_area"])
        if geometry.area(area) <= 1e-9:
            raise MessageError(name, "motion_area", data["motion_area"], "the polygon has no area (its corners are collinear or repeated)")
        point = tuple(float(v) for v in data["point"])
        if not geometry.inside(point[0], point[1], area):
            raise MessageError(name, "point", data["point"], "the point lies outside motion_area")
        return cls(Header.from_json(data["header"]), data["point_id"], data["task_id"], data["motion_id"], point,
                   _axes(data["max_velocity"]), _axes(data["max_acceleration"]), area, int(data["sequence"]))

    def to_json(self) -> Json:
        return {"header": self.header.to_json(), "point_id": self.point_id, "task_id": self.task_id,
                "motion_id": self.motion_id, "point": list(self.point), "max_velocity": list(self.max_velocity),
                "max_acceleration": list(self.max_acceleration),
                "motion_area": [list(p) for p in self.motion_area], "sequence": self.sequence}


class ActionKind(str, enum.Enum):
    LOAD = "load"
    UNLOAD = "unload"
    IDLE = "idle"
    WAIT = "wait"
    CHARGE = "charge"


@dataclass(frozen=True)
class ActionItem:
    header: Header
    action_id: str
    task_id: str
    action: ActionKind
    sequence: int
    duration: float | None = None

    @classmethod
    def from_json(cls, data: Json) -> ActionItem:
        check(Kind.ACTION_ITEM, data)
        duration = data.get("duration")
        return cls(Header.from_json(data["header"]), data["action_id"], data["task_id"], ActionKind(data["action"]),
                   int(data["sequence"]), float(duration) if duration is not None else None)

    def to_json(self) -> Json:
        out: Json = {"header": self.header.to_json(), "action_id": self.action_id, "task_id": self.task_id,
                     "action": self.action.value, "sequence": self.sequence}
        if self.duration is not None:
            out["duration"] = self.duration
        return out


class MachineState(str, enum.Enum):
    IDLE = "IDLE"
    MOVING = "MOVING"
    ACTING = "ACTING"
    CHARGING = "CHARGING"
    ERROR = "ERROR"
    OFFLINE = "OFFLINE"


@dataclass(frozen=True)
class StatusError:
    channel: str  # motion_channel | action_channel | vehicle
    item_id: str
    reason: str

    def to_json(self) -> Json:
        return {"channel": self.channel, "item_id": self.item_id, "reason": self.reason}


@dataclass(frozen=True)
class Status:
    header: Header
    agv_id: str
    state: MachineState
    battery: float | None = None
    charging: bool | None = None
    task_id: str | None = None
    motion_id: str | None = None
    action_id: str | None = None
    last_finished_sequence: int | None = None
    finished_task_id: str | None = None
    refused: int | None = None
    errors: tuple[StatusError, ...] | None = None

    OPTIONAL = ("battery", "charging", "task_id", "motion_id", "action_id", "last_finished_sequence",
                "finished_task_id", "refused")

    @classmethod
    def from_json(cls, data: Json) -> Status:
        check(Kind.STATUS, data)
        errors = data.get("errors")
        return cls(Header.from_json(data["header"]), data["agv_id"], MachineState(data["state"]),
                   **{k: data.get(k) for k in cls.OPTIONAL},
                   errors=tuple(StatusError(e["channel"], e["item_id"], e["reason"]) for e in errors)
                   if errors is not None else None)

    def to_json(self) -> Json:
        out: Json = {"header": self.header.to_json(), "agv_id": self.agv_id, "state": self.state.value}
        for key in self.OPTIONAL:
            value = getattr(self, key)
            if value is not None:
                out[key] = value
        if self.errors is not None:
            out["errors"] = [e.to_json() for e in self.errors]
        return out


@dataclass(frozen=True)
class Movement:
    header: Header
    agv_id: str
    x: float
    y: float
    theta: float
    linear: float
    angular: float

    @classmethod
    def from_json(cls, data: Json) -> Movement:
        check(Kind.MOVEMENT, data)
        pose, velocity = data["pose"], data["velocity"]
        return cls(Header.from_json(data["header"]), data["agv_id"], float(pose["x"]), float(pose["y"]),
                   float(pose["theta"]), float(velocity["linear"]), float(velocity["angular"]))

    def to_json(self) -> Json:
        return {"header": self.header.to_json(), "agv_id": self.agv_id,
                "pose": {"x": self.x, "y": self.y, "theta": self.theta},
                "velocity": {"linear": self.linear, "angular": self.angular}}


@dataclass(frozen=True)
class Physical:
    max_velocity: tuple[float, float, float]
    max_acceleration: tuple[float, float, float]
    payload_kg: float
    length: float
    width: float
    battery_capacity_wh: float | None = None

    def to_json(self) -> Json:
        out: Json = {"max_velocity": list(self.max_velocity), "max_acceleration": list(self.max_acceleration),
                     "payload_kg": self.payload_kg}
        if self.battery_capacity_wh is not None:
            out["battery_capacity_wh"] = self.battery_capacity_wh
        out["footprint"] = {"length": self.length, "width": self.width}
        return out


@dataclass(frozen=True)
class Description:
    header: Header
    agv_id: str
    name: str
    manufacturer: str
    skills: tuple[str, ...]
    physical: Physical = field(repr=False)

    @classmethod
    def from_json(cls, data: Json) -> Description:
        check(Kind.DESCRIPTION, data)
        p = data["physical"]
        capacity = p.get("battery_capacity_wh")
        physical = Physical(_axes(p["max_velocity"]), _axes(p["max_acceleration"]), float(p["payload_kg"]),
                            float(p["footprint"]["length"]), float(p["footprint"]["width"]),
                            float(capacity) if capacity is not None else None)
        return cls(Header.from_json(data["header"]), data["agv_id"], data["name"], data["manufacturer"],
                   tuple(data["skills"]), physical)

    def to_json(self) -> Json:
        return {"header": self.header.to_json(), "agv_id": self.agv_id, "name": self.name,
                "manufacturer": self.manufacturer, "skills": list(self.skills), "physical": self.physical.to_json()}

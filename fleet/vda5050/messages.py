"""Frozen VDA 5050 2.1 messages: what crosses our boundary, with from/to JSON.

``from_json`` takes a dict that already passed :func:`fleet.vda5050.schemas.check` (so required
fields exist and have the right JSON types); ``to_json(header)`` returns the wire form (camelCase,
optional fields left out when unset, as section 6.1 asks). Header fields are not part of these
types: the sender's :class:`~fleet.vda5050.headers.HeaderCounter` supplies them.
The factsheet has its own module (:mod:`fleet.vda5050.factsheet`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any

Json = dict[str, Any]


class BlockingType(str, enum.Enum):
    NONE = "NONE"
    SOFT = "SOFT"
    HARD = "HARD"


class ActionStatus(str, enum.Enum):
    WAITING = "WAITING"
    INITIALIZING = "INITIALIZING"
    RUNNING = "RUNNING"
    PAUSED = "PAUSED"
    FINISHED = "FINISHED"
    FAILED = "FAILED"

    @property
    def done(self) -> bool:
        return self in (ActionStatus.FINISHED, ActionStatus.FAILED)


class ConnectionState(str, enum.Enum):
    ONLINE = "ONLINE"
    OFFLINE = "OFFLINE"
    CONNECTIONBROKEN = "CONNECTIONBROKEN"


class OperatingMode(str, enum.Enum):
    AUTOMATIC = "AUTOMATIC"
    SEMIAUTOMATIC = "SEMIAUTOMATIC"
    MANUAL = "MANUAL"
    SERVICE = "SERVICE"
    TEACHIN = "TEACHIN"


class ErrorLevel(str, enum.Enum):
    WARNING = "WARNING"
    FATAL = "FATAL"


def _optional(out: Json, key: str, value: Any) -> None:
    if value is not None:
        out[key] = value


@dataclass(frozen=True)
class ActionParameter:
    key: str
    value: Any


@dataclass(frozen=True)
class Action:
    action_type: str
    action_id: str
    blocking_type: BlockingType = BlockingType.HARD
    parameters: tuple[ActionParameter, ...] = ()
    description: str | None = None

    def param(self, key: str, default: Any = None) -> Any:
        for p in self.parameters:
            if p.key == key:
                return p.value
        return default

    @classmethod
    def from_json(cls, data: Json) -> Action:
        return cls(
            action_type=data["actionType"],
            action_id=data["actionId"],
            blocking_type=BlockingType(data["blockingType"]),
            parameters=tuple(ActionParameter(p["key"], p["value"]) for p in data.get("actionParameters", ())),
            description=data.get("actionDescription"),
        )

    def to_json(self) -> Json:
        out: Json = {"actionType": self.action_type, "actionId": self.action_id,
                     "blockingType": self.blocking_type.value}
        if self.parameters:
            out["actionParameters"] = [{"key": p.key, "value": p.value} for p in self.parameters]
        _optional(out, "actionDescription", self.description)
        return out


@dataclass(frozen=True)
class NodePosition:
    x: float
    y: float
    map_id: str
    theta: float | None = None
    allowed_deviation_xy: float | None = None

    @classmethod
    def from_json(cls, data: Json) -> NodePosition:
        return cls(float(data["x"]), float(data["y"]), data["mapId"], data.get("theta"),
                   data.get("allowedDeviationXY"))

    def to_json(self) -> Json:
        out: Json = {"x": self.x, "y": self.y, "mapId": self.map_id}
        _optional(out, "theta", self.theta)
        _optional(out, "allowedDeviationXY", self.allowed_deviation_xy)
        return out


@dataclass(frozen=True)
class Node:
    node_id: str
    sequence_id: int
    released: bool = True
    actions: tuple[Action, ...] = ()
    position: NodePosition | None = None

    @classmethod
    def from_json(cls, data: Json) -> Node:
        position = data.get("nodePosition")
        return cls(data["nodeId"], data["sequenceId"], data["released"],
                   tuple(Action.from_json(a) for a in data["actions"]),
                   NodePosition.from_json(position) if position is not None else None)

    def to_json(self) -> Json:
        out: Json = {"nodeId": self.node_id, "sequenceId": self.sequence_id, "released": self.released,
                     "actions": [a.to_json() for a in self.actions]}
        if self.position is not None:
            out["nodePosition"] = self.position.to_json()
        return out


@dataclass(frozen=True)
class Edge:
    edge_id: str
    sequence_id: int
    start_node_id: str
    end_node_id: str
    released: bool = True
    actions: tuple[Action, ...] = ()
    max_speed: float | None = None

    @classmethod
    def from_json(cls, data: Json) -> Edge:
        return cls(data["edgeId"], data["sequenceId"], data["startNodeId"], data["endNodeId"],
                   data["released"], tuple(Action.from_json(a) for a in data["actions"]),
                   data.get("maxSpeed"))

    def to_json(self) -> Json:
        out: Json = {"edgeId": self.edge_id, "sequenceId": self.sequence_id, "released": self.released,
                     "startNodeId": self.start_node_id, "endNodeId": self.end_node_id,
                     "actions": [a.to_json() for a in self.actions]}
        _optional(out, "maxSpeed", self.max_speed)
        return out


@dataclass(frozen=True)
class Order:
    order_id: str
    order_update_id: int
    nodes: tuple[Node, ...]
    edges: tuple[Edge, ...] = ()
    zone_set_id: str | None = None

    @classmethod
    def from_json(cls, data: Json) -> Order:
        return cls(data["orderId"], data["orderUpdateId"], tuple(Node.from_json(n) for n in data["nodes"]),
                   tuple(Edge.from_json(e) for e in data["edges"]), data.get("zoneSetId"))

    def to_json(self, header: Json) -> Json:
        out: Json = {**header, "orderId": self.order_id, "orderUpdateId": self.order_update_id,
                     "nodes": [n.to_json() for n in self.nodes], "edges": [e.to_json() for e in self.edges]}
        _optional(out, "zoneSetId", self.zone_set_id)
        return out


@dataclass(frozen=True)
class InstantActions:
    actions: tuple[Action, ...]

    @classmethod
    def from_json(cls, data: Json) -> InstantActions:
        return cls(tuple(Action.from_json(a) for a in data["actions"]))

    def to_json(self, header: Json) -> Json:
        return {**header, "actions": [a.to_json() for a in self.actions]}


@dataclass(frozen=True)
class ActionState:
    action_id: str
    status: ActionStatus
    action_type: str | None = None
    result_description: str | None = None

    @classmethod
    def from_json(cls, data: Json) -> ActionState:
        return cls(data["actionId"], ActionStatus(data["actionStatus"]), data.get("actionType"),
                   data.get("resultDescription"))

    def to_json(self) -> Json:
        out: Json = {"actionId": self.action_id, "actionStatus": self.status.value}
        _optional(out, "actionType", self.action_type)
        _optional(out, "resultDescription", self.result_description)
        return out


@dataclass(frozen=True)
class BatteryState:
    charge: float
    charging: bool
    reach: int | None = None

    @classmethod
    def from_json(cls, data: Json) -> BatteryState:
        return cls(float(data["batteryCharge"]), data["charging"], data.get("reach"))

    def to_json(self) -> Json:
        out: Json = {"batteryCharge": round(self.charge, 3), "charging": self.charging}
        _optional(out, "reach", self.reach)
        return out


@dataclass(frozen=True)
class AgvPosition:
    x: float
    y: float
    theta: float
    map_id: str
    initialized: bool = True

    @classmethod
    def from_json(cls, data: Json) -> AgvPosition:
        return cls(float(data["x"]), float(data["y"]), float(data["theta"]), data["mapId"],
                   data["positionInitialized"])

    def to_json(self) -> Json:
        return {"x": round(self.x, 4), "y": round(self.y, 4), "theta": round(self.theta, 4),
                "mapId": self.map_id, "positionInitialized": self.initialized}


@dataclass(frozen=True)
class NodeState:
    node_id: str
    sequence_id: int
    released: bool
    position: NodePosition | None = None

    @classmethod
    def from_json(cls, data: Json) -> NodeState:
        position = data.get("nodePosition")
        return cls(data["nodeId"], data["sequenceId"], data["released"],
                   NodePosition.from_json(position) if position else None)

    def to_json(self) -> Json:
        out: Json = {"nodeId": self.node_id, "sequenceId": self.sequence_id, "released": self.released}
        if self.position is not None:
            out["nodePosition"] = self.position.to_json()
        return out


@dataclass(frozen=True)
class EdgeState:
    edge_id: str
    sequence_id: int
    released: bool

    @classmethod
    def from_json(cls, data: Json) -> EdgeState:
        return cls(data["edgeId"], data["sequenceId"], data["released"])

    def to_json(self) -> Json:
        return {"edgeId": self.edge_id, "sequenceId": self.sequence_id, "released": self.released}


@dataclass(frozen=True)
class VehicleError:
    """One entry of ``state.errors`` (named so it is not mistaken for a Python exception)."""

    error_type: str
    level: ErrorLevel
    description: str
    references: tuple[tuple[str, str], ...] = ()

    @classmethod
    def from_json(cls, data: Json) -> VehicleError:
        refs = tuple((r["referenceKey"], r["referenceValue"]) for r in data.get("errorReferences", ()))
        return cls(data["errorType"], ErrorLevel(data["errorLevel"]), data.get("errorDescription", ""), refs)

    def to_json(self) -> Json:
        out: Json = {"errorType": self.error_type, "errorLevel": self.level.value,
                     "errorDescription": self.description}
        if self.references:
            out["errorReferences"] = [{"referenceKey": k, "referenceValue": v} for k, v in self.references]
        return out


@dataclass(frozen=True)
class State:
    order_id: str
    order_update_id: int
    last_node_id: str
    last_node_sequence_id: int
    driving: bool
    battery: BatteryState
    node_states: tuple[NodeState, ...] = ()
    edge_states: tuple[EdgeState, ...] = ()
    action_states: tuple[ActionState, ...] = ()
    errors: tuple[VehicleError, ...] = ()
    operating_mode: OperatingMode = OperatingMode.AUTOMATIC
    position: AgvPosition | None = None
    velocity: tuple[float, float] | None = None  # (vx, omega) in the vehicle frame
    paused: bool = False
    e_stop: str = "NONE"
    field_violation: bool = False
    extra: dict[str, Any] = field(default_factory=dict, compare=False)

    @classmethod
    def from_json(cls, data: Json) -> State:
        position = data.get("agvPosition")
        velocity = data.get("velocity")
        return cls(
            order_id=data["orderId"], order_update_id=data["orderUpdateId"],
            last_node_id=data["lastNodeId"], last_node_sequence_id=data["lastNodeSequenceId"],
            driving=data["driving"], battery=BatteryState.from_json(data["batteryState"]),
            node_states=tuple(NodeState.from_json(n) for n in data["nodeStates"]),
            edge_states=tuple(EdgeState.from_json(e) for e in data["edgeStates"]),
            action_states=tuple(ActionState.from_json(a) for a in data["actionStates"]),
            errors=tuple(VehicleError.from_json(e) for e in data["errors"]),
            operating_mode=OperatingMode(data["operatingMode"]),
            position=AgvPosition.from_json(position) if position else None,
            velocity=(velocity.get("vx", 0.0), velocity.get("omega", 0.0)) if velocity else None,
            paused=data.get("paused", False),
            e_stop=data["safetyState"]["eStop"], field_violation=data["safetyState"]["fieldViolation"],
        )

    def to_json(self, header: Json) -> Json:
        out: Json = {
            **header,
            "orderId": self.order_id, "orderUpdateId": self.order_update_id,
            "lastNodeId": self.last_node_id, "lastNodeSequenceId": self.last_node_sequence_id,
            "nodeStates": [n.to_json() for n in self.node_states],
            "edgeStates": [e.to_json() for e in self.edge_states],
            "driving": self.driving, "paused": self.paused,
            "actionStates": [a.to_json() for a in self.action_states],
            "batteryState": self.battery.to_json(),
            "operatingMode": self.operating_mode.value,
            "errors": [e.to_json() for e in self.errors],
            "safetyState": {"eStop": self.e_stop, "fieldViolation": self.field_violation},
        }
        if self.position is not None:
            out["agvPosition"] = self.position.to_json()
        if self.velocity is not None:
            out["velocity"] = {"vx": round(self.velocity[0], 4), "vy": 0.0, "omega": round(self.velocity[1], 4)}
        return out

    def action_status(self, action_id: str) -> ActionStatus | None:
        for a in self.action_states:
            if a.action_id == action_id:
                return a.status
        return None


@dataclass(frozen=True)
class Connection:
    state: ConnectionState

    @classmethod
    def from_json(cls, data: Json) -> Connection:
        return cls(ConnectionState(data["connectionState"]))

    def to_json(self, header: Json) -> Json:
        return {**header, "connectionState": self.state.value}


def visualization_json(header: Json, position: AgvPosition | None, velocity: tuple[float, float] | None) -> Json:
    """A ``visualization`` message: position and velocity only, at a higher rate than ``state``."""
    out: Json = dict(header)
    if position is not None:
        out["agvPosition"] = position.to_json()
    if velocity is not None:
        out["velocity"] = {"vx": round(velocity[0], 4), "vy": 0.0, "omega": round(velocity[1], 4)}
    return out

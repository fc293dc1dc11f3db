"""One received MQTT message -> a typed event, or :class:`RefusedMessage` saying why not.

What the fleet manager subscribes to, and what each topic becomes:

| topic | event |
|-------|-------|
| ``uagv/v2/<m>/<s>/connection`` | :class:`ConnectionSeen` (ONLINE, OFFLINE, CONNECTIONBROKEN) |
| ``uagv/v2/<m>/<s>/factsheet`` | :class:`DescriptionSeen` (the factsheet) |
| ``uagv/v2/<m>/<s>/state`` | :class:`StateSeen` (order progress, action states, battery) |
| ``<agv-id>/description_channel`` | :class:`DescriptionSeen` (the paper's description; empty = removed) |
| ``<agv-id>/status_channel`` | :class:`ConnectionSeen` (``"state": "OFFLINE"`` is the paper's last will) |

Everything is checked before it is believed: the topic's levels (``fleet.vda5050.topics``), the
size (at most 1 MB), UTF-8 JSON object, the official VDA 5050 2.1 schema of the topic, and that
the header's ``manufacturer`` / ``serialNumber`` are the topic's (a header serial with ``/`` or
``#`` is refused naming the character). The functions are pure: no MQTT client here.
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass
from typing import Any

from fleet.vda5050 import schemas, topics
from fleet.vda5050.errors import SchemaError, TopicError
from fleet.vda5050.topics import Subtopic
from fleet.discovery.errors import RefusedMessage

MAX_PAYLOAD_BYTES = schemas.MAX_MESSAGE_BYTES
PAPER_DESCRIPTION = "description_channel"
PAPER_STATUS = "status_channel"
UNAVAILABLE = frozenset({"OFFLINE", "CONNECTIONBROKEN"})

#: What the fleet manager subscribes to (QoS 1: connection and descriptions are QoS 1, retained).
SUBSCRIPTIONS: tuple[str, ...] = (
    topics.subscription(Subtopic.CONNECTION),
    topics.subscription(Subtopic.FACTSHEET),
    topics.subscription(Subtopic.STATE),
    f"+/{PAPER_DESCRIPTION}",
    f"+/{PAPER_STATUS}",
)


class Interface(str, enum.Enum):
    VDA5050 = "vda5050"
    PAPER = "paper-channels"


@dataclass(frozen=True, order=True)
class VehicleKey:
    """Who a message is about. Paper vehicles have no manufacturer in their topics ("")."""

    interface: Interface
    manufacturer: str
    serial: str

    @property
    def label(self) -> str:
        return f"{self.manufacturer}/{self.serial}" if self.manufacturer else self.serial


@dataclass(frozen=True)
class ConnectionSeen:
    key: VehicleKey
    state: str  # ONLINE | OFFLINE | CONNECTIONBROKEN
    retained: bool = False


@dataclass(frozen=True)
class DescriptionSeen:
    """A factsheet (VDA 5050) or a paper description; ``payload`` None: the vehicle was removed."""

    key: VehicleKey
    payload: dict[str, Any] | None


@dataclass(frozen=True)
class ActionStatus:
    action_id: str
    action_type: str
    status: str


@dataclass(frozen=True)
class AgvPosition:
    """The state's ``agvPosition`` (VDA 5050 2.1: x, y in m, theta in rad, on map ``map_id``)."""

    x: float
    y: float
    theta: float
    map_id: str
    initialized: bool

    def to_json(self) -> dict[str, Any]:
        return {"x": self.x, "y": self.y, "theta": self.theta, "mapId": self.map_id,
                "positionInitialized": self.initialized}


@dataclass(frozen=True)
class VehicleState:
    """What the fleet manager keeps of a vehicle's last ``state``."""

    order_id: str
    order_update_id: int
    last_node_id: str
    last_node_sequence_id: int
    driving: bool
    battery_charge: float | None
    charging: bool | None
    action_states: tuple[ActionStatus, ...]
    errors: tuple[str, ...]
    timestamp: str
    position: AgvPosition | None = None  # None: the state had no agvPosition

    def to_json(self) -> dict[str, Any]:
        return {
            "orderId": self.order_id, "orderUpdateId": self.order_update_id,
            "lastNodeId": self.last_node_id, "lastNodeSequenceId": self.last_node_sequence_id,
            "driving": self.driving, "batteryCharge": self.battery_charge, "charging": self.charging,
            "actionStates": [{"actionId": a.action_id, "actionType": a.action_type,
                              "actionStatus": a.status} for a in self.action_states],
            "errors": list(self.errors), "timestamp": self.timestamp,
            "agvPosition": self.position.to_json() if self.position is not None else None,
        }


@dataclass(frozen=True)
class StateSeen:
    key: VehicleKey
    state: VehicleState


Event = ConnectionSeen | DescriptionSeen | StateSeen


def classify(topic: str, payload: bytes, retained: bool = False) -> Event:
    """The event one message means; raises :class:`RefusedMessage` with the reason."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise RefusedMessage(topic, f"payload is {len(payload)} bytes, more than the "
                                    f"{MAX_PAYLOAD_BYTES} accepted")
    levels = topic.split("/")
    if len(levels) == 2 and levels[1] in (PAPER_DESCRIPTION, PAPER_STATUS):
        return _paper(topic, levels[0], levels[1], payload, retained)
    try:
        where = topics.parse(topic)
    except TopicError as exc:
        raise RefusedMessage(topic, exc.message) from None
    if where.subtopic not in (Subtopic.CONNECTION, Subtopic.FACTSHEET, Subtopic.STATE):
        raise RefusedMessage(topic, f"the fleet manager does not read {where.subtopic.value}")
    try:
        message = schemas.parse(where.subtopic, payload)
    except SchemaError as exc:
        raise RefusedMessage(topic, exc.message) from None
    _check_header(topic, message, where.manufacturer, where.serial)
    key = VehicleKey(Interface.VDA5050, where.manufacturer, where.serial)
    if where.subtopic is Subtopic.CONNECTION:
        return ConnectionSeen(key, str(message["connectionState"]), retained)
    if where.subtopic is Subtopic.FACTSHEET:
        return DescriptionSeen(key, message)
    return StateSeen(key, _state(message))


def _check_header(topic: str, message: dict[str, Any], manufacturer: str, serial: str) -> None:
    try:
        topics.check_serial(message["serialNumber"])
        topics.check_level("manufacturer", message["manufacturer"])
    except TopicError as exc:
        raise RefusedMessage(topic, f"header {exc.message}") from None
    if message["serialNumber"] != serial:
        raise RefusedMessage(topic, f"header serialNumber {message['serialNumber']!r} is not the "
                                    f"topic's {serial!r}")
    if message["manufacturer"] != manufacturer:
        raise RefusedMessage(topic, f"header manufacturer {message['manufacturer']!r} is not the "
                                    f"topic's {manufacturer!r}")


def _state(message: dict[str, Any]) -> VehicleState:
    battery = message.get("batteryState") or {}
    return VehicleState(
        order_id=message["orderId"], order_update_id=int(message["orderUpdateId"]),
        last_node_id=message["lastNodeId"], last_node_sequence_id=int(message["lastNodeSequenceId"]),
        driving=bool(message["driving"]),
        battery_charge=float(battery["batteryCharge"]) if "batteryCharge" in battery else None,
        charging=bool(battery["charging"]) if "charging" in battery else None,
        action_states=tuple(ActionStatus(a["actionId"], a.get("actionType", ""), a["actionStatus"])
                            for a in message["actionStates"]),
        errors=tuple(f"{e['errorType']}: {e.get('errorDescription', '')}" for e in message["errors"]),
        timestamp=message["timestamp"],
        position=_position(message.get("agvPosition")),
    )


def _position(pos: Any) -> AgvPosition | None:
    """The schema has checked the fields' types (x, y, theta, mapId, positionInitialized required)."""
    if not isinstance(pos, dict):
        return None
    return AgvPosition(float(pos["x"]), float(pos["y"]), float(pos["theta"]), str(pos["mapId"]),
                       bool(pos["positionInitialized"]))


def _paper(topic: str, agv_id: str, channel: str, payload: bytes, retained: bool) -> Event:
    try:
        topics.check_serial(agv_id)
    except TopicError as exc:
        raise RefusedMessage(topic, f"agv id {exc.message}") from None
    key = VehicleKey(Interface.PAPER, "", agv_id)
    if channel == PAPER_DESCRIPTION and not payload:
        return DescriptionSeen(key, None)  # an empty retained description: the vehicle was removed
    try:
        message = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise RefusedMessage(topic, f"not UTF-8 JSON: {exc}") from None
    if not isinstance(message, dict):
        raise RefusedMessage(topic, f"a message is a JSON object, got {type(message).__name__}")
    if channel == PAPER_STATUS:
        state = message.get("state")
        if not isinstance(state, str) or not state:
            raise RefusedMessage(topic, f"state: expected a non-empty string, got {state!r}")
        return ConnectionSeen(key, state if state in UNAVAILABLE else "ONLINE", retained)
    if message.get("agv_id") != agv_id:
        raise RefusedMessage(topic, f"agv_id {message.get('agv_id')!r} is not the topic's {agv_id!r}")
    return DescriptionSeen(key, message)

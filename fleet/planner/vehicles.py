"""What the planner knows of the vehicles now: the fleet manager's list (over its HTTP API:
discovered vehicles, connection state, skills) joined with each vehicle's last VDA 5050 ``state``
(over MQTT: position, battery, orderId, lastNodeId, actionStates).

The planner subscribes to ``uagv/v2/+/+/state`` itself because the manager's vehicle rows carry no
position (a new order must start where the vehicle stands, VDA 5050 6.6), and so it hears
progress without polling. paho's network thread stores the latest state per vehicle under a lock;
a state that is not JSON or names no vehicle is ignored (the manager refuses and reports those).
"""

from __future__ import annotations

import json
import logging
import os
import threading
from dataclasses import dataclass
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from fleet.manager.client import ManagerClient, ManagerRefusedError, ManagerUnreachableError
from fleet.planner.assign import Live
from fleet.planner.machine import VehicleView

log = logging.getLogger("fleet.planner")
STATE_TOPIC = "uagv/v2/+/+/state"


@dataclass(frozen=True)
class Vehicle:
    key: str  # topicManufacturer/serial
    serial: str
    manufacturer: str
    interface: str
    online: bool
    connection_state: str
    state: dict[str, Any] | None  # the last VDA 5050 state heard over MQTT (else the manager's)

    def position(self) -> tuple[float, float] | None:
        pos = (self.state or {}).get("agvPosition") or {}
        x, y = pos.get("x"), pos.get("y")
        return (float(x), float(y)) if isinstance(x, (int, float)) and isinstance(y, (int, float)) else None

    def battery(self) -> float | None:
        value = ((self.state or {}).get("batteryState") or {}).get("batteryCharge")
        return float(value) if isinstance(value, (int, float)) else None

    def view(self) -> VehicleView:
        s = self.state or {}
        actions = tuple((str(a.get("actionId")), str(a.get("actionStatus"))) for a in s.get("actionStates") or ()
                        if isinstance(a, dict))
        return VehicleView(self.key, self.online, str(s.get("orderId") or ""), str(s.get("lastNodeId") or ""), actions)

    def live(self, idle: bool) -> Live:
        pos = self.position()
        return Live(self.serial, self.manufacturer, self.connection_state, idle,
                    pos[0] if pos else None, pos[1] if pos else None, self.battery())


class StateListener:
    """The latest VDA 5050 state of every vehicle, from MQTT."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self._states: dict[str, dict[str, Any]] = {}
        self._lock = threading.Lock()
        self.connected = threading.Event()
        self.changed = threading.Event()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"plantkg-planner-{os.getpid()}")
        self.client.reconnect_delay_set(0.1, 2)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = lambda *_: self.connected.clear()
        self.client.on_message = self._on_message

    def start(self) -> None:
        self.client.connect_async(self.host, self.port, keepalive=15)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_connect(self, client: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        if reason.is_failure:
            log.warning("MQTT %s:%d refused the planner: %s", self.host, self.port, reason)
            return
        client.subscribe(STATE_TOPIC, qos=0)
        self.connected.set()

    def _on_message(self, _c: mqtt.Client, _u: Any, message: mqtt.MQTTMessage) -> None:
        levels = message.topic.split("/")
        try:
            state = json.loads(message.payload)
        except ValueError:
            return
        if len(levels) != 5 or not isinstance(state, dict):
            return
        with self._lock:
            self._states[f"{levels[2]}/{levels[3]}"] = state
        self.changed.set()

    def get(self, key: str) -> dict[str, Any] | None:
        with self._lock:
            return self._states.get(key)


class Fleet:
    """The manager's vehicle list, refreshed on demand, joined with the MQTT states."""

    def __init__(self, manager: ManagerClient, states: StateListener) -> None:
        self.manager = manager
        self.states = states
        self.rows: list[dict[str, Any]] = []
        self.reachable = False

    def refresh(self) -> None:
        try:
            rows = self.manager.vehicles()
        except (ManagerUnreachableError, ManagerRefusedError) as exc:
            if self.reachable:
                log.warning("the fleet manager does not answer: %s", exc)
            self.reachable = False
            return  # keep the last list: vehicles are not lost because the manager restarts
        self.rows, self.reachable = [r for r in rows if isinstance(r, dict)], True

    def vehicles(self) -> dict[str, Vehicle]:
        out = {}
        for row in self.rows:
            key = f"{row.get('topicManufacturer')}/{row.get('serial')}"
            state = self.states.get(key) or row.get("state")
            out[key] = Vehicle(key, str(row.get("serial")), str(row.get("topicManufacturer")),
                               str(row.get("interface")), row.get("connectionState") == "ONLINE",
                               str(row.get("connectionState")), state)
        return out

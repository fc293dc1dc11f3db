"""Good VDA 5050 messages for the plug-and-play tests (valid by construction: built by our own
message layer and checked against the official schemas), and their topics."""

from __future__ import annotations

import json
from typing import Any

from fleet.sim.actions import catalogue
from fleet.vda5050 import schemas, topics
from fleet.vda5050.factsheet import Factsheet
from fleet.vda5050.headers import HeaderCounter

MANUFACTURER = "acme"
SERIAL = "agv-42"


def factsheet(manufacturer: str = MANUFACTURER, serial: str = SERIAL, speed: float = 1.5) -> dict[str, Any]:
    sheet = Factsheet("acme carrier", "DIFF", "CARRIER", 120.0, 0.0, speed, 0.5, 0.5, 1.2, 0.7, 1.0, catalogue())
    return schemas.check("factsheet", sheet.to_json(HeaderCounter(manufacturer, serial).next("factsheet")))


def connection(state: str = "ONLINE", manufacturer: str = MANUFACTURER, serial: str = SERIAL) -> dict[str, Any]:
    return {**HeaderCounter(manufacturer, serial).next("connection"), "connectionState": state}


def state(manufacturer: str = MANUFACTURER, serial: str = SERIAL, **extra: Any) -> dict[str, Any]:
    body = {**HeaderCounter(manufacturer, serial).next("state"), "orderId": "o-1", "orderUpdateId": 0,
            "lastNodeId": "n2", "lastNodeSequenceId": 4, "nodeStates": [], "edgeStates": [],
            "driving": False, "actionStates": [{"actionId": "p1", "actionType": "pick", "actionStatus": "FINISHED"}],
            "batteryState": {"batteryCharge": 81.5, "charging": False}, "operatingMode": "AUTOMATIC",
            "errors": [], "safetyState": {"eStop": "NONE", "fieldViolation": False}, **extra}
    return schemas.check("state", body)


def topic(kind: str, manufacturer: str = MANUFACTURER, serial: str = SERIAL) -> str:
    return topics.topic(manufacturer, serial, kind)


def wire(message: Any) -> bytes:
    return json.dumps(message).encode("utf-8")


def paper_description(agv_id: str = "agv-7", **extra: Any) -> dict[str, Any]:
    return {"header": {"seq": 0, "stamp": "2026-11-24T20:00:00.000Z", "frame_id": "map"},
            "agv_id": agv_id, "name": "AGV 7", "manufacturer": "plantkg-sim",
            "skills": ["move", "load", "unload", "wait", "charge"],
            "physical": {"max_velocity": [1.0, 0.0, 1.2], "max_acceleration": [0.5, 0.0, 1.0],
                         "payload_kg": 100.0, "battery_capacity_wh": 1200.0,
                         "footprint": {"length": 1.0, "width": 0.7}}, **extra}

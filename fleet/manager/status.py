"""The manager's status for people and the dashboard: ``<data-dir>/status.json``, written atomically.

::

    {"updated": "...Z", "manager": {"pid", "api", "mqtt", "connected", "dropped"},
     "vehicles": [{"vehicle": "m/s", "serial", "manufacturer", "interface", "name", "connectionState",
                   "available", "pinned", "file", "discoveredAt", "readySeconds", "state": {...} | null}],
     "lastReconcile": {"at", "ok", "valid", "summary", "changes", "seconds", "joined", "refused"} | null,
     "refused": [{"vehicle", "reason"}],             # refused vehicles (refused/*.reason.txt)
     "refusedMessages": [{"at", "topic", "reason"}],  # the last 50 messages refused on receipt
     "orders": [{"at", "vehicle", "orderId"}]}         # the last 50 orders sent

``readySeconds``: from the first message that made the vehicle known to the manager (its
``connection: ONLINE``, or a paper description) until the reconcile that applied it finished.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from fleet.discovery import files
from fleet.discovery.inbox import VehicleKey, VehicleState
from fleet.discovery.records import VehicleRecord


def vehicle_row(key: VehicleKey, record: VehicleRecord, turtle: Path, state: VehicleState | None,
                ready: float | None) -> dict[str, Any]:
    return {
        "vehicle": record.label, "serial": record.serial, "manufacturer": record.manufacturer,
        "topicManufacturer": key.manufacturer, "interface": record.interface,
        "name": record.name or record.description.get("name"), "connectionState": record.connection_state,
        "available": record.connection_state == "ONLINE", "pinned": record.pinned, "file": str(turtle),
        "discoveredAt": record.discovered_at, "readySeconds": ready,
        "skills": list(record.description.get("skills", ())),
        "state": state.to_json() if state is not None else None,
    }


def write(path: Path, status: dict[str, Any]) -> None:
    files.atomic_write(path, json.dumps(status, indent=1, sort_keys=True) + "\n")

"""Shared good messages of the paper's channels for the tests (valid by construction)."""

from __future__ import annotations

import uuid
from typing import Any

HEADER = {"seq": 3, "stamp": "2026-11-24T20:00:00.000Z", "frame_id": "hall-1"}
AREA = [[0, 0], [40, 0], [40, 20], [0, 20]]
TASK = "6f1c2b5e-0d7a-4c5e-9b1a-2f3d4e5f6a7b"


def uid() -> str:
    return str(uuid.uuid4())


def motion(task: str = TASK, sequence: int = 0, point: list[float] | None = None, **extra: Any) -> dict[str, Any]:
    return {"header": dict(HEADER), "point_id": uid(), "task_id": task, "motion_id": uid(),
            "point": point if point is not None else [5.0, 4.0], "max_velocity": [0.8, 0.0, 1.0],
            "max_acceleration": [0.5, 0.0, 1.0], "motion_area": [list(p) for p in AREA],
            "sequence": sequence, **extra}


def action(kind: str = "wait", task: str = TASK, sequence: int = 1, **extra: Any) -> dict[str, Any]:
    return {"header": dict(HEADER), "action_id": uid(), "task_id": task, "action": kind, "sequence": sequence, **extra}


STATUS = {"header": HEADER, "agv_id": "agv-7", "state": "MOVING", "battery": 87.5, "charging": False,
          "task_id": TASK, "motion_id": "0b6a1a2e-7f3c-4f7e-8d9a-1b2c3d4e5f60", "action_id": "",
          "last_finished_sequence": 2, "finished_task_id": "", "refused": 1,
          "errors": [{"channel": "motion_channel", "item_id": "x", "reason": "sequence 1 is not after 2"}]}
MOVEMENT = {"header": HEADER, "agv_id": "agv-7", "pose": {"x": 1.5, "y": 2.0, "theta": -0.5},
            "velocity": {"linear": 0.4, "angular": 0.0}}
DESCRIPTION = {"header": {"seq": 0, "stamp": "2026-11-24T20:00:00.000Z", "frame_id": "map"},
               "agv_id": "agv-7", "name": "AGV 7", "manufacturer": "plantkg-sim",
               "skills": ["move", "load", "unload", "wait", "charge"],
               "physical": {"max_velocity": [1.0, 0.0, 1.2], "max_acceleration": [0.5, 0.0, 1.0],
                            "payload_kg": 100.0, "battery_capacity_wh": 1200.0,
                            "footprint": {"length": 1.0, "width": 0.7}}}

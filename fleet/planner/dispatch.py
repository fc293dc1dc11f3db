"""A sub-task as a VDA 5050 order, sent through the fleet manager's API (POST /v1/orders).

One sub-task is one order: a first node where the vehicle stands (VDA 5050 6.6: a new order
starts at the vehicle's position, within its allowed deviation) and the station with the
sub-task's actions (HARD blocking, ids ``<orderId>-<station>-<i>``, fleet/manager/orders.py).
When the vehicle already stands on the station (within ``AT_STATION`` m) the station is the only
node. The planner's abstract actions map to VDA 5050 action types (pick, drop, wait are the
standard's own names). The paper's motion/action items over the context broker are not sent yet.
"""

from __future__ import annotations

import math

from fleet.manager.client import ManagerClient, ManagerRefusedError, ManagerUnreachableError
from fleet.manager.orders import NodeSpec
from fleet.planner.errors import PlannerError
from fleet.planner.machine import SendOrder
from fleet.planner.vehicles import Vehicle

AT_STATION = 0.05  # m
VDA5050_ACTIONS = {"pick": "pick", "drop": "drop", "wait": "wait"}


def order_nodes(send: SendOrder, position: tuple[float, float], map_id: str) -> list[NodeSpec]:
    actions = tuple(VDA5050_ACTIONS[a] for a in send.actions)
    station = NodeSpec(send.station, send.x, send.y, map_id, actions)
    x, y = position
    if math.hypot(send.x - x, send.y - y) <= AT_STATION:
        return [station]
    return [NodeSpec(f"{send.order_id}-start", x, y, map_id), station]


class VdaSender:
    """Sends a sub-task's order through the fleet manager's API; a refusal becomes a PlannerError."""

    def __init__(self, manager: ManagerClient, map_id: str) -> None:
        self.manager, self.map_id = manager, map_id

    def __call__(self, send: SendOrder, vehicle: Vehicle) -> None:
        if vehicle.interface != "vda5050":
            raise PlannerError(f"{vehicle.key} speaks {vehicle.interface}; the planner sends VDA 5050 orders only")
        position = vehicle.position()
        if position is None:
            raise PlannerError(f"{vehicle.key} has reported no position yet")
        try:
            self.manager.order(vehicle.serial, order_nodes(send, position, self.map_id),
                               manufacturer=vehicle.manufacturer, order_id=send.order_id)
        except (ManagerRefusedError, ManagerUnreachableError) as exc:
            raise PlannerError(exc.message) from None

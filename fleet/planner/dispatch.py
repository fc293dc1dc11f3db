"""A sub-task to its vehicle: a VDA 5050 order through the fleet manager's API (POST /v1/orders),
or the paper's motion and action items on the context broker (fleet/planner/paper.py); and
``cancelOrder`` (POST /v1/instantActions) when a task is taken away from a VDA 5050 vehicle.

VDA 5050: one sub-task is one order: a first node where the vehicle stands (VDA 5050 6.6: a new
order starts at the vehicle's position, within its allowed deviation) and the station with the
sub-task's actions (HARD blocking, ids ``<orderId>-<station>-<i>``, fleet/manager/orders.py).
When the vehicle already stands on the station (within ``AT_STATION`` m) the station is the only
node. The planner's abstract actions map to VDA 5050 action types (pick, drop, wait are the
standard's own names). The paper's channels have no way to cancel a task (the paper defines none):
a task taken from a paper vehicle runs to its end there.
"""

from __future__ import annotations

import math

from fleet.manager.client import ManagerClient, ManagerRefusedError, ManagerUnreachableError
from fleet.manager.orders import NodeSpec
from fleet.planner.errors import PlannerError
from fleet.planner.machine import SendOrder
from fleet.planner.paper import PaperSender
from fleet.planner.vehicles import ManagerHandle, Vehicle

AT_STATION = 0.05  # m
VDA5050_ACTIONS = {"pick": "pick", "drop": "drop", "wait": "wait", "startCharging": "startCharging"}


def order_nodes(send: SendOrder, position: tuple[float, float], map_id: str) -> list[NodeSpec]:
    actions = tuple(VDA5050_ACTIONS[a] for a in send.actions)
    station = NodeSpec(send.station, send.x, send.y, map_id, actions)
    x, y = position
    if math.hypot(send.x - x, send.y - y) <= AT_STATION:
        return [station]
    return [NodeSpec(f"{send.order_id}-start", x, y, map_id), station]


def _handle(manager: ManagerHandle | ManagerClient) -> ManagerHandle:
    return manager if isinstance(manager, ManagerHandle) else ManagerHandle(manager)


class VdaSender:
    """Sends a sub-task's order through the fleet manager's API; a refusal becomes a PlannerError."""

    def __init__(self, manager: ManagerHandle | ManagerClient, map_id: str) -> None:
        self.handle, self.map_id = _handle(manager), map_id

    def __call__(self, send: SendOrder, vehicle: Vehicle) -> None:
        if vehicle.interface != "vda5050":
            raise PlannerError(f"{vehicle.key} speaks {vehicle.interface}, not VDA 5050")
        position = vehicle.position()
        if position is None:
            raise PlannerError(f"{vehicle.key} has reported no position yet")
        try:
            self.handle.client.order(vehicle.serial, order_nodes(send, position, self.map_id),
                                     manufacturer=vehicle.manufacturer, order_id=send.order_id)
        except (ManagerRefusedError, ManagerUnreachableError) as exc:
            raise PlannerError(exc.message) from None

    def stop_charging(self, vehicle: Vehicle) -> None:
        """``stopCharging`` to ``vehicle`` (a charging vehicle does not drive): raises PlannerError."""
        try:
            self.handle.client.instant_action(vehicle.serial, "stopCharging", manufacturer=vehicle.manufacturer)
        except (ManagerRefusedError, ManagerUnreachableError) as exc:
            raise PlannerError(exc.message) from None

    def cancel(self, vehicle: Vehicle) -> bool:
        """``cancelOrder`` to ``vehicle``: True when sent, or when there is nobody to send it to (the
        manager says 404/409: unknown or not ONLINE); raises PlannerError when it should be retried."""
        try:
            self.handle.client.instant_action(vehicle.serial, "cancelOrder", manufacturer=vehicle.manufacturer)
        except ManagerRefusedError as exc:
            if exc.status in (404, 409):
                return False
            raise PlannerError(exc.message) from None
        except ManagerUnreachableError as exc:
            raise PlannerError(exc.message) from None
        return True


class Dispatcher:
    """Sends by the vehicle's interface; paper vehicles need the context broker (``paper``)."""

    def __init__(self, vda: VdaSender, paper: PaperSender | None = None) -> None:
        self.vda, self.paper = vda, paper

    @property
    def interfaces(self) -> tuple[str, ...]:
        return ("vda5050", "paper-channels") if self.paper is not None else ("vda5050",)

    def __call__(self, send: SendOrder, vehicle: Vehicle) -> None:
        if not vehicle.paper:
            self.vda(send, vehicle)
        elif self.paper is None:
            raise PlannerError(f"{vehicle.key} speaks the paper's channels: start the planner with --ngsi-url")
        else:
            self.paper(send, vehicle.state, vehicle.serial)

    def cancel(self, vehicle: Vehicle) -> bool:
        return False if vehicle.paper else self.vda.cancel(vehicle)

    def stop_charging(self, vehicle: Vehicle) -> None:
        if not vehicle.paper:  # the paper adapter stops charging by itself before a new task
            self.vda.stop_charging(vehicle)

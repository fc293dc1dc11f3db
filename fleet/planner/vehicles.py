"""What the planner knows of the vehicles now: the fleet manager's list (over its HTTP API:
discovered vehicles, connection state, skills and, for VDA 5050 vehicles, the last ``state`` with
``agvPosition``, battery, orderId, lastNodeId, actionStates) and, for paper-channel vehicles,
their entity ``urn:ngsi-ld:AGV:<agv-id>`` on the context broker (the status and movement channels
the mqtt-ngsi bridge merges into it: state, task_id, finished_task_id, errors, pose, battery).

The manager answers ``503 NotReady`` while it reads its records after a (re)start: the planner
then waits (``reachable`` is False: nobody is lost, nothing is assigned) and keeps its last list.
When the manager's address changes (a restart on another port), the client is found again through
the manager's data directory (``rediscover``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fleet.manager.client import ManagerClient, ManagerRefusedError, ManagerUnreachableError
from fleet.planner.assign import Live
from fleet.planner.machine import VehicleView

log = logging.getLogger("fleet.planner")
PAPER = "paper-channels"


class ManagerHandle:
    """The manager's client, found again through its data directory when it stops answering."""

    def __init__(self, client: ManagerClient, rediscover: Callable[[], ManagerClient] | None = None) -> None:
        self.client, self.rediscover = client, rediscover

    def renew(self) -> None:
        if self.rediscover is None:
            return
        try:
            fresh = self.rediscover()
        except ManagerUnreachableError:
            return
        if fresh.url != self.client.url:
            log.info("the fleet manager now answers at %s", fresh.url)
            self.client = fresh


@dataclass(frozen=True)
class Vehicle:
    key: str  # topicManufacturer/serial ("/<agv-id>" for a paper vehicle: its topics name no manufacturer)
    serial: str
    manufacturer: str
    interface: str
    online: bool
    connection_state: str
    state: dict[str, Any] | None  # VDA 5050: the manager's last state; paper: the AGV entity (keyValues)

    @property
    def paper(self) -> bool:
        return self.interface == PAPER

    def position(self) -> tuple[float, float] | None:
        s = self.state or {}
        pos = (s.get("pose") if self.paper else s.get("agvPosition")) or {}
        x, y = pos.get("x"), pos.get("y")
        return (float(x), float(y)) if isinstance(x, (int, float)) and isinstance(y, (int, float)) else None

    def battery(self) -> float | None:
        s = self.state or {}
        value = s.get("battery") if self.paper else s.get("batteryCharge", (s.get("batteryState") or {}).get(
            "batteryCharge"))  # the manager's rows: flat (fleet/discovery/inbox.py); a raw VDA 5050 state: nested
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None

    def charging(self) -> bool:
        s = self.state or {}
        value = s.get("charging") if self.paper else s.get("charging", (s.get("batteryState") or {}).get("charging"))
        return value is True

    def view(self) -> VehicleView:
        s = self.state or {}
        if self.paper:
            return paper_view(self.key, self.online, s)
        actions = tuple((str(a.get("actionId")), str(a.get("actionStatus"))) for a in s.get("actionStates") or ()
                        if isinstance(a, dict))
        return VehicleView(self.key, self.online, str(s.get("orderId") or ""), str(s.get("lastNodeId") or ""), actions)

    def live(self, idle: bool) -> Live:
        pos = self.position()
        return Live(self.serial, self.manufacturer, self.connection_state, idle,
                    pos[0] if pos else None, pos[1] if pos else None, self.battery())


def paper_view(key: str, online: bool, status: dict[str, Any]) -> VehicleView:
    """A paper vehicle's status as a view: the task it runs (or, when idle, the last one it ended;
    a task ends with its wait action), ended or not, and its refused/failed items as FAILED."""
    running, ended = str(status.get("task_id") or ""), str(status.get("finished_task_id") or "")
    errors = status.get("errors") if isinstance(status.get("errors"), list) else []
    failed = tuple((str(e.get("item_id")), "FAILED") for e in errors if isinstance(e, dict) and e.get("item_id"))
    order = running or ended
    return VehicleView(key, online, order, "", failed, paper=True, ended=bool(order) and order == ended and not running)


class Fleet:
    """The manager's vehicle list, refreshed on demand; paper vehicles joined with their entity."""

    def __init__(self, manager: ManagerHandle | ManagerClient,
                 paper_status: Callable[[str], dict[str, Any] | None] | None = None) -> None:
        self.handle = manager if isinstance(manager, ManagerHandle) else ManagerHandle(manager)
        self.paper_status = paper_status
        self.rows: list[dict[str, Any]] = []
        self.paper: dict[str, dict[str, Any]] = {}
        self.reachable = False
        self.waiting = False  # the manager said 503 NotReady

    def refresh(self) -> None:
        try:
            rows = self.handle.client.vehicles()
        except ManagerRefusedError as exc:
            if exc.status == 503:
                if not self.waiting:
                    log.info("the fleet manager is loading its records (503); waiting")
                self.waiting, self.reachable = True, False
                return
            if self.reachable:
                log.warning("the fleet manager refused the vehicle list: %s", exc)
            self.reachable = False
            return
        except ManagerUnreachableError as exc:
            if self.reachable:
                log.warning("the fleet manager does not answer: %s", exc)
            self.reachable = False
            self.handle.renew()
            return  # keep the last list: vehicles are not lost because the manager restarts
        self.rows = [r for r in rows if isinstance(r, dict)]
        self.reachable, self.waiting = True, False
        if self.paper_status is not None:
            for row in self.rows:
                if row.get("interface") == PAPER:
                    status = self.paper_status(str(row.get("serial")))
                    if status is not None:
                        self.paper[str(row.get("serial"))] = status

    def vehicles(self) -> dict[str, Vehicle]:
        out = {}
        for row in self.rows:
            key = f"{row.get('topicManufacturer')}/{row.get('serial')}"
            interface = str(row.get("interface"))
            state = self.paper.get(str(row.get("serial"))) if interface == PAPER else row.get("state")
            out[key] = Vehicle(key, str(row.get("serial")), str(row.get("topicManufacturer")), interface,
                               row.get("connectionState") == "ONLINE", str(row.get("connectionState")), state)
        return out

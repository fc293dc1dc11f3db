"""A sub-task for a paper-channel vehicle: the paper's motion and action items, written as NGSI-v2
entities on the context broker over HTTP (the plant's mqtt-ngsi bridge delivers them to the
vehicle's ``motion_channel`` / ``action_channel``); progress read back from the vehicle's entity.

Items (fleet/paper/messages.py; ids from fleet/planner/paperids.py): one motion item to the
sub-task's station, then its actions (pick -> load, drop -> unload, wait -> wait) and, unless the
last one is a wait already, a wait of 0 s that ends the task (Fig. 5, fleet/paper/tasks.py: a
wait action ends a task, and the vehicle takes no other task before). Sequences rise within the
task and start at a number derived from the orderId (paperids.first_sequence), so a status's
``last_finished_sequence`` tells whose motion finished. The motion area is the map's rectangle; the limits are the vehicle's own (its description).

Entities: ``urn:ngsi-ld:Thing:<agv-id>:motion_channel`` and ``...:action_channel`` (type
``Thing``, one attribute per field: the defaults derive mints for those topics, docs/ontology.md;
ontology/examples/agv-fleet.ttl), written with ``PUT /v2/entities/<id>/attrs`` (all attributes
replaced: no field of an earlier item stays behind), created with ``POST /v2/entities`` the first
time. The actions are written only once the vehicle shows the motion accepted (its status names
the task, or the motion finished): the two entities reach the vehicle through different
notifications, and an action arriving before its task's motion would make the motion refused.
What was written is kept in memory; after a restart the motion is written again (the vehicle
ignores an item id it has seen) and the rest follows from the vehicle's status.

The vehicle's status: ``GET /v2/entities/urn:ngsi-ld:AGV:<agv-id>?options=keyValues`` (its status,
movement and description channels merged by the bridge).
"""

from __future__ import annotations

import json
import logging
import ssl
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from typing import Any

from fleet.planner import paperids
from fleet.planner.errors import PlannerError
from fleet.planner.machine import SendOrder
from fleet.planner.ngsi_tls import unreachable
from fleet.sim.map import SiteMap

log = logging.getLogger("fleet.planner")
PAPER_ACTIONS = {"pick": "load", "drop": "unload", "wait": "wait", "startCharging": "charge"}
NGSI_TYPE = {str: "Text", bool: "Boolean", int: "Number", float: "Number"}
DEFAULT_LIMITS = ([1.0, 0.0, 1.0], [0.5, 0.0, 1.0])
MAX_REMEMBERED = 10_000  # orderIds the sender remembers (the oldest are forgotten first)


def motion_entity(agv_id: str) -> str:
    return f"urn:ngsi-ld:Thing:{agv_id}:motion_channel"


def action_entity(agv_id: str) -> str:
    return f"urn:ngsi-ld:Thing:{agv_id}:action_channel"


def status_entity(agv_id: str) -> str:
    return f"urn:ngsi-ld:AGV:{agv_id}"


@dataclass(frozen=True)
class Items:
    task_id: str
    motions: tuple[dict[str, Any], ...]
    actions: tuple[dict[str, Any], ...]

    @property
    def motion_sequences(self) -> frozenset[int]:
        return frozenset(int(m["sequence"]) for m in self.motions)


def _limits(status: dict[str, Any] | None) -> tuple[list[float], list[float]]:
    physical = (status or {}).get("physical")
    try:
        v, a = [float(x) for x in physical["max_velocity"]], [float(x) for x in physical["max_acceleration"]]
        if len(v) == 3 and len(a) == 3 and v[0] > 0 and v[2] > 0 and a[0] > 0 and a[2] > 0:
            return v, a
    except (TypeError, KeyError, ValueError):
        pass
    return list(DEFAULT_LIMITS[0]), list(DEFAULT_LIMITS[1])


def items(send: SendOrder, site: SiteMap, status: dict[str, Any] | None = None, stamp: str = "") -> Items:
    """The paper's items of one sub-task (pure: the same sub-task gives the same items)."""
    oid, header = send.order_id, {"seq": 0, "stamp": stamp or "1970-01-01T00:00:00.000Z", "frame_id": site.map_id}
    velocity, acceleration = _limits(status)
    task = paperids.task_uuid(oid)
    base = paperids.first_sequence(oid)
    area = [[0.0, 0.0], [site.width, 0.0], [site.width, site.height], [0.0, site.height]]
    motions = ({"header": header, "point_id": paperids.point_uuid(send.station), "task_id": task,
                "motion_id": paperids.motion_uuid(oid, 0), "point": [send.x, send.y], "max_velocity": velocity,
                "max_acceleration": acceleration, "motion_area": area, "sequence": base},)
    actions = []
    for i, name in enumerate(send.actions):
        if name not in PAPER_ACTIONS:
            raise PlannerError(f"action {name!r} of {oid} has no paper action (known: {', '.join(PAPER_ACTIONS)})")
        item = {"header": header, "action_id": paperids.action_uuid(oid, i), "task_id": task,
                "action": PAPER_ACTIONS[name], "sequence": base + 1 + i}
        if name == "wait":
            item["duration"] = 1.0
        actions.append(item)
    if not actions or actions[-1]["action"] != "wait":
        actions.append({"header": header, "action_id": paperids.end_uuid(oid), "task_id": task, "action": "wait",
                        "sequence": base + 1 + len(send.actions), "duration": 0.0})
    return Items(task, motions, tuple(actions))


def attributes(item: dict[str, Any]) -> dict[str, Any]:
    """An item as NGSI-v2 attributes, one per field (as FIROS wrote ROS messages)."""
    return {k: {"type": NGSI_TYPE.get(type(v), "StructuredValue"), "value": v} for k, v in item.items()}


def motion_accepted(status: dict[str, Any] | None, plan: Items) -> bool:
    """The vehicle runs the task (any item of it) or has finished its motion, or ended the task."""
    s = status or {}
    if plan.task_id in (s.get("task_id"), s.get("finished_task_id")):
        return True
    return s.get("last_finished_sequence") in plan.motion_sequences and not s.get("task_id")


class NgsiClient:
    """The few NGSI-v2 calls the planner makes, with the broker's write token (over HTTPS verified
    with ``context`` for an ``https://`` broker: fleet/planner/ngsi_tls.py)."""

    def __init__(self, url: str, token: str | None, timeout: float = 2.0, pause: float = 3.0, *,
                 context: ssl.SSLContext | None = None) -> None:
        self.url, self.token, self.timeout, self.context = url.rstrip("/"), token, timeout, context
        self.pause = pause  # s without reads after the broker did not answer (the loop waits on reads)
        self._down_until = float("-inf")

    def _call(self, method: str, path: str, body: Any = None) -> tuple[int, bytes]:
        headers = {"Content-Type": "application/json"} if body is not None else {}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        data = json.dumps(body).encode("utf-8") if body is not None else None
        request = urllib.request.Request(self.url + path, data=data, method=method, headers=headers)
        try:
            with urllib.request.urlopen(request, timeout=self.timeout, context=self.context) as reply:
                return reply.status, reply.read()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read()
        except (urllib.error.URLError, OSError) as exc:
            raise PlannerError(unreachable(self.url, exc)) from None

    def write(self, entity_id: str, item: dict[str, Any]) -> None:
        quoted = urllib.parse.quote(entity_id, safe=":")
        status, body = self._call("PUT", f"/v2/entities/{quoted}/attrs", attributes(item))
        if status == 404:
            status, body = self._call("POST", "/v2/entities", {"id": entity_id, "type": "Thing", **attributes(item)})
        if status >= 300:
            raise PlannerError(f"the context broker refused {entity_id}: {status} "
                               f"{body[:300].decode('utf-8', 'replace')}")

    def read(self, entity_id: str) -> dict[str, Any] | None:
        """The entity (keyValues), or None: absent, or the broker does not answer (then no read is
        tried for ``pause`` s, so a dead broker costs the planner's loop one timeout, not one per tick)."""
        if time.monotonic() < self._down_until:
            return None
        quoted = urllib.parse.quote(entity_id, safe=":")
        try:
            status, body = self._call("GET", f"/v2/entities/{quoted}?options=keyValues")
        except PlannerError as exc:
            log.warning("%s; no status read for %.0f s", exc, self.pause)
            self._down_until = time.monotonic() + self.pause
            return None
        if status != 200:
            return None
        try:
            found = json.loads(body)
        except ValueError:
            return None
        return found if isinstance(found, dict) else None

    def agv_status(self, agv_id: str) -> dict[str, Any] | None:
        return self.read(status_entity(agv_id))


class PaperSender:
    """Writes a sub-task's items for a paper vehicle, motion first, actions once it is accepted.
    Called on every tick while the sub-task is SENT (cheap when nothing is to be written)."""

    def __init__(self, ngsi: NgsiClient, site: SiteMap, rewrite: float = 3.0) -> None:
        self.ngsi, self.site, self.rewrite = ngsi, site, rewrite
        self._motion_at: dict[str, float] = {}  # orderId -> when its motion was written
        self._acted: dict[str, None] = {}  # orderIds whose actions were written (insertion ordered)
        self._retry_at: dict[str, float] = {}  # orderId -> no write before (after a failed one)

    def __call__(self, send: SendOrder, status: dict[str, Any] | None, agv_id: str) -> None:
        oid = send.order_id
        if oid in self._acted or time.monotonic() < self._retry_at.get(oid, float("-inf")):
            return
        try:
            self._write(send, status, agv_id)
        except PlannerError:
            self._retry_at[oid] = time.monotonic() + self.rewrite
            raise
        self._retry_at.pop(oid, None)
        for book in (self._acted, self._motion_at):
            while len(book) > MAX_REMEMBERED:
                del book[next(iter(book))]

    def _write(self, send: SendOrder, status: dict[str, Any] | None, agv_id: str) -> None:
        oid = send.order_id
        plan = items(send, self.site, status, time.strftime("%Y-%m-%dT%H:%M:%S.000Z", time.gmtime()))
        if (status or {}).get("finished_task_id") == plan.task_id:
            self._acted[oid] = None
            return
        if motion_accepted(status, plan):
            for item in plan.actions:
                self.ngsi.write(action_entity(agv_id), item)
            self._acted[oid] = None
            log.info("order %s: %d action item(s) written for %s (task %s)", oid, len(plan.actions), agv_id,
                     plan.task_id)
            return
        if time.monotonic() - self._motion_at.get(oid, float("-inf")) >= self.rewrite:
            for item in plan.motions:
                self.ngsi.write(motion_entity(agv_id), item)
            self._motion_at[oid] = time.monotonic()
            log.info("order %s: motion item to %s written for %s (task %s)", oid, send.station, agv_id, plan.task_id)

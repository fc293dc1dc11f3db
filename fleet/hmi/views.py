"""What the operators' pages show, as pure functions of the LoTLan program, the map, the planner's
snapshot (``GET /v1/tasks``) and the manager's vehicle rows (``GET /v1/vehicles``).

A station's page: the LoTLan tasks that start or end there (the jobs an operator may start), the
planner's tasks that pass there and their jobs' states, and whether a vehicle stands there waiting
for the operator: a sub-task at this station whose actions are done (``ACTED``) waits for its
step's ``FinishedBy`` — "ready to load" when it is a pick, "ready to unload" when it is a drop. The
**Loaded** / **Unloaded** button fires the Boolean Events that ``FinishedBy`` names (value true).

The fleet page: every vehicle with its position (``agvPosition`` of the last VDA 5050 state the
manager's row carries; none for a vehicle that has sent none, e.g. a paper-channel vehicle), its
battery, connection state and the task it holds; the task list filtered by state and vehicle.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from fleet.lotlan.model import Program, Ref, RefKind, expression_names
from fleet.planner.build import station_of
from fleet.planner.errors import BuildError
from fleet.planner.states import TaskState
from fleet.sim.map import SiteMap

HOLDING = ("ASSIGNED", "BEING_PROCESSED")
PROGRESS = ("RAW", "ACTIVE", "ASSIGNED", "BEING_PROCESSED")  # the job's state: its most advanced open task
VEHICLE_FILTER = re.compile(r"[A-Za-z0-9_.:/-]{0,200}")
BUTTONS = {"loaded": "pick", "unloaded": "drop"}  # button -> the action of the sub-task it finishes


class InputError(ValueError):
    """Bad input of a form or query: ``field`` names it, the message says what is accepted."""

    def __init__(self, field: str, message: str, status: int = 400) -> None:
        super().__init__(f"{field}: {message}")
        self.field, self.status = field, status


@dataclass(frozen=True)
class Route:
    """A LoTLan task an operator can start: its transport's two stations."""

    task: str
    pickup: str
    delivery: str

    def to_json(self) -> dict[str, str]:
        return {"task": self.task, "from": self.pickup, "to": self.delivery}


def routes(program: Program, site: SiteMap) -> tuple[Route, ...]:
    out = []
    for task in program.tasks:
        try:
            out.append(Route(task.name, station_of(task.pickup.step.location, site).name,
                             station_of(task.delivery.step.location, site).name))
        except BuildError:
            continue  # the planner refuses such a program at its start; nothing to offer here
    return tuple(out)


def stations(program: Program, site: SiteMap) -> list[dict[str, Any]]:
    """The stations that have a page: every station a LoTLan task starts or ends at, map order."""
    used = {name for r in routes(program, site) for name in (r.pickup, r.delivery)}
    return [{"name": s.name, "x": s.x, "y": s.y} for s in site.stations if s.name in used]


def site_json(site: SiteMap, program: Program) -> dict[str, Any]:
    used = {s["name"] for s in stations(program, site)}
    return {"mapId": site.map_id, "width": site.width, "height": site.height,
            "stations": [{"name": s.name, "x": s.x, "y": s.y, "charger": s.charger, "page": s.name in used}
                         for s in site.stations]}


def finish_events(program: Program, step_name: str) -> list[str]:
    """The Boolean Events a step's FinishedBy names (what a button sets true)."""
    step = next((s for s in program.steps if s.name == step_name), None)
    if step is None or step.finished_by is None:
        return []
    booleans = {e.name for e in program.events if e.type.lower() == "boolean"}
    names = [n.name for n in expression_names(step.finished_by)
             if isinstance(n, Ref) and n.kind is RefKind.EVENT and n.name in booleans]
    return list(dict.fromkeys(names))


def job_state(tasks: list[dict[str, Any]]) -> str:
    states = [str(t.get("state")) for t in tasks]
    if not states:
        return "RAW"
    if all(s == "FINISHED" for s in states):
        return "FINISHED"
    if "FAILED" in states:
        return "FAILED"
    open_states = [s for s in states if s in PROGRESS]
    if not open_states:
        return "WITHDRAWN"
    return max(open_states, key=PROGRESS.index)


def step_text(task: dict[str, Any]) -> str:
    legs = task.get("legs") or []
    current = next((g for g in legs if g.get("state") != "DONE"), None)
    if current is None:
        return "all sub-tasks done" if legs else ""
    return f"{current.get('index')}: {current.get('station')} [{' '.join(current.get('actions') or [])}] " \
           f"{current.get('state')}"


def waiting_at(program: Program, station: str, tasks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The sub-tasks at ``station`` whose actions are done and that wait for the operator."""
    out = []
    for task in tasks:
        if task.get("state") != "BEING_PROCESSED":
            continue
        leg = next((g for g in task.get("legs") or [] if g.get("state") != "DONE"), None)
        if leg is None or leg.get("station") != station or leg.get("state") != "ACTED":
            continue
        actions = leg.get("actions") or []
        kind = "load" if "pick" in actions else "unload" if "drop" in actions else ""
        events = finish_events(program, str(leg.get("step")))
        if kind and events:
            out.append({"task": task.get("id"), "job": task.get("job"), "kind": kind,
                        "vehicle": task.get("vehicle"), "events": events})
    return out


def station_view(program: Program, site: SiteMap, station: str, snapshot: dict[str, Any]) -> dict[str, Any]:
    here = site.station(station)
    tasks = [t for t in snapshot.get("tasks") or [] if isinstance(t, dict)]
    passing = [t for t in tasks if any(g.get("station") == station for g in t.get("legs") or [])]
    jobs: dict[str, list[dict[str, Any]]] = {}
    for t in tasks:
        jobs.setdefault(str(t.get("job")), []).append(t)
    shown = sorted({str(t.get("job")) for t in passing}, key=_job_number, reverse=True)
    waiting = waiting_at(program, station, tasks)
    kinds = {w["kind"] for w in waiting}
    ready = " and ".join(f"ready to {k}" for k in ("load", "unload") if k in kinds)
    return {
        "station": here.name, "x": here.x, "y": here.y,
        "startable": [r.to_json() for r in routes(program, site) if station in (r.pickup, r.delivery)],
        "ready": ready or "", "loadReady": "load" in kinds, "unloadReady": "unload" in kinds, "waiting": waiting,
        "approaching": [{"task": t.get("id"), "vehicle": t.get("vehicle"), "step": step_text(t)} for t in passing
                        if t.get("state") in HOLDING and _current_station(t) == station
                        and not any(w["task"] == t.get("id") for w in waiting)],
        "jobs": [{"job": j, "state": job_state(jobs[j]),
                  "tasks": [_task_row(t) for t in jobs[j]]} for j in shown[:20]],
    }


def _current_station(task: dict[str, Any]) -> str | None:
    leg = next((g for g in task.get("legs") or [] if g.get("state") != "DONE"), None)
    return None if leg is None else leg.get("station")


def _job_number(job: str) -> tuple[int, str]:
    digits = re.sub(r"\D", "", job)
    return (int(digits) if digits else 0, job)


def _task_row(t: dict[str, Any]) -> dict[str, Any]:
    purpose = str(t.get("purpose") or "job")  # park / charge: a task the planner made (no LoTLan task)
    return {"id": t.get("id"), "job": t.get("job"), "purpose": purpose,
            "lotlanTask": t.get("lotlanTask") or (f"({purpose})" if purpose != "job" else ""), "state": t.get("state"),
            "vehicle": t.get("vehicle") or "", "step": step_text(t), "updated": t.get("updated", ""),
            "reason": t.get("reason", "")}


def check_start(program: Program, site: SiteMap, station: str, task: Any) -> str:
    """The LoTLan task to start at ``station``; InputError naming ``task`` otherwise."""
    offered = [r.task for r in routes(program, site) if station in (r.pickup, r.delivery)]
    if not isinstance(task, str) or task not in offered:
        raise InputError("task", f"{str(task)[:80]!r} is no LoTLan task of station {station} "
                                 f"(its tasks: {', '.join(offered) or 'none'})")
    return task


def button_events(program: Program, station: str, button: str, tasks: list[dict[str, Any]]) -> list[str]:
    """The Events the **Loaded** / **Unloaded** button at ``station`` fires now; InputError (409)
    when nothing there waits for it."""
    if button not in BUTTONS:
        raise InputError("button", f"{button[:40]!r}: the buttons are {', '.join(BUTTONS)}", 404)
    kind = "load" if button == "loaded" else "unload"
    waiting = [w for w in waiting_at(program, station, tasks) if w["kind"] == kind]
    if not waiting:
        raise InputError("button", f"nothing at {station} is ready to {kind} now", 409)
    return list(dict.fromkeys(e for w in waiting for e in w["events"]))


TASK_ID = re.compile(r"[A-Za-z0-9_.-]{1,200}")


def check_task_id(task_id: str) -> str:
    if not TASK_ID.fullmatch(task_id):
        raise InputError("task", f"{task_id[:80]!r} is no task id (letters, digits, _ . -, e.g. j1-transport-1)")
    return task_id


def check_filters(state: str | None, vehicle: str | None) -> tuple[str, str]:
    state, vehicle = (state or "").strip(), (vehicle or "").strip()
    known = [s.value for s in TaskState]
    if state and state not in (*known, "open"):
        raise InputError("state", f"{state[:40]!r} is no task state (one of: open, {', '.join(known)})")
    if not VEHICLE_FILTER.fullmatch(vehicle):
        raise InputError("vehicle", "a vehicle is manufacturer/serial or a serial: letters, digits, _ . : / -, "
                                    "at most 200 characters")
    return state, vehicle


def filter_tasks(tasks: list[dict[str, Any]], state: str, vehicle: str) -> list[dict[str, Any]]:
    rows = [_task_row(t) for t in tasks if isinstance(t, dict)]
    if state == "open":
        rows = [r for r in rows if r["state"] in PROGRESS]
    elif state:
        rows = [r for r in rows if r["state"] == state]
    if vehicle:
        rows = [r for r in rows if r["vehicle"] == vehicle or r["vehicle"].split("/")[-1] == vehicle]
    return sorted(rows, key=lambda r: (_job_number(str(r["job"])), str(r["id"])), reverse=True)


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None


def vehicle_rows(rows: list[dict[str, Any]], tasks: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The manager's rows with position (``state.agvPosition``), battery and the task each holds."""
    holding = {str(t.get("vehicle")): t for t in tasks if isinstance(t, dict) and t.get("state") in HOLDING}
    out = []
    for row in rows:
        key = f"{row.get('topicManufacturer') or row.get('manufacturer')}/{row.get('serial')}"
        state = row.get("state") if isinstance(row.get("state"), dict) else {}
        position = state.get("agvPosition")
        position = position if isinstance(position, dict) else {}
        battery = _number(state.get("batteryCharge"))
        task = holding.get(key)
        x, y = _number(position.get("x")), _number(position.get("y"))
        out.append({"key": key, "serial": row.get("serial"), "name": row.get("name") or "",
                    "interface": str(row.get("interface") or ""), "pinned": row.get("pinned") is True,
                    "connectionState": row.get("connectionState"), "battery": battery,
                    "driving": bool(state.get("driving")),
                    "x": x, "y": y, "theta": _number(position.get("theta")) or 0.0,
                    "task": task.get("id") if task else "", "taskState": task.get("state") if task else "",
                    "step": step_text(task) if task else ""})
    return sorted(out, key=lambda v: v["key"])


MAX_REFUSED = 50


def refused_rows(status: Any) -> list[dict[str, str]]:
    """The vehicles plug and play refused, with their reasons, from the manager's ``status.json``
    (its ``refused`` list; anything malformed is left out, never an error)."""
    items = status.get("refused") if isinstance(status, dict) else None
    out = []
    for item in items if isinstance(items, list) else []:
        if isinstance(item, dict) and isinstance(item.get("vehicle"), str):
            out.append({"vehicle": item["vehicle"], "reason": str(item.get("reason") or "")[:500]})
    return out[:MAX_REFUSED]

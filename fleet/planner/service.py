"""The planner's loop: journal -> tasks; vehicles -> transitions; SPARQL -> assignments; orders out.

One lock guards the planner's state; the loop (every ``tick`` s; the vehicle list is refreshed
every ``refresh`` s) and the HTTP API (start a job, fire an event, withdraw a task) take it. Every change is
journaled (fsync'd) before it is acted upon; so after kill -9 the planner restarts from
``journal.jsonl``: tasks in their last state, sub-tasks already DONE stay done, a sub-task that
was SENT is re-sent with the same orderId unless the vehicle's state already shows it (a vehicle
ignores an order it has), follow-up tasks (Repeat, OnDone) are created if they are missing (ids
are deterministic: ``<job>-<task>-<run>``, so nothing is created twice).

Idle vehicles (fleet/planner/idle.py): with ``waiting_area`` set, the vehicle of a job task that
finished gets a ``park`` task ``<task>-park`` to the waiting area (the paper's steps 10-11); a
vehicle below ``min_battery`` that no job holds gets a ``charge`` task ``charge-<serial>-<n>`` to
the nearest free charger (``startCharging`` there). Neither holds its vehicle: a job assigned to it
withdraws them (``cancelOrder`` when their order was sent, ``stopCharging`` when it charges).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fleet.discovery.records import now_iso
from fleet.lotlan import cycles
from fleet.lotlan.model import Program
from fleet.planner import build, idle, machine
from fleet.planner.assign import Need, choose
from fleet.planner.errors import PlannerError
from fleet.planner.journal import Journal
from fleet.planner.machine import Now, Rules, SendOrder
from fleet.planner.model import Task
from fleet.planner.ngsi import TaskPublisher
from fleet.planner.plantview import PlantView
from fleet.planner.states import LegState, TaskState
from fleet.planner.vehicles import Fleet, Vehicle
from fleet.sim.map import SiteMap

log = logging.getLogger("fleet.planner")
HOLDING = (TaskState.ASSIGNED, TaskState.BEING_PROCESSED)
EVENT_TYPES: dict[str, tuple[type, ...]] = {"boolean": (bool,), "integer": (int,), "float": (int, float),
                                             "number": (int, float), "string": (str,)}


class RequestError(PlannerError):
    """A request the planner refuses: ``status`` is the HTTP status, the message names the field."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


@dataclass(frozen=True)
class PlannerConfig:
    site: SiteMap
    min_battery: float = 20.0
    tick: float = 0.1
    refresh: float = 0.3
    resend: float = 3.0
    settle: float = 5.0  # s after start to hear every online vehicle's position before assigning
    paper: bool = False  # paper-channel vehicles can be sent to (the planner has the context broker)
    waiting_area: str | None = None  # None: vehicles stay where they finished; "park" or a LoTLan Location
    charging: bool = True  # a vehicle below min_battery that no job holds is sent to a charger


def rules_of(program: Program) -> dict[str, Rules]:
    return {t.name: Rules(t.triggered_by, t.finished_by, tuple((u.step.triggered_by, u.step.finished_by)
                                                                for u in (t.pickup, t.delivery)))
            for t in program.tasks}


class Planner:
    def __init__(self, config: PlannerConfig, program: Program, journal: Journal, fleet: Fleet, plant: PlantView,
                 send: Callable[[SendOrder, Vehicle], None], publisher: TaskPublisher | None = None,
                 cancel: Callable[[Vehicle], bool] | None = None,
                 stop_charging: Callable[[Vehicle], None] | None = None) -> None:
        build.check_program(program, config.site)
        self.waiting = idle.waiting_area(config.waiting_area, program, config.site)
        self.stop_charging = stop_charging
        self.config, self.program, self.journal = config, program, journal
        self.fleet, self.plant, self.send, self.publisher = fleet, plant, send, publisher
        self.cancel = cancel
        self.cancels: dict[str, str] = {}  # vehicle key -> orderId to cancel there (not sent yet)
        self.rules = rules_of(program)
        self.lock = threading.RLock()
        replayed = journal.state
        self.tasks: dict[str, Task] = dict(replayed.tasks)
        self.events: list[dict[str, Any]] = list(replayed.events)
        self.jobs: dict[str, list[str]] = dict(replayed.jobs)
        self.last_sent: dict[str, float] = {}
        self.assign_seconds: deque[float] = deque(maxlen=10_000)
        self._unfit: set[str] = set()  # tasks no vehicle fits (logged once)
        self._stop = threading.Event()
        self.started = time.monotonic()
        self._unplaced: set[str] = set()  # orders waiting for their vehicle's position (logged once)
        if self.tasks:
            log.info("resuming %d task(s) of %d job(s) from %s", len(self.tasks), len(self.jobs), journal.path)
        for task in self.tasks.values():
            if not task.service and task.lotlan_task not in self.rules:
                raise PlannerError(f"the journal has task {task.id} of LoTLan task {task.lotlan_task!r}, which "
                                   "the LoTLan file no longer has", hint="start with the same LoTLan file, or "
                                   "another --data-dir")

    # ------------------------------------------------------------------ state
    def _record(self, task: Task, note: str) -> None:
        self.journal.task(task, note)
        self.tasks[task.id] = task
        log.info("task %s: %s [%s%s]", task.id, note, task.state.value, f" {task.vehicle}" if task.vehicle else "")
        if self.publisher is not None:
            self.publisher.publish(task)

    def _events_after(self, number: int) -> dict[str, Any]:
        return {e["event"]: e["value"] for e in self.events if e["number"] > number}

    def done(self) -> dict[str, frozenset[str]]:
        out: dict[str, set[str]] = {}
        for t in self.tasks.values():
            if t.state is TaskState.FINISHED and t.run >= t.repeat and not t.service:
                out.setdefault(t.job, set()).add(t.lotlan_task)
        return {job: frozenset(names) for job, names in out.items()}

    def _now(self, vehicles: dict[str, Vehicle]) -> Now:
        return Now(len(self.events), self._events_after, self.done(), {k: v.view() for k, v in vehicles.items()},
                   now_iso())

    def _create(self, job: str, name: str, run: int) -> None:
        task_id = f"{job}-{name}-{run}"
        if task_id not in self.tasks:
            task = build.build_task(task_id, job, self.program.task(name), run, self.config.site,
                                    armed=len(self.events), at=now_iso())
            self._record(task, "created")

    def _follow_ups(self) -> None:
        for job, names in self.jobs.items():
            for name in names:
                self._create(job, name, 1)
        for task in list(self.tasks.values()):
            if task.state is not TaskState.FINISHED or task.service:
                continue
            if task.run < task.repeat:
                self._create(task.job, task.lotlan_task, task.run + 1)
            else:
                for name, _ in cycles.follow_ups(self.program.task(task.lotlan_task)):
                    self._create(task.job, name, 1)

    # ------------------------------------------------------------------ the loop
    def stop(self) -> None:
        self._stop.set()

    def run(self) -> None:
        next_refresh = 0.0
        with self.lock:
            if self.publisher is not None:
                for task in self.tasks.values():
                    self.publisher.publish(task)
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_refresh:
                self.fleet.refresh()
                next_refresh = now + self.config.refresh
            with self.lock:
                self.tick()
            self._stop.wait(self.config.tick)

    def tick(self) -> None:
        self._follow_ups()
        vehicles = self.fleet.vehicles()
        if self.fleet.reachable:  # not while the manager is away or loading (503): nobody is lost then
            self._lost(vehicles)
        self._send_cancels(vehicles)
        self._advance_all(vehicles)
        self._assign(vehicles)
        if self.config.charging and self.fleet.reachable:
            self._charge(vehicles)
        self._resend(vehicles)

    def _lost(self, vehicles: dict[str, Vehicle]) -> None:
        """A held vehicle that reports OFFLINE / CONNECTIONBROKEN, or that the manager no longer
        lists (a person removed it), is lost. Only called with a list from a manager that has
        loaded its records (it answers 503 NotReady before: the planner waits)."""
        for task in list(self.tasks.values()):
            if task.state not in HOLDING:
                continue
            vehicle = vehicles.get(task.vehicle)
            if vehicle is None or not vehicle.online:
                why = "is no longer known" if vehicle is None else f"is {vehicle.connection_state}"
                if task.service:  # nobody else is sent to its waiting area or charger
                    self._record(machine.withdraw(task, f"vehicle {task.vehicle} {why}", now_iso()),
                                 f"vehicle {task.vehicle} {why}: withdrawn")
                    continue
                self._record(machine.vehicle_lost(task, f"vehicle {task.vehicle} {why}; re-assigning", now_iso()),
                             f"vehicle {task.vehicle} {why}: back to ACTIVE")

    def _advance(self, task: Task, vehicles: dict[str, Vehicle]) -> None:
        steps, sends = machine.advance(task, self.rules.get(task.lotlan_task, Rules()), self._now(vehicles))
        for moved, note in steps:
            self._record(moved, note)
        for order in sends:  # after the journal has them (write-ahead)
            self._send(order, vehicles)
        if steps and steps[-1][0].state is TaskState.FINISHED and not task.service:
            self._park(steps[-1][0], vehicles)

    def _advance_all(self, vehicles: dict[str, Vehicle]) -> None:
        for task_id in list(self.tasks):
            if not self.tasks[task_id].state.final:
                self._advance(self.tasks[task_id], vehicles)

    def _assign(self, vehicles: dict[str, Vehicle]) -> None:
        waiting = [t for t in self.tasks.values() if t.state is TaskState.ACTIVE and not t.service]
        if not waiting or not self.fleet.reachable:
            return
        unheard = sorted(k for k, v in vehicles.items() if v.online and v.position() is None)
        if unheard and time.monotonic() - self.started < self.config.settle:
            return  # nearest first needs every position: wait (a little) for their states
        store = self.plant.current()
        for task in waiting:
            held = {t.vehicle for t in self.tasks.values() if t.state in HOLDING and not t.service} | set(self.cancels)
            if not any(v.online and k not in held for k, v in vehicles.items()):
                return  # nobody free: no query to run
            leg = task.current
            if leg is None:
                continue
            need = Need("pick", "drop", leg.x, leg.y, payload=0.0, min_battery=self.config.min_battery,
                        also=(("paper-channels", "load", "unload"),) if self.config.paper else ())
            live = [v.live(idle=v.key not in held) for v in vehicles.values()]
            choice = choose(store, live, need)
            self.assign_seconds.append(choice.seconds)
            if choice.vehicle is None:
                if task.id not in self._unfit:
                    self._unfit.add(task.id)
                    log.info("task %s waits: %s", task.id, choice.explain())
                continue
            self._unfit.discard(task.id)
            self._free(choice.vehicle, vehicles, f"job task {task.id} needs it")
            self._record(machine.assign(task, choice.vehicle, choice.explain(), now_iso()),
                         f"ACTIVE -> ASSIGNED to {choice.vehicle} in {choice.seconds * 1000:.1f} ms; {choice.explain()}")
            self._advance(self.tasks[task.id], vehicles)

    # ------------------------------------------------------------------ idle vehicles
    def _service_of(self, key: str) -> Task | None:
        return next((t for t in self.tasks.values() if t.service and t.vehicle == key and t.state in HOLDING), None)

    def _busy(self, key: str) -> bool:
        return any(t.vehicle == key and t.state in HOLDING for t in self.tasks.values())

    def _targets(self, purpose: str) -> set[str]:
        return {t.legs[0].station for t in self.tasks.values() if t.purpose == purpose and t.state in HOLDING}

    def _free(self, key: str, vehicles: dict[str, Vehicle], why: str) -> None:
        """Before a job takes ``key``: withdraw its park/charge task (cancelOrder first when its
        order was sent) and stop its charging (a charging vehicle does not drive)."""
        service = self._service_of(key)
        if service is not None:
            leg = service.current
            if leg is not None and leg.state is LegState.SENT:
                self.cancels[key] = leg.order_id
            self._record(machine.withdraw(service, why, now_iso()), f"withdrawn: {why}")
            self._send_cancels(vehicles)
            self.cancels.pop(key, None)  # sent, or retried by the order's resend if the vehicle refuses
        vehicle = vehicles.get(key)
        if vehicle is not None and vehicle.charging() and self.stop_charging is not None:
            try:
                self.stop_charging(vehicle)
                log.info("stopCharging sent to %s: %s", key, why)
            except PlannerError as exc:
                log.warning("stopCharging to %s not sent (%s)", key, exc)

    def _park(self, finished: Task, vehicles: dict[str, Vehicle]) -> None:
        """The paper's steps 10-11: the vehicle of a finished job task goes to the waiting area,
        unless another task holds it, it is low (a charger comes first) or there is no waiting area."""
        key = finished.vehicle
        vehicle = vehicles.get(key)
        task_id = f"{finished.id}-park"
        if self.config.waiting_area is None or task_id in self.tasks or vehicle is None or self._busy(key):
            return
        if self.config.charging and idle.needs_charge(vehicle.battery(), vehicle.charging(), self.config.min_battery):
            return
        pos = vehicle.position() or (finished.legs[-1].x, finished.legs[-1].y)
        station = idle.park_station(self.waiting, self.config.site, pos[0], pos[1], self._targets(idle.PARK))
        if station is None:
            log.info("no free waiting area for %s: it stays at %s", key, finished.legs[-1].station)
            return
        task = idle.service_task(task_id, finished.job, idle.PARK, key, station,
                                 f"{finished.id} finished: back to the waiting area {station.name}", now_iso())
        self._record(task, f"created: {key} to the waiting area {station.name}")
        self._advance(task, vehicles)

    def _charge(self, vehicles: dict[str, Vehicle]) -> None:
        """A vehicle below min_battery that no job holds goes to the nearest free charger."""
        for key, vehicle in sorted(vehicles.items()):
            if not vehicle.online or not idle.needs_charge(vehicle.battery(), vehicle.charging(),
                                                           self.config.min_battery):
                continue
            service = self._service_of(key)
            if (service is not None and service.purpose == idle.CHARGE) or key in self.cancels:
                continue
            if any(t.vehicle == key and t.state in HOLDING and not t.service for t in self.tasks.values()):
                continue  # it finishes its job first
            pos = vehicle.position()
            if pos is None or self._charged_there(vehicle.serial, pos):
                continue
            station = idle.charger(self.config.site, pos[0], pos[1], self._targets(idle.CHARGE))
            if station is None:
                continue
            if service is not None:
                self._free(key, vehicles, f"battery {vehicle.battery():.0f} % < {self.config.min_battery:g} %")
            n = 1 + sum(1 for t in self.tasks if t.startswith(f"charge-{vehicle.serial}-"))
            task = idle.service_task(f"charge-{vehicle.serial}-{n}", "planner", idle.CHARGE, key, station,
                                     f"battery {vehicle.battery():.0f} % < {self.config.min_battery:g} %: "
                                     f"to charger {station.name}", now_iso())
            self._record(task, f"created: {key} to charger {station.name}")
            self._advance(task, vehicles)

    def _charged_there(self, serial: str, pos: tuple[float, float]) -> bool:
        """Its last charge task finished at the charger it stands on (its state says charging soon)."""
        mine = [t for t in self.tasks.values() if t.id.startswith(f"charge-{serial}-")]
        last = max(mine, key=lambda t: t.created, default=None)
        at = self.config.site.charger_at(*pos)
        return last is not None and last.state is TaskState.FINISHED and at is not None \
            and at.name == last.legs[0].station

    def _send(self, order: SendOrder, vehicles: dict[str, Vehicle]) -> None:
        vehicle = vehicles.get(order.vehicle)
        self.last_sent[order.order_id] = time.monotonic()
        if vehicle is None or (not vehicle.paper and vehicle.position() is None):  # its state comes soon
            self.last_sent[order.order_id] -= self.config.resend - 0.25  # try again in 0.25 s
            if order.order_id not in self._unplaced:
                self._unplaced.add(order.order_id)
                log.info("order %s: no position of %s heard yet; sending it once there is", order.order_id,
                         order.vehicle)
            return
        try:
            self.send(order, vehicle)
        except PlannerError as exc:
            log.warning("order %s to %s not sent (%s); will resend", order.order_id, order.vehicle, exc)

    def _resend(self, vehicles: dict[str, Vehicle]) -> None:
        now = time.monotonic()
        for task in self.tasks.values():
            leg = task.current
            if task.state is not TaskState.BEING_PROCESSED or leg is None or leg.state is not LegState.SENT:
                continue
            vehicle = vehicles.get(task.vehicle)
            if vehicle is not None and vehicle.paper:  # the paper sender writes what is due (or nothing)
                self._send(SendOrder(task.id, leg.index, task.vehicle, leg.order_id, leg.station, leg.x, leg.y,
                                     leg.actions), vehicles)
                continue
            if vehicle is not None and vehicle.view().order_id == leg.order_id:
                continue
            if now - self.last_sent.get(leg.order_id, float("-inf")) >= self.config.resend:
                log.info("order %s: %s does not show it; sending it (again)", leg.order_id, task.vehicle)
                self._send(SendOrder(task.id, leg.index, task.vehicle, leg.order_id, leg.station, leg.x, leg.y,
                                     leg.actions), vehicles)

    # ------------------------------------------------------------------ API
    def start_job(self, names: list[str] | None) -> dict[str, Any]:
        known = [t.name for t in self.program.tasks]
        names = names if names else [t.name for t in self.program.start_tasks()]
        for name in names:
            if name not in known:
                raise RequestError(400, f"tasks: {name!r} is no Task of {self.program.file} "
                                        f"(its tasks: {', '.join(known)})")
        with self.lock:
            job = f"j{len(self.jobs) + 1}"
            self.journal.append("job", job=job, tasks=names, at=now_iso())
            self.jobs[job] = list(names)
            self._follow_ups()
            return {"job": job, "tasks": [f"{job}-{n}-1" for n in names]}

    def fire(self, name: Any, value: Any) -> dict[str, Any]:
        if not isinstance(name, str) or not name:
            raise RequestError(400, f"event: expected the name of an Event, got {name!r}"[:300])
        event = next((e for e in self.program.events if name in (e.name, e.physical_name)), None)
        if event is None:
            raise RequestError(404, f"event: {name!r} is no Event of {self.program.file} "
                                    f"({', '.join(e.name for e in self.program.events) or 'it has none'})")
        allowed = EVENT_TYPES.get(event.type.lower())
        if allowed and (not isinstance(value, allowed) or (bool not in allowed and isinstance(value, bool))):
            raise RequestError(400, f"value: Event {event.name} is of type {event.type}, got {value!r}"[:300])
        with self.lock:
            number = len(self.events) + 1
            record = {"number": number, "event": event.name, "value": value, "at": now_iso()}
            self.journal.append("event", **record)
            self.events.append(record)
            log.info("event %s = %r (number %d)", event.name, value, number)
            return record

    def withdraw(self, task_id: str) -> dict[str, Any]:
        with self.lock:
            task = self.tasks.get(task_id)
            if task is None:
                raise RequestError(404, f"no task {task_id!r}")
            if task.state.final:
                raise RequestError(409, f"task {task_id} is {task.state.value} already")
            leg = task.current
            if task.state in HOLDING and leg is not None and leg.state is LegState.SENT:
                self.cancels[task.vehicle] = leg.order_id  # before any other order can reach it
            self._record(machine.withdraw(task, "withdrawn by an operator", now_iso()), "withdrawn")
            self._send_cancels(self.fleet.vehicles())
            return self.tasks[task_id].to_json()

    def _send_cancels(self, vehicles: dict[str, Vehicle]) -> None:
        """``cancelOrder`` to each vehicle a SENT sub-task was taken from while it is ONLINE; the
        vehicle takes no new task until it was sent (or the vehicle is gone / not ONLINE)."""
        for key, order_id in list(self.cancels.items()):
            vehicle = vehicles.get(key)
            if self.cancel is None or vehicle is None or not vehicle.online or vehicle.paper:
                del self.cancels[key]
                continue
            try:
                sent = self.cancel(vehicle)
            except PlannerError as exc:
                log.warning("cancelOrder for %s to %s not sent (%s); will retry", order_id, key, exc)
                continue
            del self.cancels[key]
            log.info("cancelOrder %s to %s (order %s taken from it)", "sent" if sent else "not needed", key, order_id)

    def snapshot(self) -> dict[str, Any]:
        with self.lock:
            return {"tasks": [t.to_json() for t in self.tasks.values()], "jobs": dict(self.jobs),
                    "events": len(self.events)}

    def task_json(self, task_id: str) -> dict[str, Any]:
        with self.lock:
            task = self.tasks.get(task_id)
            if task is None:
                raise RequestError(404, f"no task {task_id!r}")
            return task.to_json()

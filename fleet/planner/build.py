"""A LoTLan ``Task`` -> planner :class:`~fleet.planner.model.Task`, its locations resolved to map
stations.

A LoTLan ``Location``'s ``name`` attribute (its physical name) is the station of the map
(fleet/sim/map.py); when the map has no station of that name, the Location's own name is tried.
``Transport From P To D`` becomes the items ``Motion(P), Act(pick), Motion(D), Act(drop)`` which
:func:`fleet.planner.split.split` cuts into two sub-tasks (an action is never followed by a
motion inside one). :func:`check_program` refuses, before anything starts, a program whose
locations are not on the map or whose conditions name a ``Time`` (cron triggers are not planned
yet), each problem with file:line.
"""

from __future__ import annotations

from fleet.lotlan.model import Expr, Location, Program, Ref, RefKind, Task as LotlanTask, expression_names
from fleet.planner.errors import BuildError
from fleet.planner.model import Leg, Task
from fleet.planner.split import Act, Motion, split
from fleet.sim.map import MapError, SiteMap, Station

PICK, DROP = "pick", "drop"


def station_of(location: Location, site: SiteMap) -> Station:
    for name in (location.physical_name, location.name):
        try:
            return site.station(name)
        except MapError:
            continue
    raise BuildError(f"Location {location.name} (name {location.physical_name!r}) is no station of map "
                     f"{site.map_id!r}", hint="set the Location's name to a station of the map "
                     f"({', '.join(s.name for s in site.stations[:8])}, ...)")


def _conditions(program: Program) -> list[tuple[str, Expr]]:
    out: list[tuple[str, Expr]] = []
    for step in program.steps:
        out += [(f"TransportOrderStep {step.name}", e) for e in (step.triggered_by, step.finished_by) if e]
    for task in program.tasks:
        out += [(f"Task {task.name}", e) for e in (task.triggered_by, task.finished_by) if e]
    return out


def check_program(program: Program, site: SiteMap) -> None:
    """Raise one :class:`BuildError` listing every problem (file:line: what to change)."""
    problems = []
    for step in program.steps:
        try:
            station_of(step.location, site)
        except BuildError as exc:
            problems.append(f"{program.file}:{step.location.at.line}: {exc.message}")
    for where, expr in _conditions(program):
        for name in expression_names(expr):
            if isinstance(name, Ref) and name.kind is RefKind.TIME:
                problems.append(f"{program.file}:{name.at.line}: {where} waits for Time {name.name}: "
                                "time triggers are not planned yet; use an Event (an operator's button)")
    if problems:
        raise BuildError("; ".join(problems), hint="fix the LoTLan file or the map, then start again")


def items_of(task: LotlanTask, site: SiteMap) -> tuple[Motion | Act, ...]:
    pickup, delivery = task.pickup.step, task.delivery.step
    p, d = station_of(pickup.location, site), station_of(delivery.location, site)
    return (Motion(p.name, p.x, p.y, pickup.name), Act(PICK, pickup.name),
            Motion(d.name, d.x, d.y, delivery.name), Act(DROP, delivery.name))


def legs_of(items: tuple[Motion | Act, ...]) -> tuple[Leg, ...]:
    legs = []
    for i, subtask in enumerate(split(items)):
        motions = [m for m in subtask if isinstance(m, Motion)]
        if len(motions) != 1:
            raise BuildError(f"sub-task {i} has {len(motions)} motions; the planner sends one station per sub-task")
        m = motions[0]
        legs.append(Leg(i, m.step, m.station, m.x, m.y, tuple(a.action for a in subtask if isinstance(a, Act))))
    return tuple(legs)


def build_task(task_id: str, job: str, task: LotlanTask, run: int, site: SiteMap, *, armed: int = 0,
               at: str = "") -> Task:
    return Task(task_id, job, task.name, run, task.repeat, legs_of(items_of(task, site)), armed=armed,
                created=at, updated=at)

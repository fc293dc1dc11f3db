"""What an idle vehicle does, pure: back to the waiting area after a job, to a charger when low.

The paper's workflow ends (step 10-11) with the planner sending the vehicle to the waiting area;
a vehicle whose battery is below ``--min-battery`` takes no work (fleet/planner/assign.rq) and goes
to a charger instead. Both are tasks the planner makes itself (:attr:`Task.purpose` ``park`` /
``charge``) with one sub-task: drive to the station (``park``: no action; ``charge``:
``startCharging`` there). They never hold a vehicle from a job: a job assigned to the vehicle
withdraws them (fleet/planner/service.py).

The waiting area (``--waiting-area``): ``park`` picks the nearest ``park-*`` spot of the map that
no other vehicle is being sent to (each vehicle its own spot); any other value names a LoTLan
``Location`` of the program (its station on the map, fleet/planner/build.py) shared by all. A
charger is the nearest charger station no other vehicle is being sent to.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

from fleet.lotlan.model import Program
from fleet.planner.build import station_of
from fleet.planner.errors import BuildError
from fleet.planner.model import Leg, Task
from fleet.planner.states import TaskState
from fleet.sim.map import SiteMap, Station

PARK, CHARGE = "park", "charge"
ACTIONS = {PARK: (), CHARGE: ("startCharging",)}


def waiting_area(spec: str | None, program: Program, site: SiteMap) -> Station | None:
    """The shared waiting area named by ``spec`` (None for ``park`` / off); BuildError when the
    name is no Location of the program (file:line of nothing: the program's Locations listed)."""
    if spec is None or spec == PARK:
        if spec == PARK and not any(s.name.startswith("park-") for s in site.stations):
            raise BuildError(f"--waiting-area park: map {site.map_id!r} has no park-* station",
                             hint="add park-* stations to the map or name a Location of the LoTLan file")
        return None
    for location in program.locations:
        if spec in (location.name, location.physical_name):
            return station_of(location, site)
    raise BuildError(f"--waiting-area {spec!r} is no Location of {program.file} "
                     f"(its Locations: {', '.join(loc.name for loc in program.locations) or 'none'})",
                     hint="name a Location of the LoTLan file, or use --waiting-area park")


def nearest(stations: Iterable[Station], x: float, y: float, taken: Iterable[str] = ()) -> Station | None:
    """The station nearest (x, y) whose name is not taken (ties: by name)."""
    busy = set(taken)
    free = [s for s in stations if s.name not in busy]
    return min(free, key=lambda s: (math.hypot(s.x - x, s.y - y), s.name), default=None)


def park_station(shared: Station | None, site: SiteMap, x: float, y: float, taken: Iterable[str]) -> Station | None:
    if shared is not None:
        return shared
    return nearest((s for s in site.stations if s.name.startswith("park-")), x, y, taken)


def charger(site: SiteMap, x: float, y: float, taken: Iterable[str]) -> Station | None:
    return nearest((s for s in site.stations if s.charger), x, y, taken)


def needs_charge(battery: float | None, charging: bool, min_battery: float) -> bool:
    """Below the minimum and not charging already (an unknown battery is not low)."""
    return battery is not None and battery < min_battery and not charging


def service_task(task_id: str, job: str, purpose: str, vehicle: str, station: Station, reason: str,
                 at: str = "") -> Task:
    """A planner-made task, ASSIGNED to ``vehicle`` from the start (nobody else is asked)."""
    if purpose not in ACTIONS:
        raise ValueError(f"purpose must be one of {', '.join(ACTIONS)}, got {purpose!r}")
    leg = Leg(0, purpose, station.name, station.x, station.y, ACTIONS[purpose])
    return Task(task_id, job, "", 1, 1, (leg,), TaskState.ASSIGNED, vehicle, reason=reason, created=at, updated=at,
                purpose=purpose)

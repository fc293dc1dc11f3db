"""The ideals the task-planner benchmark (bench_fleet_tasks.py) compares its makespan with.

- :func:`loaded_only` (issue 12's first reading): the orders' loaded legs — pickup -> drop in a
  straight line, the continuous trapezoid at ``v_max``/``a_max`` — plus pick and drop, summed and
  divided by the number of vehicles. It leaves out the empty runs to the pickups and the turns in
  place, which no planner can avoid: the gap to it is mostly those, not the planner.
- :func:`executed` (what the goal is judged on): the legs as executed — for each vehicle, its
  tasks in the order it was given them, the empty run from where it stood to the pickup and the
  loaded leg to the drop, each a turn in place to face the goal (the simulator's unicycle turns
  before it drives: the trapezoid at ``omega_max``/``alpha_max`` over the angle) and the straight
  drive (the trapezoid at ``v_max``/``a_max`` over the distance), plus pick and drop. A vehicle's
  total is the time it cannot do without; the busiest vehicle's total is the makespan a planner
  without any overhead would reach with these assignments, when vehicles never wait on each
  other (they share no station at once and the simulator has no collisions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol


class OrderLike(Protocol):
    name: str
    pickup: str
    drop: str


@dataclass(frozen=True)
class Limits:
    v_max: float
    a_max: float
    omega_max: float
    alpha_max: float
    pick: float
    drop: float


def trapezoid_seconds(distance: float, v_max: float, a_max: float) -> float:
    """Time to drive ``distance`` from rest to rest with speed ``v_max`` and acceleration ``a_max``:
    ``d/v + v/a`` when the vehicle reaches ``v_max`` (``d >= v²/a``), else the triangle ``2·sqrt(d/a)``."""
    if distance < 0 or v_max <= 0 or a_max <= 0:
        raise ValueError(f"distance >= 0, v_max > 0, a_max > 0 expected, got {distance}, {v_max}, {a_max}")
    if distance >= v_max * v_max / a_max:
        return distance / v_max + v_max / a_max
    return 2.0 * math.sqrt(distance / a_max)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def loaded_only(all_orders: list[OrderLike], at: dict[str, tuple[float, float]], vehicles: int,
                limits: Limits) -> dict[str, Any]:
    per_order = [trapezoid_seconds(math.dist(at[o.pickup], at[o.drop]), limits.v_max, limits.a_max)
                 + limits.pick + limits.drop for o in all_orders]
    total = sum(per_order)
    return {"order_seconds_sum": total, "makespan_s": total / vehicles,
            "loaded_leg_s": {o.name: trapezoid_seconds(math.dist(at[o.pickup], at[o.drop]), limits.v_max,
                                                       limits.a_max) + limits.drop for o in all_orders},
            "orders_per_min": len(all_orders) / (total / vehicles) * 60}


def executed(carried: dict[str, list[OrderLike]], start: dict[str, tuple[float, float, float]],
             at: dict[str, tuple[float, float]], limits: Limits) -> dict[str, Any]:
    """Per vehicle (``carried``: its orders in the order it was given them; ``start``: its pose
    x, y, theta when the job began) the time its legs take at best, split into driving, turning
    and actions; ``busiest_s`` is the largest total, ``mean_s`` the sum over the vehicles."""
    rows: dict[str, dict[str, float]] = {}
    for vehicle, its_orders in carried.items():
        x, y, theta = start[vehicle]
        row = {"drive_s": 0.0, "turn_s": 0.0, "action_s": 0.0, "distance_m": 0.0, "empty_m": 0.0}
        for order in its_orders:
            for station, action, empty in ((order.pickup, limits.pick, True), (order.drop, limits.drop, False)):
                gx, gy = at[station]
                distance = math.hypot(gx - x, gy - y)
                if distance > 1e-6:
                    bearing = math.atan2(gy - y, gx - x)
                    row["turn_s"] += trapezoid_seconds(abs(_wrap(bearing - theta)), limits.omega_max,
                                                       limits.alpha_max)
                    theta = bearing
                row["drive_s"] += trapezoid_seconds(distance, limits.v_max, limits.a_max)
                row["action_s"] += action
                row["distance_m"] += distance
                row["empty_m"] += distance if empty else 0.0
                x, y = gx, gy
        row["total_s"] = row["drive_s"] + row["turn_s"] + row["action_s"]
        row["total_no_turns_s"] = row["drive_s"] + row["action_s"]
        rows[vehicle] = row
    totals = [r["total_s"] for r in rows.values()]

    def summed(key: str) -> float:
        return sum(r[key] for r in rows.values())

    return {"per_vehicle": rows, "busiest_s": max(totals), "mean_s": sum(totals) / len(totals),
            "busiest_no_turns_s": max(r["total_no_turns_s"] for r in rows.values()),
            "drive_s": summed("drive_s"), "turn_s": summed("turn_s"), "action_s": summed("action_s"),
            "distance_m": summed("distance_m"), "empty_m": summed("empty_m")}


def path_length(track: list[list[float]]) -> float:
    """Metres along ``[t, x, y]`` samples (the path the vehicle drove, as sampled)."""
    return sum(math.hypot(b[1] - a[1], b[2] - a[2]) for a, b in zip(track, track[1:]))

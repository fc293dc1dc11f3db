"""Kinematics (limits never exceeded, trapezoidal arrival time) and battery, with a fixed tick."""

from __future__ import annotations

import math

import pytest

from fleet.sim.battery import Battery, BatteryModel
from fleet.sim.kinematics import Limits, Motion, Pose, drive_step, turn_step, wrap
from fleet.sim.map import MapError, default_map, from_json


def trapezoid_time(distance: float, v_max: float, a_max: float) -> float:
    if distance >= v_max * v_max / a_max:
        return distance / v_max + v_max / a_max
    return 2 * math.sqrt(distance / a_max)


def drive(limits: Limits, goal: tuple[float, float], dt: float, start: Pose = Pose(0, 0, 0)):
    motion, t, history = Motion(start), 0.0, [Motion(start)]
    for _ in range(100_000):
        motion, _, arrived = drive_step(motion, *goal, limits, dt)
        t += dt
        history.append(motion)
        if arrived:
            return motion, t, history
    raise AssertionError("never arrived")


CASES = [  # (limits, distance, dt)
    (Limits(1.0, 0.5, 1.0, 1.0), 5.0, 0.05),   # trapezoid: cruises at vmax
    (Limits(1.0, 0.5, 1.0, 1.0), 1.0, 0.05),   # triangle: never reaches vmax
    (Limits(2.0, 1.0, 1.0, 1.0), 12.3, 0.1),
    (Limits(0.3, 0.2, 1.0, 1.0), 0.07, 0.02),
]


@pytest.mark.parametrize(("limits", "distance", "dt"), CASES)
def test_reaches_the_point_within_limits_and_trapezoid_time(limits: Limits, distance: float, dt: float) -> None:
    motion, t, history = drive(limits, (distance, 0.0), dt)
    assert (motion.pose.x, motion.pose.y) == pytest.approx((distance, 0.0), abs=1e-9)
    assert motion.v == 0.0
    speeds = [m.v for m in history]
    assert max(speeds) <= limits.v_max + 1e-12
    assert max(abs(b - a) for a, b in zip(speeds, speeds[1:])) <= limits.a_max * dt + 1e-9
    expected = trapezoid_time(distance, limits.v_max, limits.a_max)
    assert abs(t - expected) <= 3 * dt, (t, expected)


def test_turns_in_place_first_within_angular_limits() -> None:
    limits = Limits(1.0, 0.5, 0.8, 0.6)
    motion, t, history = drive(limits, (0.0, 3.0), 0.05)
    assert motion.pose.theta == pytest.approx(math.pi / 2)
    turning = [m for m in history if m.omega != 0.0]
    assert turning and all(m.v == 0.0 for m in turning)  # no driving while turning
    omegas = [m.omega for m in history]
    assert max(abs(w) for w in omegas) <= limits.omega_max + 1e-12
    assert max(abs(b - a) for a, b in zip(omegas, omegas[1:])) <= limits.alpha_max * 0.05 + 1e-9
    expected = trapezoid_time(math.pi / 2, 0.8, 0.6) + trapezoid_time(3.0, 1.0, 0.5)
    assert abs(t - expected) <= 6 * 0.05


def test_edge_speed_limit_lowers_the_cruise_speed() -> None:
    motion, top = Motion(Pose(0, 0, 0)), 0.0
    for _ in range(2000):
        motion, _, arrived = drive_step(motion, 10.0, 0.0, Limits(), 0.05, v_limit=0.4)
        top = max(top, motion.v)
        if arrived:
            break
    assert top == pytest.approx(0.4)


def test_final_heading_turn() -> None:
    motion, done = Motion(Pose(0, 0, 3.0)), False
    for _ in range(500):
        motion, done = turn_step(motion, -3.0, Limits(), 0.05)
        if done:
            break
    assert done and motion.pose.theta == pytest.approx(-3.0)


def test_wrap() -> None:
    assert wrap(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


@pytest.mark.parametrize("bad", [{"v_max": 0}, {"a_max": -1}, {"omega_max": float("nan")}])
def test_limits_refuse_bad_values(bad: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(bad))):
        Limits(**bad)


def test_battery_drains_with_distance_and_time_and_charges() -> None:
    model = BatteryModel(drain_per_metre=0.1, drain_per_second=0.01, charge_per_second=1.0)
    b = Battery(50.0, model=model).step(10.0, 20.0)
    assert b.charge == pytest.approx(50.0 - 2.0 - 0.1)
    assert Battery(1.0, model=model).step(1.0, 100.0).charge == 0.0 and Battery(0.0, model=model).empty
    charged = Battery(99.5, True, model).step(2.0, 0.0)
    assert charged.charge == 100.0
    assert Battery(40.0, model=model).reach == 400
    with pytest.raises(ValueError, match="0..100"):
        Battery(120.0)


def test_default_map_and_bad_maps() -> None:
    site = default_map()
    assert len(site.parking()) == 50 and site.charger_at(2.0, 1.0).name == "charger-1"
    with pytest.raises(MapError, match="outside"):
        from_json({"mapId": "m", "width": 5, "height": 5, "stations": [{"name": "a", "x": 6, "y": 1}]})
    with pytest.raises(MapError, match=r"stations\[0\]: x must be a finite number"):
        from_json({"mapId": "m", "width": 5, "height": 5, "stations": [{"name": "a", "x": "1", "y": 1}]})
    with pytest.raises(MapError, match="repeated: a"):
        from_json({"mapId": "m", "width": 5, "height": 5, "stations": [{"name": "a", "x": 1, "y": 1}, {"name": "a", "x": 2, "y": 1}]})

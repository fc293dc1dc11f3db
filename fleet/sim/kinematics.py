"""A unicycle (differential-drive) vehicle with velocity and acceleration limits, stepped at a fixed tick.

State: pose (x, y, theta), linear speed v along the heading, angular speed omega. Motion to a
goal point is "turn in place, then drive straight", each phase with a discrete time-optimal
trapezoidal profile: the speed rises by at most ``a*dt`` a tick, never exceeds ``vmax``, and is the
largest speed from which the vehicle can still stop at the goal with steps of ``a*dt`` (so the
deceleration never exceeds ``a`` either, which a plain ``sqrt(2*a*d)`` rule breaks in the last tick).
Positions advance by ``v*dt`` with the tick's speed (explicit Euler on a straight line is exact).
The arrival time therefore matches the continuous trapezoid ``d/vmax + vmax/a`` (or ``2*sqrt(d/a)``
for a triangle) to within a couple of ticks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

ANGLE_TOLERANCE = 1e-3  # rad: heading error that counts as "facing the goal"
POSITION_TOLERANCE = 1e-6  # m


@dataclass(frozen=True)
class Limits:
    v_max: float = 1.0  # m/s
    a_max: float = 0.5  # m/s²
    omega_max: float = 1.0  # rad/s
    alpha_max: float = 1.0  # rad/s²

    def __post_init__(self) -> None:
        for name in ("v_max", "a_max", "omega_max", "alpha_max"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"Limits.{name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True)
class Pose:
    x: float
    y: float
    theta: float


@dataclass(frozen=True)
class Motion:
    """Pose plus the speeds of the last tick."""

    pose: Pose
    v: float = 0.0
    omega: float = 0.0

    @property
    def stopped(self) -> bool:
        return self.v == 0.0 and self.omega == 0.0


def wrap(angle: float) -> float:
    """An angle in [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def profile_speed(remaining: float, speed: float, v_max: float, a_max: float, dt: float) -> float:
    """The speed (>= 0) for the next tick when ``remaining`` >= 0 is left and ``speed`` is the current one.

    Stopping from ``k*a*dt`` with steps of ``a*dt`` covers ``a*dt²*k(k+1)/2``; the largest real k
    that fits in ``remaining`` bounds the speed, as do ``v_max`` and the acceleration limit."""
    step = a_max * dt
    k = (-1.0 + math.sqrt(1.0 + 8.0 * remaining / (a_max * dt * dt))) / 2.0
    return max(0.0, min(v_max, k * step, speed + step))


def brake(speed: float, a_max: float, dt: float) -> float:
    """One tick of full deceleration towards zero (keeps the sign)."""
    step = a_max * dt
    return 0.0 if abs(speed) <= step else speed - math.copysign(step, speed)


def turn_step(motion: Motion, target_theta: float, limits: Limits, dt: float) -> tuple[Motion, bool]:
    """Rotate in place towards ``target_theta``; return the new motion and whether it is reached."""
    if motion.v != 0.0:  # never turn in place while still rolling: stop first
        return replace(motion, v=brake(motion.v, limits.a_max, dt), omega=brake(motion.omega, limits.alpha_max, dt)), False
    error = wrap(target_theta - motion.pose.theta)
    if abs(error) <= ANGLE_TOLERANCE and abs(motion.omega) <= limits.alpha_max * dt:
        pose = replace(motion.pose, theta=wrap(target_theta))
        return Motion(pose, 0.0, 0.0), True
    sign = 1.0 if error >= 0 else -1.0
    current = motion.omega * sign  # speed towards the target (negative: turning away)
    if current < 0:
        omega = brake(motion.omega, limits.alpha_max, dt)
        moved = omega * dt
    else:
        speed = profile_speed(abs(error), current, limits.omega_max, limits.alpha_max, dt)
        moved = min(speed * dt, abs(error)) * sign
        omega = speed * sign
    pose = replace(motion.pose, theta=wrap(motion.pose.theta + moved))
    return Motion(pose, 0.0, omega), False


def drive_step(motion: Motion, goal_x: float, goal_y: float, limits: Limits, dt: float,
               v_limit: float | None = None) -> tuple[Motion, float, bool]:
    """One tick towards (goal_x, goal_y), facing it first.

    Returns (new motion, distance travelled this tick, arrived). ``v_limit`` lowers ``v_max``
    (an edge's ``maxSpeed``)."""
    dx, dy = goal_x - motion.pose.x, goal_y - motion.pose.y
    remaining = math.hypot(dx, dy)
    if remaining <= POSITION_TOLERANCE:
        if motion.v == 0.0 and motion.omega == 0.0:
            return motion, 0.0, True
        v = brake(motion.v, limits.a_max, dt)
        return Motion(motion.pose, v, brake(motion.omega, limits.alpha_max, dt)), 0.0, v == 0.0
    bearing = math.atan2(dy, dx)
    if motion.v == 0.0 and abs(wrap(bearing - motion.pose.theta)) > ANGLE_TOLERANCE or motion.omega != 0.0:
        turned, _ = turn_step(motion, bearing, limits, dt)
        return turned, 0.0, False
    v_max = limits.v_max if v_limit is None else max(1e-3, min(limits.v_max, v_limit))
    speed = profile_speed(remaining, motion.v, v_max, limits.a_max, dt)
    if motion.v > v_max:  # a lower edge limit: slow down at the acceleration limit
        speed = max(speed, motion.v - limits.a_max * dt)
    travelled = min(speed * dt, remaining)
    if travelled >= remaining:
        # At the goal with at most a*dt left (the profile guarantees it): the next tick brakes to 0
        # and reports the arrival, so no tick ever changes the speed by more than a*dt.
        return Motion(Pose(goal_x, goal_y, bearing), speed, 0.0), remaining, False
    pose = Pose(motion.pose.x + travelled * math.cos(bearing), motion.pose.y + travelled * math.sin(bearing), bearing)
    return Motion(pose, speed, 0.0), travelled, False

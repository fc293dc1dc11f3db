"""``plantkg fleet demo --speed``: the simulators' limits for vehicles N times as fast on the same paths."""

from __future__ import annotations

import math

from click.testing import CliRunner

from fleet.cli import fleet_group
from fleet.demo import limit_flags
from fleet.sim.kinematics import Limits


def _limits(flags: list[str]) -> Limits:
    values = dict(zip(flags[::2], map(float, flags[1::2])))
    assert set(values) == {"--vmax", "--amax", "--omega-max", "--alpha-max"}, flags
    return Limits(values["--vmax"], values["--amax"], values["--omega-max"], values["--alpha-max"])


def _trapezoid(distance: float, v_max: float, a_max: float) -> float:
    if distance >= v_max * v_max / a_max:
        return distance / v_max + v_max / a_max
    return 2.0 * math.sqrt(distance / a_max)


def test_speed_one_is_the_simulators_defaults() -> None:
    assert _limits(limit_flags(1.0)) == Limits()


def test_every_drive_and_turn_takes_a_speedth_of_the_time() -> None:
    base, fast = Limits(), _limits(limit_flags(4.0))
    for distance in (0.1, 0.5, 3.0, 35.0):  # triangles and trapezoids alike
        assert math.isclose(_trapezoid(distance, fast.v_max, fast.a_max),
                            _trapezoid(distance, base.v_max, base.a_max) / 4)
    for angle in (0.2, math.pi / 2, math.pi):
        assert math.isclose(_trapezoid(angle, fast.omega_max, fast.alpha_max),
                            _trapezoid(angle, base.omega_max, base.alpha_max) / 4)


def test_a_speed_below_one_or_above_ten_is_refused_before_anything_starts() -> None:
    for bad in ("0.5", "11", "fast"):
        result = CliRunner().invoke(fleet_group, ["demo", "--speed", bad])
        assert result.exit_code == 2 and "--speed" in result.output, result.output

"""The security benchmark's arithmetic (benchmarks/bench_security.py), without brokers: per-message
CPU of brokers and clients, medians over repeats, the goal lines."""

from __future__ import annotations

from typing import Any

import pytest

from benchmarks import bench_security as sec


def run(received: int, msg_per_s: float, broker_cpu_s: float, pub_cpu_s: float = 0.0,
        sub_cpu_s: float = 0.0) -> dict[str, Any]:
    return {"received": received, "missing": 0, "msg_per_s": msg_per_s,
            "puback_ms": {"p50": 1.0, "p99": 2.0}, "broker_cpu_s": broker_cpu_s,
            "client_cpu_s": {"publisher": pub_cpu_s, "subscriber": sub_cpu_s}}


def test_cpu_per_message_is_the_median_over_repeats() -> None:
    runs = [run(100_000, 10_000, 3.0, 2.0, 1.0), run(100_000, 12_000, 5.0, 2.0, 2.0),
            run(50_000, 11_000, 1.0, 0.5, 0.5)]
    med = sec.medians(runs)
    assert med["broker_cpu_us_per_msg"] == pytest.approx(30.0)   # 30, 50, 20 µs/msg
    assert med["client_cpu_us_per_msg"] == pytest.approx(30.0)   # 30, 40, 20
    assert med["total_cpu_us_per_msg"] == pytest.approx(60.0)    # 60, 90, 40
    assert med["msg_per_s"] == 11_000


def test_no_delivery_does_not_divide_by_zero() -> None:
    med = sec.medians([run(0, 0.0, 1.0)])
    assert med["broker_cpu_us_per_msg"] == pytest.approx(1e6)


def test_every_arm_names_its_brokers_and_every_costed_arm_a_baseline() -> None:
    assert set(sec.ARM_BROKERS) == set(sec.ARMS)
    assert set(sec.BASELINE) == set(sec.GOAL_NAMES)
    assert all(len(sec.ARM_BROKERS[arm]) == 2 for arm in ("bridge-open", "bridge-closed-tls"))


@pytest.mark.parametrize(("ratio", "met"), [(0.86, True), (0.85, True), (0.84, False), (None, False)])
def test_goal_is_at_most_fifteen_percent_throughput_cost(ratio: float | None, met: bool) -> None:
    ratios = {arm: {"throughput": 1.0} for arm in sec.BASELINE}
    ratios["bridge-closed-tls"]["throughput"] = ratio
    found = {g["goal"]: g["met"] for g in sec.goals({"ratios": ratios})}
    assert found[sec.GOAL_NAMES["bridge-closed-tls"]] is met
    assert found[sec.GOAL_NAMES["closed"]] is True

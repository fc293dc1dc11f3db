"""The context broker benchmark's pure parts: spreading clients over worker processes, pacing,
rates and CPU shares, the goal verdicts and the table (the study itself runs in
tests/integration/test_bench_context_broker.py)."""

from __future__ import annotations

import pytest

from benchmarks import bench_context_broker as bench
from benchmarks import context_broker_load as load


@pytest.mark.parametrize("clients, procs, expected", [
    (1, 4, [1]), (8, 4, [2, 2, 2, 2]), (32, 4, [8, 8, 8, 8]), (10, 4, [3, 3, 2, 2]), (3, 4, [1, 1, 1]),
])
def test_split_clients_spreads_evenly(clients: int, procs: int, expected: list[int]) -> None:
    assert load.split_clients(clients, procs) == expected
    assert sum(load.split_clients(clients, procs)) == clients


@pytest.mark.parametrize("clients, procs", [(0, 4), (4, 0)])
def test_split_clients_refuses_nothing_to_split(clients: int, procs: int) -> None:
    with pytest.raises(ValueError, match="at least 1"):
        load.split_clients(clients, procs)


def test_pace_time_spaces_messages_by_the_rate() -> None:
    assert load.pace_time(100.0, 0, 500) == 100.0
    assert load.pace_time(100.0, 250, 500) == pytest.approx(100.5)
    with pytest.raises(ValueError, match="positive"):
        load.pace_time(0.0, 1, 0)


def test_rate_summary_gives_rate_and_cpu_share() -> None:
    got = load.rate_summary(completed=5000, window_s=2.0, cpu_s=1.5, cores=2)
    assert got == {"per_s": 2500.0, "cpu_pct_of_core": 75.0, "cpu_pct_of_machine": 37.5}
    with pytest.raises(ValueError):
        load.rate_summary(1, 0.0, 0.0)


def _data(cb_rates: dict[int, float], p99: float, lost: int, q99: float) -> dict[str, object]:
    updates = []
    for clients, rate in cb_rates.items():
        for target, per_s in (("context-broker", rate), ("mosquitto", 10 * rate)):
            updates.append({"target": target, "clients": clients, "processes": 1, "per_s": per_s, "errors": 0,
                            "vs_mosquitto": 0.1 if target == "context-broker" else 1.0,
                            "generator_cpu_pct_of_core": 20.0, "server_cpu_pct_of_core": 95.0,
                            "server_cpu_ms_per_request": 0.4})
    lat = {"n": 10, "p50": p99 / 2, "p99": p99, "max": p99}
    return {"command": "python -m benchmarks.bench_context_broker", "machine": {"cpus": 2}, "duration_s": 1.0,
            "updates": updates,
            "notification": {"rows": [
                {"path": "context-broker -> mqtt", "offered_rate": 500.0, "achieved_rate": 499.0, "max_lag_ms": 1.0,
                 "received": 10 - lost, "lost": lost, "duplicates": 0, "latency_ms": lat},
                {"path": "raw mosquitto", "offered_rate": 500.0, "achieved_rate": 500.0, "max_lag_ms": 0.5,
                 "received": 10, "lost": 0, "duplicates": 0, "latency_ms": lat}]},
            "query": {"entities": 10000, "requests": 10, "load_s": 3.0, "rows": [
                {"query": "q selective (zone==7;battery>90)", "results": 10, "matching": 10,
                 "latency_ms": {"n": 10, "p50": q99 / 2, "p99": q99, "max": q99}},
                {"query": "GET /v2/entities/{id}", "results": 1, "matching": None,
                 "latency_ms": {"n": 10, "p50": 500.0, "p99": 900.0, "max": 900.0}}]}}


def test_goals_met_from_the_best_client_count() -> None:
    data = _data({1: 900.0, 8: 2400.0}, p99=12.0, lost=0, q99=40.0)
    verdicts = {g["goal"]: g for g in bench.goals(data)}
    updates = verdicts["attribute updates/s (best client count)"]
    assert updates["met"] and "2400/s with 8 clients" in updates["measured"]
    assert verdicts["update -> MQTT notification p99 at 500 updates/s"]["met"]
    assert verdicts["q selective (zone==7;battery>90) p99 at 10000 entities"]["met"]
    assert len(verdicts) == 3  # GET by id has no goal


def test_notification_goal_counts_from_the_schedule() -> None:
    data = _data({1: 2400.0}, p99=12.0, lost=0, q99=40.0)
    data["notification"]["rows"][0]["from_schedule_ms"] = {"n": 10, "p50": 30.0, "p99": 70.0}
    verdict = next(g for g in bench.goals(data) if g["goal"].startswith("update -> MQTT"))
    assert not verdict["met"] and verdict["measured"] == "70.0 ms (lost 0)"


def test_goals_not_met_when_slow_or_lossy() -> None:
    data = _data({1: 900.0, 32: 1999.0}, p99=12.0, lost=1, q99=100.0)
    assert [g["met"] for g in bench.goals(data)] == [False, False, False]


def test_markdown_has_goal_verdicts_and_every_row() -> None:
    data = _data({1: 900.0, 8: 2400.0}, p99=60.0, lost=0, q99=40.0)
    data["goals"] = bench.goals(data)
    text = bench.to_markdown(data)
    assert "| update -> MQTT notification p99 at 500 updates/s | 60.0 ms (lost 0) | < 50 ms, none lost | **not met** |" in text
    assert "| context-broker | 8 | 1 | 2400 | 0.10 | 0 | 20 | 95 | 0.40 | 0.00 |" in text
    assert "| mosquitto | 1 | 1 | 9000 |" in text
    assert "| GET /v2/entities/{id} | 1 | - | 500.00 | 900.00 | 900.00 |" in text

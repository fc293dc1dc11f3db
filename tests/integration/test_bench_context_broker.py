"""The context broker benchmark runs tiny against a real context broker and a real Mosquitto:
every study produces rows, nothing is lost, every query answered what it should, and the run
leaves no process behind (the autouse fixture of tests/conftest.py checks that)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_context_broker

pytestmark = pytest.mark.integration


def test_context_broker_benchmark_runs_tiny(tmp_path: Path) -> None:
    assert bench_context_broker.main(["--tiny", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "context_broker.json").read_text())
    assert {(r["target"], r["clients"]) for r in data["updates"]} == {
        (t, c) for t in ("context-broker", "mosquitto") for c in (1, 2)} | {("context-broker GET /version", 2)}
    for row in data["updates"]:
        assert row["completed"] > 0 and row["errors"] == 0, row
        assert row["generator_cpu_pct_of_core"] > 0 and row["server_cpu_pct_of_core"] > 0, row
    notify = data["notification"]["rows"]
    assert {(r["path"], r["role"]) for r in notify if r["role"] == "goal"} == {
        ("context-broker -> mqtt", "goal"), ("raw mosquitto", "goal")}
    assert {r["role"] for r in notify} <= {"goal", "below-capacity"} and len(notify) in (2, 4)
    for row in notify:
        assert row["lost"] == 0 and row["received"] == row["messages"] == 200, row
        assert row["latency_ms"]["p99"] > 0
        assert row["update_failures"] == 0, row
    queries = data["query"]["rows"]
    assert data["query"]["entities"] == 300 and len(queries) == 3
    assert all(q["latency_ms"]["n"] == 20 for q in queries)  # each answer was checked by the study
    assert len(data["goals"]) == 4 and all(isinstance(g["met"], bool) for g in data["goals"])
    assert "| context-broker | 2 |" in (tmp_path / "context_broker.md").read_text()

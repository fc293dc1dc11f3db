"""The plug-and-play join benchmark runs at a tiny size and its results say what it measured."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_fleet_join, report

pytestmark = pytest.mark.integration  # real agents, Mosquitto, context broker, fleet manager, simulated AGVs


def test_fleet_join_benchmark_runs_tiny(tmp_path: Path) -> None:
    assert bench_fleet_join.main(["--counts", "1", "2", "--floor-runs", "1", "--settle", "1",
                                  "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "fleet_join.json").read_text())
    assert data["floor"]["n"] == 1 and data["floor"]["p50"] > 0
    rows = {r["count"]: r for r in data["rows"]}
    assert set(rows) == {1, 2}
    for count, row in rows.items():
        assert row["ready"]["n"] == count and row["ready"]["p50"] > 0
        assert row["discovered_files"] == row["distinct_vehicles"] == count  # each discovered once
        assert row["plan_after_empty"]                                      # nothing left to apply
    assert "| 2 |" in (tmp_path / "fleet_join.md").read_text()
    (goal,) = [g for g in report.goals(tmp_path) if g[0].startswith("one AGV")]
    assert goal[1].endswith("ms (max)")

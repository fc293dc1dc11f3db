"""The Table 1 benchmark runs on one run of each path against a real agent and Mosquitto."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_deploy

pytestmark = pytest.mark.integration


def test_deploy_benchmark_runs(tmp_path: Path) -> None:
    assert bench_deploy.main(["--runs", "2", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "deploy.json").read_text())
    assert set(data["ms"]) == {"bare", "plantkg", "plantkg-dispatch"}
    assert all(row["n"] == 2 for row in data["ms"].values())

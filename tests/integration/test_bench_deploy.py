"""The Table 1 benchmark runs one run of each path against a real agent, Mosquitto and Kafka; the
emulated remote machine (network namespace) is measured where this process may build one."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from benchmarks import bench_deploy

pytestmark = pytest.mark.integration


def test_deploy_benchmark_runs(tmp_path: Path) -> None:
    assert bench_deploy.main(["--runs", "1", "--kafka-runs", "1", "--delay-ms", "0", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "deploy.json").read_text())
    rows = set(data["ms"])
    assert rows >= {"bare", "plantkg", "plantkg-dispatch", "kafka-bare", "kafka-plantkg"}
    assert all(row["n"] == 1 for row in data["ms"].values())
    if "plantkg-remote-0ms" in rows:
        assert data["remote_note"] == ""
    else:  # not root, or no iproute2: the row is skipped and says why
        assert os.geteuid() != 0 or data["remote_note"].startswith("not measured")
        assert "not measured" in (tmp_path / "deploy.md").read_text()

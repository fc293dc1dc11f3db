"""The MQTT -> NGSI bridge benchmark runs tiny against a real Mosquitto, the real context broker
and a real worker: both rows are measured, nothing refused, no process left behind (the autouse
fixture of tests/conftest.py checks that)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_bridge_ngsi

pytestmark = pytest.mark.integration


def test_bridge_ngsi_benchmark_runs_tiny(tmp_path: Path) -> None:
    assert bench_bridge_ngsi.main(["--messages", "200", "--topics", "1", "2", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "bridge_ngsi.json").read_text())
    assert data["messages"] == 200 and data["direct_per_s"] > 0
    assert [r["topics"] for r in data["rows"]] == [1, 2]
    for row in data["rows"]:
        assert row["msg_per_s"] > 0 and row["refused"] == 0, row
    assert "worker, 2 topic(s)" in (tmp_path / "bridge_ngsi.md").read_text()

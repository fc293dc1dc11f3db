"""Each benchmark runs end to end on a tiny size and writes its results (figures are not checked:
timings are measured by the benchmarks, never asserted by tests)."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import bench_reason, bench_validate


def test_validate_benchmark_runs(tmp_path: Path) -> None:
    assert bench_validate.main(["--sizes", "40", "--repeat", "1", "--reference-max", "40", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "validate.json").read_text())
    (row,) = data["rows"]
    assert row["resources"] == 40 and row["plantkg"]["results"] == row["pyshacl"]["results"] == 0
    assert "| 40 |" in (tmp_path / "validate.md").read_text()


def test_reason_benchmark_runs(tmp_path: Path) -> None:
    args = ["--sizes", "20", "--repeat", "1", "--hermit-max", "20", "--hermit-repeat", "1", "--out", str(tmp_path)]
    assert bench_reason.main(args) == 0
    text = (tmp_path / "reason.md").read_text()
    assert "| 20 |" in text and "| yes |" in text  # HermiT and the fast engine agreed


def test_replan_benchmark_runs(tmp_path: Path) -> None:
    from benchmarks import bench_replan

    assert bench_replan.main(["--sizes", "30", "--repeat", "1", "--out", str(tmp_path)]) == 0
    (row,) = json.loads((tmp_path / "replan.json").read_text())["rows"]
    assert row["resources"] == 30  # the benchmark itself asserts the hit and the empty plans

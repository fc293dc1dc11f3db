"""The command-line start-up benchmark runs at a tiny size and writes its table (no timing asserted)."""

from __future__ import annotations

import json
from pathlib import Path

from benchmarks import bench_cli


def test_cli_benchmark_runs_and_reports_every_row(tmp_path: Path) -> None:
    assert bench_cli.main(["--runs", "1", "--no-agents", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "cli.json").read_text())
    names = ["python -c pass", "python -c 'import click'", "plantkg --help", "plantkg --version",
             "plantkg validate EXAMPLE"]
    assert list(data["seconds"]) == names and data["baseline"] == "python -c pass"
    assert all(len(v) == 1 and v[0] > 0 for v in data["seconds"].values())
    assert all(len(v) == 1 and v[0] > 0 for v in data["cpu_seconds"].values())
    table = (tmp_path / "cli.md").read_text()
    assert all(f"| `{name}` | 1 |" in table for name in names)
    assert "Goal `plantkg --help` < 0.15 s:" in table

"""benchmarks.loadgen reads the Go load generator's JSON report into a typed Result, and says what
to install when the binary is missing (pure: no broker, no child process)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import loadgen

SUB = {"mode": "mqtt-sub", "count": 10, "received": 9, "missing": 1, "duplicates": 2, "elapsed_s": 0.5,
       "rate_per_s": 18.0, "latency_p50_ms": 1.5, "latency_p99_ms": 4.0, "latency_max_ms": 4.5,
       "cpu_user_s": 0.25, "cpu_sys_s": 0.5, "timed_out": True, "first_unix_ns": 1, "last_unix_ns": 2}


def test_a_subscriber_report_becomes_a_result() -> None:
    got = loadgen.parse_report(json.dumps(SUB), 1)
    assert (got.mode, got.received, got.missing, got.duplicates, got.timed_out) == ("mqtt-sub", 9, 1, 2, True)
    assert (got.p50_ms, got.p99_ms, got.cpu_s, got.exit_code, got.last_ns) == (1.5, 4.0, 0.75, 1, 2)


def test_an_error_report_is_an_error_naming_it() -> None:
    with pytest.raises(loadgen.LoadgenError, match="mqtt-pub failed: connect to x: refused"):
        loadgen.parse_report(json.dumps({"mode": "mqtt-pub", "error": "connect to x: refused"}), 2)


@pytest.mark.parametrize("line", ["not json", json.dumps({"count": 3})])
def test_a_line_that_is_no_report_is_an_error(line: str) -> None:
    with pytest.raises(loadgen.LoadgenError, match="loadgen"):
        loadgen.parse_report(line, 0)


def test_a_missing_binary_names_what_to_install(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setattr(loadgen, "ROOT", tmp_path)
    monkeypatch.setattr(loadgen, "BINARY", tmp_path / ".plantkg" / "loadgen" / "loadgen")
    with pytest.raises(loadgen.LoadgenError, match=r"install Go .*make setup"):
        loadgen.binary()

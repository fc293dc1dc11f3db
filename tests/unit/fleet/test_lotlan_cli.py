"""``python -m fleet.lotlan check FILE...``: exit 0 / 1 with ``file:line:col: message`` lines."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

CASES = Path(__file__).resolve().parents[2] / "cases" / "lotlan" / "ours"
LINE = re.compile(r"^(?P<file>[^:]+):(?P<line>\d+):(?P<column>\d+): (?P<message>.+)$")


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fleet.lotlan", *args], capture_output=True,
                          text=True, timeout=60, check=False, cwd=cwd)


def test_good_files_exit_0_silently() -> None:
    done = run("check", str(CASES / "paper-load-unload.tl"), str(CASES / "precedence.tl"))
    assert (done.returncode, done.stdout, done.stderr) == (0, "", "")


def test_bad_files_exit_1_with_one_line_per_problem() -> None:
    good, bad = CASES / "paper-load-unload.tl", CASES / "all-errors-reported.tl"
    done = run("check", str(good), str(bad))
    assert done.returncode == 1
    lines = done.stdout.splitlines()
    assert len(lines) == 6
    parsed = [LINE.match(line) for line in lines]
    assert all(parsed), lines
    assert {m["file"] for m in parsed} == {str(bad)}
    assert [(int(m["line"]), int(m["column"])) for m in parsed][:2] == [(13, 14), (14, 17)]
    assert "did you mean 'dock'?" in parsed[0]["message"]
    assert "1 of 2 file(s) refused" in done.stderr
    assert "Traceback" not in done.stderr


def test_an_unreadable_file_is_a_problem_of_that_file(tmp_path: Path) -> None:
    binary = tmp_path / "latin1.tl"
    binary.write_bytes(b"Location caf\xe9\n")
    done = run("check", str(tmp_path / "missing.tl"), str(binary))
    assert done.returncode == 1
    lines = done.stdout.splitlines()
    assert lines[0].startswith(f"{tmp_path / 'missing.tl'}:1:1: cannot read the file")
    assert lines[1].startswith(f"{binary}:1:1: cannot read the file")
    assert "Traceback" not in done.stderr


def test_no_file_is_a_usage_error() -> None:
    done = run("check")
    assert done.returncode == 2
    assert "FILE" in done.stderr


def test_checking_writes_nothing(tmp_path: Path) -> None:
    done = run("check", str(CASES / "ondone-cycle.tl"), cwd=tmp_path)
    assert done.returncode == 1
    assert list(tmp_path.iterdir()) == []

"""``plantkg serve``'s bad input ends with a message and exit code 2, before anything listens."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.cli import main


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
    code = main(["serve", *args])
    return code, capsys.readouterr().err


def test_a_missing_agents_file(capsys: pytest.CaptureFixture[str], plant_file: Path, tmp_path: Path) -> None:
    code, err = run(capsys, str(plant_file), "--agents", str(tmp_path / "nope.toml"))
    assert code == 2 and "no such agents file" in err


def test_a_remote_listen_address_needs_allow_remote(capsys: pytest.CaptureFixture[str], plant_file: Path) -> None:
    code, err = run(capsys, str(plant_file), "--listen", "10.1.2.3:8080")
    assert code == 2 and "not a loopback address" in err and "--allow-remote" in err


def test_no_file(capsys: pytest.CaptureFixture[str]) -> None:
    code, err = run(capsys)
    assert code == 2 and "FILE" in err


def test_help_names_the_options(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["serve", "--help"]) == 0
    out = capsys.readouterr().out
    assert all(option in out for option in ("--listen", "--agents", "--auto-apply", "--query-timeout"))

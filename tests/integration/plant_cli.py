"""Helpers of the end-to-end tests that drive ``plantkg`` on a plant file with real agents:
secret files for the plant's ``pk:secretRef "file:..."`` and the CLI run in this process."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.cli import main


def secret_files(folder: Path, passwords: dict[str, str]) -> dict[str, Path]:
    """One 0600 file per user in ``folder``, holding its password and a newline (as an editor
    writes it; the agent drops one trailing newline)."""
    files = {}
    for name, password in passwords.items():
        files[name] = folder / f"{name}.pw"
        files[name].write_text(password + "\n", encoding="utf-8")
        files[name].chmod(0o600)
    return files


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
    """``plantkg ARGS...``: its exit code and everything it printed."""
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out + out.err

"""Helpers of the end-to-end tests that drive ``plantkg`` on a plant file with real agents:
secret files for the plant's ``pk:secretRef "file:..."`` and the CLI run in this process."""

from __future__ import annotations

from collections.abc import Iterable
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


def files_holding(folders: Iterable[Path], secret: str) -> tuple[list[Path], int]:
    """The files under ``folders`` that hold ``secret``, each checked to be readable by its owner
    only and not a log; and how many files were read (a test asserts that it read some)."""
    holders, checked = [], 0
    for folder in folders:
        for path in folder.rglob("*"):
            if not path.is_file():
                continue
            checked += 1
            if secret in path.read_bytes().decode("utf-8", "replace"):
                holders.append(path)
                assert path.stat().st_mode & 0o077 == 0, f"{path} holds the password and others may read it"
                assert "logs" not in path.parts and not path.name.endswith(".log"), path
    return holders, checked

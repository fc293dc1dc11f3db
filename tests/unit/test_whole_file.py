"""Files written whole by concurrent writers (engine.whole_file)."""

from __future__ import annotations

import stat
import threading
from pathlib import Path

import pytest

from engine.whole_file import create_once, write_whole


def _together(n: int, work) -> list:
    """Run ``work(i)`` in ``n`` threads released at once; their results."""
    barrier, out, errors = threading.Barrier(n), [None] * n, []

    def run(i: int) -> None:
        barrier.wait()
        try:
            out[i] = work(i)
        except Exception as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    return out


def test_threads_creating_one_file_agree_on_the_first_writer(tmp_path: Path) -> None:
    for round_ in range(20):
        path = tmp_path / f"key-{round_}"
        created = _together(8, lambda i, path=path: create_once(path, f"writer {i}\n"))
        assert created.count(True) == 1
        assert path.read_text() == f"writer {created.index(True)}\n"
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert not list(tmp_path.glob(".*"))


def test_threads_replacing_one_file_leave_one_whole_version(tmp_path: Path) -> None:
    path = tmp_path / "state.json"
    texts = [f"{i}" * 100_000 for i in range(8)]
    _together(8, lambda i: write_whole(path, texts[i], mode=0o640))
    assert path.read_text() in texts
    assert stat.S_IMODE(path.stat().st_mode) == 0o640
    assert not list(tmp_path.glob(".*"))


def test_write_whole_makes_the_folder_and_create_once_does_not(tmp_path: Path) -> None:
    write_whole(tmp_path / "a" / "b" / "f", b"\x00data", durable=True)
    assert (tmp_path / "a" / "b" / "f").read_bytes() == b"\x00data"
    with pytest.raises(FileNotFoundError):
        create_once(tmp_path / "missing" / "f", "x")
    assert create_once(tmp_path / "a" / "b" / "f", "other") is False
    assert (tmp_path / "a" / "b" / "f").read_bytes() == b"\x00data"

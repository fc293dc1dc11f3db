"""Agent folders: a spec or bridges file that does not parse is an error naming the file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.agent.folder import BRIDGES_FILE, SPEC_FILE, BrokerFolder
from engine.agent.workers import WorkerFolder
from engine.errors import EngineError


@pytest.mark.parametrize("read, name", [
    (lambda f: BrokerFolder(f).read_spec(), SPEC_FILE),
    (lambda f: BrokerFolder(f).read_bridges(), BRIDGES_FILE),
    (lambda f: WorkerFolder(f).read_bridge(), SPEC_FILE),
])
def test_a_file_that_does_not_parse_is_named(tmp_path: Path, read, name: str) -> None:  # type: ignore[no-untyped-def]
    assert read(tmp_path) in (None, ())  # absent: nothing stored yet
    (tmp_path / name).write_text(json.dumps([{"id": 1}] if name == BRIDGES_FILE else {"id": 1}))
    with pytest.raises(EngineError) as caught:
        read(tmp_path)
    assert str(tmp_path / name) in caught.value.message and "PUT" in (caught.value.hint or "")


@pytest.mark.parametrize("name", ["../escape.conf", "sub/dir.conf", "", ".", "..", "spec.json", "pid.json",
                                  "topics.json", "bridges.json"])
def test_a_driver_writes_only_plain_config_files_in_its_folder(tmp_path: Path, name: str) -> None:
    folder = BrokerFolder(tmp_path / "b")
    with pytest.raises(EngineError, match="outside its config files"):
        folder.write_rendered({"ok.conf": "x\n", name: "y\n"})
    assert not (tmp_path / "escape.conf").exists()


def test_rendered_files_are_written_0600_and_replace_a_symlink_rather_than_follow_it(tmp_path: Path) -> None:
    folder = BrokerFolder(tmp_path / "b")
    folder.path.mkdir()
    outside = tmp_path / "outside.conf"
    outside.write_text("kept\n")
    (folder.path / "mosquitto.conf").symlink_to(outside)
    folder.write_rendered({"mosquitto.conf": "listener 1883\n"})
    written = folder.path / "mosquitto.conf"
    assert not written.is_symlink() and written.read_text() == "listener 1883\n"
    assert outside.read_text() == "kept\n" and (written.stat().st_mode & 0o777) == 0o600

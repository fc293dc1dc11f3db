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

"""The project's shapes are parsed once per process while their files are unchanged, and read
again as soon as one changes (the cache is keyed by each file's size and modification time)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from kg import resources
from kg.validate import load_default_shapes


@pytest.fixture
def home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A PLANTKG_HOME holding a copy of the project's ontology and shapes."""
    root = resources.project_root()
    for folder in ("ontology", "shapes"):
        shutil.copytree(root / folder, tmp_path / folder)
    monkeypatch.setenv("PLANTKG_HOME", str(tmp_path))
    return tmp_path


def test_unchanged_shapes_are_parsed_once(home: Path) -> None:
    first = load_default_shapes()
    assert load_default_shapes() is first
    core = tuple(sorted((home / "shapes").glob("*.ttl")))  # then the shapes of installed plugins
    assert first.files[:len(core)] == core


def test_a_changed_shapes_file_is_read_again(home: Path) -> None:
    first = load_default_shapes()
    shapes_file = first.files[0]
    triples = len(first.graph)
    with shapes_file.open("a") as fh:  # one more triple: size and mtime change
        fh.write('\n<urn:plantkg:test> <http://www.w3.org/2000/01/rdf-schema#comment> "changed" .\n')
    stat = shapes_file.stat()
    os.utime(shapes_file, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000))
    second = load_default_shapes()
    assert second is not first and len(second.graph) == triples + 1

"""LoTLan programs as data: tests/cases/lotlan/{ours,authors}/NAME.tl with NAME.json beside it.

NAME.json is either {"accepted": true, "program": <fleet.lotlan.render.program_json>} or
{"accepted": false, "errors": ["line:col: message", ...]} with every problem of the file in
position order. ``authors/`` holds the LoTLan authors' example and test programs (Apache-2.0,
see tests/cases/lotlan/README.md); ``ours/`` the cases written for this project.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fleet.lotlan import analyse
from fleet.lotlan.render import program_json

CASES = Path(__file__).resolve().parents[2] / "cases" / "lotlan"
PROGRAMS = sorted(CASES.glob("*/*.tl"))


def test_the_case_folders_are_there() -> None:
    assert len(list((CASES / "authors").glob("*.tl"))) >= 90
    assert len(list((CASES / "ours").glob("*.tl"))) >= 20


@pytest.mark.parametrize("path", PROGRAMS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_case(path: Path) -> None:
    expected = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    program, diagnostics = analyse(path.read_text(encoding="utf-8"), path.name)
    got = [f"{d.line}:{d.column}: {d.message}" for d in diagnostics]
    if expected["accepted"]:
        assert got == [], "\n".join(got)
        assert program is not None
        assert program_json(program) == expected["program"]
    else:
        assert program is None
        assert got == expected["errors"]
        assert all(d.file == path.name for d in diagnostics)

"""The shipped example plants are valid, and validation reports where a problem is."""

from __future__ import annotations

from pathlib import Path

import pytest

from kg.load import load_plant
from kg.validate import validate

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "ontology" / "examples").glob("*.ttl"))


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.name for e in EXAMPLES])
@pytest.mark.parametrize("engine", ["oxigraph", "pyshacl"])
def test_example_is_valid(example: Path, engine: str) -> None:
    report = validate(load_plant([example]), engine=engine)  # type: ignore[arg-type]
    assert report.conforms, [r.message for r in report.results]
    assert report.violations == ()


def test_auto_engine_uses_oxigraph_for_project_shapes() -> None:
    report = validate(load_plant([EXAMPLES[0]]))
    assert report.engine == "oxigraph"

"""The README's example plant is valid: what a new user copies first must work."""

from __future__ import annotations

import re

from tests.cli.conftest import ROOT


def test_readme_turtle_example_validates(plantkg, write) -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    (block,) = re.findall(r"```turtle\n(.*?)```", text, re.S)
    run = plantkg("validate", write("readme.ttl", block))
    assert run.code == 0, run.out

"""The fast engine (SPARQL on Oxigraph) and pySHACL (the reference) must give the same results.

Two sources of plants: every shape case under ``tests/cases/shapes/`` (the fast engine held to its
``expected.json`` here, pySHACL to the same file in tests/shapes/test_shapes_reference.py), and
mutants of the example plants — triples dropped, literals replaced with hostile values, ids
duplicated — generated from a fixed seed so a failure is reproducible, on which both engines run
here and must agree.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import pyoxigraph as ox
import pytest

from kg.load import load_plant
from kg.validate import ValidationResult, validate
from kg.shapes import load_shapes
from kg import resources

ROOT = Path(__file__).resolve().parents[2]
CASES = sorted(p for p in (ROOT / "tests" / "cases" / "shapes").glob("*") if (p / "plant.ttl").exists())
EXAMPLES = sorted((ROOT / "ontology" / "examples").glob("*.ttl"))


@pytest.fixture(scope="module")
def shapes():
    return load_shapes(resources.shapes_files())


def _keys(results: tuple[ValidationResult, ...]) -> set[tuple]:
    return {r.key() for r in results}


def _expected(case: Path, name: str = "expected.json") -> set[tuple]:
    rows = json.loads((case / name).read_text())
    if isinstance(rows, dict):  # pyshacl-deviation.json: {"reason": ..., "results": [...]}
        rows = rows["results"]
    return {
        (r["severity"], r["focus"], r["path"], r["value"], r["message"], r["shape"], r["component"])
        for r in rows
    }


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_fast_engine_gives_each_shape_case_its_expected_results(case: Path, shapes) -> None:
    """The fast engine gives each case exactly its ``expected.json``, each result naming the case's
    file. pySHACL on the same cases is held to the same ``expected.json`` (or the documented
    ``pyshacl-deviation.json``) by tests/shapes/test_shapes_reference.py, so the two engines agree
    on every case through that file; running pySHACL here a second time on each case doubled the
    suite's slowest work. The product's own pySHACL path (``engine="pyshacl"``) is held to the fast
    engine on the mutants below."""
    plant = load_plant([case / "plant.ttl"])
    fast = validate(plant, shapes, engine="oxigraph")
    assert fast.engine == "oxigraph"
    assert _keys(fast.results) == _expected(case)
    for r in fast.results:
        assert r.file == str(case / "plant.ttl"), (case.name, r)


def test_the_reference_engine_is_what_engine_pyshacl_runs(shapes) -> None:
    """``engine="pyshacl"`` reports pySHACL's results (the engine it says, and a violation the
    fast engine also finds) on one case of each kind: a violation and a conforming plant."""
    broken = next(c for c in CASES if _expected(c) and not (c / "pyshacl-deviation.json").exists())
    for case in (broken, next(c for c in CASES if not _expected(c))):
        plant = load_plant([case / "plant.ttl"])
        reference = validate(plant, shapes, engine="pyshacl")
        assert reference.engine == "pyshacl"
        assert _keys(reference.results) == _expected(case), case.name


_HOSTILE = ["", "a\nb", "x\x00y", "70000", "-1", "0", "kafka", "MOSQUITTO", "a/b+#", "..", "é" * 300,
            "999.1.2.3", "::1", "true", "3.5", "not-a-date"]


def _mutants(example: Path, count: int, seed: int) -> list[tuple[str, list[ox.Quad]]]:
    rng = random.Random(seed)
    base = list(ox.parse(path=str(example), format=ox.RdfFormat.TURTLE))
    literals = [q for q in base if isinstance(q.object, ox.Literal)]
    ids = [q for q in base if q.predicate.value.endswith("#id")]
    out = []
    for i in range(count):
        quads = list(base)
        kind = i % 4
        if kind == 0:
            victim = rng.choice(quads)
            quads.remove(victim)
            label = f"drop {victim}"
        elif kind == 1:
            victim = rng.choice(literals)
            new = ox.Literal(rng.choice(_HOSTILE))
            quads[quads.index(victim)] = ox.Quad(victim.subject, victim.predicate, new)
            label = f"replace {victim} with {new}"
        elif kind == 2:
            a, b = rng.sample(ids, 2)
            quads[quads.index(b)] = ox.Quad(b.subject, b.predicate, a.object)
            label = f"duplicate id {a.object}"
        else:
            victim = rng.choice(literals)
            typed = ox.Literal(rng.choice(["12", "x", "1.5", "true"]),
                               datatype=ox.NamedNode("http://www.w3.org/2001/XMLSchema#" + rng.choice(["integer", "boolean", "decimal", "string"])))
            quads[quads.index(victim)] = ox.Quad(victim.subject, victim.predicate, typed)
            label = f"retype {victim} as {typed}"
        out.append((label, quads))
    return out


@pytest.mark.parametrize("example", EXAMPLES, ids=[e.name for e in EXAMPLES])
def test_engines_agree_on_mutants(example: Path, shapes, tmp_path: Path) -> None:
    disagreements = []
    for n, (label, quads) in enumerate(_mutants(example, 24, seed=7)):
        path = tmp_path / f"mutant-{n}.nt"
        path.write_bytes(ox.serialize(quads, format=ox.RdfFormat.N_TRIPLES))
        plant = load_plant([path])
        fast = _keys(validate(plant, shapes, engine="oxigraph").results)
        ref = _keys(validate(plant, shapes, engine="pyshacl").results)
        if fast != ref:
            disagreements.append((label, sorted(fast - ref), sorted(ref - fast)))
    assert not disagreements, json.dumps(disagreements, indent=1, default=str)[:4000]

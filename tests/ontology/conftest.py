"""Fixtures for the ontology tests: file locations, a HermiT runner and its timings.

owlready2 does not read Turtle, so every file goes through rdflib to N-Triples in the test's temp
dir first. Each reasoner call gets a fresh owlready2 World (no state leaks between tests), and its
wall time is recorded; the timings are printed at the end of the run.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import owlready2
import pytest
from rdflib import Graph

from kg.namespaces import ONTOLOGY_IRI

ROOT = Path(__file__).resolve().parents[2]
ONTOLOGY_DIR = ROOT / "ontology"
ONTOLOGY_TTL = ONTOLOGY_DIR / "plantkg.ttl"
ONTOLOGY_OWL = ONTOLOGY_DIR / "plantkg.owl"
EXAMPLES = sorted((ONTOLOGY_DIR / "examples").glob("*.ttl"))
EXAMPLES_BASE = "https://w3id.org/plantkg/examples/"

_TIMINGS = pytest.StashKey[list[tuple[str, float]]]()


@dataclass
class Reasoned:
    """A World after HermiT ran on it, and how long the run took (seconds)."""

    world: owlready2.World
    seconds: float


CATALOG_NS = "{urn:oasis:names:tc:entity:xmlns:xml:catalog}"


def catalog_mapping(folder: Path) -> dict[str, Path]:
    """Ontology IRI -> file, as Protégé resolves owl:imports from ``folder/catalog-v001.xml``."""
    import xml.etree.ElementTree as ET  # noqa: PLC0415 - only the catalog users need it

    catalog = folder / "catalog-v001.xml"
    entries = ET.parse(catalog).getroot().findall(f"{CATALOG_NS}uri")
    return {str(e.get("name")): (folder / str(e.get("uri"))).resolve() for e in entries}


def imports_in_order(path: Path, done: set[str] | None = None) -> list[tuple[str, Path]]:
    """The ontologies ``path`` imports, transitively, resolved through the catalog next to each
    file, dependencies first (what owlready2 must hold before it parses ``path`` offline)."""
    from rdflib.namespace import OWL  # noqa: PLC0415

    done = set() if done is None else done
    out: list[tuple[str, Path]] = []
    mapping = catalog_mapping(path.parent)
    for iri in sorted(str(o) for o in Graph().parse(path, format="turtle").objects(None, OWL.imports)):
        if iri in done:
            continue
        done.add(iri)
        target = mapping[iri]
        out += imports_in_order(target, done)
        out.append((iri, target))
    return out


def _to_ntriples(turtle: str | Path, dst: Path) -> Path:
    graph = Graph()
    if isinstance(turtle, Path):
        graph.parse(turtle, format="turtle")
    else:
        graph.parse(data=turtle, format="turtle")
    graph.serialize(dst, format="nt", encoding="utf-8")
    return dst


@pytest.fixture
def hermit(tmp_path: Path, request: pytest.FixtureRequest) -> Callable[..., Reasoned]:
    """``hermit(label, plant)`` loads the ontology plus ``plant`` (a path or Turtle text, with its
    ontology IRI found from the file) in a new World and runs HermiT on it."""

    def run(label: str, plant: Path | str | None = None, plant_iri: str | None = None,
            infer_property_values: bool = False) -> Reasoned:
        world = owlready2.World()
        tbox = _to_ntriples(ONTOLOGY_TTL, tmp_path / "plantkg.nt")
        with tbox.open("rb") as fh:
            world.get_ontology(ONTOLOGY_IRI).load(fileobj=fh, format="ntriples")
        if isinstance(plant, Path):  # its other imports (the fleet module), offline through the catalog
            for n, (iri, path) in enumerate(imports_in_order(plant, {ONTOLOGY_IRI})):
                module = _to_ntriples(path, tmp_path / f"import-{n}.nt")
                with module.open("rb") as fh:
                    world.get_ontology(iri).load(fileobj=fh, format="ntriples")
        if plant is not None:
            abox = _to_ntriples(plant, tmp_path / "plant.nt")
            iri = plant_iri or (EXAMPLES_BASE + Path(plant).stem if isinstance(plant, Path) else None)
            assert iri, "give plant_iri for inline Turtle"
            with abox.open("rb") as fh:
                world.get_ontology(iri).load(fileobj=fh, format="ntriples")
        start = time.perf_counter()
        try:
            owlready2.sync_reasoner(world, infer_property_values=infer_property_values, debug=0)
        finally:
            seconds = time.perf_counter() - start
            request.config.stash.setdefault(_TIMINGS, []).append((label, seconds))
        return Reasoned(world, seconds)

    return run


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter, config: pytest.Config) -> None:
    timings = config.stash.get(_TIMINGS, [])
    if not timings:
        return
    terminalreporter.section("HermiT (owlready2 sync_reasoner) wall time")
    for label, seconds in timings:
        terminalreporter.write_line(f"{seconds:6.2f} s  {label}")
    total = sum(s for _, s in timings)
    terminalreporter.write_line(f"{total:6.2f} s  total, {len(timings)} runs")

"""A plant that passes the shapes must not break the reasoner: HermiT finds every such case consistent.

The next stage reasons over the plant with HermiT (through owlready2, which first parses the plant
itself). The shapes promise that a conforming plant is consistent with the ontology and made of
literals both can read (see the header of shapes/plantkg-shapes.ttl). Here that promise is tested on
every shape case without a Violation (valid plants, boundary cases, warnings only), and, the other
way round, on one case per reasoner-motivated shape: HermiT does refuse those plants, so the shape
is not stricter than it claims.

Speed: all conforming cases go to HermiT as one document (one JVM run, a few seconds), each case's
IRIs renamed into a namespace of its own so they cannot meet; only if that run fails is each case
run alone, to name the ones at fault. Consistency is monotonic, so one consistent union means every
case is consistent. The plant is written as the reasoning stage writes it (engine/reasoning/rules_owlready.py):
the N-Triples Oxigraph holds after kg.load, every individual an owl:NamedIndividual and the
individuals of one plant owl:AllDifferent (the unique-name assumption of unique pk:ids).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import owlready2
import pyoxigraph as ox
import pytest

from kg.load import PlantGraph, load_plant
from kg.namespaces import ONTOLOGY_IRI, OWL, RDF

ROOT = Path(__file__).resolve().parents[2]
CASES_DIR = ROOT / "tests" / "cases" / "shapes"
CASES = sorted(p for p in CASES_DIR.iterdir() if (p / "plant.ttl").exists())
EX = "http://example.org/plant#"

pytestmark = pytest.mark.skipif(shutil.which("java") is None, reason="HermiT needs Java")


def _conforms(case: Path) -> bool:
    return all(r["severity"] != "Violation" for r in json.loads((case / "expected.json").read_text()))


CONFORMING = [c for c in CASES if _conforms(c)]

#: Non-conforming cases, one per kind of reasoner-motivated shape, and how HermiT fails on them (a
#: JVM run each, ~2 s: the rest of these shapes' cases were checked the same way once, see
#: docs/shapes.md).
REFUSED_BY_HERMIT = {
    "disjoint-mqttbroker-and-topic": "inconsistent",   # pks:PlantElement-disjointClasses
    "domain-brand-on-broker": "inconsistent",          # pks:Resource-domain
    "typed-missing": "inconsistent",                   # pks:PlantElement-typed (pk:id 5)
    "sameas-two-individuals": "inconsistent",          # pks:PlantElement-sameAs
    "property-value-date-datatype": "error",           # pks:Property-valueLiteral (HermiT)
    "property-value-integer-too-big": "error",         # pks:Property-valueLiteral (owlready2)
    "fleet-resource-domain": "inconsistent",           # pks:FleetResource-domain (shapes/plantkg-fleet.ttl)
    "fleet-properties-twice": "inconsistent",          # pks:FleetResource-* maxCount (functional)
}

_TYPE = ox.NamedNode(str(RDF.type))
_NAMED = ox.NamedNode(str(OWL.NamedIndividual))
_FIRST, _REST, _NIL = (ox.NamedNode(str(RDF[x])) for x in ("first", "rest", "nil"))


def _rename(term: ox.NamedNode | ox.BlankNode | ox.Literal, tag: str):  # noqa: ANN202 - same kind out
    if isinstance(term, ox.NamedNode) and term.value.startswith(EX):
        return ox.NamedNode(f"http://example.org/{tag}#{term.value[len(EX):]}")
    if isinstance(term, ox.BlankNode):
        return ox.BlankNode(f"{tag}x{term.value}")
    return term


def _abox(plant: PlantGraph, tag: str) -> list[ox.Triple]:
    """The plant's triples (IRIs moved into namespace ``tag``), its individuals all different."""
    triples = [
        ox.Triple(_rename(q.subject, tag), q.predicate, _rename(q.object, tag))  # type: ignore[arg-type]
        for g in plant.plant_graphs for q in plant.store.quads_for_pattern(None, None, None, g)
    ]
    individuals = sorted({t.subject for t in triples if t.predicate == _TYPE and isinstance(t.subject, ox.NamedNode)},
                         key=str)
    triples += [ox.Triple(i, _TYPE, _NAMED) for i in individuals]
    if len(individuals) > 1:
        head, cell = ox.BlankNode(), ox.BlankNode()
        triples += [ox.Triple(head, _TYPE, ox.NamedNode(str(OWL.AllDifferent))),
                    ox.Triple(head, ox.NamedNode(str(OWL.distinctMembers)), cell)]
        for n, node in enumerate(individuals):
            nxt = ox.BlankNode() if n + 1 < len(individuals) else _NIL
            triples += [ox.Triple(cell, _FIRST, node), ox.Triple(cell, _REST, nxt)]
            cell = nxt  # type: ignore[assignment]
    return triples


def _tbox(plant: PlantGraph) -> bytes:
    return plant.store.dump(format=ox.RdfFormat.N_TRIPLES, from_graph=ox.NamedNode(plant.ontology.graph))


def hermit(cases: list[Path], tmp: Path) -> str:
    """Run HermiT on ``cases`` as one document: "consistent", "inconsistent" or "error: ..."."""
    plants = [load_plant([c / "plant.ttl"]) for c in cases]
    abox: list[ox.Triple] = [ox.Triple(ox.NamedNode("urn:plantkg:shape-cases"), _TYPE, ox.NamedNode(str(OWL.Ontology)))]
    for n, plant in enumerate(plants):
        abox += _abox(plant, f"case{n}")
    (tmp / "tbox.nt").write_bytes(_tbox(plants[0]))
    (tmp / "abox.nt").write_bytes(ox.serialize(abox, format=ox.RdfFormat.N_TRIPLES))
    world = owlready2.World()
    try:
        with (tmp / "tbox.nt").open("rb") as fh:
            world.get_ontology(ONTOLOGY_IRI).load(fileobj=fh, format="ntriples")
        with (tmp / "abox.nt").open("rb") as fh:
            world.get_ontology("urn:plantkg:shape-cases").load(fileobj=fh, format="ntriples")
        owlready2.sync_reasoner(world, infer_property_values=False, debug=0)
    except owlready2.OwlReadyInconsistentOntologyError:
        return "inconsistent"
    except (owlready2.OwlReadyJavaError, owlready2.OwlReadyOntologyParsingError) as e:
        lines = [x for x in str(e).splitlines() if "Exception" in x] or [str(e)]
        return "error: " + lines[0][:300]
    finally:
        world.close()
    return "consistent"


def test_there_are_conforming_cases() -> None:
    assert len(CONFORMING) >= 20
    assert all((CASES_DIR / c / "plant.ttl").exists() and not _conforms(CASES_DIR / c) for c in REFUSED_BY_HERMIT)


def test_every_conforming_case_is_consistent(tmp_path: Path) -> None:
    if hermit(CONFORMING, tmp_path) == "consistent":
        return
    failures = {c.name: outcome for c in CONFORMING if (outcome := hermit([c], tmp_path)) != "consistent"}
    assert not failures, f"cases that pass the shapes but not HermiT: {failures}"


@pytest.mark.parametrize("case", sorted(REFUSED_BY_HERMIT))
def test_hermit_refuses_what_the_reasoner_shapes_refuse(case: str, tmp_path: Path) -> None:
    outcome = hermit([CASES_DIR / case], tmp_path)
    assert outcome.split(":")[0] == REFUSED_BY_HERMIT[case], outcome

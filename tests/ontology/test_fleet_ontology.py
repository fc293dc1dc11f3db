"""The fleet module (ontology/plantkg-fleet.ttl): its terms as the fleet contract names them, its
SWRL rules in the subset both reasoners read, Protégé-editable (OWL API, catalog), loadable by
owlready2 through the catalog with HermiT concluding what the rules say, and its shapes keeping
every axiom a plant could break.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import owlready2
import pyoxigraph as ox
import pytest
from rdflib import Graph, Literal, URIRef
from rdflib.collection import Collection
from rdflib.namespace import OWL, RDF, RDFS, SH

from kg import namespaces as ns
from kg.namespaces import FLEET, FLEET_ONTOLOGY_IRI, ONTOLOGY_IRI, PK, SWRL

from .conftest import ONTOLOGY_DIR, ROOT, _to_ntriples, catalog_mapping, imports_in_order

MODULE = ONTOLOGY_DIR / "plantkg-fleet.ttl"
EXAMPLE = ONTOLOGY_DIR / "examples" / "agv-fleet.ttl"
SHAPES = ROOT / "shapes" / "plantkg-fleet.ttl"
RULES_IRI = ONTOLOGY_IRI + "/rules"
AF = "https://w3id.org/plantkg/examples/agv-fleet#"

#: The contract's data properties: name -> (domain, range); all functional.
PROPERTIES = {
    "interface": (PK.Resource, ns.XSD.string), "manufacturer": (PK.Resource, ns.XSD.string),
    "serialNumber": (PK.Resource, ns.XSD.string), "discovered": (PK.Resource, ns.XSD.boolean),
    "connectionState": (PK.Resource, ns.XSD.string), "pinned": (PK.Resource, ns.XSD.boolean),
    "channel": (PK.Topic, ns.XSD.string),
}
RESOURCE_TYPES = ("agv", "fleet-manager", "fleet-view")


@pytest.fixture(scope="module")
def module() -> Graph:
    return Graph().parse(MODULE, format="turtle")


def test_parses_in_rdflib_and_oxigraph(module: Graph) -> None:
    store = ox.Store()
    store.load(path=str(MODULE), format=ox.RdfFormat.TURTLE)
    assert len(store) == len(module) > 100


def test_header_imports_the_core_and_its_rules(module: Graph) -> None:
    onto = URIRef(FLEET_ONTOLOGY_IRI)
    assert (onto, RDF.type, OWL.Ontology) in module
    assert set(module.objects(onto, OWL.imports)) == {URIRef(ONTOLOGY_IRI), URIRef(RULES_IRI)}
    for prop in (OWL.versionInfo, RDFS.label, RDFS.comment):
        assert module.value(onto, prop) is not None, prop


def test_the_contracts_terms_and_nothing_else(module: Graph) -> None:
    for name, (domain, range_) in PROPERTIES.items():
        term = FLEET[name]
        assert set(module.objects(term, RDF.type)) == {OWL.DatatypeProperty, OWL.FunctionalProperty}, name
        assert set(module.objects(term, RDFS.domain)) == {domain}, name
        assert set(module.objects(term, RDFS.range)) == {range_}, name
        labels, comments = list(module.objects(term, RDFS.label)), list(module.objects(term, RDFS.comment))
        assert len(labels) == 1 and labels[0].language == "en" and len(comments) == 1, name
    declared = {s for s in module.subjects() if isinstance(s, URIRef) and str(s).startswith(str(FLEET))}
    assert declared == {FLEET[n] for n in PROPERTIES} | {FLEET[t] for t in RESOURCE_TYPES}
    assert not set(module.subjects(RDF.type, OWL.Class)), "no new class: AGVs are pk:Resources"


def test_resource_types_cannot_meet_a_plants_ids(module: Graph) -> None:
    for name in RESOURCE_TYPES:
        term = FLEET[name]
        assert (term, RDF.type, PK.ResourceType) in module
        assert str(module.value(term, PK.id)) == f"fleet.{name}"
        assert module.value(term, PK.name) is not None


def test_rules_are_dl_safe_and_read_by_the_fast_engine() -> None:
    from engine.reasoning.reason import input_graphs
    from engine.reasoning.rules_tbox import read_tbox
    from kg.load import load_plant

    plant = load_plant([EXAMPLE])
    tbox = read_tbox(plant.store, input_graphs(plant), str)  # refuses anything it cannot translate
    fleet_rules = [r for r in tbox.rules if r.name.startswith("F")]
    assert [r.name.split()[0] for r in fleet_rules] == [f"F{i}" for i in range(1, 8)]
    for rule in fleet_rules:
        assert {a.kind for a in rule.body} <= {"object", "data"}
        assert [(a.kind, a.predicate) for a in rule.head] in (
            [("object", str(PK.subscribes))], [("object", str(PK.publishes))])


def test_every_rule_has_a_label_and_a_comment(module: Graph) -> None:
    rules = list(module.subjects(RDF.type, SWRL.Imp))
    assert len(rules) == 7
    for rule in rules:
        assert module.value(rule, RDFS.label) is not None and module.value(rule, RDFS.comment) is not None


@pytest.mark.skipif(shutil.which("javac") is None, reason="needs a JDK for the OWL API check")
@pytest.mark.parametrize("path", [MODULE, EXAMPLE], ids=lambda p: p.name)
def test_owl_api_reads_every_triple_through_the_catalog(path: Path) -> None:
    """What Protégé sees when it opens the file: imports resolved by the catalog next to it, every
    triple parsed, OWL 2 DL."""
    jar = Path(owlready2.__file__).parent / "hermit" / "HermiT.jar"
    checker = Path(__file__).parent / "OwlDlCheck.java"
    mapping = [f"{iri}={f}" for iri, f in catalog_mapping(path.parent).items()]
    done = subprocess.run(["java", "-cp", str(jar), str(checker), str(path), *mapping],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("OK "), done.stdout + done.stderr


def test_both_catalogs_map_the_module() -> None:
    assert catalog_mapping(ONTOLOGY_DIR)[FLEET_ONTOLOGY_IRI] == MODULE.resolve()
    assert catalog_mapping(EXAMPLE.parent)[FLEET_ONTOLOGY_IRI] == MODULE.resolve()
    assert [iri for iri, _ in imports_in_order(EXAMPLE)] == [ONTOLOGY_IRI, RULES_IRI, FLEET_ONTOLOGY_IRI]


@pytest.mark.skipif(shutil.which("java") is None, reason="HermiT needs Java")
def test_owlready2_loads_it_through_the_catalog_and_hermit_applies_the_rules(tmp_path: Path) -> None:
    world = owlready2.World()
    for n, (iri, path) in enumerate(imports_in_order(EXAMPLE)):
        with _to_ntriples(path, tmp_path / f"m{n}.nt").open("rb") as fh:
            world.get_ontology(iri).load(fileobj=fh, format="ntriples")
    with _to_ntriples(EXAMPLE, tmp_path / "plant.nt").open("rb") as fh:
        world.get_ontology("https://w3id.org/plantkg/examples/agv-fleet").load(fileobj=fh, format="ntriples")
    owlready2.sync_reasoner(world, infer_property_values=True, debug=0)
    view = world[AF + "fleet-view"]
    reads = {t.iri[len(AF):] for t in view.subscribes}
    writes = {t.iri[len(AF):] for t in view.publishes}
    assert reads == {"agv-sim-0001-state", "agv-sim-0001-connection", "agv-sim-0001-factsheet",
                     "agv-cart-1-status_channel", "agv-cart-1-movement_channel", "agv-cart-1-description_channel"}
    assert writes == {"agv-cart-1-motion_channel", "agv-cart-1-action_channel"}
    manager = world[AF + "fleet-manager"]
    assert {t.iri[len(AF):] for t in manager.publishes} == {"agv-sim-0001-order", "agv-sim-0001-instantActions"}
    assert len(manager.subscribes) == 4 + 3  # F1: everything the vehicles publish


# --- the shapes keep every axiom of the module a plant could break ---------------------------------

def _select(shapes: Graph, shape: URIRef) -> str:
    return " ".join(str(shapes.value(c, SH.select)) for c in shapes.objects(shape, SH.sparql))


def test_shapes_cover_the_modules_axioms(module: Graph) -> None:
    shapes = Graph().parse(SHAPES, format="turtle")
    pks = "https://w3id.org/plantkg/shapes#"
    domain_shape = {PK.Resource: URIRef(pks + "FleetResource-domain"), PK.Topic: URIRef(pks + "FleetTopic-domain")}
    owner = {PK.Resource: URIRef(pks + "FleetResource"), PK.Topic: URIRef(pks + "FleetTopic")}
    for name, (domain, range_) in PROPERTIES.items():
        term = FLEET[name]
        assert f"fleet:{name}" in _select(shapes, domain_shape[domain]), name
        assert term in set(shapes.objects(domain_shape[domain], SH.targetSubjectsOf)), name
        here = [p for p in shapes.objects(owner[domain], SH.property) if (p, SH.path, term) in shapes]
        assert any((p, SH.maxCount, Literal(1)) in shapes for p in here), f"{name} is functional"

        def typed(p: URIRef) -> bool:
            if (p, SH.datatype, range_) in shapes:
                return True
            members = [m for lst in shapes.objects(p, SH["in"]) for m in Collection(shapes, lst)]
            return bool(members) and all(isinstance(m, Literal) and (m.datatype or ns.XSD.string) == range_
                                         and not m.language for m in members)
        assert any(typed(p) for p in here), f"{name}: range {range_}"
    kinds = {o for s in module.subjects(RDF.type, OWL.DatatypeProperty) for o in module.objects(s, RDF.type)}
    assert kinds == {OWL.DatatypeProperty, OWL.FunctionalProperty}, "a new kind of axiom needs its shape"
    for axiom in (OWL.disjointWith, OWL.inverseOf, OWL.equivalentClass, RDFS.subClassOf, RDFS.subPropertyOf):
        assert not list(module.subjects(axiom, None)), axiom


def test_channel_values_of_shapes_and_ontology_agree(module: Graph) -> None:
    """The channel list in the shapes is the one the module's comment and the contract name."""
    shapes = Graph().parse(SHAPES, format="turtle")
    (lst,) = shapes.objects(URIRef("https://w3id.org/plantkg/shapes#FleetTopic-channel"), SH["in"])
    channels = {str(m) for m in Collection(shapes, lst)}
    comment = str(module.value(FLEET.channel, RDFS.comment))
    assert channels == set(re.findall(r'"([A-Za-z_]+)"', comment))
    assert len(channels) == 11

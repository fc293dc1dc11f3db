"""The ontology (TBox), its RDF/XML copy and the example plants.

What is checked, and why:
- the Turtle parses in rdflib and Oxigraph (both are used by kg/), and the OWL API (Protégé's
  library) reads every triple of it and finds it in the OWL 2 DL profile;
- every term of docs/conventions.md is declared with its kind, label, comment, domain, range and
  characteristics, and no undeclared term slips in;
- plantkg.owl is the Turtle, byte for byte as ``python -m kg.owl_export`` writes it;
- the examples use only declared terms and follow the plant rules the shapes will enforce;
- HermiT finds the examples consistent, classifies their brokers by brokerType, and finds plants
  that break the ontology's axioms inconsistent.
"""

from __future__ import annotations

import ipaddress
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path
from typing import Callable

import owlready2
import pyoxigraph as ox
import pytest
from rdflib import BNode, Graph, Literal, URIRef
from rdflib.collection import Collection
from rdflib.compare import isomorphic

from kg import namespaces as ns
from kg.namespaces import ONTOLOGY_IRI, PK
from kg.owl_export import export_rdfxml, to_rdfxml

from .conftest import EXAMPLES, EXAMPLES_BASE, ONTOLOGY_OWL, ONTOLOGY_TTL, ROOT, Reasoned, catalog_mapping

Hermit = Callable[..., Reasoned]

# --- what docs/conventions.md fixes -----------------------------------------------------------

CLASSES = {"Resource", "ResourceType", "Property", "Skill", "Broker", "Topic"}
DEFINED_CLASSES = {"KafkaBroker": "kafka", "ContextBroker": "ngsi-v2"}
#: Classes a broker type implies one way (a general class axiom): other types may be members too.
IMPLIED_CLASSES = {"MqttBroker": "mosquitto"}
OBJECT_PROPERTIES = {  # name: (domain, range)
    "executes": ("Resource", "Skill"),
    "isType": ("Resource", "ResourceType"),
    "hasProperty": ("Resource", "Property"),
    "sendsTo": ("Resource", "Broker"),
    "hasTopic": ("Broker", "Topic"),
    "bridgesTo": ("Broker", "Broker"),
    "publishes": ("Resource", "Topic"),
    "subscribes": ("Resource", "Topic"),
    "mayWrite": ("Resource", "Topic"),
    "mayRead": ("Resource", "Topic"),
    "nodeOf": ("Broker", "Broker"),
}
DATA_PROPERTIES = {  # name: (domain or None for all classes, range or None for rdfs:Literal, functional)
    "id": (None, ns.XSD.string, True),
    "name": (None, ns.XSD.string, True),
    "description": (None, ns.XSD.string, True),
    "brand": ("Resource", ns.XSD.string, True),
    "localization": ("Resource", ns.XSD.string, True),
    "attribute": ("ResourceType", ns.XSD.string, False),
    "value": ("Property", None, True),
    "valueType": ("Property", ns.XSD.string, True),
    "brokerType": ("Broker", ns.XSD.string, True),
    "ip": ("Broker", ns.XSD.string, True),
    "port": ("Broker", ns.XSD.integer, True),
    "mqttPort": ("Broker", ns.XSD.integer, True),
    "secretRef": ("Resource", ns.XSD.string, True),
    "clientCertificate": ("Resource", ns.XSD.boolean, True),
    "certificatePort": ("Broker", ns.XSD.integer, True),
    "principalName": ("ResourceType", ns.XSD.string, True),
    "persistEvery": ("Broker", ns.XSD.integer, True),
    "allowAnonymous": ("Broker", ns.XSD.boolean, True),
    "tls": ("Broker", ns.XSD.boolean, True),
    "external": ("Broker", ns.XSD.boolean, True),
    "valueTopic": ("Topic", ns.XSD.string, True),
    "typeTopic": ("Topic", ns.XSD.string, True),
    "partitions": ("Topic", ns.XSD.integer, True),
    "replicationFactor": ("Topic", ns.XSD.integer, True),
    "retentionMs": ("Topic", ns.XSD.integer, True),
    "qos": ("Topic", ns.XSD.integer, True),
    "retain": ("Topic", ns.XSD.boolean, True),
    "kafkaKey": ("Topic", ns.XSD.string, True),
    "entityId": ("Topic", ns.XSD.string, True),
    "entityType": ("Topic", ns.XSD.string, True),
    "nodeId": ("Broker", ns.XSD.integer, True),
    "kafkaRole": ("Broker", ns.XSD.string, False),
    "controllerPort": ("Broker", ns.XSD.integer, True),
    "minInsyncReplicas": (None, ns.XSD.integer, True),
}
#: Annotation properties of a plant's own owl:Ontology header (docs/operating.md).
ANNOTATION_PROPERTIES = {"plantName"}
SKOS_ALT_LABEL = URIRef("http://www.w3.org/2004/02/skos/core#altLabel")
DCTERMS_LICENSE = URIRef("http://purl.org/dc/terms/license")
PAPER_NAMES = {
    "Resource": "Resources",
    "ResourceType": "R_type",
    "Topic": "Topic_sub",
    "sendsTo": "broker()",
    "hasTopic": "topic_sub()",
    "bridgesTo": "bridge()",
    "brokerType": "B_type",
}

# --- plant rules (the shapes enforce them on every plant; here they keep the examples honest) ----

KAFKA_TOPIC = re.compile(r"^[A-Za-z0-9._-]{1,249}$")
KAFKA_TYPES = {"kafka"}
MQTT_TYPES = {"mosquitto"}
NGSI_TYPES = {"ngsi-v2"}
KAFKA_TOPIC_SETTINGS = (PK.partitions, PK.replicationFactor, PK.retentionMs)
MQTT_TOPIC_SETTINGS = (PK.qos, PK.retain)


def pk(name: str) -> URIRef:
    return PK[name]


@pytest.fixture(scope="module")
def tbox() -> Graph:
    return Graph().parse(ONTOLOGY_TTL, format="turtle")


def _example(path: Path) -> Graph:
    return Graph().parse(path, format="turtle")


example_params = pytest.mark.parametrize("example", EXAMPLES, ids=[p.stem for p in EXAMPLES])


def test_examples_exist() -> None:
    assert {p.stem for p in EXAMPLES} >= {"robot-cell", "multi-machine"}


# =============================================================================================
# Parsing
# =============================================================================================


@pytest.mark.parametrize("path", [ONTOLOGY_TTL, *EXAMPLES], ids=lambda p: p.name)
def test_turtle_parses_in_rdflib_and_oxigraph(path: Path) -> None:
    rdflib_count = len(Graph().parse(path, format="turtle"))
    store = ox.Store()
    store.load(path=str(path), format=ox.RdfFormat.TURTLE)
    assert rdflib_count > 0
    assert len(store) == rdflib_count


def test_rdfxml_parses_in_rdflib_and_oxigraph() -> None:
    store = ox.Store()
    store.load(path=str(ONTOLOGY_OWL), format=ox.RdfFormat.RDF_XML)
    assert len(store) == len(Graph().parse(ONTOLOGY_OWL, format="xml"))


def _javac_available() -> bool:
    return shutil.which("java") is not None and shutil.which("javac") is not None


@pytest.mark.skipif(not _javac_available(), reason="needs a JDK (java + javac) for the OWL API check")
@pytest.mark.parametrize("path", [ONTOLOGY_TTL, ONTOLOGY_OWL, *EXAMPLES], ids=lambda p: p.name)
def test_owl_api_reads_every_triple_and_finds_owl2_dl(path: Path) -> None:
    """What Protégé would see: no unparsed triple, no OWL 2 DL profile violation."""
    hermit_jar = Path(owlready2.__file__).parent / "hermit" / "HermiT.jar"
    checker = Path(__file__).parent / "OwlDlCheck.java"
    modules = catalog_mapping(ONTOLOGY_TTL.parent)  # the examples may import the fleet module too
    cmd = ["java", "-cp", str(hermit_jar), str(checker), str(path), *(f"{iri}={f}" for iri, f in modules.items())]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.startswith("OK "), done.stdout


# =============================================================================================
# The TBox: terms, annotations, axioms
# =============================================================================================


def test_header(tbox: Graph) -> None:
    onto = URIRef(ONTOLOGY_IRI)
    assert (onto, ns.RDF.type, ns.OWL.Ontology) in tbox
    for prop in (ns.OWL.versionInfo, ns.RDFS.label, ns.RDFS.comment):
        assert tbox.value(onto, prop) is not None, prop
    assert isinstance(tbox.value(onto, URIRef("http://purl.org/dc/terms/license")), URIRef)


def test_terms_of_the_conventions_are_declared_with_their_kind(tbox: Graph) -> None:
    for name in CLASSES | set(DEFINED_CLASSES) | set(IMPLIED_CLASSES):
        assert (pk(name), ns.RDF.type, ns.OWL.Class) in tbox, name
    for name in OBJECT_PROPERTIES:
        assert (pk(name), ns.RDF.type, ns.OWL.ObjectProperty) in tbox, name
    for name in DATA_PROPERTIES:
        assert (pk(name), ns.RDF.type, ns.OWL.DatatypeProperty) in tbox, name
    for name in ANNOTATION_PROPERTIES:
        assert (pk(name), ns.RDF.type, ns.OWL.AnnotationProperty) in tbox, name


def test_no_term_beyond_the_conventions(tbox: Graph) -> None:
    declared = {s for s in tbox.subjects() if isinstance(s, URIRef) and str(s).startswith(str(PK))}
    expected = {pk(n) for n in CLASSES | set(DEFINED_CLASSES) | set(IMPLIED_CLASSES) | set(OBJECT_PROPERTIES)
                | set(DATA_PROPERTIES)
                | ANNOTATION_PROPERTIES}
    assert declared == expected


def test_every_term_has_label_and_comment(tbox: Graph) -> None:
    for kind in (ns.OWL.Class, ns.OWL.ObjectProperty, ns.OWL.DatatypeProperty, ns.OWL.AnnotationProperty):
        for term in tbox.subjects(ns.RDF.type, kind):
            if not isinstance(term, URIRef) or not str(term).startswith(str(PK)):
                continue
            labels = list(tbox.objects(term, ns.RDFS.label))
            comments = list(tbox.objects(term, ns.RDFS.comment))
            assert len(labels) == 1 and labels[0].language == "en", f"{term}: rdfs:label"
            assert len(comments) == 1 and len(str(comments[0])) > 20, f"{term}: rdfs:comment"


def test_paper_names_are_alt_labels(tbox: Graph) -> None:
    for name, paper in PAPER_NAMES.items():
        assert paper in {str(o) for o in tbox.objects(pk(name), SKOS_ALT_LABEL)}, name


def test_annotation_properties_are_declared(tbox: Graph) -> None:
    """OWL 2 DL needs every annotation property outside rdfs:/owl: declared."""
    builtin = (str(ns.RDFS), str(ns.OWL), str(ns.RDF))
    for prop in set(tbox.predicates()):
        if str(prop).startswith(builtin) or str(prop).startswith(str(PK)):
            continue
        assert (prop, ns.RDF.type, ns.OWL.AnnotationProperty) in tbox, prop


def test_the_six_classes_are_pairwise_disjoint(tbox: Graph) -> None:
    groups = [set(Collection(tbox, m)) for d in tbox.subjects(ns.RDF.type, ns.OWL.AllDisjointClasses)
              for m in tbox.objects(d, ns.OWL.members)]
    assert {pk(n) for n in CLASSES} in groups


def test_object_properties_domain_and_range(tbox: Graph) -> None:
    for name, (domain, range_) in OBJECT_PROPERTIES.items():
        assert set(tbox.objects(pk(name), ns.RDFS.domain)) == {pk(domain)}, name
        assert set(tbox.objects(pk(name), ns.RDFS.range)) == {pk(range_)}, name


def test_bridges_to_is_irreflexive_and_simple(tbox: Graph) -> None:
    """Irreflexivity is legal in OWL 2 DL only for a simple property: no chain, not transitive."""
    assert (pk("bridgesTo"), ns.RDF.type, ns.OWL.IrreflexiveProperty) in tbox
    assert (pk("bridgesTo"), ns.RDF.type, ns.OWL.TransitiveProperty) not in tbox
    assert not any(tbox.triples((None, ns.OWL.propertyChainAxiom, None)))


def test_data_properties_domain_range_and_functionality(tbox: Graph) -> None:
    for name, (domain, range_, functional) in DATA_PROPERTIES.items():
        term = pk(name)
        assert set(tbox.objects(term, ns.RDFS.domain)) == ({pk(domain)} if domain else set()), name
        assert set(tbox.objects(term, ns.RDFS.range)) == ({range_} if range_ else set()), name
        assert ((term, ns.RDF.type, ns.OWL.FunctionalProperty) in tbox) == functional, name


@pytest.mark.parametrize("name", sorted(DEFINED_CLASSES))
def test_defined_broker_classes(tbox: Graph, name: str) -> None:
    """pk:X ≡ pk:Broker ⊓ ∃pk:brokerType.{"..."} — an owl:hasValue restriction."""
    (equivalent,) = tbox.objects(pk(name), ns.OWL.equivalentClass)
    members = list(Collection(tbox, tbox.value(equivalent, ns.OWL.intersectionOf)))
    assert pk("Broker") in members and len(members) == 2
    (restriction,) = [m for m in members if isinstance(m, BNode)]
    assert tbox.value(restriction, ns.OWL.onProperty) == pk("brokerType")
    assert tbox.value(restriction, ns.OWL.hasValue) == Literal(DEFINED_CLASSES[name])


@pytest.mark.parametrize("name", sorted(IMPLIED_CLASSES))
def test_implied_broker_classes(tbox: Graph, name: str) -> None:
    """pk:Broker ⊓ ∃pk:brokerType.{"..."} ⊑ pk:X, and nothing more: a plugin's broker type may be
    a pk:X too (its class a subclass), which an equivalence would make inconsistent."""
    assert not list(tbox.objects(pk(name), ns.OWL.equivalentClass))
    (general,) = [s for s in tbox.subjects(ns.RDFS.subClassOf, pk(name)) if isinstance(s, BNode)]
    members = list(Collection(tbox, tbox.value(general, ns.OWL.intersectionOf)))
    assert pk("Broker") in members and len(members) == 2
    (restriction,) = [m for m in members if isinstance(m, BNode)]
    assert tbox.value(restriction, ns.OWL.onProperty) == pk("brokerType")
    assert tbox.value(restriction, ns.OWL.hasValue) == Literal(IMPLIED_CLASSES[name])


# =============================================================================================
# The RDF/XML copy
# =============================================================================================


def test_rdfxml_copy_is_isomorphic_to_the_turtle(tbox: Graph) -> None:
    assert isomorphic(tbox, Graph().parse(ONTOLOGY_OWL, format="xml")), (
        "ontology/plantkg.owl is stale: run `python -m kg.owl_export`"
    )


def test_rdfxml_copy_is_what_the_exporter_writes(tmp_path: Path) -> None:
    out = tmp_path / "plantkg.owl"
    export_rdfxml(ONTOLOGY_TTL, out)
    assert out.read_bytes() == ONTOLOGY_OWL.read_bytes(), "run `python -m kg.owl_export`"


def test_export_does_not_depend_on_hash_seed(tmp_path: Path) -> None:
    outputs = []
    for seed in ("1", "2"):
        dst = tmp_path / f"seed{seed}.owl"
        env = {**os.environ, "PYTHONHASHSEED": seed}
        subprocess.run([sys.executable, "-m", "kg.owl_export", str(ONTOLOGY_TTL), str(dst)],
                       cwd=ROOT, env=env, check=True, capture_output=True, timeout=120)
        outputs.append(dst.read_bytes())
    assert outputs[0] == outputs[1]


def test_exporter_round_trips_examples_too() -> None:
    """The writer is not tuned to the TBox: example plants (lists-free, many literals) survive."""
    for path in EXAMPLES:
        graph = _example(path)
        assert isomorphic(graph, Graph().parse(data=to_rdfxml(graph), format="xml")), path.name


# =============================================================================================
# The example plants: terms and plant rules
# =============================================================================================


@example_params
def test_examples_use_only_declared_terms(tbox: Graph, example: Path) -> None:
    g = _example(example)
    object_props = set(tbox.subjects(ns.RDF.type, ns.OWL.ObjectProperty))
    data_props = set(tbox.subjects(ns.RDF.type, ns.OWL.DatatypeProperty))
    declared = object_props | data_props | set(tbox.subjects(ns.RDF.type, ns.OWL.Class))
    used = {t for triple in g for t in triple if isinstance(t, URIRef) and str(t).startswith(str(PK))}
    assert used - declared == set()
    for s, p, o in g:
        if p in object_props:
            assert isinstance(o, URIRef), (s, p, o)
        if p in data_props:
            assert isinstance(o, Literal), (s, p, o)


def _individuals(g: Graph) -> dict[URIRef, URIRef]:
    """Every individual typed with one of the six classes, and that class."""
    out: dict[URIRef, URIRef] = {}
    for s, _, cls in g.triples((None, ns.RDF.type, None)):
        if cls in {pk(n) for n in CLASSES}:
            assert s not in out, f"{s} has two plantkg classes"
            out[s] = cls  # type: ignore[assignment]
    return out


@example_params
def test_every_individual_has_a_unique_id_and_a_name(example: Path) -> None:
    g = _example(example)
    individuals = _individuals(g)
    for s in individuals:
        assert len(list(g.objects(s, PK.id))) == 1, f"{s}: exactly one pk:id"
        assert len(list(g.objects(s, PK.name))) == 1, f"{s}: exactly one pk:name"
        assert str(s).endswith("#" + str(g.value(s, PK.id))), f"{s}: IRI local name is its id"
    ids = Counter(str(g.value(s, PK.id)) for s in individuals)
    assert [i for i, n in ids.items() if n > 1] == []
    typed = {s for s in g.subjects(ns.RDF.type, None)} - {URIRef(EXAMPLES_BASE + example.stem)}
    assert typed == set(individuals), "every subject is one of the six classes"


@example_params
def test_literals_hold_no_line_breaks_or_nul(example: Path) -> None:
    for _, _, o in _example(example):
        if isinstance(o, Literal):
            assert not set(str(o)) & {"\n", "\r", "\x00"}, repr(o)


@example_params
def test_brokers_have_valid_addresses(example: Path) -> None:
    g = _example(example)
    seen = set()
    for broker in g.subjects(ns.RDF.type, PK.Broker):
        port = g.value(broker, PK.port)
        ip = g.value(broker, PK.ip)
        if (None, PK.nodeOf, broker) in g:  # a Kafka cluster: its nodes have the addresses
            assert ip is None and port is None, broker
            continue
        assert port.datatype == ns.XSD.integer and 1 <= port.toPython() <= 65535, broker
        ipaddress.ip_address(str(ip))
        assert g.value(broker, PK.brokerType) in {Literal(t) for t in MQTT_TYPES | KAFKA_TYPES | NGSI_TYPES}
        assert (str(ip), int(port)) not in seen, f"{broker}: ip+port already used"
        seen.add((str(ip), int(port)))


@example_params
def test_bridges_join_distinct_brokers_sharing_a_topic(example: Path) -> None:
    g = _example(example)
    bridges = list(g.subject_objects(PK.bridgesTo))
    # An example may rely on rule R1 alone (agv-middleware.ttl: every bridge is derived).
    assert bridges or list(g.subjects(PK.subscribes, None))
    for a, b in bridges:
        assert a != b
        shared = set(g.objects(a, PK.hasTopic)) & set(g.objects(b, PK.hasTopic))
        assert shared, f"{a} -> {b} share no topic"


@example_params
def test_a_resource_broker_carries_its_topics(example: Path) -> None:
    g = _example(example)
    for resource in g.subjects(ns.RDF.type, PK.Resource):
        topics = set(g.objects(resource, PK.publishes)) | set(g.objects(resource, PK.subscribes))
        brokers = list(g.objects(resource, PK.sendsTo))
        if topics:
            assert brokers, f"{resource} publishes or subscribes but sends to no broker"
        for broker in brokers:
            missing = topics - set(g.objects(broker, PK.hasTopic))
            assert not missing, f"{broker} does not carry {missing} of {resource}"


@example_params
def test_property_values_fit_their_value_type(example: Path) -> None:
    g = _example(example)
    for prop in g.subjects(ns.RDF.type, PK.Property):
        value, value_type = g.value(prop, PK.value), g.value(prop, PK.valueType)
        assert isinstance(value, Literal) and value_type is not None, prop
        datatype = value.datatype or (ns.XSD.string if not value.language else ns.RDF.langString)
        assert datatype == ns.XSD[str(value_type)], f"{prop}: {value!r} is not {value_type}"
        assert not value.ill_typed, f"{prop}: {value!r} is not a valid {value_type}"


@example_params
def test_topic_names_are_valid_for_every_broker_carrying_them(example: Path) -> None:
    g = _example(example)
    for topic in g.subjects(ns.RDF.type, PK.Topic):
        name = str(g.value(topic, PK.name))
        kinds = {str(g.value(b, PK.brokerType)) for b in g.subjects(PK.hasTopic, topic)}
        assert kinds, f"{topic} is carried by no broker"
        if kinds & KAFKA_TYPES:
            assert KAFKA_TOPIC.match(name) and name not in {".", ".."}, name
            clusters = all((None, PK.nodeOf, b) in g for b in g.subjects(PK.hasTopic, topic)
                           if str(g.value(b, PK.brokerType)) in KAFKA_TYPES)
            for setting in KAFKA_TOPIC_SETTINGS:
                if setting == PK.replicationFactor and clusters:
                    continue  # each cluster gives it its own default (docs/kafka.md)
                assert g.value(topic, setting) is not None, f"{topic}: Kafka needs {setting}"
        if kinds & MQTT_TYPES:
            assert name and not set(name) & {"+", "#", "\x00", " "} and not name.startswith("$"), name
            assert len(name.encode()) <= 65535
            assert g.value(topic, PK.qos).toPython() in {0, 1, 2}, topic
            assert g.value(topic, PK.retain).datatype == ns.XSD.boolean, topic


# =============================================================================================
# HermiT through owlready2
# =============================================================================================


def _iris(cls: object) -> set[str]:
    return {i.iri for i in cls.instances()}  # type: ignore[attr-defined]


def test_hermit_finds_the_ontology_consistent(hermit: Hermit) -> None:
    run = hermit("TBox alone")
    assert run.world[str(PK.Broker)] is not None


@example_params
def test_hermit_finds_the_example_consistent_and_classifies_brokers(hermit: Hermit, example: Path) -> None:
    g = _example(example)
    expected = {
        "MqttBroker": {str(b) for b, t in g.subject_objects(PK.brokerType) if str(t) in MQTT_TYPES},
        "KafkaBroker": {str(b) for b, t in g.subject_objects(PK.brokerType) if str(t) in KAFKA_TYPES},
        "ContextBroker": {str(b) for b, t in g.subject_objects(PK.brokerType) if str(t) in NGSI_TYPES},
    }
    assert (PK.MqttBroker, None, None) not in g and (None, ns.RDF.type, PK.MqttBroker) not in g
    assert expected["MqttBroker"] and (expected["KafkaBroker"] or expected["ContextBroker"])
    run = hermit(f"{example.stem} (TBox + plant)", example)
    for name, brokers in expected.items():
        assert _iris(run.world[str(PK[name])]) == brokers, name


@example_params
def test_protege_sees_the_rules_conclusions_in_each_example(hermit: Hermit, example: Path) -> None:
    """Each example imports the rules module (the catalog resolves it offline), so HermiT with
    its SWRL rules — as Protégé runs it — concludes what plantkg's own engine concludes: which
    brokers must bridge to which, and which topics each broker must carry."""
    from engine.reasoning.reason import reason
    from kg.load import load_plant
    from kg.namespaces import GRAPH_INFERRED

    imported = {str(o) for o in _example(example).objects(None, ns.OWL.imports)}
    assert "https://w3id.org/plantkg/ontology/rules" in imported or example.stem == "agv-fleet"
    plant = load_plant([example])
    reason(plant, engine="fast")
    inferred = ox.NamedNode(GRAPH_INFERRED)
    expected = {(p, q.subject.value, q.object.value)
                for p in ("requiresBridge", "mustCarry")
                for q in plant.store.quads_for_pattern(None, ox.NamedNode(str(PK[p])), None, inferred)}
    assert {p for p, _, _ in expected} == {"requiresBridge", "mustCarry"}, expected
    run = hermit(f"{example.stem} (rules, property values)", example, infer_property_values=True)
    found = set()
    for broker in {s for _, s, _ in expected}:
        individual = run.world[broker]
        for p in ("requiresBridge", "mustCarry"):  # INDIRECT_: through sub-properties too, as Protégé shows
            found |= {(p, broker, value.iri) for value in getattr(individual, f"INDIRECT_{p}")}
    assert found == expected, (sorted(expected - found), sorted(found - expected))


_PLANT_HEAD = """
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <https://example.org/bad#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
<https://example.org/bad> a owl:Ontology .
"""

INCONSISTENT_PLANTS = {
    # the six classes are disjoint
    "broker-and-topic": 'ex:x a pk:Broker , pk:Topic ; pk:id "x" .',
    # bridgesTo is irreflexive
    "self-bridge": 'ex:b a pk:Broker ; pk:brokerType "mosquitto" ; pk:bridgesTo ex:b .',
    # brand's domain is Resource, disjoint from Broker
    "brand-on-a-broker": 'ex:b a pk:Broker ; pk:brand "ABB" .',
    # brokerType is functional
    "two-broker-types": 'ex:b a pk:Broker ; pk:brokerType "mosquitto" , "kafka" .',
    # hasTopic's range is Topic, disjoint from Broker
    "broker-as-topic": 'ex:a a pk:Broker ; pk:hasTopic ex:b . ex:b a pk:Broker .',
    # name's range is xsd:string; a language-tagged literal is not one
    "language-tagged-name": 'ex:s a pk:Skill ; pk:name "Weld"@en .',
}


@pytest.mark.parametrize("case", sorted(INCONSISTENT_PLANTS))
def test_hermit_reports_an_inconsistent_plant(hermit: Hermit, case: str) -> None:
    with pytest.raises(owlready2.OwlReadyInconsistentOntologyError):
        hermit(f"inconsistent: {case}", _PLANT_HEAD + INCONSISTENT_PLANTS[case], "https://example.org/bad")


def test_protege_catalog_maps_the_ontology_iri_to_the_turtle() -> None:
    """Protégé resolves the examples' owl:imports offline through ontology/examples/catalog-v001.xml."""
    catalog = EXAMPLES[0].parent / "catalog-v001.xml"
    entries = ET.parse(catalog).getroot().findall("{urn:oasis:names:tc:entity:xmlns:xml:catalog}uri")
    mapping = {e.get("name"): (catalog.parent / str(e.get("uri"))).resolve() for e in entries}
    assert mapping[ONTOLOGY_IRI] == ONTOLOGY_TTL.resolve()
    for example in EXAMPLES:
        imports = set(_example(example).objects(None, ns.OWL.imports))
        assert URIRef(ONTOLOGY_IRI) in imports, example.name
        for iri in imports:  # agv-fleet.ttl also imports the fleet module
            assert mapping[str(iri)] == (ONTOLOGY_TTL.parent / catalog_mapping(ONTOLOGY_TTL.parent)[str(iri)].name).resolve()


def _docs_plant() -> str:
    text = (ROOT / "docs" / "ontology.md").read_text(encoding="utf-8")
    (block,) = re.findall(r"```turtle\n(.*?)```", text, flags=re.S)
    return block


def test_the_plant_in_docs_uses_declared_terms_and_reasons(tbox: Graph, hermit: Hermit) -> None:
    g = Graph().parse(data=_docs_plant(), format="turtle")
    declared = set(tbox.subjects(ns.RDF.type, None))
    used = {t for triple in g for t in triple if isinstance(t, URIRef) and str(t).startswith(str(PK))}
    assert used <= declared
    head = "<https://example.org/my-plant> a <http://www.w3.org/2002/07/owl#Ontology> .\n"
    run = hermit("docs/ontology.md plant", head + _docs_plant(), "https://example.org/my-plant")
    assert _iris(run.world[str(PK.KafkaBroker)]) == {"https://example.org/my-plant#kafka"}

"""engine.reasoning.reason: the rules live in the graph, the inferred graph is what SPARQL reads, and the fast
engine refuses — naming it — what it cannot translate (the engines' agreement is in
test_reason_engines.py)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import owlready2
import pyoxigraph as ox
import pytest

from benchmarks import synthetic
from engine.reasoning.reason import (
    InconsistentPlantError, ReasonerTimeoutError, ReasoningError, UnsupportedConstructError,
    is_reasoned, reason,
)
from kg import resources
from kg.load import load_plant
from kg.namespaces import GRAPH_INFERRED, GRAPH_OBSERVED, GRAPH_ONTOLOGY, PK, RDF, SWRL
from tests.conftest import child_pids

ROOT = Path(__file__).resolve().parents[2]
ROBOT_CELL = ROOT / "ontology" / "examples" / "robot-cell.ttl"
MULTI = ROOT / "ontology" / "examples" / "multi-machine.ttl"
INFERRED = ox.NamedNode(GRAPH_INFERRED)
P = str(PK)
RC = "https://w3id.org/plantkg/examples/robot-cell#"

HEADER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix swrl: <http://www.w3.org/2003/11/swrl#> .
@prefix : <http://example.org/p#> .
"""

SMALL = """
:mq a pk:Broker ; pk:brokerType "mosquitto" . :kf a pk:Broker ; pk:brokerType "kafka" .
:t a pk:Topic .
:p a pk:Resource ; pk:sendsTo :mq ; pk:publishes :t .
:s a pk:Resource ; pk:sendsTo :kf ; pk:subscribes :t .
"""


def plant_of(tmp_path: Path, body: str, name: str = "plant.ttl"):
    path = tmp_path / name
    path.write_text(HEADER + body)
    return load_plant([path])


def inferred(plant) -> set[tuple[str, str, str]]:
    return {(q.subject.value, q.predicate.value, q.object.value)
            for q in plant.store.quads_for_pattern(None, None, None, INFERRED) if q.subject != INFERRED}


def ask(plant, query: str) -> bool:
    return bool(plant.store.query(query, prefixes={"pk": P}, use_default_graph_as_union=True))


# --- where the rules are ------------------------------------------------------------------------

def test_ontology_graph_holds_every_tbox_file() -> None:
    plant = load_plant([ROBOT_CELL])
    files = [s.path.name for s in plant.tbox]
    assert files[0] == "plantkg.ttl" and "plantkg-rules.ttl" in files
    core = [p.name for p in resources.ontology_files()]
    assert all(p.parent.name == "ontology" for p in (s.path for s in plant.tbox[:len(core)]))
    # then the ontology files of installed plugin packages (plantkg.ontology entry points)
    assert [p.name for p in resources.tbox_files()] == files and files[:len(core)] == core
    g = ox.NamedNode(GRAPH_ONTOLOGY)
    assert list(plant.store.quads_for_pattern(ox.NamedNode(P + "requiresBridge"), None, None, g))
    # R1, R2a, R2b of plantkg-rules.ttl, F1-F7 of plantkg-fleet.ttl, A1-A2 of plantkg-access.ttl,
    # K1 of plantkg-kafka.ttl
    assert len(list(plant.store.quads_for_pattern(None, ox.NamedNode(str(RDF.type)), ox.NamedNode(str(SWRL.Imp)), g))) == 3 + 7 + 2 + 1


@pytest.mark.skipif(shutil.which("javac") is None, reason="needs a JDK for the OWL API check")
def test_rules_file_reads_in_the_owl_api_as_owl2_dl() -> None:
    """What Protégé sees: every triple parsed (the three rules with their labels), OWL 2 DL."""
    jar = Path(owlready2.__file__).parent / "hermit" / "HermiT.jar"
    checker = ROOT / "tests" / "ontology" / "OwlDlCheck.java"
    done = subprocess.run(["java", "-cp", str(jar), str(checker), str(ROOT / "ontology" / "plantkg-rules.ttl"),
                           f"https://w3id.org/plantkg/ontology={resources.ontology_file()}"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.startswith("OK "), done.stdout + done.stderr


def test_without_the_rules_file_nothing_is_required() -> None:
    """The rules are read from the graph: load only plantkg.ttl and no bridge is required."""
    plant = load_plant([ROBOT_CELL], ontology=resources.ontology_file())
    reason(plant, engine="fast")
    assert not any(p == P + "requiresBridge" for _, p, _ in inferred(plant))
    assert (RC + "kafka", str(RDF.type), P + "KafkaBroker") in inferred(plant)


def test_a_rule_added_in_a_plant_file_is_applied(tmp_path: Path) -> None:
    """A plant may bring a SWRL rule (here: a subscriber 'listens to' the brokers of its topic's
    publishers); the fast engine translates it like the ontology's own, and reads back its head."""
    plant = plant_of(tmp_path, SMALL + """
        :listensTo a owl:ObjectProperty ; rdfs:label "listens to" .
        <urn:swrl:var#s> a swrl:Variable . <urn:swrl:var#t> a swrl:Variable .
        <urn:swrl:var#p> a swrl:Variable . <urn:swrl:var#b> a swrl:Variable .
        [ a swrl:Imp ; rdfs:label "listener" ;
          swrl:body (
            [ a swrl:IndividualPropertyAtom ; swrl:propertyPredicate pk:subscribes ; swrl:argument1 <urn:swrl:var#s> ; swrl:argument2 <urn:swrl:var#t> ]
            [ a swrl:IndividualPropertyAtom ; swrl:propertyPredicate pk:publishes ; swrl:argument1 <urn:swrl:var#p> ; swrl:argument2 <urn:swrl:var#t> ]
            [ a swrl:IndividualPropertyAtom ; swrl:propertyPredicate pk:sendsTo ; swrl:argument1 <urn:swrl:var#p> ; swrl:argument2 <urn:swrl:var#b> ] ) ;
          swrl:head (
            [ a swrl:IndividualPropertyAtom ; swrl:propertyPredicate :listensTo ; swrl:argument1 <urn:swrl:var#s> ; swrl:argument2 <urn:swrl:var#b> ] ) ] .
        """)
    reason(plant, engine="fast")
    assert ("http://example.org/p#s", "http://example.org/p#listensTo", "http://example.org/p#mq") in inferred(plant)


# --- what reason() writes -------------------------------------------------------------------------

def test_inferences_summary_and_marker() -> None:
    plant = load_plant([ROBOT_CELL])
    assert not is_reasoned(plant)
    result = reason(plant, engine="fast")
    assert result.engine == "fast" and result.fallback is None and result.seconds > 0
    assert result.count(P + "DeployedBroker") == 2
    assert result.count(P + "KafkaBroker") == result.count(P + "MqttBroker") == 1
    assert result.count(P + "requiresBridge") == 1  # from the asserted bridgesTo (R1 agrees)
    assert result.count(P + "mustCarry") == 3       # the three hasTopic
    assert result.total == len(inferred(plant))
    assert is_reasoned(plant)
    assert result.to_dict()["engine"] == "fast"


def test_sparql_sees_inferred_facts_next_to_asserted_ones() -> None:
    plant = load_plant([ROBOT_CELL])
    reason(plant)
    assert ask(plant, f"ASK {{ <{RC}mosquitto> a pk:MqttBroker , pk:DeployedBroker ; pk:requiresBridge <{RC}kafka> }}")
    # only what no file asserts is in the inferred graph
    assert not ask(plant, f"ASK {{ GRAPH <{GRAPH_INFERRED}> {{ ?b a pk:Broker }} }}")


def test_reason_again_replaces_the_inferred_graph(tmp_path: Path) -> None:
    plant = plant_of(tmp_path, SMALL)
    first = reason(plant, engine="fast")
    before = inferred(plant)
    second = reason(plant, engine="fast")
    assert inferred(plant) == before and first.classes == second.classes
    # the plant changes: the subscriber leaves, its bridge and its broker's topic go away
    s = ox.NamedNode("http://example.org/p#s")
    for q in list(plant.store.quads_for_pattern(s, ox.NamedNode(P + "sendsTo"), None, None)):
        plant.store.remove(q)
    reason(plant, engine="fast")
    gone = before - inferred(plant)
    assert {(a.rsplit("#")[-1], p.rsplit("#")[-1], b.rsplit("#")[-1]) for a, p, b in gone} == {
        ("mq", "requiresBridge", "kf"), ("kf", "mustCarry", "t"), ("kf", "type", "DeployedBroker")}


def test_observed_graph_is_not_read(tmp_path: Path) -> None:
    plant = plant_of(tmp_path, ":idle a pk:Broker . :t a pk:Topic .")
    observed = ox.NamedNode(GRAPH_OBSERVED)
    plant.store.add(ox.Quad(ox.NamedNode("http://example.org/p#idle"), ox.NamedNode(P + "hasTopic"),
                            ox.NamedNode("http://example.org/p#t"), observed))
    reason(plant, engine="fast")
    assert inferred(plant) == set()


def test_unknown_engine_is_refused() -> None:
    with pytest.raises(ReasoningError, match="unknown reasoning engine"):
        reason(load_plant([ROBOT_CELL]), engine="pellet")  # type: ignore[arg-type]


def test_every_derived_bridge_forwards_the_topic_that_caused_it(tmp_path: Path) -> None:
    """R1 + R2a/R2b: both ends of a bridge R1 requires carry its topic, so the bridge forwards it."""
    path = tmp_path / "synthetic-300.ttl"
    with path.open("w") as fh:
        synthetic.write(300, fh)
    plant = load_plant([path])
    reason(plant, engine="fast")
    rows = list(plant.store.query("""
        SELECT ?a ?c WHERE {
            ?p pk:sendsTo ?a ; pk:publishes ?t . ?s pk:sendsTo ?c ; pk:subscribes ?t . FILTER(?a != ?c)
            FILTER NOT EXISTS { ?a pk:mustCarry ?t . ?c pk:mustCarry ?t . ?a pk:requiresBridge ?c }
        }""", prefixes={"pk": P}, use_default_graph_as_union=True))
    assert rows == []
    assert ask(plant, "ASK { ?a pk:requiresBridge ?c FILTER NOT EXISTS { ?a pk:bridgesTo ?c } }")


# --- refusals -------------------------------------------------------------------------------------

UNSUPPORTED = {
    "owl:TransitiveProperty": ":near a owl:ObjectProperty , owl:TransitiveProperty . :mq :near :kf .",
    "owl:allValuesFrom": """:Quiet a owl:Class ; owl:equivalentClass [ a owl:Restriction ;
                             owl:onProperty pk:hasTopic ; owl:allValuesFrom pk:Topic ] .""",
    "owl:complementOf": ":Idle a owl:Class ; owl:equivalentClass [ a owl:Class ; owl:complementOf pk:DeployedBroker ] .",
    "owl:sameAs": ":mq owl:sameAs :mq2 .",
    "owl:propertyChainAxiom": ":feeds a owl:ObjectProperty ; owl:propertyChainAxiom ( pk:sendsTo pk:hasTopic ) .",
    "swrl:BuiltinAtom": """<urn:swrl:var#x> a swrl:Variable .
        [ a swrl:Imp ; rdfs:label "builtin" ;
          swrl:body ( [ a swrl:ClassAtom ; swrl:classPredicate pk:Broker ; swrl:argument1 <urn:swrl:var#x> ]
                      [ a swrl:BuiltinAtom ; swrl:builtin <http://www.w3.org/2003/11/swrlb#equal> ] ) ;
          swrl:head ( [ a swrl:ClassAtom ; swrl:classPredicate pk:Broker ; swrl:argument1 <urn:swrl:var#x> ] ) ] .""",
    "not DL-safe": """<urn:swrl:var#x> a swrl:Variable . <urn:swrl:var#y> a swrl:Variable .
        [ a swrl:Imp ; rdfs:label "unsafe" ;
          swrl:body ( [ a swrl:ClassAtom ; swrl:classPredicate pk:Broker ; swrl:argument1 <urn:swrl:var#x> ] ) ;
          swrl:head ( [ a swrl:IndividualPropertyAtom ; swrl:propertyPredicate pk:requiresBridge ;
                        swrl:argument1 <urn:swrl:var#x> ; swrl:argument2 <urn:swrl:var#y> ] ) ] .""",
    "anonymous individual": "[] a pk:Resource ; pk:sendsTo :mq .",
}


@pytest.mark.parametrize("construct", sorted(UNSUPPORTED))
def test_fast_engine_names_what_it_cannot_translate(construct: str, tmp_path: Path) -> None:
    plant = plant_of(tmp_path, SMALL + UNSUPPORTED[construct])
    with pytest.raises(UnsupportedConstructError) as caught:
        reason(plant, engine="fast")
    assert construct in str(caught.value)
    assert not is_reasoned(plant) and inferred(plant) == set()


def test_auto_falls_back_to_hermit_and_says_why(tmp_path: Path) -> None:
    plant = plant_of(tmp_path, SMALL + ":near a owl:ObjectProperty , owl:SymmetricProperty . :mq :near :kf .")
    result = reason(plant)  # auto
    assert result.engine == "owlready2"
    assert result.fallback and "owl:SymmetricProperty" in result.fallback
    assert ("http://example.org/p#mq", P + "requiresBridge", "http://example.org/p#kf") in inferred(plant)


def test_inconsistent_plant_names_the_individual(tmp_path: Path) -> None:
    plant = plant_of(tmp_path, SMALL + ":p a pk:Topic .")
    with pytest.raises(InconsistentPlantError) as caught:
        reason(plant, engine="fast")
    assert any(":p" in x or "p#p" in x or x.startswith("<http://example.org/p#p>") for x in caught.value.individuals), caught.value
    assert "disjoint" in str(caught.value) and str(tmp_path / "plant.ttl") in str(caught.value)
    assert not is_reasoned(plant)


def test_an_individual_outside_an_enumeration_is_inconsistent(tmp_path: Path) -> None:
    """A class that is exactly its listed individuals: under unique names a further member is a
    contradiction (HermiT agrees once the engine states owl:AllDifferent)."""
    plant = plant_of(tmp_path, SMALL + """
        :Shift a owl:Class ; owl:equivalentClass [ a owl:Class ; owl:oneOf ( :day :night ) ] .
        :weird a :Shift .""")
    with pytest.raises(InconsistentPlantError, match="none of the enumerated"):
        reason(plant, engine="fast")


def test_hermit_deadline_kills_the_jvm() -> None:
    plant = load_plant([MULTI])
    before = child_pids()
    with pytest.raises(ReasonerTimeoutError, match="did not finish"):
        reason(plant, engine="owlready2", timeout=0.3)
    assert child_pids() - before == set()
    assert not is_reasoned(plant)

"""The fast engine (SPARQL on Oxigraph) and HermiT through owlready2 (the reference) must conclude
the same facts.

Three sources of plants, each reasoned over by both engines and the inferred graphs compared:

- the example plants;
- small plants, one per rule and per branch of ``pk:DeployedBroker``'s definition (and a few
  traps: two brokers that only the unique-name assumption tells apart, a broker typed only by a
  property's domain). They are merged into one plant for HermiT (their individuals do not meet,
  so each keeps its own conclusions) to pay for one JVM instead of a dozen; each is also checked
  alone against the facts it must give;
- a dozen mutants of the examples from a fixed seed — triples dropped, brokers retargeted,
  publishers turned subscribers, kinds changed, bridges added — three of them inconsistent, which
  both engines must refuse the same way.

HermiT runs take 1–2 s each on an idle machine (a JVM per run); a module fixture starts all of
them at once in a few threads so the JVMs share the cores, and the file takes ~20 s on two.
"""

from __future__ import annotations

import os
import random
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Callable, Iterator

import pyoxigraph as ox
import pytest

from engine.reasoning.reason import InconsistentPlantError, ReasoningError, UnsupportedConstructError, reason
from kg.load import PlantGraph, load_plant
from kg.namespaces import GRAPH_INFERRED, PK, RDF

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = sorted((ROOT / "ontology" / "examples").glob("*.ttl"))
INFERRED = ox.NamedNode(GRAPH_INFERRED)
P = str(PK)

Fact = tuple[str, str, str]


def facts(plant: PlantGraph) -> set[Fact]:
    """The inferred graph's facts (the engine's marker left out), as IRI strings."""
    return {(q.subject.value, q.predicate.value, q.object.value)  # type: ignore[union-attr]
            for q in plant.store.quads_for_pattern(None, None, None, INFERRED)
            if q.subject != INFERRED}


def hermit(paths: list[Path]) -> set[Fact] | BaseException:
    """The owlready2 engine's facts for ``paths`` (or the error it raised)."""
    plant = load_plant(paths)
    try:
        assert reason(plant, engine="owlready2").engine == "owlready2"
    except ReasoningError as exc:
        assert facts(plant) == set()  # nothing half-written
        return exc
    return facts(plant)


class HermitRuns:
    """HermiT runs started together in a few threads (each waits for its JVM child process), so
    the JVMs use every core; ``get`` waits for one."""

    def __init__(self) -> None:
        self.pool = ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2))
        self.jobs: dict[str, Future[set[Fact] | BaseException]] = {}

    def submit(self, key: str, paths: list[Path]) -> None:
        self.jobs[key] = self.pool.submit(hermit, paths)

    def get(self, key: str) -> set[Fact] | BaseException:
        return self.jobs[key].result()


def fast_facts(paths: list[Path]) -> set[Fact]:
    plant = load_plant(paths)
    assert reason(plant, engine="fast").engine == "fast"
    return facts(plant)


def short(fact: Fact) -> str:
    return " ".join(x.replace(P, "pk:").rsplit("/", 1)[-1] for x in fact)


def assert_same(fast: set[Fact], ref: set[Fact]) -> None:
    assert fast == ref, ("only fast: " + ", ".join(sorted(map(short, fast - ref))) +
                         " | only HermiT: " + ", ".join(sorted(map(short, ref - fast))))


# =============================================================================================
# Examples
# =============================================================================================

@pytest.mark.parametrize("example", EXAMPLES, ids=[e.stem for e in EXAMPLES])
def test_engines_agree_on_example(example: Path, runs: HermitRuns) -> None:
    fast, ref = fast_facts([example]), runs.get(example.stem)
    assert not isinstance(ref, BaseException), ref
    assert_same(fast, ref)
    bridges = {(s, o) for s, p, o in fast if p == P + "requiresBridge"}
    deployed = {s for s, p, o in fast if p == str(RDF.type) and o == P + "DeployedBroker"}
    assert bridges and deployed  # the examples exercise the rules


# =============================================================================================
# Small plants: each rule, each branch of DeployedBroker
# =============================================================================================

HEADER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/{name}#> .
"""

#: name → (Turtle body, facts it must give: (subject, predicate, object) with ':' local names and
#: 'pk:' terms; only predicates listed in CHECKED are compared exactly).
SCENARIOS: dict[str, tuple[str, set[tuple[str, str, str]]]] = {
    # R1 with two brokers only the unique-name assumption tells apart (no ids, no kinds): HermiT
    # needs the owl:AllDifferent the engine states, or it derives no bridge.
    "r1-una": ("""
        :a a pk:Broker . :c a pk:Broker . :t a pk:Topic .
        :p a pk:Resource ; pk:sendsTo :a ; pk:publishes :t .
        :s a pk:Resource ; pk:sendsTo :c ; pk:subscribes :t .
        """, {(":a", "pk:requiresBridge", ":c"), (":a", "pk:mustCarry", ":t"), (":c", "pk:mustCarry", ":t"),
              (":a", "a", "pk:DeployedBroker"), (":c", "a", "pk:DeployedBroker")}),
    # R1 across kinds, as in the paper: Mosquitto publisher, Kafka consumer.
    "r1-kinds": ("""
        :mq a pk:Broker ; pk:id "mq" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1883 .
        :kf a pk:Broker ; pk:id "kf" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ; pk:port 9092 .
        :t a pk:Topic .
        :p a pk:Resource ; pk:sendsTo :mq ; pk:publishes :t .
        :s a pk:Resource ; pk:sendsTo :kf ; pk:subscribes :t .
        """, {(":mq", "pk:requiresBridge", ":kf"), (":mq", "pk:mustCarry", ":t"), (":kf", "pk:mustCarry", ":t"),
              (":mq", "a", "pk:DeployedBroker"), (":kf", "a", "pk:DeployedBroker"),
              (":mq", "a", "pk:MqttBroker"), (":kf", "a", "pk:KafkaBroker")}),
    # Publisher and subscriber on one broker: no bridge (differentFrom).
    "r1-same-broker": ("""
        :b a pk:Broker . :t a pk:Topic .
        :p a pk:Resource ; pk:sendsTo :b ; pk:publishes :t .
        :s a pk:Resource ; pk:sendsTo :b ; pk:subscribes :t .
        """, {(":b", "pk:mustCarry", ":t"), (":b", "a", "pk:DeployedBroker")}),
    # R2a alone: a publisher's broker must carry the topic (and is deployed by two branches).
    "r2a": ("""
        :b a pk:Broker . :t a pk:Topic .
        :p a pk:Resource ; pk:sendsTo :b ; pk:publishes :t .
        """, {(":b", "pk:mustCarry", ":t"), (":b", "a", "pk:DeployedBroker")}),
    # R2b alone, a subscriber sending to two brokers: both must carry the topic.
    "r2b-two-brokers": ("""
        :b1 a pk:Broker . :b2 a pk:Broker . :t a pk:Topic .
        :s a pk:Resource ; pk:sendsTo :b1 , :b2 ; pk:subscribes :t .
        """, {(":b1", "pk:mustCarry", ":t"), (":b2", "pk:mustCarry", ":t"),
              (":b1", "a", "pk:DeployedBroker"), (":b2", "a", "pk:DeployedBroker")}),
    # DeployedBroker, branch "some resource sends to it" only (the resource publishes nothing).
    "deployed-sendsTo": ("""
        :b a pk:Broker . :r a pk:Resource ; pk:sendsTo :b .
        """, {(":b", "a", "pk:DeployedBroker")}),
    # Branch "must carry a topic" only, through the asserted hasTopic (a sub-property).
    "deployed-hasTopic": ("""
        :b a pk:Broker ; pk:hasTopic :t . :t a pk:Topic .
        """, {(":b", "pk:mustCarry", ":t"), (":b", "a", "pk:DeployedBroker")}),
    # Branches "requiresBridge" and "inverse requiresBridge" only, through an asserted bridgesTo.
    "deployed-bridge": ("""
        :a a pk:Broker ; pk:bridgesTo :c . :c a pk:Broker .
        """, {(":a", "pk:requiresBridge", ":c"), (":a", "a", "pk:DeployedBroker"),
              (":c", "a", "pk:DeployedBroker")}),
    # A broker nothing needs is not deployed; a kind nobody defines gets no kind class.
    "idle-and-unknown-kind": ("""
        :idle a pk:Broker ; pk:brokerType "mosquitto" .
        :nats a pk:Broker ; pk:brokerType "nats" ; pk:hasTopic :t . :t a pk:Topic .
        """, {(":idle", "a", "pk:MqttBroker"), (":nats", "pk:mustCarry", ":t"),
              (":nats", "a", "pk:DeployedBroker")}),
    # Typed by domains and ranges only: no rdf:type at all in the plant.
    "untyped": ("""
        :r pk:sendsTo :b ; pk:publishes :t .
        :b pk:brokerType "kafka" .
        """, {(":r", "a", "pk:Resource"), (":b", "a", "pk:Broker"), (":t", "a", "pk:Topic"),
              (":b", "a", "pk:KafkaBroker"), (":b", "a", "pk:DeployedBroker"), (":b", "pk:mustCarry", ":t")}),
    # An enumeration (owl:oneOf) as a sufficient condition: the listed broker is a Mosquitto one,
    # so it gets the kind's class (and, internally, its brokerType) without stating either.
    "enumeration": ("""
        @prefix owl: <http://www.w3.org/2002/07/owl#> .
        @prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
        :Legacy a owl:Class ; owl:equivalentClass [ a owl:Class ; owl:oneOf ( :old ) ] ;
            rdfs:subClassOf pk:MqttBroker .
        :old a pk:Broker ; pk:hasTopic :t . :t a pk:Topic .
        """, {(":old", "a", "pk:MqttBroker"), (":old", "a", "pk:DeployedBroker"), (":old", "pk:mustCarry", ":t")}),
    # A chain: publisher on A, subscribers on B and C, bridge A->B asserted too.
    "fan-out": ("""
        :a a pk:Broker ; pk:bridgesTo :b . :b a pk:Broker . :c a pk:Broker . :t a pk:Topic .
        :p a pk:Resource ; pk:sendsTo :a ; pk:publishes :t .
        :s1 a pk:Resource ; pk:sendsTo :b ; pk:subscribes :t .
        :s2 a pk:Resource ; pk:sendsTo :c ; pk:subscribes :t .
        """, {(":a", "pk:requiresBridge", ":b"), (":a", "pk:requiresBridge", ":c"),
              (":a", "pk:mustCarry", ":t"), (":b", "pk:mustCarry", ":t"), (":c", "pk:mustCarry", ":t"),
              (":a", "a", "pk:DeployedBroker"), (":b", "a", "pk:DeployedBroker"), (":c", "a", "pk:DeployedBroker")}),
}
CHECKED = {"pk:requiresBridge", "pk:mustCarry", "pk:DeployedBroker", "pk:MqttBroker", "pk:KafkaBroker"}


def _expand(name: str, fact: tuple[str, str, str]) -> Fact:
    def term(x: str) -> str:
        if x == "a":
            return str(RDF.type)
        return P + x[3:] if x.startswith("pk:") else f"http://example.org/{name}#{x[1:]}"
    return (term(fact[0]), term(fact[1]), term(fact[2]))


def _checked(found: set[Fact], name: str) -> set[Fact]:
    prefix = f"http://example.org/{name}#"
    keep = {P + c[3:] for c in CHECKED}
    return {f for f in found if f[0].startswith(prefix) and (f[1] in keep or f[2] in keep)}


def _write(tmp_path: Path, name: str, body: str) -> Path:
    path = tmp_path / f"{name}.ttl"
    path.write_text(HEADER.format(name=name) + body)
    return path


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_scenario_gives_its_facts(name: str, tmp_path: Path) -> None:
    """Fast engine alone, each small plant: exactly the facts the rules promise."""
    body, expected = SCENARIOS[name]
    plant = load_plant([_write(tmp_path, name, body)])
    reason(plant, engine="fast")
    found = _checked(facts(plant), name)
    wanted = {_expand(name, f) for f in expected}
    wanted = {f for f in wanted if f[1] in {P + c[3:] for c in CHECKED} or f[2] in {P + c[3:] for c in CHECKED}}
    assert {short(f) for f in found} == {short(f) for f in wanted}
    extra = {_expand(name, f) for f in expected} - wanted
    assert extra <= facts(plant)  # the other promised facts (types from domains) are there too


def test_engines_agree_on_scenarios(runs: HermitRuns, work: Path) -> None:
    """All small plants in one store (their individuals never meet, so each keeps its own
    conclusions), both engines: the same facts, including every fact each scenario promises."""
    fast, ref = fast_facts(scenario_paths(work)), runs.get("scenarios")
    assert not isinstance(ref, BaseException), ref
    assert_same(fast, ref)
    for name, (body, expected) in SCENARIOS.items():
        for fact in expected:
            assert _expand(name, fact) in ref, (name, fact)


# =============================================================================================
# Mutants of the examples
# =============================================================================================

Triples = list[ox.Triple]
TYPE = ox.NamedNode(str(RDF.type))


def _pk(name: str) -> ox.NamedNode:
    return ox.NamedNode(P + name)


def _subjects(triples: Triples, cls: str) -> list[ox.NamedNode]:
    return sorted({t.subject for t in triples if t.predicate == TYPE and t.object == _pk(cls)},  # type: ignore[misc]
                  key=lambda n: n.value)


def _with(triples: Triples, pred: str) -> list[ox.Triple]:
    return sorted((t for t in triples if t.predicate == _pk(pred)), key=str)


def drop_random(rng: random.Random, triples: Triples) -> Triples:
    pool = [t for t in triples if t.predicate == TYPE or t.predicate.value.startswith(P)]
    gone = set(rng.sample(pool, 4))
    return [t for t in triples if t not in gone]


def retarget_sends(rng: random.Random, triples: Triples) -> Triples:
    edge = rng.choice(_with(triples, "sendsTo"))
    other = rng.choice([b for b in _subjects(triples, "Broker") if b != edge.object])
    return [t for t in triples if t != edge] + [ox.Triple(edge.subject, edge.predicate, other)]


def swap_publish_subscribe(rng: random.Random, triples: Triples) -> Triples:
    edges = rng.sample(_with(triples, "publishes") + _with(triples, "subscribes"), 3)
    flip = {"publishes": _pk("subscribes"), "subscribes": _pk("publishes")}
    swapped = [ox.Triple(e.subject, flip[e.predicate.value[len(P):]], e.object) for e in edges]
    return [t for t in triples if t not in edges] + swapped


def new_subscriber(rng: random.Random, triples: Triples) -> Triples:
    r = ox.NamedNode("http://example.org/mutant#consumer")
    return triples + [ox.Triple(r, TYPE, _pk("Resource")),
                      ox.Triple(r, _pk("sendsTo"), rng.choice(_subjects(triples, "Broker"))),
                      ox.Triple(r, _pk("subscribes"), rng.choice(_subjects(triples, "Topic")))]


def change_kind(rng: random.Random, triples: Triples) -> Triples:
    edge = rng.choice(_with(triples, "brokerType"))
    kind = rng.choice([k for k in ("mosquitto", "kafka", "nats") if k != edge.object.value])  # type: ignore[union-attr]
    return [t for t in triples if t != edge] + [ox.Triple(edge.subject, edge.predicate, ox.Literal(kind))]


def drop_broker_types(rng: random.Random, triples: Triples) -> Triples:
    broker = rng.choice(_subjects(triples, "Broker"))
    return [t for t in triples if not (t.subject == broker and t.predicate == TYPE)]


def add_bridge(rng: random.Random, triples: Triples) -> Triples:
    a, c = rng.sample(_subjects(triples, "Broker"), 2)
    return triples + [ox.Triple(a, _pk("bridgesTo"), c)]


def isolate_broker(rng: random.Random, triples: Triples) -> Triples:
    broker = rng.choice(_subjects(triples, "Broker"))
    return [t for t in triples if not (t.object == broker or (t.subject == broker and t.predicate in
                                                              (_pk("hasTopic"), _pk("bridgesTo"))))]


def combo(rng: random.Random, triples: Triples) -> Triples:
    for op in (retarget_sends, swap_publish_subscribe, add_bridge, drop_random):
        triples = op(rng, triples)
    return triples


def resource_is_topic(rng: random.Random, triples: Triples) -> Triples:  # inconsistent
    return triples + [ox.Triple(rng.choice(_subjects(triples, "Resource")), TYPE, _pk("Topic"))]


def two_kinds(rng: random.Random, triples: Triples) -> Triples:  # inconsistent: functional
    broker = rng.choice(_subjects(triples, "Broker"))
    return triples + [ox.Triple(broker, _pk("brokerType"), ox.Literal("nats"))]


def self_bridge(rng: random.Random, triples: Triples) -> Triples:  # inconsistent: irreflexive
    broker = rng.choice(_subjects(triples, "Broker"))
    return triples + [ox.Triple(broker, _pk("bridgesTo"), broker)]


MUTATIONS: list[Callable[[random.Random, Triples], Triples]] = [
    drop_random, retarget_sends, swap_publish_subscribe, new_subscriber, change_kind,
    drop_broker_types, add_bridge, isolate_broker, combo, resource_is_topic, two_kinds, self_bridge,
]
INCONSISTENT = {resource_is_topic, two_kinds, self_bridge}
SEED = 20261122


def _mutant(index: int, folder: Path) -> Path:
    rng = random.Random(SEED + index)
    example = EXAMPLES[index % len(EXAMPLES)]
    store = ox.Store()
    store.load(path=str(example), format=ox.RdfFormat.TURTLE)
    triples = sorted((ox.Triple(q.subject, q.predicate, q.object) for q in store), key=str)
    path = folder / f"mutant-{index}-{MUTATIONS[index].__name__}.nt"
    with path.open("wb") as fh:
        ox.serialize(MUTATIONS[index](rng, triples), fh, ox.RdfFormat.N_TRIPLES)
    return path


@pytest.mark.parametrize("index", range(len(MUTATIONS)), ids=[m.__name__ for m in MUTATIONS])
def test_engines_agree_on_mutant(index: int, runs: HermitRuns, work: Path) -> None:
    path = work / "mutants" / _mutant_name(index)
    ref = runs.get(f"mutant-{index}")
    if MUTATIONS[index] in INCONSISTENT:
        assert isinstance(ref, InconsistentPlantError), ref
        plant = load_plant([path])
        with pytest.raises(InconsistentPlantError) as caught:
            reason(plant, engine="fast")
        assert facts(plant) == set()  # nothing half-written
        assert caught.value.individuals, str(caught.value)  # the fast engine names them
        return
    assert not isinstance(ref, BaseException), ref
    assert_same(fast_facts([path]), ref)


def _mutant_name(index: int) -> str:
    return f"mutant-{index}-{MUTATIONS[index].__name__}.nt"


def scenario_paths(work: Path) -> list[Path]:
    return sorted((work / "scenarios").glob("*.ttl"))


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Every plant of this file, written once."""
    folder = tmp_path_factory.mktemp("reason-engines")
    (folder / "scenarios").mkdir()
    (folder / "mutants").mkdir()
    for name, (body, _) in sorted(SCENARIOS.items()):
        _write(folder / "scenarios", name, body)
    for i in range(len(MUTATIONS)):
        _mutant(i, folder / "mutants")
    _write(folder, "asserted", ASSERTED_DEPLOYED)
    return folder


@pytest.fixture(scope="module")
def runs(work: Path) -> Iterator[HermitRuns]:
    """Every HermiT run of this file, started at once."""
    pool = HermitRuns()
    for example in EXAMPLES:
        pool.submit(example.stem, [example])
    pool.submit("scenarios", scenario_paths(work))
    for i in range(len(MUTATIONS)):
        pool.submit(f"mutant-{i}", [work / "mutants" / _mutant_name(i)])
    pool.submit("asserted", [work / "asserted.ttl"])
    yield pool
    pool.pool.shutdown(wait=True)


ASSERTED_DEPLOYED = """
    :b a pk:Broker , pk:DeployedBroker ; pk:brokerType "kafka" .
"""


def test_asserted_defined_class_falls_back_to_hermit(runs: HermitRuns, work: Path) -> None:
    """An idle broker asserted to be a DeployedBroker: HermiT knows it has *some* resource, topic
    or bridge; the fast engine cannot name one, so it refuses and ``auto`` uses HermiT."""
    path = work / "asserted.ttl"
    with pytest.raises(UnsupportedConstructError, match="DeployedBroker"):
        reason(load_plant([path]), engine="fast")
    ref = runs.get("asserted")
    assert not isinstance(ref, BaseException), ref
    assert ("http://example.org/asserted#b", str(RDF.type), P + "KafkaBroker") in ref
    plant = load_plant([path])
    result = reason(plant, engine="auto")
    assert result.engine == "owlready2" and result.fallback and "DeployedBroker" in result.fallback
    assert facts(plant) == ref

"""Observed state: asking the agents (against the in-test double), and the observed named graph."""

from __future__ import annotations

from pathlib import Path

import pyoxigraph as ox
import pytest
import rdflib

from engine.errors import AgentAuthError
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker, ObservedState, ObservedTopic
from engine.observed import ObserveError, observe, observed_quads, write_observed
from kg.load import load_plant
from kg.namespaces import GRAPH_OBSERVED, ONTOLOGY_IRI, PK
from kg.query import run_query
from tests.unit.fake_agents import FakeFleet

ROOT = Path(__file__).resolve().parents[2]
VOCABULARY = ROOT / "ontology" / "plantkg-observed.ttl"

PLANT = """
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <https://example.org/plant#> .
ex:a a pk:Broker ; pk:id "a" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1883 .
ex:b a pk:Broker ; pk:id "b" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1884 .
ex:c a pk:Broker ; pk:id "c" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1885 .
ex:d a pk:Broker ; pk:id "d" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ; pk:port 9092 .
ex:e a pk:Broker ; pk:id "e" ; pk:brokerType "kafka" ; pk:ip "127.0.0.4" ; pk:port 9092 .
"""
EX = "https://example.org/plant#"

NOT_RUNNING_ON = """
SELECT ?broker ?status WHERE {
  ?broker a pk:Broker ; pk:ip ?ip .
  GRAPH <https://w3id.org/plantkg/graph/observed> { ?broker pk:status ?status }
  FILTER (?status != pk:Running)
} ORDER BY ?broker
"""


def spec(broker_id: str, kind: str, host: str, port: int) -> BrokerSpec:
    return BrokerSpec(broker_id, EX + broker_id, broker_id, kind, host, port)


OBSERVED = ObservedState(
    brokers=(
        ObservedBroker(spec("a", "mosquitto", "127.0.0.2", 1883), BrokerStatus.RUNNING,
                       (ObservedTopic("cell/x", qos=1, retain=False),), pid=41, started_at=1763780000.25,
                       restarts=0, config_hash="abc"),
        ObservedBroker(spec("b", "mosquitto", "127.0.0.2", 1884), BrokerStatus.CRASHED, restarts=3,
                       last_error="exited with code 3"),
        ObservedBroker(spec("d", "kafka", "127.0.0.3", 9092), BrokerStatus.RUNNING, pid=52),
    ),
    unreachable=("127.0.0.4",),
)


@pytest.fixture
def plant(tmp_path: Path):  # type: ignore[no-untyped-def]
    path = tmp_path / "plant.ttl"
    path.write_text(PLANT, encoding="utf-8")
    return load_plant([path])


def test_sparql_finds_brokers_on_a_host_that_are_not_running(plant) -> None:  # type: ignore[no-untyped-def]
    write_observed(plant, OBSERVED, at=1763790000.0)
    result = run_query(plant, NOT_RUNNING_ON, {"ip": ox.Literal("127.0.0.2")})
    rows = [(b.value.removeprefix(EX), s.value.removeprefix(str(PK))) for b, s in result.rows]  # type: ignore[union-attr]
    assert rows == [("b", "Crashed"), ("c", "Absent")]
    unknown = run_query(plant, NOT_RUNNING_ON, {"ip": ox.Literal("127.0.0.4")})
    assert [s.value for _b, s in unknown.rows] == [str(PK.Unknown)]  # type: ignore[union-attr]


def test_observed_facts_are_typed(plant) -> None:  # type: ignore[no-untyped-def]
    write_observed(plant, OBSERVED, at=1763790000.0)
    q = """SELECT ?port ?pid ?started ?restarts ?hash ?topic WHERE { GRAPH <%s> {
             ?b pk:observedPort ?port ; pk:pid ?pid ; pk:startedAt ?started ; pk:restarts ?restarts ;
                pk:configHash ?hash ; pk:topicPresent ?topic } }""" % GRAPH_OBSERVED
    (row,) = run_query(plant, q, {"b": ox.NamedNode(EX + "a")}).rows
    port, pid, started, restarts, digest, topic = row
    assert (port.value, pid.value, restarts.value, digest.value, topic.value) == (  # type: ignore[union-attr]
        "1883", "41", "0", "abc", "cell/x")
    assert started.datatype.value.endswith("#dateTime") and started.value == "2025-11-22T02:53:20.25Z"  # type: ignore[union-attr]


def test_writing_again_replaces_the_graph(plant) -> None:  # type: ignore[no-untyped-def]
    first = write_observed(plant, OBSERVED, at=1.0)
    again = write_observed(plant, OBSERVED, at=2.0)
    graph = ox.NamedNode(GRAPH_OBSERVED)
    assert first == again == len(list(plant.store.quads_for_pattern(None, None, None, graph)))
    # the plant's own graphs are untouched
    assert not list(plant.store.quads_for_pattern(None, ox.NamedNode(str(PK.status)), None,
                                                  ox.NamedNode(plant.sources[0].graph)))


def test_every_observation_term_is_declared_with_label_and_comment() -> None:
    vocab = rdflib.Graph().parse(VOCABULARY)
    onto = rdflib.URIRef("https://w3id.org/plantkg/ontology/observed")
    assert (onto, rdflib.OWL.imports, rdflib.URIRef(ONTOLOGY_IRI)) in vocab
    quads = observed_quads([(EX + "c", "127.0.0.2"), (EX + "e", "127.0.0.4")], OBSERVED, at=0.0)
    used = {q.predicate.value for q in quads}
    used |= {q.object.value for q in quads if isinstance(q.object, ox.NamedNode)}
    assert used
    for term in sorted(used):
        node = rdflib.URIRef(term)
        assert term.startswith(str(PK)), term
        assert (node, rdflib.RDFS.label, None) in vocab, f"{term} has no label"
        assert (node, rdflib.RDFS.comment, None) in vocab, f"{term} has no comment"


# --------------------------------------------------------------------------------- observe()

def test_observe_asks_each_agent_once_and_lists_unreachable_hosts() -> None:
    fleet = FakeFleet.from_observed(ObservedState(OBSERVED.brokers))
    fleet.down.add("127.0.0.3")
    state = observe(fleet.directory(), ["127.0.0.2", "127.0.0.3", "127.0.0.2"])
    assert [b.spec.id for b in state.brokers] == ["a", "b"]
    assert state.unreachable == ("127.0.0.3",)
    assert sorted(h for h, v, _ in fleet.calls if v == "list_brokers") == ["127.0.0.2", "127.0.0.3"]
    assert [h for h, v, _ in fleet.calls if v == "list_bridges"] == ["127.0.0.2"]  # .3 is down


def test_observe_reports_a_wrong_token_as_an_error_to_fix() -> None:
    fleet = FakeFleet()
    fleet.fail[("list_brokers", "")] = [AgentAuthError("401: bad token")]
    with pytest.raises(ObserveError, match="refused the token") as err:
        observe(fleet.directory(), ["127.0.0.2"])
    assert "127.0.0.2" in (err.value.hint or "")

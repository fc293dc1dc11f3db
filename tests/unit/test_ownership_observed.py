"""Owners in the observed graph: ``pk:observedOwner`` on a broker and on a bridge observation,
absent for what nobody owns, and declared in ontology/plantkg-observed.ttl."""

from __future__ import annotations

from pathlib import Path

import pyoxigraph as ox
import rdflib

from engine.model import (
    BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec, BridgeStatus, BrokerSpec,
    BrokerStatus, ObservedBridge, ObservedBroker, ObservedState,
)
from engine.observed import observed_quads
from kg.namespaces import PK

VOCABULARY = Path(__file__).resolve().parents[2] / "ontology" / "plantkg-observed.ttl"
EX = "https://example.org/plant#"
OWNED = BrokerSpec("a", EX + "a", "a", "mosquitto", "127.0.0.2", 1883)
HAND = BrokerSpec("h", EX + "h", "h", "mosquitto", "127.0.0.2", 1884)
BRIDGE = BridgeSpec(BridgeEnd("a", "mosquitto", "127.0.0.2", 1883),
                    BridgeEnd("h", "mosquitto", "127.0.0.2", 1884), BridgeMechanism.MOSQUITTO,
                    (BridgeRoute("t", BridgeDirection.OUT),))


def test_owners_are_in_the_observed_graph() -> None:
    observed = ObservedState(
        brokers=(ObservedBroker(OWNED, BrokerStatus.RUNNING, owner="plant-a"),
                 ObservedBroker(HAND, BrokerStatus.RUNNING)),
        bridges=(ObservedBridge(BRIDGE, BridgeStatus.RUNNING, owner="plant-a"),))
    quads = observed_quads([(EX + "a", "127.0.0.2")], observed, at=0.0)
    owners = {(q.subject.value, q.object.value) for q in quads
              if q.predicate == ox.NamedNode(str(PK.observedOwner))}
    assert owners == {(EX + "a", "plant-a"),
                      ("https://w3id.org/plantkg/graph/observed/bridge/a/h", "plant-a")}


def test_observed_owner_is_declared() -> None:
    vocab = rdflib.Graph().parse(VOCABULARY)
    term = PK.observedOwner
    assert (term, rdflib.RDF.type, rdflib.OWL.DatatypeProperty) in vocab
    assert (term, rdflib.RDFS.label, None) in vocab and (term, rdflib.RDFS.comment, None) in vocab

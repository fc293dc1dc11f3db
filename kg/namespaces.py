"""Every IRI plantkg's Python code uses, in one place.

Modules never spell an IRI out: they import it from here, so a rename of a term is one edit and a
typo is an ImportError instead of a query that silently matches nothing.
"""

from __future__ import annotations

from rdflib import Namespace
from rdflib.namespace import OWL, RDF, RDFS, SH, XSD

#: The ontology itself (owl:Ontology IRI) and its terms.
ONTOLOGY_IRI = "https://w3id.org/plantkg/ontology"
PK = Namespace(ONTOLOGY_IRI + "#")
#: The fleet module (ontology/plantkg-fleet.ttl): AGVs, their interfaces and channels.
FLEET_ONTOLOGY_IRI = ONTOLOGY_IRI + "/fleet"
FLEET = Namespace("https://w3id.org/plantkg/fleet#")
#: SWRL rules in RDF (swrl:Imp, swrl:ClassAtom, ...), as Protégé writes them.
SWRL = Namespace("http://www.w3.org/2003/11/swrl#")
#: Shapes of shapes/*.ttl.
PKS = Namespace("https://w3id.org/plantkg/shapes#")
#: Named graphs the engine and the SPARQL endpoint expose.
GRAPH_ONTOLOGY = ONTOLOGY_IRI
GRAPH_INFERRED = "https://w3id.org/plantkg/graph/inferred"
GRAPH_OBSERVED = "https://w3id.org/plantkg/graph/observed"
#: What the fast reasoner derived on the way but GRAPH_INFERRED does not hold, kept by an
#: incremental session (engine.incremental.replan) to continue from the whole fixpoint.
GRAPH_REASONING_SCRATCH = "https://w3id.org/plantkg/graph/reasoning-scratch"
#: The NGSI-v2 context broker's context as RDF (docs/context-broker.md, "The context as RDF"):
#: its vocabulary, the bases of minted entity/attribute/type IRIs and of the per-tenant graphs.
NGSI = Namespace("https://w3id.org/plantkg/ngsi#")
NGSI_ENTITY_BASE = "https://w3id.org/plantkg/ngsi/entity/"
NGSI_TYPE_BASE = "https://w3id.org/plantkg/ngsi/type/"
NGSI_GRAPH_BASE = "https://w3id.org/plantkg/graph/ngsi/"
RDF_JSON = str(RDF) + "JSON"

#: Prefixes offered to every SPARQL query (a user may still declare their own).
PREFIXES: dict[str, str] = {
    "pk": str(PK),
    "pks": str(PKS),
    "rdf": str(RDF),
    "rdfs": str(RDFS),
    "owl": str(OWL),
    "xsd": str(XSD),
    "sh": str(SH),
    "ngsi": str(NGSI),   # the context brokers' context (docs/context-broker.md)
    "fleet": str(FLEET),  # AGVs (ontology/plantkg-fleet.ttl, docs/fleet.md)
}

__all__ = [
    "FLEET",
    "FLEET_ONTOLOGY_IRI",
    "GRAPH_INFERRED",
    "GRAPH_OBSERVED",
    "GRAPH_REASONING_SCRATCH",
    "GRAPH_ONTOLOGY",
    "NGSI",
    "NGSI_ENTITY_BASE",
    "NGSI_GRAPH_BASE",
    "NGSI_TYPE_BASE",
    "ONTOLOGY_IRI",
    "OWL",
    "PK",
    "PKS",
    "PREFIXES",
    "RDF",
    "RDFS",
    "RDF_JSON",
    "SH",
    "SWRL",
    "XSD",
]

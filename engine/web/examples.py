"""Example queries offered on the SPARQL page: the questions people who run a plant ask.

Values are never spliced into these texts; a person edits them in the page. Named graphs: the
plant files (one graph per file), the ontology, ``GRAPH_INFERRED`` and ``GRAPH_OBSERVED``.
"""

from __future__ import annotations

from dataclasses import dataclass

from kg.namespaces import GRAPH_INFERRED, GRAPH_OBSERVED


@dataclass(frozen=True)
class Example:
    title: str
    query: str


EXAMPLES: tuple[Example, ...] = (
    Example("Which resource sends where", """SELECT ?resource ?name ?broker ?kind ?ip ?port WHERE {
  ?r a pk:Resource ; pk:id ?resource ; pk:sendsTo ?b .
  OPTIONAL { ?r pk:name ?name }
  ?b pk:id ?broker ; pk:brokerType ?kind ; pk:ip ?ip ; pk:port ?port .
} ORDER BY ?resource LIMIT 200"""),
    Example("Which broker is not running", f"""SELECT ?broker ?status WHERE {{
  GRAPH <{GRAPH_OBSERVED}> {{ ?b pk:status ?s }}
  ?b pk:id ?broker .
  FILTER (?s != pk:Running)
  BIND (STRAFTER(STR(?s), "#") AS ?status)
}} ORDER BY ?broker"""),
    Example("Status and restarts of every broker", f"""SELECT ?broker ?kind ?status ?restarts ?pid WHERE {{
  ?b a pk:Broker ; pk:id ?broker ; pk:brokerType ?kind .
  OPTIONAL {{ GRAPH <{GRAPH_OBSERVED}> {{ ?b pk:status ?s . BIND (STRAFTER(STR(?s), "#") AS ?status) }} }}
  OPTIONAL {{ GRAPH <{GRAPH_OBSERVED}> {{ ?b pk:restarts ?restarts }} }}
  OPTIONAL {{ GRAPH <{GRAPH_OBSERVED}> {{ ?b pk:pid ?pid }} }}
}} ORDER BY ?broker"""),
    Example("Bridges the plant needs (inferred)", f"""SELECT ?from ?to WHERE {{
  GRAPH <{GRAPH_INFERRED}> {{ ?a pk:requiresBridge ?b }}
  ?a pk:id ?from . ?b pk:id ?to .
}} ORDER BY ?from ?to"""),
    Example("Topics per broker", """SELECT ?broker (COUNT(DISTINCT ?t) AS ?topics) WHERE {
  ?b a pk:Broker ; pk:id ?broker ; pk:hasTopic ?t .
} GROUP BY ?broker ORDER BY DESC(?topics)"""),
    Example("Triples per named graph", """SELECT ?graph (COUNT(*) AS ?triples) WHERE {
  GRAPH ?graph { ?s ?p ?o }
} GROUP BY ?graph ORDER BY ?graph"""),
    Example("Describe the brokers (CONSTRUCT, Turtle)", """CONSTRUCT { ?b ?p ?o } WHERE {
  ?b a pk:Broker ; ?p ?o .
} LIMIT 200"""),
)

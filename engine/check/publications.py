"""Who publishes what, read from the plant's graph (asserted and inferred facts).

A resource publishes a topic on a broker when it ``pk:publishes`` the topic, ``pk:sendsTo`` the
broker, and the broker ``pk:hasTopic`` it (the same three facts the reasoner's bridge rule reads).
"""

from __future__ import annotations

from engine.check.flows import Publication
from kg.load import PlantGraph
from kg.query import run_query

PUBLICATIONS_QUERY = """
SELECT DISTINCT ?resourceId ?resourceName ?topicName ?brokerId WHERE {
  ?resource pk:publishes ?topic ; pk:sendsTo ?broker .
  ?broker pk:hasTopic ?topic ; pk:id ?brokerId .
  ?topic pk:name ?topicName .
  OPTIONAL { ?resource pk:id ?resourceId }
  OPTIONAL { ?resource pk:name ?resourceName }
}
"""


def publications(plant: PlantGraph) -> list[Publication]:
    """Every (resource, topic, broker) the plant publishes."""
    found = []
    for row in run_query(plant, PUBLICATIONS_QUERY).rows:
        rid, name, topic, broker = (term.value if term is not None else None for term in row)
        if topic and broker:
            ident = rid or name or "?"
            found.append(Publication(ident, name or ident, topic, broker))
    return found

"""Derive the desired state — brokers, topics, bridges — from the reasoned plant graph.

``derive(plant)`` reads, by SPARQL over the asserted and the inferred facts (``reason`` must have
run), only what the ontology concluded:

- a :class:`BrokerSpec` for every ``pk:DeployedBroker`` (kind = ``pk:brokerType``, host =
  ``pk:ip``, port = ``pk:port``; ``allow_anonymous`` = ``pk:allowAnonymous``, false on a
  ``pk:ContextBroker`` or a Mosquitto that does not say (closed by default: engine.derived.access), so
  a plan shows who may connect; users from ``pk:secretRef`` / ``pk:clientCertificate`` and the
  bridges' principals; ``tls`` = ``pk:tls`` (TLS-only listeners: a Mosquitto, a Kafka broker of
  its own, every node of a Kafka cluster that says it, a context broker's HTTPS API); ``certificate_port`` = ``pk:certificatePort`` (a TLS Mosquitto's certificate listener);
  ``mqtt_port`` = ``pk:mqttPort``, the MQTT listener of a broker type that speaks MQTT beside its
  own protocol, which bridges from MQTT brokers connect to). A broker
  marked ``pk:external`` runs outside plantkg: it is left out of the brokers (and topics) to
  deploy, but can be the far end of a bridge;
- a :class:`TopicSpec` for every ``pk:mustCarry(broker, topic)``, with the topic settings that
  apply to the broker's kind. Which settings apply is read from the broker's inferred classes:
  ``pk:KafkaBroker pk:topicSetting pk:partitions`` (``ontology/plantkg-rules.ttl``). A setting
  property maps to the TopicSpec field of the same name in snake case (``pk:replicationFactor`` →
  ``replication_factor``), so a new setting is Turtle plus a model field, not a branch here. On a
  ``pk:ContextBroker`` a topic is an entity, and its defaults are applied here so plans show the
  real entity: type "Thing", id ``urn:ngsi-ld:<type>:<topic name with / replaced by :>``;
- a :class:`BridgeSpec` for every pair of brokers joined by ``pk:requiresBridge`` (either way),
  forwarding the topics both brokers must carry (a bridge only R1 derives: the topics that made
  it fire, from publisher to subscriber — query ``SHARED``), its mechanism chosen from the brokers' inferred
  classes (:mod:`engine.derived.bridge_pairs`), ``asserted`` when the plant states ``pk:bridgesTo``.
  Bridges that would forward a topic round a cycle of three or more brokers are refused
  (:mod:`engine.derived.bridge_cycles`) before anything is deployed.

No value is spliced into a query: the only constants are vocabulary IRIs, serialised by Oxigraph.
A deployed broker or carried topic missing what its spec needs raises :class:`DeriveError` naming
it (the shapes catch this first on a validated plant). The output is sorted by address.
"""

from __future__ import annotations

import re
from bisect import insort
from collections import defaultdict
from dataclasses import dataclass, field, fields, replace
from typing import Iterable

import pyoxigraph as ox

from engine.derived.access import (
    broker_users,
    check_access_supported,
    check_kafka_tls_supported,
    close_brokers,
    run_principals,
    with_bridge_principals,
    with_plant_kafkas,
    with_run_principals,
)
from engine.errors import ConfigValueError, EngineError
from engine.derived.bridge_cycles import check_no_cycles
from engine.derived.kafka_cluster import join_clusters, read_clusters
from engine.derived.bridge_pairs import DirectedBridge, TopicOptions, pair_bridges
from engine.model import BridgeSpec, BrokerSpec, DesiredState, TopicSpec
from engine.reasoning.reason import INFERRED, input_graphs, is_reasoned
from engine.reasoning.rules_fast import short_name
from engine.reasoning.rules_tbox import dataset_options
from engine.values import check_ngsi_id
from kg.load import PlantGraph
from kg.namespaces import PK, XSD

__all__ = ["Assembled", "DeriveError", "NotReasonedError", "Parts", "PartsConflict", "assemble", "assemble_from",
           "default_entity_id", "derive", "derive_parts"]

#: The inferred class of brokers whose topics are NGSI entities, and the entity defaults.
CONTEXT_BROKER = "pk:ContextBroker"
DEFAULT_ENTITY_TYPE = "Thing"

_PREFIXES = {"pk": str(PK)}
_TOPIC_FIELDS = {f.name for f in fields(TopicSpec)} - {"broker_id", "name", "iri"}
_INTEGERS = {str(XSD[t]) for t in ("integer", "int", "long", "short", "byte", "nonNegativeInteger",
                                    "positiveInteger", "unsignedInt", "unsignedLong", "unsignedShort",
                                    "unsignedByte", "negativeInteger", "nonPositiveInteger")}

BROKERS = """
SELECT ?b ?id ?name ?kind ?ip ?port ?mqtt ?persist ?anonymous ?external ?tls ?cport WHERE {
    ?b a pk:DeployedBroker .
    FILTER NOT EXISTS { ?b a pk:KafkaCluster }
    OPTIONAL { ?b pk:id ?id } OPTIONAL { ?b pk:name ?name } OPTIONAL { ?b pk:brokerType ?kind }
    OPTIONAL { ?b pk:ip ?ip } OPTIONAL { ?b pk:port ?port } OPTIONAL { ?b pk:persistEvery ?persist }
    OPTIONAL { ?b pk:allowAnonymous ?anonymous } OPTIONAL { ?b pk:external ?external }
    OPTIONAL { ?b pk:mqttPort ?mqtt } OPTIONAL { ?b pk:tls ?tls } OPTIONAL { ?b pk:certificatePort ?cport }
}"""

ANONYMOUS_SAID = """SELECT ?b WHERE { ?b a pk:DeployedBroker ; pk:allowAnonymous ?any }"""
#: The nodes of a Kafka cluster that says ``pk:allowAnonymous true`` (a cluster is open or closed as
#: a whole; the shapes require it open, and refuse the setting on a node).
OPEN_CLUSTER_NODES = """
SELECT ?b WHERE { ?b a pk:DeployedBroker ; pk:nodeOf ?c . ?c pk:allowAnonymous ?flag . FILTER (STR(?flag) IN ("true", "1")) }"""
#: The nodes of a Kafka cluster that says ``pk:tls true``: every node's listeners speak TLS (a
#: cluster speaks TLS as a whole; the shapes refuse the setting on a node, and
#: engine.derived.access refuses a cluster whose nodes disagree, which only an unvalidated plant
#: can make).
TLS_CLUSTER_NODES = """
SELECT ?b WHERE { ?b a pk:DeployedBroker ; pk:nodeOf ?c . ?c pk:tls ?flag . FILTER (STR(?flag) IN ("true", "1")) }"""

TOPICS = """
SELECT ?b ?t ?name WHERE {
    ?b a pk:DeployedBroker ; pk:mustCarry ?t .
    OPTIONAL { ?t pk:name ?name }
}"""

SETTINGS = """
SELECT ?b ?t ?setting ?value WHERE {
    ?kind pk:topicSetting ?setting .
    ?b a ?kind ; a pk:DeployedBroker ; pk:mustCarry ?t .
    ?t ?setting ?value .
}"""

BRIDGES = """
SELECT ?a ?c ?asserted WHERE {
    ?a pk:requiresBridge ?c .
    BIND (EXISTS { ?a pk:bridgesTo ?c } AS ?asserted)
}"""

# The topics a bridge forwards from ?a to ?c: an asserted bridge (pk:bridgesTo) forwards every
# topic both ends carry; a bridge only rule R1 derives forwards the topics that made R1 fire — a
# resource publishes ?t on ?a and one subscribes to it on ?c. Without that second condition, a pair
# bridged both ways (a publisher each side) forwarded every shared topic both ways, so a context
# broker echoed each VDA 5050 state it received back onto the vehicle's state topic.
SHARED = """
SELECT DISTINCT ?a ?c ?t ?qos ?key WHERE {
    ?a pk:requiresBridge ?c .
    ?a pk:mustCarry ?t .
    ?c pk:mustCarry ?t .
    FILTER (EXISTS { ?a pk:bridgesTo ?c }
            || EXISTS { ?p pk:sendsTo ?a ; pk:publishes ?t . ?s pk:sendsTo ?c ; pk:subscribes ?t . })
    OPTIONAL { ?t pk:qos ?qos } OPTIONAL { ?t pk:kafkaKey ?key }
}"""

CLASSES = """
SELECT ?b ?class WHERE {
    ?b a pk:DeployedBroker ; a ?class .
    FILTER (?class IN (pk:MqttBroker, pk:KafkaBroker, pk:ContextBroker))
}"""


class NotReasonedError(EngineError):
    """``derive`` ran on a store ``reason`` has not filled."""

    def __init__(self) -> None:
        super().__init__("the plant has not been reasoned over: there are no inferred facts to derive from",
                         hint="call engine.reasoning.reason.reason(plant) before engine.derive.derive(plant)")


class DeriveError(EngineError):
    """A deployed broker or a carried topic lacks (or has several of) what its spec needs."""

    def __init__(self, node: str, problem: str) -> None:
        super().__init__(f"{node}: {problem}",
                         hint="run `plantkg validate` on the plant: the shapes name what to fix")
        self.node = node
        self.problem = problem


def derive(plant: PlantGraph) -> DesiredState:
    """The desired state the reasoned ``plant`` asks for (see the module docstring)."""
    return assemble(derive_parts(plant))


@dataclass
class Parts:
    """What derive concludes per deployed broker (by IRI), before the steps that look at all of
    them (bridge pairs, cycles, access, order): an incremental derive (engine.incremental.replan) recomputes
    the parts of the brokers an edit can reach and keeps the others."""

    brokers: dict[str, BrokerSpec] = field(default_factory=dict)
    external: set[str] = field(default_factory=set)
    classes: dict[str, frozenset[str]] = field(default_factory=dict)
    topics: dict[str, list[TopicSpec]] = field(default_factory=dict)
    #: broker -> topic IRI -> its spec on that context broker (the NGSI entity a bridge needs)
    entities: dict[str, dict[str, TopicSpec]] = field(default_factory=dict)
    #: bridge source broker -> topic name -> what its bridges need of the topic
    options: dict[str, dict[str, TopicOptions]] = field(default_factory=dict)
    directed: dict[str, list[DirectedBridge]] = field(default_factory=dict)
    #: a full derive's options by topic name, the last row of a name winning, as derive always
    #: did; None once parts were recomputed apart (then the sources must agree: PartsConflict)
    in_row_order: dict[str, TopicOptions] | None = None

    def without(self, iris: frozenset[str]) -> "Parts":
        """These parts but those of ``iris``."""
        def keep(d: dict) -> dict:  # type: ignore[type-arg]
            return {k: v for k, v in d.items() if k not in iris}
        return Parts(keep(self.brokers), self.external - iris, keep(self.classes), keep(self.topics),
                     keep(self.entities), keep(self.options), keep(self.directed), None)

    def merged(self, other: "Parts") -> "Parts":
        return Parts({**self.brokers, **other.brokers}, self.external | other.external,
                     {**self.classes, **other.classes}, {**self.topics, **other.topics},
                     {**self.entities, **other.entities}, {**self.options, **other.options},
                     {**self.directed, **other.directed}, None)


class PartsConflict(EngineError):
    """Parts derived apart disagree where a full derive picks by row order (two topics of one
    name with different bridge options): only a full derive gives its answer."""


def anchor(query: str) -> str:
    """The variable a derive query is restricted by for some brokers: ``?b`` (a broker), else
    ``?a`` (a bridge's source)."""
    if re.search(r"\?b\b", query):
        return "b"
    if re.search(r"\?a\b", query):
        return "a"
    raise PartsConflict(f"a derive query names neither ?b nor ?a: {query[:80]}")


def derive_parts(plant: PlantGraph, only: frozenset[str] | None = None, known: Parts | None = None,
                 queries: list[str] | None = None) -> Parts:
    """The per-broker parts of the desired state: of every deployed broker, or (``only``) of the
    brokers with these IRIs, every query restricted to them (``known``: the parts of the others,
    for the far end of a bridge and a topic's entity). ``queries`` collects the text of each
    query run (with the ``pk:`` prefix declared), for an incremental run to read."""
    if not is_reasoned(plant):
        raise NotReasonedError()
    store = plant.store
    options = dataset_options(store, [*input_graphs(plant), INFERRED])
    restrict = "" if only is None else " ".join(str(ox.NamedNode(iri)) for iri in sorted(only))

    def select(query: str) -> Iterable[ox.QuerySolution]:
        if queries is not None and only is None:
            queries.append(f"PREFIX pk: <{PK}>\n{query}")
        if only is not None:
            brace = query.index("{")
            query = f"{query[:brace + 1]} VALUES ?{anchor(query)} {{ {restrict} }} {query[brace + 1:]}"
        return store.query(query, prefixes=_PREFIXES, **options)  # type: ignore[arg-type]

    classes: dict[str, set[str]] = defaultdict(set)
    for row in select(CLASSES):
        classes[row["b"].value].add(short_name(row["class"].value))
    brokers, external = _brokers(plant, select(BROKERS), classes)
    clusters = read_clusters(lambda q: store.query(q, prefixes=_PREFIXES, **options))  # a few rows
    if only is not None and clusters:
        # A cluster joins its nodes across brokers (voters, bootstrap, lead): not derived in parts.
        raise PartsConflict("a plant with a Kafka cluster is derived in full")
    brokers, leads = join_clusters(brokers, clusters)
    by_iri = {b.iri: b for b in brokers} | leads  # a cluster's topics and bridges: on its lead node
    topics = _topics(plant, select(TOPICS), select(SETTINGS), by_iri)
    iri_of_id = {b.id: b.iri for b in brokers}
    topics = [_with_entity(plant, t) if CONTEXT_BROKER in classes[iri_of_id[t.broker_id]] else t
              for t in topics]
    # a context broker's principals get their topics' entities (the broker knows no topic names)
    carried = {(iri_of_id[t.broker_id], t.iri): t.name if t.entity_id is None else t.entity_id for t in topics}
    # a cluster's clients send to the cluster, whose topics are planned on its lead node
    carried |= {(cluster, topic): name for cluster, lead in leads.items()
                for (broker, topic), name in list(carried.items()) if broker == lead.iri}
    users = broker_users(select, carried)
    for cluster, lead in leads.items():  # a cluster's clients are its nodes' users (refused below)
        if cluster in users and lead.kafka is not None:
            users |= {b.iri: users[cluster] for b in brokers if b.kafka and b.kafka.cluster == lead.kafka.cluster}
    said = frozenset(row["b"].value for row in select(ANONYMOUS_SAID))
    open_nodes = frozenset(row["b"].value for row in select(OPEN_CLUSTER_NODES))
    brokers = [replace(b, allow_anonymous=True) if b.iri in open_nodes else b for b in brokers]
    tls_nodes = frozenset(row["b"].value for row in select(TLS_CLUSTER_NODES))
    brokers = [replace(b, tls=True) if b.iri in tls_nodes else b for b in brokers]
    brokers = close_brokers(brokers, users, said | open_nodes)
    brokers = with_run_principals(brokers, run_principals(select, carried))  # the fleet manager's
    by_iri = {b.iri: b for b in brokers}
    by_iri |= {cluster: by_iri[lead.iri] for cluster, lead in leads.items()}
    iri_of = {b.id: b.iri for b in brokers}
    parts = Parts(brokers=by_iri, external=set(external),
                  classes={b.iri: frozenset(classes[b.iri]) for b in brokers})
    for t in topics:
        parts.topics.setdefault(iri_of[t.broker_id], []).append(t)
        if t.entity_id is not None:
            parts.entities.setdefault(iri_of[t.broker_id], {})[t.iri] = t
    names = {t.iri: t.name for t in topics}
    entities = {iri: t for es in (known.entities if known else {}).values() for iri, t in es.items()}
    entities.update({t.iri: t for t in topics if t.entity_id is not None})
    shared: dict[tuple[str, str], set[str]] = defaultdict(set)
    if only is None:
        parts.in_row_order = {}
    for row in select(SHARED):
        t = row["t"].value
        if t in names:
            shared[(row["a"].value, row["c"].value)].add(names[t])
            entity = entities.get(t)
            opts = TopicOptions(
                qos=int(row["qos"].value) if row["qos"] is not None else None,
                kafka_key=row["key"].value if row["key"] is not None else None,
                entity_id=entity.entity_id if entity else None,
                entity_type=entity.entity_type if entity else None)
            parts.options.setdefault(row["a"].value, {})[names[t]] = opts
            if parts.in_row_order is not None:
                parts.in_row_order[names[t]] = opts
    ends = {**(known.brokers if known else {}), **by_iri}
    for row in select(BRIDGES):
        a, c = row["a"].value, row["c"].value
        if a not in ends or c not in ends:  # both ends are deployed by definition
            raise DeriveError(_name(plant, row["a" if a not in ends else "c"]),
                              "is at one end of a required bridge but is not a deployed broker")
        parts.directed.setdefault(a, []).append(DirectedBridge(ends[a].id, ends[c].id, frozenset(shared[(a, c)]),
                                                               asserted=row["asserted"].value == "true"))
    return parts


@dataclass
class Assembled:
    """What :func:`assemble` made, and what a later assemble of mostly the same parts reuses:
    each bridge pair's inputs and spec, and the hops that forward each topic name."""

    desired: DesiredState
    pairs: dict[frozenset[str], tuple[object, BridgeSpec]] = field(default_factory=dict)
    hops: dict[str, frozenset[tuple[str, str]]] = field(default_factory=dict)
    ids: dict[str, str] = field(default_factory=dict)  # broker IRI -> id
    #: broker id -> its topics in address order (DesiredState.topics_of's index, kept current)
    index: dict[str, tuple[TopicSpec, ...]] = field(default_factory=dict)

    def with_owner(self, owner: str | None) -> DesiredState:
        """The desired state with ``owner``, its per-broker topic index already filled (building
        it walks every topic: 0.2 s at 100k resources)."""
        desired = replace(self.desired, owner=owner)
        desired.__dict__["_topics_by_broker"] = self.index  # DesiredState's cached_property
        return desired


def assemble(parts: Parts) -> DesiredState:
    """The desired state from the parts of every deployed broker: bridge pairs and their
    mechanisms, the refusals that look at all brokers (cycles, access), sorted by address."""
    return assemble_from(parts).desired


def assemble_from(parts: Parts, previous: Assembled | None = None,
                  changed: frozenset[str] = frozenset()) -> Assembled:
    """:func:`assemble`, reusing ``previous`` where its inputs are unchanged: the parts of the
    brokers ``changed`` (IRIs) were derived again, the others are those ``previous`` was made of.
    A pair's bridge is made again only when its directed bridges, brokers, classes or topic
    options changed; cycles are looked for only among the topics whose hops changed; the other
    brokers' topics keep their (sorted) place. The result equals a full assemble's."""
    # A cluster's lead node is in the parts twice: under its own IRI and under its cluster's.
    brokers = list({b.id: b for b in parts.brokers.values()}.values())
    options: dict[str, TopicOptions] = {}
    if parts.in_row_order is not None:
        options = parts.in_row_order
    else:
        for per_source in parts.options.values():
            for name, opts in per_source.items():
                if options.setdefault(name, opts) != opts:
                    raise PartsConflict(f"topic name {name!r} has two sets of bridge options")
    directed = [d for ds in parts.directed.values() for d in ds]
    hops: dict[str, set[tuple[str, str]]] = defaultdict(set)
    for d in directed:
        for name in d.topics:
            hops[name].add((d.source, d.target))
    frozen_hops = {name: frozenset(h) for name, h in hops.items()}
    if previous is None:
        check_no_cycles(directed)  # a topic forwarded round 3+ brokers loops for ever (docs/bridges.md)
    else:
        moved = {n for n in frozen_hops.keys() | previous.hops.keys() if frozen_hops.get(n) != previous.hops.get(n)}
        check_no_cycles(replace(d, topics=d.topics & moved) for d in directed if d.topics & moved)
    by_id = {b.id: b for b in brokers}
    external = frozenset(parts.brokers[iri].id for iri in parts.external)
    classes = {b.id: parts.classes[b.iri] for b in brokers}
    per_pair: dict[frozenset[str], list[DirectedBridge]] = defaultdict(list)
    for d in directed:
        per_pair[frozenset((d.source, d.target))].append(d)
    pairs: dict[frozenset[str], tuple[object, BridgeSpec]] = {}
    todo: list[DirectedBridge] = []
    for pair, ds in per_pair.items():
        key = (tuple(sorted(ds, key=lambda d: (d.source, d.target))), tuple((by_id.get(i), classes.get(i), i in external)
                                                                             for i in sorted(pair)),
               tuple(sorted((n, options.get(n)) for d in ds for n in d.topics)))
        old = previous.pairs.get(pair) if previous is not None else None
        if old is not None and old[0] == key:
            pairs[pair] = old
        else:
            pairs[pair] = (key, None)  # type: ignore[assignment]
            todo.extend(ds)
    for spec in pair_bridges(todo, by_id, classes, options, external=external):
        pair = frozenset((spec.local.id, spec.remote.id))
        pairs[pair] = (pairs[pair][0], spec)
    bridges = sorted((spec for _, spec in pairs.values()), key=lambda s: s.address)
    deployed = [b for b in brokers if b.iri not in parts.external]
    check_access_supported(deployed)
    check_kafka_tls_supported(deployed)
    deployed = with_bridge_principals(deployed, bridges)  # each bridge a user where it logs in
    deployed = with_plant_kafkas(deployed)  # where a context broker's kafka:// notifications log in, and use TLS
    outside = {parts.brokers[iri].id for iri in parts.external}
    ids = {b.iri: b.id for b in brokers}
    if previous is None:
        topics = sorted((t for ts in parts.topics.values() for t in ts if t.broker_id not in outside),
                        key=lambda t: t.address)
        grouped: dict[str, list[TopicSpec]] = {}
        for t in topics:
            grouped.setdefault(t.broker_id, []).append(t)
        index = {k: tuple(v) for k, v in grouped.items()}
    else:
        again = {previous.ids[i] for i in changed if i in previous.ids} | {ids[i] for i in changed if i in ids}
        topics = [t for t in previous.desired.topics if t.broker_id not in again]
        index = {k: v for k, v in previous.index.items() if k not in again}
        for iri in changed:
            mine = sorted((t for t in parts.topics.get(iri, ()) if t.broker_id not in outside),
                          key=lambda t: t.address)
            for t in mine:
                insort(topics, t, key=lambda t: t.address)
            if mine:
                index[mine[0].broker_id] = tuple(mine)
    desired = DesiredState(
        brokers=tuple(sorted(deployed, key=lambda b: b.address)),
        topics=tuple(topics),
        bridges=tuple(bridges),
    )
    return Assembled(desired, pairs, frozen_hops, ids, index)


def default_entity_id(entity_type: str, topic_name: str) -> str:
    """The entity a topic is on a context broker when the plant sets no ``pk:entityId``:
    ``urn:ngsi-ld:<type>:<topic name with every / replaced by :>``."""
    return f"urn:ngsi-ld:{entity_type}:{topic_name.replace('/', ':')}"


def _with_entity(plant: PlantGraph, topic: TopicSpec) -> TopicSpec:
    """``topic`` (on a context broker) with the entity defaults applied and checked."""
    entity_type = topic.entity_type or DEFAULT_ENTITY_TYPE
    entity_id = topic.entity_id or default_entity_id(entity_type, topic.name)
    for prop, value in (("entityType", entity_type), ("entityId", entity_id)):
        try:
            check_ngsi_id(prop, value)
        except ConfigValueError as exc:
            how = "" if prop == "entityType" or topic.entity_id else " (minted from the topic name)"
            raise DeriveError(_name(plant, ox.NamedNode(topic.iri)),
                              f"pk:{prop} {value!r}{how} is not an NGSI identifier: {exc.problem}; "
                              f"set pk:{prop} on the topic") from None
    return replace(topic, entity_id=entity_id, entity_type=entity_type)


def _name(plant: PlantGraph, node: object) -> str:
    text = short_name(node.value) if isinstance(node, ox.NamedNode) else str(node)
    path = plant.source_of(node) if isinstance(node, (ox.NamedNode, ox.BlankNode)) else None
    return f"{text} ({path})" if path else text


def _one(plant: PlantGraph, node: object, prop: str, values: set[object]) -> ox.Literal:
    if not values:
        raise DeriveError(_name(plant, node), f"has no pk:{prop}")
    if len(values) > 1:
        raise DeriveError(_name(plant, node), f"has several pk:{prop} values: {sorted(map(str, values))}")
    value = next(iter(values))
    if not isinstance(value, ox.Literal):
        raise DeriveError(_name(plant, node), f"pk:{prop} is {value}, not a literal")
    return value


def _brokers(plant: PlantGraph, rows: Iterable[ox.QuerySolution],
             classes: dict[str, set[str]]) -> tuple[list[BrokerSpec], set[str]]:
    """The deployed brokers' specs, and the IRIs of those marked ``pk:external``."""
    values: dict[ox.NamedNode, dict[str, set[object]]] = defaultdict(lambda: defaultdict(set))
    for row in rows:
        slot = values[row["b"]]
        for var in ("id", "name", "kind", "ip", "port", "mqtt", "persist", "anonymous", "external", "tls", "cport"):
            if row[var] is not None:
                slot[var].add(row[var])
    out = []
    external = set()
    props = {"id": "id", "name": "name", "kind": "brokerType", "ip": "ip", "port": "port"}
    for node, slot in values.items():
        got = {var: _one(plant, node, prop, slot[var]) for var, prop in props.items()}
        port = _integer(plant, node, "port", got["port"])
        mqtt = (_integer(plant, node, "mqttPort", _one(plant, node, "mqttPort", slot["mqtt"]))
                if slot["mqtt"] else None)
        persist = (_integer(plant, node, "persistEvery", _one(plant, node, "persistEvery", slot["persist"]))
                   if slot["persist"] else None)
        anonymous = (_boolean(plant, node, "allowAnonymous", _one(plant, node, "allowAnonymous", slot["anonymous"]))
                     if slot["anonymous"] else (False if CONTEXT_BROKER in classes[node.value] else None))
        if slot["external"] and _boolean(plant, node, "external", _one(plant, node, "external", slot["external"])):
            external.add(node.value)
        tls = bool(slot["tls"]) and _boolean(plant, node, "tls", _one(plant, node, "tls", slot["tls"]))
        cport = (_integer(plant, node, "certificatePort", _one(plant, node, "certificatePort", slot["cport"]))
                 if slot["cport"] else None)
        out.append(BrokerSpec(id=got["id"].value, iri=node.value, name=got["name"].value,
                              kind=got["kind"].value, host=got["ip"].value, port=port,
                              persist_every=persist, allow_anonymous=anonymous, mqtt_port=mqtt, tls=tls,
                              certificate_port=cport))
    return _unique(out, "broker"), external


def _boolean(plant: PlantGraph, node: object, prop: str, literal: ox.Literal) -> bool:
    if literal.datatype.value != str(XSD.boolean) or literal.value not in ("true", "false", "1", "0"):
        raise DeriveError(_name(plant, node), f"pk:{prop} {literal} is not a boolean")
    return literal.value in ("true", "1")


def _topics(plant: PlantGraph, rows: Iterable[ox.QuerySolution], settings: Iterable[ox.QuerySolution],
            brokers: dict[str, BrokerSpec]) -> list[TopicSpec]:
    # Rows unpacked by position (TOPICS: ?b ?t ?name; SETTINGS: ?b ?t ?setting ?value): a lookup
    # by variable name costs about as much again as the row, 0.4 s at 100k topics.
    names: dict[tuple[str, ox.NamedNode], set[object]] = {}
    for b, t, name in rows:
        found = names.setdefault((b.value, t), set())  # a topic without a name: a (failing) entry
        if name is not None:
            found.add(name)
    values: dict[tuple[str, str], dict[str, set[object]]] = defaultdict(lambda: defaultdict(set))
    for b, t, setting, value in settings:
        values[(b.value, t.value)][_field(setting.value)].add(value)
    out = []
    for (broker, topic), found in names.items():
        name = _one(plant, topic, "name", found)
        kwargs = {}
        for field_name, vals in values.get((broker, topic.value), {}).items():
            literal = _one(plant, topic, _camel(field_name), vals)
            kwargs[field_name] = _convert(plant, topic, field_name, literal)
        out.append(TopicSpec(broker_id=brokers[broker].id, name=name.value, iri=topic.value, **kwargs))
    return _unique(out, "topic")


def _field(setting: str) -> str:
    """``pk:replicationFactor`` → ``replication_factor``: the TopicSpec field of a setting."""
    local = setting.rsplit("#", 1)[-1]
    name = re.sub(r"(?<!^)(?=[A-Z])", "_", local).lower()
    if name not in _TOPIC_FIELDS:
        raise DeriveError(short_name(setting), "is named a pk:topicSetting in the ontology, but the "
                          f"desired-state model has no topic field {name!r} for it")
    return name


def _camel(field_name: str) -> str:
    head, *rest = field_name.split("_")
    return head + "".join(w.capitalize() for w in rest)


def _integer(plant: PlantGraph, node: object, prop: str, literal: ox.Literal) -> int:
    if literal.datatype.value not in _INTEGERS:
        raise DeriveError(_name(plant, node), f"pk:{prop} {literal} is not an integer")
    return int(literal.value)


def _convert(plant: PlantGraph, node: object, field_name: str, literal: ox.Literal) -> int | bool | str:
    dt = literal.datatype.value
    if dt in _INTEGERS:
        return int(literal.value)
    if dt == str(XSD.boolean):
        return literal.value in ("true", "1")
    if dt == str(XSD.string):
        return literal.value
    raise DeriveError(_name(plant, node), f"pk:{_camel(field_name)} {literal} has a datatype the "
                      "desired state cannot hold")


def _unique(specs: list, what: str) -> list:  # type: ignore[type-arg]
    seen: dict[str, object] = {}
    for spec in specs:
        if spec.address in seen and seen[spec.address] != spec:
            raise DeriveError(spec.address, f"two different {what}s have this address: "
                              f"{getattr(seen[spec.address], 'iri', seen[spec.address])} and "
                              f"{getattr(spec, 'iri', spec)} (ids and topic names must be unique)")
        seen[spec.address] = spec
    return list(seen.values())

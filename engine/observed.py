"""Observed state: ask the agents what runs, and keep the answer in the knowledge graph.

- :func:`observe` asks every agent serving the given hosts, in parallel, for its brokers. An agent
  that does not answer (connection refused, timeout, 5xx) makes its hosts *unreachable*: the plan
  then knows it cannot decide anything there. A wrong token is an error the user must fix.
- :func:`write_observed` replaces the named graph ``GRAPH_OBSERVED`` of the plant's store with
  the observation, in the terms of ``ontology/plantkg-observed.ttl`` (``pk:status``,
  ``pk:observedPort``, ``pk:pid``, ``pk:startedAt``, ``pk:restarts``, ``pk:configHash``,
  ``pk:topicPresent``, ``pk:observedOwner`` (the plant that owns it, absent: nobody) ...) on the plant's broker individuals, so SPARQL can join desired and
  observed state. A broker of the plant that no agent runs is ``pk:Absent``; one whose agent did
  not answer is ``pk:Unknown``.
"""

from __future__ import annotations

import time
from collections import defaultdict
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from datetime import UTC, datetime

import pyoxigraph as ox

from engine.agents_config import AgentDirectory
from engine.errors import AgentAuthError, EngineError, PermanentDispatchError, TemporaryDispatchError
from engine.model import BrokerStatus, ObservedBridge, ObservedBroker, ObservedState
from kg.load import PlantGraph
from kg.namespaces import GRAPH_OBSERVED, PK, RDF, XSD
from kg.query import run_query

#: pk: individual per status, plus the two the engine adds (not observed, agent unreachable).
STATUS_TERMS: dict[BrokerStatus, str] = {
    BrokerStatus.RUNNING: "Running",
    BrokerStatus.STARTING: "Starting",
    BrokerStatus.STOPPED: "Stopped",
    BrokerStatus.STOPPED_BY_OPERATOR: "Stopped",  # the ontology has no term of its own for it yet
    BrokerStatus.CRASHED: "Crashed",
    BrokerStatus.FAILED: "Failed",
}
ABSENT = "Absent"
UNKNOWN = "Unknown"


class ObserveError(EngineError):
    """An agent answered, but refused to say what it runs (wrong token, incompatible API)."""


def observe(directory: AgentDirectory, hosts: Iterable[str], *, parallelism: int = 8) -> ObservedState:
    """Ask the agents of ``hosts`` (each distinct agent once, in parallel) what they run."""
    by_url: dict[str, list[str]] = defaultdict(list)
    for host in sorted(set(hosts)):
        by_url[directory.url_for(host)].append(host)
    if not by_url:
        return ObservedState()
    clients = {url: directory.client_for(hosts_[0]) for url, hosts_ in by_url.items()}

    def ask(url: str) -> tuple[list[ObservedBroker], list[ObservedBridge]] | None:
        try:
            client = clients[url]
            state = getattr(client, "state", None)  # one request; a client with the lists only: two
            return state() if state is not None else (client.list_brokers(), client.list_bridges())
        except TemporaryDispatchError:
            return None
        except AgentAuthError as exc:
            raise ObserveError(f"the agent at {url} refused the token ({exc.message})",
                               hint="check the token for " + ", ".join(by_url[url])
                               + " (agents file, token_file or PLANTKG_TOKEN)") from None
        except PermanentDispatchError as exc:
            raise ObserveError(f"the agent at {url} could not list its brokers: {exc.message}",
                               hint=exc.hint) from None

    with ThreadPoolExecutor(max_workers=max(1, min(parallelism, len(by_url))),
                            thread_name_prefix="observe") as pool:
        answers = dict(zip(by_url, pool.map(ask, by_url)))
    brokers: dict[str, ObservedBroker] = {}
    bridges: dict[str, ObservedBridge] = {}
    unreachable: list[str] = []
    for url, answer in answers.items():
        if answer is None:
            unreachable.extend(by_url[url])
            continue
        for broker in answer[0]:
            brokers.setdefault(broker.spec.id, broker)
        for bridge in answer[1]:
            bridges.setdefault(bridge.spec.address, bridge)
    return ObservedState(
        brokers=tuple(sorted(brokers.values(), key=lambda b: b.spec.id)),
        unreachable=tuple(sorted(unreachable)),
        bridges=tuple(sorted(bridges.values(), key=lambda b: b.spec.address)),
    )


# ----------------------------------------------------------------------------- the named graph

_PLANT_BROKERS = "SELECT ?broker ?ip WHERE { ?broker a pk:Broker ; pk:ip ?ip }"


def _lit(value: object, datatype: str) -> ox.Literal:
    return ox.Literal(str(value), datatype=ox.NamedNode(str(XSD[datatype])))


def _timestamp(seconds: float) -> ox.Literal:
    text = datetime.fromtimestamp(seconds, tz=UTC).isoformat().replace("+00:00", "Z")
    return _lit(text, "dateTime")


def _p(name: str) -> ox.NamedNode:
    return ox.NamedNode(str(PK[name]))


def observed_quads(
    plant_brokers: Iterable[tuple[str, str]], observed: ObservedState, *, at: float
) -> list[ox.Quad]:
    """The observed graph's quads; ``plant_brokers`` are (broker IRI, ip) pairs of the plant."""
    graph = ox.NamedNode(GRAPH_OBSERVED)
    quads = [ox.Quad(graph, _p("observedAt"), _timestamp(at), graph)]

    def add(subject: ox.NamedNode, prop: str, obj: ox.NamedNode | ox.Literal) -> None:
        quads.append(ox.Quad(subject, _p(prop), obj, graph))

    seen: set[str] = set()
    for broker in observed.brokers:
        try:
            node = ox.NamedNode(broker.spec.iri)
        except ValueError:
            continue  # an agent reported an IRI that is none; nothing to attach the facts to
        seen.add(broker.spec.iri)
        add(node, "status", _p(STATUS_TERMS[broker.status]))
        add(node, "observedHost", ox.Literal(broker.spec.host))
        add(node, "observedPort", _lit(broker.spec.port, "integer"))
        add(node, "observedKind", ox.Literal(broker.spec.kind))
        add(node, "restarts", _lit(broker.restarts, "integer"))
        if broker.owner is not None:
            add(node, "observedOwner", ox.Literal(broker.owner))
        if broker.pid is not None:
            add(node, "pid", _lit(broker.pid, "integer"))
        if broker.started_at is not None:
            add(node, "startedAt", _timestamp(broker.started_at))
        if broker.config_hash:
            add(node, "configHash", ox.Literal(broker.config_hash))
        if broker.last_error:
            add(node, "lastError", ox.Literal(broker.last_error))
        for topic in broker.topics:
            add(node, "topicPresent", ox.Literal(topic.name))
    iris = {b.spec.id: b.spec.iri for b in observed.brokers if b.spec.iri in seen}
    for bridge in observed.bridges:
        carrier = iris.get(bridge.spec.local.id)
        if carrier is None:
            continue
        node = ox.NamedNode(f"{GRAPH_OBSERVED}/bridge/{bridge.spec.local.id}/{bridge.spec.remote.id}")
        quads.append(ox.Quad(node, ox.NamedNode(str(RDF.type)), _p("BridgeObservation"), graph))
        add(ox.NamedNode(carrier), "carriesBridge", node)
        add(node, "bridgeRemote", ox.Literal(bridge.spec.remote.id))
        add(node, "bridgeMechanism", ox.Literal(bridge.spec.mechanism.value))
        add(node, "bridgeStatus", ox.Literal(bridge.status.value))
        if bridge.owner is not None:
            add(node, "observedOwner", ox.Literal(bridge.owner))
        for prop, value in (("forwarded", bridge.forwarded), ("retried", bridge.retried),
                            ("refused", bridge.refused)):
            if value is not None:
                add(node, prop, _lit(value, "integer"))
        if bridge.last_error:
            add(node, "bridgeError", ox.Literal(bridge.last_error))
    unreachable = set(observed.unreachable)
    for iri, ip in plant_brokers:
        if iri not in seen:
            add(ox.NamedNode(iri), "status", _p(UNKNOWN if ip in unreachable else ABSENT))
    return quads


def plant_brokers(plant: PlantGraph) -> list[tuple[str, str]]:
    """(IRI, ip) of every broker individual the plant describes."""
    result = run_query(plant, _PLANT_BROKERS)
    return sorted(
        (row[0].value, row[1].value) for row in result.rows
        if isinstance(row[0], ox.NamedNode) and isinstance(row[1], ox.Literal)
    )


def write_observed(plant: PlantGraph, observed: ObservedState, *, at: float | None = None) -> int:
    """Replace the plant's observed graph with ``observed``; returns the number of triples."""
    quads = observed_quads(plant_brokers(plant), observed, at=time.time() if at is None else at)
    graph = ox.NamedNode(GRAPH_OBSERVED)
    if plant.store.contains_named_graph(graph):
        plant.store.remove_graph(graph)
    plant.store.extend(quads)
    return len(quads)

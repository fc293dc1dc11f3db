"""Multi-node Kafka clusters in the desired state: from the reasoned graph to each node's KafkaNode.

A cluster is a ``pk:KafkaCluster`` (a broker some broker is ``pk:nodeOf``; ontology/plantkg-kafka.ttl):
it runs no process itself. Each of its nodes is a broker of its own with a :class:`KafkaNode` that
says what the node needs to join: the cluster's KRaft id, its own node id and roles, the quorum
voters (rule K1, ``pk:quorumVoter``), the internal topics' replication factor and the cluster's
default ``min.insync.replicas``.

The cluster's topics and bridges are planned once, on its *lead* node — the broker-role node with
the smallest ``pk:nodeId`` — so a topic's settings are applied cluster-wide through one agent
(:func:`lead_nodes`); the other nodes report no topics.

The KRaft cluster id is derived from the cluster's IRI (:func:`kraft_cluster_id`): every node's
agent formats its storage with the same id without any exchange between machines, and a node that
restarts, or is re-created, finds the id its data was formatted with.
"""

from __future__ import annotations

import base64
import uuid
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace

from engine.errors import EngineError
from engine.model import BrokerSpec, KafkaNode, KafkaVoter
from engine.values import host_in_url

ROLES = ("broker", "controller")
#: Kafka's own default for the internal topics (__consumer_offsets, transactions): at most 3.
MAX_INTERNAL_REPLICATION = 3

CLUSTERS = """
SELECT ?c ?id ?mis WHERE {
    ?c a pk:KafkaCluster ; a pk:DeployedBroker .
    OPTIONAL { ?c pk:id ?id } OPTIONAL { ?c pk:minInsyncReplicas ?mis }
}"""

NODES = """
SELECT ?n ?c ?nid ?role ?cport WHERE {
    ?n a pk:DeployedBroker ; pk:nodeOf ?c .
    OPTIONAL { ?n pk:nodeId ?nid } OPTIONAL { ?n pk:kafkaRole ?role }
    OPTIONAL { ?n pk:controllerPort ?cport }
}"""

VOTERS = """SELECT ?c ?n WHERE { ?c pk:quorumVoter ?n }"""


class KafkaClusterError(EngineError):
    """A cluster or node lacks what it needs (the shapes report this first on a validated plant)."""

    def __init__(self, node: str, problem: str) -> None:
        super().__init__(f"{node}: {problem}",
                         hint="run `plantkg validate` on the plant: the shapes name what to fix")
        self.node = node


@dataclass(frozen=True)
class ClusterFacts:
    """What the graph says of one cluster: its id, default min ISR, nodes and quorum voters."""

    iri: str
    id: str
    min_insync: int | None
    nodes: Mapping[str, tuple[int, tuple[str, ...], int | None]]  # node IRI -> (id, roles, controller port)
    voters: frozenset[str]                                        # node IRIs (rule K1)


def kraft_cluster_id(iri: str) -> str:
    """The KRaft cluster id of the cluster ``iri``: base64url (no padding) of a name-based UUID,
    22 characters, never starting with ``-`` (StorageTool would read it as an option)."""
    salt = 0
    while True:
        raw = uuid.uuid5(uuid.NAMESPACE_URL, iri if salt == 0 else f"{iri}#{salt}").bytes
        text = base64.urlsafe_b64encode(raw).decode("ascii").rstrip("=")
        if not text.startswith("-"):
            return text
        salt += 1


def read_clusters(select: Callable[[str], Iterable[object]]) -> dict[str, ClusterFacts]:
    """The deployed clusters of the reasoned graph, by IRI (``select`` runs a SPARQL query)."""
    heads: dict[str, tuple[str, int | None]] = {}
    for row in select(CLUSTERS):
        iri = row["c"].value  # type: ignore[index]
        if row["id"] is None:  # type: ignore[index]
            raise KafkaClusterError(iri, "a Kafka cluster has no pk:id")
        mis = row["mis"]  # type: ignore[index]
        heads[iri] = (row["id"].value, _int(iri, "minInsyncReplicas", mis.value) if mis is not None else None)  # type: ignore[index]
    nodes: dict[str, dict[str, dict[str, set[object]]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(set)))
    for row in select(NODES):
        slot = nodes[row["c"].value][row["n"].value]  # type: ignore[index]
        for var in ("nid", "role", "cport"):
            if row[var] is not None:  # type: ignore[index]
                slot[var].add(row[var].value)  # type: ignore[index]
    voters: dict[str, set[str]] = defaultdict(set)
    for row in select(VOTERS):
        voters[row["c"].value].add(row["n"].value)  # type: ignore[index]
    out = {}
    for iri, (cid, mis) in heads.items():
        facts = {}
        for node, slot in nodes.get(iri, {}).items():
            ids, ports = slot.get("nid", set()), slot.get("cport", set())
            if len(ids) != 1:
                raise KafkaClusterError(node, "a Kafka node needs exactly one pk:nodeId")
            roles = tuple(sorted(str(r) for r in slot.get("role", set())))
            if not roles or not set(roles) <= set(ROLES):
                raise KafkaClusterError(node, f"pk:kafkaRole must be 'broker', 'controller' or both, not {list(roles)}")
            if len(ports) > 1:
                raise KafkaClusterError(node, "a Kafka node has at most one pk:controllerPort")
            port = _int(node, "controllerPort", next(iter(ports))) if ports else None
            facts[node] = (_int(node, "nodeId", next(iter(ids))), roles, port)
        out[iri] = ClusterFacts(iri, cid, mis, facts, frozenset(voters.get(iri, ())))
    return out


def join_clusters(brokers: Iterable[BrokerSpec], clusters: Mapping[str, ClusterFacts]
                  ) -> tuple[list[BrokerSpec], dict[str, BrokerSpec]]:
    """The broker specs with each cluster node's :class:`KafkaNode` set, and, per cluster IRI, the
    spec of its lead node (where its topics and bridges are planned)."""
    by_iri = {b.iri: b for b in brokers}
    done: dict[str, BrokerSpec] = dict(by_iri)
    leads: dict[str, BrokerSpec] = {}
    for facts in clusters.values():
        members = [(by_iri[n], f) for n, f in facts.nodes.items() if n in by_iri]
        if not members:
            raise KafkaClusterError(facts.iri, "a Kafka cluster that must run has no deployed node")
        ids = [f[0] for _, f in members]
        if len(set(ids)) != len(ids):
            raise KafkaClusterError(facts.iri, f"two nodes share a pk:nodeId: {sorted(ids)}")
        serving = sorted(((f[0], spec) for spec, f in members if "broker" in f[1]), key=lambda p: p[0])
        if not serving:
            raise KafkaClusterError(facts.iri, "a Kafka cluster needs a node with the 'broker' role")
        voters = tuple(sorted(
            (KafkaVoter(f[0], spec.host, f[2] if f[2] is not None and "broker" in f[1] else spec.port)
             for spec, f in members if spec.iri in facts.voters), key=lambda v: v.node_id))
        if not voters:
            raise KafkaClusterError(facts.iri, "a Kafka cluster needs a node with the 'controller' role")
        bootstrap = tuple(f"{host_in_url(spec.host)}:{spec.port}" for _, spec in serving)
        lead_id = serving[0][0]
        replication = min(MAX_INTERNAL_REPLICATION, len(serving))
        for spec, (node_id, roles, cport) in members:
            node = KafkaNode(cluster=facts.id, cluster_id=kraft_cluster_id(facts.iri), node_id=node_id,
                             roles=roles, voters=voters,
                             controller_port=cport if "broker" in roles else None,
                             replication=replication, min_insync=facts.min_insync,
                             bootstrap=bootstrap, lead=node_id == lead_id)
            done[spec.iri] = replace(spec, kafka=node)
        leads[facts.iri] = done[serving[0][1].iri]
    return list(done.values()), leads


def _int(node: str, prop: str, value: object) -> int:
    try:
        return int(str(value))
    except ValueError:
        raise KafkaClusterError(node, f"pk:{prop} {value!r} is not an integer") from None

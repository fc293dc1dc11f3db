"""Multi-node Kafka clusters in the desired state (engine.derived.kafka_cluster, ontology/plantkg-kafka.ttl):
the quorum concluded by rule K1 with both reasoners, one KRaft id for every node, the cluster's
topics and bridges on its lead node, and MirrorMaker 2 between two clusters."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.derive import derive
from engine.derived.kafka_cluster import kraft_cluster_id
from engine.model import BridgeMechanism, KafkaVoter, TopicSpec
from engine.reasoning.reason import reason
from kg.load import load_plant

EX = "http://example.org/p#"
HEADER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/p#> .
"""

#: A cell Mosquitto, a 3-node combined cluster on 127.0.0.2-4 and a site cluster of one broker
#: node and one controller-only node; the historian reads the line's position on the site.
PLANT = """
:mq a pk:Broker ; pk:id "mq" ; pk:name "mq" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.5" ; pk:port 1883 .
:plant a pk:Broker ; pk:id "plant" ; pk:name "plant" ; pk:brokerType "kafka" ; pk:minInsyncReplicas 2 ;
    pk:allowAnonymous true .  # mirrored: a MirrorMaker 2 end is open (docs/security.md)
:k1 a pk:Broker ; pk:id "k1" ; pk:name "k1" ; pk:brokerType "kafka" ; pk:ip "127.0.0.2" ; pk:port 9092 ;
    pk:nodeOf :plant ; pk:nodeId 1 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .
:k2 a pk:Broker ; pk:id "k2" ; pk:name "k2" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ; pk:port 9092 ;
    pk:nodeOf :plant ; pk:nodeId 2 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .
:k3 a pk:Broker ; pk:id "k3" ; pk:name "k3" ; pk:brokerType "kafka" ; pk:ip "127.0.0.4" ; pk:port 9092 ;
    pk:nodeOf :plant ; pk:nodeId 3 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .
:site a pk:Broker ; pk:id "site" ; pk:name "site" ; pk:brokerType "kafka" ; pk:allowAnonymous true .
:s1 a pk:Broker ; pk:id "s1" ; pk:name "s1" ; pk:brokerType "kafka" ; pk:ip "127.0.0.6" ; pk:port 9092 ;
    pk:nodeOf :site ; pk:nodeId 7 ; pk:kafkaRole "broker" .
:s0 a pk:Broker ; pk:id "s0" ; pk:name "s0" ; pk:brokerType "kafka" ; pk:ip "127.0.0.6" ; pk:port 9093 ;
    pk:nodeOf :site ; pk:nodeId 100 ; pk:kafkaRole "controller" .
:idle a pk:Broker ; pk:id "idle" ; pk:name "idle" ; pk:brokerType "kafka" .
:i1 a pk:Broker ; pk:id "i1" ; pk:name "i1" ; pk:brokerType "kafka" ; pk:ip "127.0.0.7" ; pk:port 9092 ;
    pk:nodeOf :idle ; pk:nodeId 1 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .
:pos a pk:Topic ; pk:id "pos" ; pk:name "line.position" ; pk:qos 1 ;
    pk:partitions 3 ; pk:replicationFactor 3 ; pk:minInsyncReplicas 2 .
:robot a pk:Resource ; pk:id "robot" ; pk:name "robot" ; pk:sendsTo :mq ; pk:publishes :pos .
:line a pk:Resource ; pk:id "line" ; pk:name "line" ; pk:sendsTo :plant ; pk:subscribes :pos ; pk:publishes :pos .
:historian a pk:Resource ; pk:id "historian" ; pk:name "historian" ; pk:sendsTo :site ; pk:subscribes :pos .
"""


@pytest.fixture(scope="module", params=["fast", "owlready2"])
def state(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    path = tmp_path_factory.mktemp("cluster") / "plant.ttl"
    path.write_text(HEADER + PLANT)
    plant = load_plant([path])
    reason(plant, engine=request.param)
    return derive(plant)


def test_every_node_is_a_broker_and_the_clusters_are_not(state) -> None:  # type: ignore[no-untyped-def]
    # the idle cluster has no client: neither it nor its node is deployed
    assert [b.id for b in state.brokers] == ["k1", "k2", "k3", "mq", "s0", "s1"]


def test_the_quorum_is_the_controllers(state) -> None:  # type: ignore[no-untyped-def]
    voters = (KafkaVoter(1, "127.0.0.2", 9093), KafkaVoter(2, "127.0.0.3", 9093), KafkaVoter(3, "127.0.0.4", 9093))
    for node_id, broker in enumerate(("k1", "k2", "k3"), start=1):
        node = state.broker(broker).kafka
        assert (node.cluster, node.node_id, node.roles, node.voters) == ("plant", node_id, ("broker", "controller"), voters)
        assert node.cluster_id == kraft_cluster_id(EX + "plant")
        assert (node.replication, node.min_insync, node.controller_port) == (3, 2, 9093)
        assert node.bootstrap == ("127.0.0.2:9092", "127.0.0.3:9092", "127.0.0.4:9092")
        assert node.lead == (broker == "k1")


def test_a_controller_only_node_votes_on_its_port(state) -> None:  # type: ignore[no-untyped-def]
    s0, s1 = state.broker("s0").kafka, state.broker("s1").kafka
    assert s0.voters == s1.voters == (KafkaVoter(100, "127.0.0.6", 9093),)
    assert (s0.roles, s0.controller_port, s0.lead) == (("controller",), None, False)
    assert (s1.roles, s1.lead, s1.bootstrap, s1.replication) == (("broker",), True, ("127.0.0.6:9092",), 1)
    assert s1.cluster_id != state.broker("k1").kafka.cluster_id


def test_topics_are_planned_once_on_each_clusters_lead(state) -> None:  # type: ignore[no-untyped-def]
    kafka = [t for t in state.topics if t.broker_id != "mq"]
    assert kafka == [
        TopicSpec("k1", "line.position", EX + "pos", partitions=3, replication_factor=3, min_insync_replicas=2),
        TopicSpec("s1", "line.position", EX + "pos", partitions=3, replication_factor=3, min_insync_replicas=2),
    ]


def test_bridges_reach_a_cluster_through_all_its_brokers(state) -> None:  # type: ignore[no-untyped-def]
    by_pair = {(b.local.id, b.remote.id): b for b in state.bridges}
    worker = by_pair[("mq", "k1")]
    assert worker.mechanism is BridgeMechanism.WORKER
    assert worker.remote.bootstrap == ("127.0.0.2:9092", "127.0.0.3:9092", "127.0.0.4:9092")
    mirror = by_pair[("s1", "k1")]  # the site pulls from the plant cluster
    assert mirror.mechanism is BridgeMechanism.MIRROR
    assert [(r.topic, r.direction.value) for r in mirror.routes] == [("line.position", "in")]
    assert mirror.local.bootstrap == ("127.0.0.6:9092",)


def test_the_kraft_id_is_stable_and_valid() -> None:
    first = kraft_cluster_id("http://example.org/p#plant")
    assert first == kraft_cluster_id("http://example.org/p#plant") != kraft_cluster_id("http://example.org/p#site")
    assert len(first) == 22 and not first.startswith("-")
    ids = {kraft_cluster_id(f"urn:c{i}") for i in range(3000)}
    assert len(ids) == 3000 and not any(i.startswith("-") for i in ids)

"""What a plan does with a Kafka cluster's nodes (pure: plan, apply's lanes, the wire, rendering).

- a config the nodes render changes: each running node is replaced, and apply joins their lanes
  so the restarts roll one node at a time, in node-id order; new nodes start in parallel;
- only the lead or the broker list changes (a node was added): an in-place update, no restart;
- the controller quorum of a running cluster would change: refused, naming the voters;
- the listener security of a running cluster changes (TLS on or off, closed or opened): every node
  is replaced as a whole-cluster restart (the reason says so), and apply keeps their lanes apart so
  all restart at once instead of rolling;
- a node leaves: its cluster's topics are not deleted with it;
- a node's spec crosses the agent API unchanged, and a bad one is refused naming the field;
- a node renders its roles, the quorum and the cluster's defaults.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from engine.agent.wire import WireError, broker_spec_from_json
from engine.apply import lanes, operations
from engine.drivers.kafka.runtime import KafkaNodeConfig, render_server_properties
from engine.derived.kafka_cluster import kraft_cluster_id
from engine.model import (
    Action,
    BrokerSpec,
    BrokerStatus,
    BrokerUser,
    DesiredState,
    KafkaNode,
    KafkaVoter,
    ObservedBroker,
    ObservedState,
    ObservedTopic,
    TopicSpec,
    to_dict,
)
from engine.plan import plan, restarts_whole_cluster

VOTERS = tuple(KafkaVoter(i, f"127.0.0.{i + 1}", 9093) for i in (1, 2, 3))
CID = kraft_cluster_id("urn:x:plant")


def node(i: int, **changes: object) -> BrokerSpec:
    kafka = KafkaNode("plant", CID, i, ("broker", "controller"), VOTERS, 9093, 3, 2,
                      tuple(f"127.0.0.{n + 1}:9092" for n in (1, 2, 3)), i == 1)
    return BrokerSpec(f"k{i}", f"urn:x:k{i}", f"k{i}", "kafka", f"127.0.0.{i + 1}", 9092,
                      kafka=replace(kafka, **changes))  # type: ignore[arg-type]


def running(spec: BrokerSpec, *topics: ObservedTopic) -> ObservedBroker:
    return ObservedBroker(spec, BrokerStatus.RUNNING, topics, pid=10 + spec.kafka.node_id)  # type: ignore[union-attr]


TOPIC = TopicSpec("k1", "line.energy", "urn:x:t", partitions=3, replication_factor=3, min_insync_replicas=2)
OBSERVED_TOPIC = ObservedTopic("line.energy", 3, 3, None, min_insync_replicas=2)


def test_a_rendered_change_rolls_the_nodes_one_at_a_time() -> None:
    desired = DesiredState(tuple(node(i, min_insync=1) for i in (1, 2, 3)), (TOPIC,))
    observed = ObservedState((running(node(1), OBSERVED_TOPIC), running(node(2)), running(node(3))))
    result = plan(desired, observed)
    assert [(c.address, c.action) for c in result.pending] == [
        ("broker.k1", Action.REPLACE), ("broker.k2", Action.REPLACE), ("broker.k3", Action.REPLACE)]
    assert result.pending[0].reason.startswith("kafka.min_insync 2 → 1 forces replacement")
    [lane] = lanes(operations(result, desired))
    assert [op.change.address for op in lane] == ["broker.k1", "broker.k2", "broker.k3"]


def test_new_nodes_start_in_parallel() -> None:
    desired = DesiredState(tuple(node(i) for i in (1, 2, 3)), (TOPIC,))
    result = plan(desired, ObservedState())
    assert len(lanes(operations(result, desired))) == 3
    # the cluster's topic is created once, in the lead's lane, after the lead
    assert [c.address for c in result.pending if c.address.startswith("topic.")] == ["topic.k1.line.energy"]


def test_adding_a_broker_node_restarts_nothing() -> None:
    bootstrap = tuple(f"127.0.0.{n + 1}:9092" for n in (1, 2, 3, 4))
    desired = DesiredState(tuple(node(i, bootstrap=bootstrap) for i in (1, 2, 3))
                           + (node(4, roles=("broker",), controller_port=None, bootstrap=bootstrap, lead=False),),
                           (TOPIC,))
    observed = ObservedState((running(node(1), OBSERVED_TOPIC), running(node(2)), running(node(3))))
    actions = {c.address: c.action for c in plan(desired, observed).pending}
    assert actions == {"broker.k1": Action.UPDATE, "broker.k2": Action.UPDATE, "broker.k3": Action.UPDATE,
                       "broker.k4": Action.CREATE}


def test_the_quorum_of_a_running_cluster_does_not_change() -> None:
    moved = tuple(v if v.node_id != 3 else KafkaVoter(3, "127.0.0.9", 9093) for v in VOTERS)
    desired = DesiredState(tuple(node(i, voters=moved) for i in (1, 2, 3)))
    observed = ObservedState(tuple(running(node(i)) for i in (1, 2, 3)))
    result = plan(desired, observed)
    assert not result.applicable
    assert [r.address for r in result.refusals] == ["broker.k1", "broker.k2", "broker.k3"]
    reason = result.refusals[0].reason
    assert "cluster 'plant'" in reason and "3@127.0.0.4:9093 →" in reason and reason.endswith(
        "pk:controllerPort") and "3@127.0.0.9:9093)" in reason


@pytest.mark.parametrize(("before", "after", "what"), [
    ({}, {"tls": True}, "tls null → true"),
    ({"tls": True}, {}, "tls true → null"),
    ({"allow_anonymous": True}, {"allow_anonymous": False}, "allow_anonymous true → false"),
    ({"allow_anonymous": False, "tls": True}, {"allow_anonymous": True}, "allow_anonymous false → true, tls true → null"),
])
def test_a_listener_security_change_restarts_the_whole_cluster_at_once(
        before: dict[str, object], after: dict[str, object], what: str) -> None:
    desired = DesiredState(tuple(replace(node(i), **after) for i in (1, 2, 3)), (TOPIC,))
    observed = ObservedState((running(replace(node(1), **before), OBSERVED_TOPIC),
                              running(replace(node(2), **before)), running(replace(node(3), **before))))
    result = plan(desired, observed)
    assert result.applicable
    assert [(c.address, c.action) for c in result.pending] == [
        ("broker.k1", Action.REPLACE), ("broker.k2", Action.REPLACE), ("broker.k3", Action.REPLACE)]
    assert all(restarts_whole_cluster(c) for c in result.pending)
    assert result.pending[0].reason.startswith(f"{what} forces replacement (whole cluster: listener security changes")
    # three lanes: every node's PUT goes out in the same wave (no roll)
    assert sorted([op.change.address for op in lane] for lane in lanes(operations(result, desired))) == [
        ["broker.k1"], ["broker.k2"], ["broker.k3"]]


def test_a_change_that_keeps_the_listeners_still_rolls() -> None:
    closed = [replace(node(i), allow_anonymous=False) for i in (1, 2, 3)]
    users = (BrokerUser("plc", "env:PLC", ("line.energy",)),)
    desired = DesiredState(tuple(replace(n, users=users) for n in closed))
    result = plan(desired, ObservedState(tuple(running(n) for n in closed)))
    assert {c.action for c in result.pending} == {Action.REPLACE}
    assert not any(restarts_whole_cluster(c) for c in result.pending)
    assert "whole cluster" not in result.pending[0].reason
    [lane] = lanes(operations(result, desired))
    assert [op.change.address for op in lane] == ["broker.k1", "broker.k2", "broker.k3"]


def test_lowering_partitions_of_a_cluster_topic_is_refused_by_name() -> None:
    desired = DesiredState(tuple(node(i) for i in (1, 2, 3)), (replace(TOPIC, partitions=2),))
    observed = ObservedState((running(node(1), OBSERVED_TOPIC), running(node(2)), running(node(3))))
    [refusal] = plan(desired, observed).refusals
    assert refusal.address == "topic.k1.line.energy" and "partitions 3 → 2" in refusal.reason


def test_a_node_that_leaves_takes_no_topic_with_it() -> None:
    desired = DesiredState((node(2, lead=True), node(3)), (replace(TOPIC, broker_id="k2"),))
    observed = ObservedState((running(node(1), OBSERVED_TOPIC), running(node(2)), running(node(3))))
    deletes = [c.address for c in plan(desired, observed).pending if c.action is Action.DELETE]
    assert deletes == ["broker.k1"]


def test_a_node_crosses_the_wire_unchanged_and_bad_values_are_named() -> None:
    spec = node(2)
    assert broker_spec_from_json(to_dict(spec)) == spec
    data = to_dict(spec)
    data["kafka"]["cluster_id"] = "-starts-with-a-dash-xx"
    with pytest.raises(WireError, match="kafka.cluster_id"):
        broker_spec_from_json(data)
    data = to_dict(spec)
    data["kafka"]["roles"] = ["leader"]
    with pytest.raises(WireError, match="kafka.roles"):
        broker_spec_from_json(data)
    data = to_dict(spec)
    data["kafka"]["bootstrap"] = ["127.0.0.2:9092\nlisteners=x"]
    with pytest.raises(WireError, match=r"kafka.bootstrap\[0\]"):
        broker_spec_from_json(data)


def test_a_node_renders_its_roles_and_the_quorum(tmp_path: Path) -> None:
    voters = tuple((v.node_id, v.host, v.port) for v in VOTERS)
    combined = render_server_properties(KafkaNodeConfig(
        "127.0.0.3", 9092, 9093, tmp_path / "data", node_id=2, voters=voters, replication=3, min_insync=2))
    assert "process.roles=broker,controller\nnode.id=2\n" in combined
    assert "controller.quorum.voters=1@127.0.0.2:9093,2@127.0.0.3:9093,3@127.0.0.4:9093\n" in combined
    assert "listeners=PLAINTEXT://127.0.0.3:9092,CONTROLLER://127.0.0.3:9093\n" in combined
    for line in ("offsets.topic.replication.factor=3", "transaction.state.log.min.isr=2",
                 "default.replication.factor=3", "min.insync.replicas=2", "auto.create.topics.enable=false"):
        assert line + "\n" in combined
    controller = render_server_properties(KafkaNodeConfig(
        "127.0.0.5", 9093, 9093, tmp_path / "data", node_id=7, roles=("controller",), voters=((7, "127.0.0.5", 9093),)))
    assert "process.roles=controller\n" in controller and "listeners=CONTROLLER://127.0.0.5:9093\n" in controller
    assert "advertised.listeners" not in controller and "inter.broker.listener.name" not in controller
    broker = render_server_properties(KafkaNodeConfig(
        "127.0.0.6", 9092, 9093, tmp_path / "data", node_id=8, roles=("broker",), voters=((7, "127.0.0.5", 9093),)))
    assert "listeners=PLAINTEXT://127.0.0.6:9092\n" in broker and "CONTROLLER://127.0.0.6" not in broker


def test_a_node_config_refuses_what_would_break_the_file(tmp_path: Path) -> None:
    from engine.errors import ConfigValueError
    with pytest.raises(ConfigValueError, match="roles"):
        KafkaNodeConfig("127.0.0.2", 9092, 9093, tmp_path, roles=("observer",))
    with pytest.raises(ConfigValueError, match="controller_port"):
        KafkaNodeConfig("127.0.0.2", 9092, 9093, tmp_path, roles=("controller",))
    with pytest.raises(ConfigValueError, match="voters"):
        KafkaNodeConfig("127.0.0.2", 9092, 9093, tmp_path, voters=((1, "127.0.0.2,x", 9093),))
    with pytest.raises(ConfigValueError, match="voters"):
        KafkaNodeConfig("127.0.0.2", 9092, 9093, tmp_path, voters=((1, "127.0.0.2", 9093), (1, "127.0.0.3", 9093)))

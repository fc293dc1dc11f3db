"""A closed Kafka's pure parts (issue 13): the SASL lines of server.properties, the ACLs a user's
rights become, the digest that restarts a broker when a password changes, and how a bridge worker
gets plantkg's own password (derived on its agent from the Kafka agent's token, never the token)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
from confluent_kafka.admin import AclOperation, ResourceType

from engine.agent.workers import TOKEN_FILE, WorkerManager
from engine.apply import operations
from engine.derived.bridge_pairs import bridge_end
from engine.drivers.kafka.access import users_digest, wanted_acls
from engine.drivers.kafka.runtime import KafkaNodeConfig, render_server_properties
from engine.errors import ConfigValueError
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    BrokerUser,
    DesiredState,
    ObservedState,
)
from engine.plan import plan
from engine.security import kafka_client
from engine.security.kafka_client import internal_password as kafka_internal_password

PASSWORD = kafka_internal_password("agent-token-of-the-kafka-machine")


def test_a_closed_kafka_renders_sasl_everywhere(tmp_path: Path) -> None:
    text = render_server_properties(KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data",
                                                    internal_password=PASSWORD))
    lines = text.splitlines()
    assert "listeners=SASL_PLAINTEXT://127.0.0.3:9092,CONTROLLER://127.0.0.3:9093" in lines
    assert "advertised.listeners=SASL_PLAINTEXT://127.0.0.3:9092" in lines
    assert "listener.security.protocol.map=CONTROLLER:SASL_PLAINTEXT,SASL_PLAINTEXT:SASL_PLAINTEXT" in lines
    assert "authorizer.class.name=org.apache.kafka.metadata.authorizer.StandardAuthorizer" in lines
    assert "super.users=User:plantkg" in lines and "allow.everyone.if.no.acl.found=false" in lines
    assert "sasl.enabled.mechanisms=SCRAM-SHA-512,PLAIN" in lines
    assert "PLAINTEXT://" not in text.replace("SASL_PLAINTEXT://", "")
    open_ = render_server_properties(KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data"))
    assert "SASL" not in open_ and "authorizer" not in open_


@pytest.mark.parametrize("bad", ['abc"; user_x="y', "short", "A" * 64])
def test_the_internal_password_cannot_break_the_jaas_line(tmp_path: Path, bad: str) -> None:
    with pytest.raises(ConfigValueError, match="internal_password"):
        KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data", internal_password=bad)


def test_rights_become_acls() -> None:
    acls = wanted_acls((BrokerUser("robot1", "env:R", write=("cell.pos",)),
                        BrokerUser("hist", "env:H", read=("cell.pos", "cell.cam"))))
    seen = {(p, r.name, n, op.name) for r, n, _pat, p, _h, op, _perm in acls}
    assert seen == {
        ("User:robot1", "TOPIC", "cell.pos", "WRITE"), ("User:robot1", "TOPIC", "cell.pos", "DESCRIBE"),
        ("User:hist", "TOPIC", "cell.pos", "READ"), ("User:hist", "TOPIC", "cell.pos", "DESCRIBE"),
        ("User:hist", "TOPIC", "cell.cam", "READ"), ("User:hist", "TOPIC", "cell.cam", "DESCRIBE"),
        ("User:hist", "GROUP", "*", "READ")}
    assert not any(op is AclOperation.ALL or r is ResourceType.BROKER for r, *_x, op, _p in acls)


def test_the_digest_follows_passwords_and_shows_none(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PW_A", "first-password")
    users = (BrokerUser("a", "env:PW_A"),)
    one = users_digest(users, PASSWORD)
    assert one == users_digest(users, PASSWORD) and "first-password" not in one
    monkeypatch.setenv("PW_A", "second-password")
    assert users_digest(users, PASSWORD) != one


def test_a_worker_into_a_closed_kafka_logs_in_with_a_derived_password(tmp_path: Path) -> None:
    spec = BridgeSpec(BridgeEnd("mq", "mosquitto", "127.0.0.2", 1883),
                      BridgeEnd("kf", "kafka", "127.0.0.3", 9092, closed=True),
                      BridgeMechanism.WORKER, (BridgeRoute("cell.cam", BridgeDirection.OUT),))
    manager = WorkerManager(tmp_path, python="/bin/false")  # the worker is not started: no open()
    manager._start = lambda w, restart: None  # type: ignore[method-assign]
    manager.put(spec)
    folder = tmp_path / "bridges" / "mq--kf"
    secret = (folder / TOKEN_FILE).read_text(encoding="utf-8")
    assert secret == kafka_client.password()  # the principal key's: nothing secret came with the PUT
    assert json.loads((folder / "worker.json").read_text())["kafka_password_file"] == str(folder / TOKEN_FILE)
    assert (folder / TOKEN_FILE).stat().st_mode & 0o777 == 0o600
    manager.put(replace(spec, remote=replace(spec.remote, closed=False)))  # the Kafka opened
    assert not (folder / TOKEN_FILE).exists()
    assert "kafka_password_file" not in json.loads((folder / "worker.json").read_text())


def test_a_bridge_end_is_closed_exactly_when_its_kafka_is_and_no_token_travels() -> None:
    mq = BrokerSpec("mq", "urn:mq", "mq", "mosquitto", "127.0.0.2", 1883)
    hist = (BrokerUser("h", "env:H", read=("t",)),)
    for anonymous, users, closed in ((None, (), False), (True, (), False), (False, (), True), (False, hist, True)):
        kf = BrokerSpec("kf", "urn:kf", "kf", "kafka", "127.0.0.3", 9092, users=users, allow_anonymous=anonymous)
        end = bridge_end(kf, {})
        assert end.closed is closed and bridge_end(mq, {}).closed is False
        bridge = BridgeSpec(bridge_end(mq, {}), end, BridgeMechanism.WORKER, (BridgeRoute("t", BridgeDirection.OUT),))
        desired = DesiredState((kf, mq), (), (bridge,))
        [put] = [c for op in operations(plan(desired, ObservedState()), desired) for c in op.calls
                 if c.verb == "put_bridge"]
        assert put.remote_token_of is None  # the worker's agent derives plantkg's password itself


def _cluster_node(node_id: int, lead: bool, *, closed: bool, users: tuple[BrokerUser, ...] = ()) -> BrokerSpec:
    from engine.model import KafkaNode, KafkaVoter  # noqa: PLC0415
    voters = tuple(KafkaVoter(i, f"127.0.0.{i + 1}", 9093) for i in (1, 2, 3))
    return BrokerSpec(f"n{node_id}", f"http://example.org/n{node_id}", f"n{node_id}", "kafka",
                      f"127.0.0.{node_id + 1}", 9092, allow_anonymous=False if closed else True, users=users,
                      kafka=KafkaNode("c", "A" * 22, node_id, ("broker", "controller"), voters,
                                      controller_port=9093, replication=3, lead=lead))


def test_a_closed_cluster_node_renders_sasl_on_its_client_inter_broker_and_controller_listeners(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every node of a closed cluster: SASL listeners, plantkg (PLAIN, a static JAAS user) between
    the nodes and to the quorum, the StandardAuthorizer; only the lead node reads the users'
    passwords (the digest) and has them in its essence, since it alone sets them for the cluster."""
    from engine.drivers.kafka.driver import KafkaDriver  # noqa: PLC0415
    monkeypatch.setenv("PLANTKG_PRINCIPAL_KEY", str(tmp_path / "key"))
    monkeypatch.setenv("PW_H", "historian-password")
    users = (BrokerUser("hist", "env:PW_H", read=("cell.cam",)),)
    driver = KafkaDriver()
    lead, other = _cluster_node(1, True, closed=True, users=users), _cluster_node(2, False, closed=True, users=users)
    for spec in (lead, other):
        lines = driver.render_config(spec, tmp_path / spec.id)["server.properties"].splitlines()
        assert "listener.security.protocol.map=CONTROLLER:SASL_PLAINTEXT,SASL_PLAINTEXT:SASL_PLAINTEXT" in lines
        assert "inter.broker.listener.name=SASL_PLAINTEXT" in lines
        assert "sasl.mechanism.inter.broker.protocol=PLAIN" in lines
        assert "sasl.mechanism.controller.protocol=PLAIN" in lines
        assert "super.users=User:plantkg" in lines
        assert "controller.quorum.voters=1@127.0.0.2:9093,2@127.0.0.3:9093,3@127.0.0.4:9093" in lines
    assert "scram.digest" in driver.render_config(lead, tmp_path / "n1")
    assert "scram.digest" not in driver.render_config(other, tmp_path / "n2")
    assert "users" in driver.essence(lead) and "users" not in driver.essence(other)
    assert driver.essence(lead)["closed"] is driver.essence(other)["closed"] is True
    opened = driver.render_config(_cluster_node(2, False, closed=False), tmp_path / "open")
    assert "SASL" not in opened["server.properties"] and "closed" not in driver.essence(_cluster_node(2, False, closed=False))

"""JSON <-> model for the agent API: strict for requests, lenient for answers, lossless."""

from __future__ import annotations

import pytest

from engine.agent.wire import (
    WireError,
    broker_spec_from_json,
    observed_broker_from_json,
    topic_spec_from_json,
)
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker, ObservedTopic, TopicSpec, to_dict

SPEC = BrokerSpec("k1", "urn:plant:k1", "Kafka", "kafka", "127.0.0.3", 9092)


def test_round_trips() -> None:
    observed = ObservedBroker(SPEC, BrokerStatus.CRASHED, (ObservedTopic("t", 3, 1, 1000),), pid=42,
                              started_at=1.5, restarts=2, config_hash="ab", last_error="x\ny")
    assert observed_broker_from_json(to_dict(observed)) == observed
    assert broker_spec_from_json(to_dict(SPEC)) == SPEC
    topic = TopicSpec("k1", "t", "urn:t", partitions=3, replication_factor=1, retention_ms=-1)
    assert topic_spec_from_json(to_dict(topic)) == topic


def test_requests_are_strict_answers_lenient() -> None:
    with pytest.raises(WireError) as info:
        broker_spec_from_json({**to_dict(SPEC), "color": "red"})
    assert info.value.field == "color"
    answer = {**to_dict(ObservedBroker(SPEC, BrokerStatus.RUNNING)), "uptime": 3}
    answer["spec"]["zone"] = "a"
    assert observed_broker_from_json(answer).spec == SPEC


@pytest.mark.parametrize(("changes", "field"), [
    ({"partitions": "3"}, "partitions"),
    ({"retain": "true"}, "retain"),
    ({"qos": 1.0}, "qos"),
    ({"name": "a\nb"}, "name"),
    ({"broker_id": None}, "broker_id"),
])
def test_bad_topic_bodies(changes: dict, field: str) -> None:
    with pytest.raises(WireError) as info:
        topic_spec_from_json({**to_dict(TopicSpec("k1", "t", "urn:t")), **changes})
    assert info.value.field == field


def test_a_bad_status_in_an_answer() -> None:
    answer = {**to_dict(ObservedBroker(SPEC, BrokerStatus.RUNNING)), "status": "sleeping"}
    with pytest.raises(WireError, match="status"):
        observed_broker_from_json(answer)


# --- NGSI: a context broker's allow_anonymous, a topic's entity, an NGSI bridge route ---------

NGSI = BrokerSpec("cb", "urn:plant:cb", "Context broker", "ngsi-v2", "127.0.0.3", 1026,
                  allow_anonymous=False)


def test_ngsi_fields_round_trip() -> None:
    from engine.agent.wire import bridge_spec_from_json
    from engine.model import BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec

    assert broker_spec_from_json(to_dict(NGSI)) == NGSI
    topic = TopicSpec("cb", "agv/1/status", "urn:t", entity_id="urn:ngsi-ld:AGV:1", entity_type="AGV")
    assert topic_spec_from_json(to_dict(topic)) == topic
    observed = ObservedBroker(NGSI, BrokerStatus.RUNNING,
                              (ObservedTopic("agv/1/status", entity_id="urn:ngsi-ld:AGV:1", entity_type="AGV"),))
    assert observed_broker_from_json(to_dict(observed)) == observed
    bridge = BridgeSpec(BridgeEnd("mqtt", "mosquitto", "127.0.0.2", 1883), BridgeEnd("cb", "ngsi-v2", "127.0.0.3", 1026),
                        BridgeMechanism.NGSI,
                        (BridgeRoute("agv/1/status", BridgeDirection.OUT, 1, "mqtt-topic", "urn:ngsi-ld:AGV:1", "AGV"),))
    assert bridge_spec_from_json(to_dict(bridge)) == bridge


def test_a_closed_end_round_trips_and_only_a_kafka_is_closed() -> None:
    from engine.agent.wire import bridge_spec_from_json
    from engine.model import BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec

    bridge = BridgeSpec(BridgeEnd("mqtt", "mosquitto", "127.0.0.2", 1883),
                        BridgeEnd("kf", "kafka", "127.0.0.3", 9092, closed=True),
                        BridgeMechanism.WORKER, (BridgeRoute("t", BridgeDirection.OUT),))
    assert bridge_spec_from_json(to_dict(bridge)) == bridge
    body = to_dict(bridge)
    body["local"]["closed"] = True
    with pytest.raises(WireError) as info:
        bridge_spec_from_json(body)
    assert info.value.field == "local.closed" and "Kafka" in str(info.value)
    body["local"]["closed"] = "yes"
    with pytest.raises(WireError) as info:
        bridge_spec_from_json(body)
    assert info.value.field == "local.closed"


@pytest.mark.parametrize(("changes", "field"), [
    ({"entity_id": "has space"}, "entity_id"),
    ({"entity_id": "a/b"}, "entity_id"),
    ({"entity_id": "x" * 257}, "entity_id"),
    ({"entity_type": "T(1)"}, "entity_type"),
    ({"entity_type": 3}, "entity_type"),
])
def test_bad_entity_fields_are_refused_naming_the_field(changes: dict, field: str) -> None:
    body = {**to_dict(TopicSpec("cb", "t", "urn:t")), **changes}
    with pytest.raises(WireError) as info:
        topic_spec_from_json(body)
    assert info.value.field == field


def test_allow_anonymous_must_be_a_boolean() -> None:
    with pytest.raises(WireError) as info:
        broker_spec_from_json({**to_dict(NGSI), "allow_anonymous": "yes"})
    assert info.value.field == "allow_anonymous"


# --- broker users: references to secrets, never secrets ----------------------------------------

USER_BASE = {"id": "m1", "iri": "urn:m1", "name": "m1", "kind": "mosquitto", "host": "127.0.0.1", "port": 1883}


def test_broker_users_round_trip() -> None:
    body = {**USER_BASE, "users": [{"name": "robot1", "secret_ref": "env:ROBOT1_PASSWORD",
                                    "write": ["cell/pose"], "read": ["cell/cmd"]},
                                   {"name": "hmi", "secret_ref": "file:/etc/plantkg/hmi.pw"}]}
    spec = broker_spec_from_json(body)
    assert [(u.name, u.secret_ref, u.write, u.read) for u in spec.users] == [
        ("robot1", "env:ROBOT1_PASSWORD", ("cell/pose",), ("cell/cmd",)),
        ("hmi", "file:/etc/plantkg/hmi.pw", (), ())]
    assert broker_spec_from_json(to_dict(spec)) == spec


@pytest.mark.parametrize(("user", "field", "shown"), [
    ({"name": "robot1", "secret_ref": "hunter2"}, "users[0].secret_ref", False),      # a secret itself
    ({"name": "robot1", "secret_ref": "file:relative/pw"}, "users[0].secret_ref", True),
    ({"name": "robot1", "secret_ref": "env:1BAD"}, "users[0].secret_ref", True),
    ({"name": "a:b", "secret_ref": "env:X"}, "users[0].name", True),                 # ':' splits a password file line
    ({"name": "robot1", "secret_ref": "env:X", "write": ["a\nb"]}, "users[0].write[0]", True),
    ({"name": "robot1", "secret_ref": "env:X", "password": "x"}, "users[0].password", True),
])
def test_bad_broker_users_are_refused_naming_the_field(user: dict, field: str, shown: bool) -> None:
    with pytest.raises(WireError) as info:
        broker_spec_from_json({**USER_BASE, "users": [user]})
    assert str(info.value).startswith(field)
    if not shown:  # what looks like a secret is never echoed back
        assert "hunter2" not in str(info.value) and "hunter2" not in (info.value.hint or "")


def test_two_users_of_one_name_are_refused() -> None:
    user = {"name": "robot1", "secret_ref": "env:X"}
    with pytest.raises(WireError, match="two users with the same name"):
        broker_spec_from_json({**USER_BASE, "users": [user, user]})


# --- client certificates: a certificate listener, users without a password ------------------------

CERT_BASE = {**USER_BASE, "port": 8883, "tls": True, "certificate_port": 8884}


def test_a_certificate_listener_and_its_users_round_trip() -> None:
    body = {**CERT_BASE, "users": [{"name": "cam1", "certificate": True, "write": ["cell/pose"]},
                                   {"name": "robot1", "secret_ref": "env:R", "certificate": True},
                                   {"name": "hmi", "secret_ref": "env:H"}]}
    spec = broker_spec_from_json(body)
    assert spec.certificate_port == 8884
    assert [(u.name, u.secret_ref, u.certificate) for u in spec.users] == [
        ("cam1", None, True), ("robot1", "env:R", True), ("hmi", "env:H", False)]
    assert broker_spec_from_json(to_dict(spec)) == spec


@pytest.mark.parametrize(("changes", "field"), [
    ({"certificate_port": 8883}, "certificate_port"),                  # the password listener's
    ({"certificate_port": 0}, "certificate_port"),
    ({"certificate_port": "8884"}, "certificate_port"),
    ({"tls": False}, "certificate_port"),                              # it speaks TLS or not at all
    ({"kind": "kafka"}, "certificate_port"),
    ({"users": [{"name": "cam1"}]}, "users[0].secret_ref"),            # neither password nor certificate
    ({"users": [{"name": "cam1", "certificate": "yes"}]}, "users[0].certificate"),
    ({"certificate_port": None, "users": [{"name": "cam1", "certificate": True}]}, "users[0].certificate"),
])
def test_bad_certificate_settings_are_refused_naming_the_field(changes: dict, field: str) -> None:
    with pytest.raises(WireError) as info:
        broker_spec_from_json({**CERT_BASE, **changes})
    assert info.value.field == field


def test_a_context_brokers_closed_kafkas_round_trip_and_bad_ones_are_refused() -> None:
    spec = broker_spec_from_json({**to_dict(NGSI), "closed_kafkas": ["127.0.0.4:9092", "[::1]:9093"]})
    assert spec.closed_kafkas == ("127.0.0.4:9092", "[::1]:9093")
    assert broker_spec_from_json(to_dict(spec)) == spec
    for bad, field in ((["kafka.local:9092"], "closed_kafkas[0].host"), (["127.0.0.4:x"], "closed_kafkas[0]"),
                       ("127.0.0.4:9092", "closed_kafkas")):
        with pytest.raises(WireError) as info:
            broker_spec_from_json({**to_dict(NGSI), "closed_kafkas": bad})
        assert info.value.field == field, (bad, info.value)


def test_a_context_brokers_tls_kafkas_round_trip_and_bad_ones_are_refused() -> None:
    spec = broker_spec_from_json({**to_dict(NGSI), "tls_kafkas": ["127.0.0.4:9092"]})
    assert spec.tls_kafkas == ("127.0.0.4:9092",) and spec.closed_kafkas == ()
    assert broker_spec_from_json(to_dict(spec)) == spec
    for bad, field in ((["kafka.local:9092"], "tls_kafkas[0].host"), ("127.0.0.4:9092", "tls_kafkas")):
        with pytest.raises(WireError) as info:
            broker_spec_from_json({**to_dict(NGSI), "tls_kafkas": bad})
        assert info.value.field == field, (bad, info.value)

"""engine.derive: the desired state read from asserted + inferred facts, with small inline plants."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.derive import DeriveError, NotReasonedError, derive
from engine.derived.bridge_pairs import BridgeNotSupportedError
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    BrokerUser,
    TopicSpec,
)
from engine.reasoning.reason import reason
from kg.load import load_plant

ROOT = Path(__file__).resolve().parents[2]
ROBOT_CELL = ROOT / "ontology" / "examples" / "robot-cell.ttl"
RC = "https://w3id.org/plantkg/examples/robot-cell#"
EX = "http://example.org/p#"

HEADER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/p#> .
"""

#: A Mosquitto and a Kafka broker; the publisher is on Mosquitto, the consumer on Kafka, no
#: bridge asserted; one idle broker; one topic both carry with settings of both kinds.
PLANT = """
:mq a pk:Broker ; pk:id "mq" ; pk:name "mq" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1883 .
:kf a pk:Broker ; pk:id "kf" ; pk:name "kf" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ; pk:port 9092 ;
    pk:hasTopic :archive .
:idle a pk:Broker ; pk:id "idle" ; pk:name "idle" ; pk:brokerType "kafka" ; pk:ip "127.0.0.4" ; pk:port 9092 .
:pos a pk:Topic ; pk:id "pos" ; pk:name "cell.robot.position" ; pk:qos 1 ; pk:retain true ;
    pk:partitions 3 ; pk:replicationFactor 1 ; pk:retentionMs 60000 .
:archive a pk:Topic ; pk:id "archive" ; pk:name "archive" ; pk:partitions 1 .
:robot a pk:Resource ; pk:id "robot" ; pk:name "robot" ; pk:sendsTo :mq ; pk:publishes :pos .
:db a pk:Resource ; pk:id "db" ; pk:name "db" ; pk:sendsTo :kf ; pk:subscribes :pos .
"""


def reasoned(tmp_path: Path, body: str, engine: str = "fast"):
    path = tmp_path / "plant.ttl"
    path.write_text(HEADER + body)
    plant = load_plant([path])
    reason(plant, engine=engine)  # type: ignore[arg-type]
    return plant


def test_needs_reasoning_first() -> None:
    with pytest.raises(NotReasonedError, match="reason"):
        derive(load_plant([ROBOT_CELL]))


def test_robot_cell() -> None:
    plant = load_plant([ROBOT_CELL])
    reason(plant)
    state = derive(plant)
    assert state.brokers == (
        # closed by default: the Raspberry Pi and the historian (their pk:secretRef), SASL users
        BrokerSpec("kafka", RC + "kafka", "kafka-aggregation", "kafka", "127.0.0.3", 9092,
                   allow_anonymous=False, users=(
                       BrokerUser("historian", "env:PLANTKG_HISTORIAN_PASSWORD",
                                  read=("robot.abb-irb120.energy", "robot.abb-irb120.position")),
                       BrokerUser("raspberry-pi", "env:PLANTKG_RASPBERRY_PI_PASSWORD",
                                  write=("robot.abb-irb120.energy",)))),
        # closed by default: the ROS machine (its pk:secretRef) and the bridge worker's principal
        BrokerSpec("mosquitto", RC + "mosquitto", "mosquitto-cell", "mosquitto", "127.0.0.2", 1883,
                   allow_anonymous=False, users=(
                       BrokerUser("plantkg.bridge.mosquitto.kafka", "plantkg:principal-key",
                                  read=("robot.abb-irb120.position",)),
                       BrokerUser("ros-machine", "env:PLANTKG_ROS_MACHINE_PASSWORD",
                                  write=("robot.abb-irb120.position",)))),
    )
    assert state.topics == (
        TopicSpec("kafka", "robot.abb-irb120.energy", RC + "robot-energy", partitions=3,
                  replication_factor=1, retention_ms=604800000),
        TopicSpec("kafka", "robot.abb-irb120.position", RC + "robot-position", partitions=3,
                  replication_factor=1, retention_ms=604800000),
        TopicSpec("mosquitto", "robot.abb-irb120.position", RC + "robot-position", qos=1, retain=False),
    )
    # Mosquitto -> Kafka: a worker beside the MQTT broker, the asserted bridge's shared topic; the
    # Kafka says nothing of pk:allowAnonymous, so it is closed and the worker logs in there
    assert state.bridges == (BridgeSpec(
        local=BridgeEnd("mosquitto", "mosquitto", "127.0.0.2", 1883),
        remote=BridgeEnd("kafka", "kafka", "127.0.0.3", 9092, closed=True),
        mechanism=BridgeMechanism.WORKER,
        routes=(BridgeRoute("robot.abb-irb120.position", BridgeDirection.OUT, qos=1, key="mqtt-topic"),),
        asserted=True),)


def test_derived_bridge_topics_and_settings_by_kind(tmp_path: Path) -> None:
    state = derive(reasoned(tmp_path, PLANT))
    assert [b.id for b in state.brokers] == ["kf", "mq"]  # idle is not deployed
    assert state.topics == (
        TopicSpec("kf", "archive", EX + "archive", partitions=1),
        TopicSpec("kf", "cell.robot.position", EX + "pos", partitions=3, replication_factor=1, retention_ms=60000),
        TopicSpec("mq", "cell.robot.position", EX + "pos", qos=1, retain=True),
    )
    # R1 required the bridge; it forwards the topic that caused it, not the Kafka-only one
    assert [(b.local.id, b.remote.id, b.mechanism, b.asserted) for b in state.bridges] == [
        ("mq", "kf", BridgeMechanism.WORKER, False)]
    assert state.bridges[0].routes == (BridgeRoute("cell.robot.position", BridgeDirection.OUT, 1),)


def test_settings_that_apply_are_read_from_the_ontology(tmp_path: Path) -> None:
    """Which settings a kind takes is Turtle: tell the plant MQTT brokers take partitions too."""
    state = derive(reasoned(tmp_path, PLANT + "pk:MqttBroker pk:topicSetting pk:partitions .\n"))
    mq = state.topics_of("mq")[0]
    assert (mq.partitions, mq.qos, mq.retain) == (3, 1, True)


def test_a_kind_without_settings_gets_bare_topics(tmp_path: Path) -> None:
    body = PLANT.replace('"kafka" ; pk:ip "127.0.0.3"', '"nats" ; pk:ip "127.0.0.3"')
    # no consumer on the other broker: no bridge (which a "nats" broker could not have)
    body = body.replace(":db a pk:Resource ; pk:id \"db\" ; pk:name \"db\" ; pk:sendsTo :kf ; pk:subscribes :pos .",
                        ":kf pk:hasTopic :pos .")
    state = derive(reasoned(tmp_path, body))
    assert state.bridges == ()
    assert state.broker("kf").kind == "nats"  # type: ignore[union-attr]
    assert state.topics_of("kf") == (TopicSpec("kf", "archive", EX + "archive"),
                                     TopicSpec("kf", "cell.robot.position", EX + "pos"))


def test_a_bridge_to_a_broker_of_no_bridgeable_class_is_refused_by_name(tmp_path: Path) -> None:
    body = PLANT.replace('"kafka" ; pk:ip "127.0.0.3"', '"nats" ; pk:ip "127.0.0.3"')
    with pytest.raises(BridgeNotSupportedError, match="bridge mq -> kf"):
        derive(reasoned(tmp_path, body))


def test_a_derived_bridge_between_two_kafka_brokers_is_a_mirror_on_the_target(tmp_path: Path) -> None:
    body = (PLANT.replace('"mosquitto" ; pk:ip "127.0.0.2"', '"kafka" ; pk:ip "127.0.0.2"')
            + ":mq pk:allowAnonymous true .\n:kf pk:allowAnonymous true .\n")
    [bridge] = derive(reasoned(tmp_path, body)).bridges
    assert (bridge.local.id, bridge.remote.id, bridge.mechanism) == ("kf", "mq", BridgeMechanism.MIRROR)
    assert bridge.routes == (BridgeRoute("cell.robot.position", BridgeDirection.IN, 1),)
    assert (bridge.local.closed, bridge.remote.closed) == (False, False)


def test_a_mirror_at_a_kafka_closed_by_default_logs_in_there(tmp_path: Path) -> None:
    """Each end says whether it is closed (MirrorMaker 2 logs in there as plantkg): the spec
    changes, and so the plan shows a change, when an end opens or closes."""
    two = PLANT.replace('"mosquitto" ; pk:ip "127.0.0.2"', '"kafka" ; pk:ip "127.0.0.2"')
    [one_open] = derive(reasoned(tmp_path, two + ":mq pk:allowAnonymous true .\n")).bridges
    assert one_open.mechanism is BridgeMechanism.MIRROR
    assert (one_open.local.id, one_open.local.closed, one_open.remote.closed) == ("kf", True, False)
    [both] = derive(reasoned(tmp_path, two)).bridges
    assert (both.local.closed, both.remote.closed) == (True, True)


def test_a_kafka_closed_by_default_and_opened_by_the_plant(tmp_path: Path) -> None:
    assert derive(reasoned(tmp_path, PLANT)).broker("kf").allow_anonymous is False  # type: ignore[union-attr]
    opened = derive(reasoned(tmp_path, PLANT + ":kf pk:allowAnonymous true .\n")).broker("kf")
    assert opened is not None and opened.allow_anonymous is True and opened.users == ()


def test_save_policy_is_read_when_set(tmp_path: Path) -> None:
    body = PLANT.replace('pk:ip "127.0.0.2" ; pk:port 1883 .', 'pk:ip "127.0.0.2" ; pk:port 1883 ; pk:persistEvery 1 .')
    state = derive(reasoned(tmp_path, body))
    assert state.broker("mq").persist_every == 1  # type: ignore[union-attr]
    assert state.broker("kf").persist_every is None  # type: ignore[union-attr]


def test_deterministic(tmp_path: Path) -> None:
    plant = reasoned(tmp_path, PLANT)
    first = derive(plant)
    reason(plant)
    assert derive(plant) == first
    assert list(first.topics) == sorted(first.topics, key=lambda t: t.address)


def test_same_state_from_hermit(tmp_path: Path) -> None:
    assert derive(reasoned(tmp_path, PLANT, "owlready2")) == derive(reasoned(tmp_path, PLANT, "fast"))


def test_missing_value_is_named(tmp_path: Path) -> None:
    with pytest.raises(DeriveError, match=r"p#mq|:mq|mq.*pk:ip") as caught:
        derive(reasoned(tmp_path, PLANT.replace(' pk:ip "127.0.0.2" ;', "")))
    assert "pk:ip" in str(caught.value) and "plant.ttl" in str(caught.value)


def test_two_topics_with_one_name_on_a_broker(tmp_path: Path) -> None:
    body = PLANT + ':other a pk:Topic ; pk:id "other" ; pk:name "archive" . :kf pk:hasTopic :other .\n'
    with pytest.raises(DeriveError, match="topic.kf.archive"):
        derive(reasoned(tmp_path, body))


def test_a_setting_without_a_model_field_is_refused(tmp_path: Path) -> None:
    body = PLANT + 'pk:KafkaBroker pk:topicSetting pk:valueTopic . :archive pk:valueTopic "x" .\n'
    with pytest.raises(DeriveError, match="value_topic"):
        derive(reasoned(tmp_path, body))


# --- context brokers: entity defaults, allowAnonymous, external ------------------------------

#: Mosquitto and a context broker; an AGV publishes its status on MQTT, the planner subscribes on
#: the context broker and publishes its orders there, which the AGV subscribes to on MQTT.
NGSI_PLANT = """
:mq a pk:Broker ; pk:id "mq" ; pk:name "mq" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1883 .
:cb a pk:Broker ; pk:id "cb" ; pk:name "cb" ; pk:brokerType "ngsi-v2" ; pk:ip "127.0.0.3" ; pk:port 1026 .
:status a pk:Topic ; pk:id "status" ; pk:name "agv/1/status" ; pk:qos 0 .
:order a pk:Topic ; pk:id "order" ; pk:name "agv/1/order" ; pk:entityId "urn:ngsi-ld:Order:agv1" ;
    pk:entityType "Order" .
:agv a pk:Resource ; pk:id "agv" ; pk:name "agv" ; pk:sendsTo :mq ; pk:publishes :status ; pk:subscribes :order .
:planner a pk:Resource ; pk:id "planner" ; pk:name "planner" ; pk:sendsTo :cb ; pk:subscribes :status ;
    pk:publishes :order .
"""


def test_a_context_broker_topic_is_an_entity_with_defaults_applied(tmp_path: Path) -> None:
    state = derive(reasoned(tmp_path, NGSI_PLANT))
    assert state.broker("cb") == BrokerSpec("cb", EX + "cb", "cb", "ngsi-v2", "127.0.0.3", 1026,
                                            allow_anonymous=False)
    assert state.broker("mq").allow_anonymous is False  # type: ignore[union-attr]  # closed by default
    assert state.topics_of("cb") == (
        TopicSpec("cb", "agv/1/order", EX + "order", entity_id="urn:ngsi-ld:Order:agv1", entity_type="Order"),
        TopicSpec("cb", "agv/1/status", EX + "status", entity_id="urn:ngsi-ld:Thing:agv:1:status",
                  entity_type="Thing"))
    assert state.topics_of("mq")[1] == TopicSpec("mq", "agv/1/status", EX + "status", qos=0)
    [bridge] = state.bridges
    assert (bridge.local.id, bridge.remote.id, bridge.mechanism, bridge.asserted) == (
        "mq", "cb", BridgeMechanism.NGSI, False)
    # R1 requires the bridge both ways (status out, order in); a derived bridge forwards only the
    # topics that made R1 fire, each in its own direction: nothing is echoed back to where it came from
    assert bridge.routes == (
        BridgeRoute("agv/1/order", BridgeDirection.IN, 1, "mqtt-topic", "urn:ngsi-ld:Order:agv1", "Order"),
        BridgeRoute("agv/1/status", BridgeDirection.OUT, 0, "mqtt-topic", "urn:ngsi-ld:Thing:agv:1:status", "Thing"))


def test_an_asserted_bridge_forwards_every_topic_both_brokers_carry(tmp_path: Path) -> None:
    """pk:bridgesTo keeps the paper's meaning: the bridge is "bound by topic_sub", every shared topic."""
    body = NGSI_PLANT.replace('pk:port 1883 .', 'pk:port 1883 ; pk:bridgesTo :cb .', 1)
    assert body != NGSI_PLANT
    [bridge] = derive(reasoned(tmp_path, body)).bridges
    assert bridge.asserted
    assert {r.topic: r.direction for r in bridge.routes} == {
        "agv/1/order": BridgeDirection.BOTH, "agv/1/status": BridgeDirection.OUT}


def test_hermit_derives_the_same_ngsi_state(tmp_path: Path) -> None:
    assert derive(reasoned(tmp_path, NGSI_PLANT, "owlready2")) == derive(reasoned(tmp_path, NGSI_PLANT))


def test_allow_anonymous_is_read(tmp_path: Path) -> None:
    body = NGSI_PLANT.replace("pk:port 1026 .", "pk:port 1026 ; pk:allowAnonymous true .")
    assert derive(reasoned(tmp_path, body)).broker("cb").allow_anonymous is True  # type: ignore[union-attr]


def test_an_external_context_broker_is_not_deployed_but_is_bridged_to(tmp_path: Path) -> None:
    body = NGSI_PLANT.replace("pk:port 1026 .", "pk:port 1026 ; pk:external true .")
    state = derive(reasoned(tmp_path, body))
    assert [b.id for b in state.brokers] == ["mq"]
    assert {t.broker_id for t in state.topics} == {"mq"}
    [bridge] = state.bridges
    assert (bridge.local.id, bridge.remote.id, bridge.remote.port) == ("mq", "cb", 1026)
    assert bridge.routes[1].entity_id == "urn:ngsi-ld:Thing:agv:1:status"
    # external false is the default: deployed
    body = NGSI_PLANT.replace("pk:port 1026 .", "pk:port 1026 ; pk:external false .")
    assert [b.id for b in derive(reasoned(tmp_path, body)).brokers] == ["cb", "mq"]


def test_an_external_broker_cannot_carry_a_bridge(tmp_path: Path) -> None:
    body = NGSI_PLANT.replace("pk:port 1883 .", "pk:port 1883 ; pk:external true .")
    with pytest.raises(BridgeNotSupportedError, match="'mq', which is pk:external"):
        derive(reasoned(tmp_path, body))


def test_an_entity_id_minted_from_an_unusable_topic_name_is_refused_by_name(tmp_path: Path) -> None:
    body = NGSI_PLANT.replace('pk:name "agv/1/status"', 'pk:name "agv/1/status?x"')
    with pytest.raises(DeriveError, match=r"status.*pk:entityId 'urn:ngsi-ld:Thing:agv:1:status\?x' "
                                          r"\(minted from the topic name\)") as info:
        derive(reasoned(tmp_path, body))
    assert "set pk:entityId on the topic" in str(info.value)


def test_a_context_broker_cannot_bridge_to_kafka(tmp_path: Path) -> None:
    body = NGSI_PLANT.replace('"mosquitto" ; pk:ip "127.0.0.2"', '"kafka" ; pk:ip "127.0.0.2"')
    body = body.replace('pk:name "agv/1/status"', 'pk:name "agv.1.status"').replace('pk:name "agv/1/order"', 'pk:name "agv.1.order"')
    with pytest.raises(BridgeNotSupportedError, match="MQTT broker only, not to a Kafka broker"):
        derive(reasoned(tmp_path, body))


def test_the_ngsi_plan_cases_start_from_the_agv_example() -> None:
    """tests/cases/plan/ngsi-*: their desired state is what the example plant derives today."""
    from tests.unit.plan_data import case_names, load_case

    plant = load_plant([ROOT / "ontology" / "examples" / "agv-middleware.ttl"])
    reason(plant)
    state = derive(plant)
    names = [n for n in case_names() if n.startswith("ngsi-")]
    assert len(names) >= 4
    for name in names:
        assert load_case(name)[0] == state, name
    [bridge] = state.bridges
    assert (bridge.address, bridge.mechanism) == ("bridge.fleet-mqtt.fleet-context", BridgeMechanism.NGSI)

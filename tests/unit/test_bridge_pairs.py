"""engine.derived.bridge_pairs: directed bridge facts -> one BridgeSpec per broker pair (pure)."""

from __future__ import annotations

import pytest

from engine.derived.bridge_pairs import (
    BridgeNotSupportedError,
    DirectedBridge,
    TopicOptions,
    pair_bridges,
)
from engine.model import BridgeDirection, BridgeMechanism, BrokerSpec

MQTT, KAFKA = frozenset({"pk:MqttBroker"}), frozenset({"pk:KafkaBroker"})
BROKERS = {
    "a": BrokerSpec("a", "urn:a", "A", "mosquitto", "127.0.0.2", 1883),
    "b": BrokerSpec("b", "urn:b", "B", "mosquitto", "127.0.0.3", 1884),
    "k": BrokerSpec("k", "urn:k", "K", "kafka", "127.0.0.4", 9092),
    "k2": BrokerSpec("k2", "urn:k2", "K2", "kafka", "127.0.0.5", 9092),
}
CLASSES = {"a": MQTT, "b": MQTT, "k": KAFKA, "k2": KAFKA}


def d(source: str, target: str, *topics: str, asserted: bool = True) -> DirectedBridge:
    return DirectedBridge(source, target, frozenset(topics), asserted)


def routes(spec) -> list[tuple[str, str, int, str]]:
    return [(r.topic, r.direction.value, r.qos, r.key) for r in spec.routes]


def test_one_way_mosquitto_bridge_is_carried_by_its_source() -> None:
    [spec] = pair_bridges([d("b", "a", "t")], BROKERS, CLASSES, {})
    assert (spec.local.id, spec.remote.id, spec.mechanism) == ("b", "a", BridgeMechanism.MOSQUITTO)
    assert (spec.remote.host, spec.remote.port) == ("127.0.0.2", 1883)
    assert routes(spec) == [("t", "out", 1, "mqtt-topic")]
    assert spec.address == "bridge.b.a"


def test_two_way_mosquitto_bridge_is_one_connection_on_the_smaller_id() -> None:
    [spec] = pair_bridges([d("b", "a", "both", "b-only"), d("a", "b", "both", "a-only", asserted=False)],
                          BROKERS, CLASSES, {"both": TopicOptions(qos=2)})
    assert (spec.local.id, spec.remote.id) == ("a", "b")
    assert routes(spec) == [("a-only", "out", 1, "mqtt-topic"), ("b-only", "in", 1, "mqtt-topic"),
                            ("both", "both", 2, "mqtt-topic")]
    assert spec.asserted  # one direction asserted is enough


def test_worker_runs_beside_the_mqtt_broker_whatever_the_direction() -> None:
    [spec] = pair_bridges([d("k", "a", "cmd", asserted=False)], BROKERS, CLASSES,
                          {"cmd": TopicOptions(qos=0, kafka_key="none")})
    assert (spec.local.id, spec.remote.id, spec.mechanism) == ("a", "k", BridgeMechanism.WORKER)
    assert routes(spec) == [("cmd", "in", 0, "none")]
    assert not spec.asserted


def test_kafka_key_only_matters_to_workers() -> None:
    [spec] = pair_bridges([d("a", "b", "t")], BROKERS, CLASSES, {"t": TopicOptions(kafka_key="none")})
    assert spec.routes[0].key == "mqtt-topic"


def test_pairs_are_sorted_and_separate() -> None:
    specs = pair_bridges([d("b", "k", "x"), d("a", "b", "y"), d("a", "k", "z")], BROKERS, CLASSES, {})
    assert [s.address for s in specs] == ["bridge.a.b", "bridge.a.k", "bridge.b.k"]
    assert [s.routes[0].direction for s in specs] == [BridgeDirection.OUT] * 3


def test_a_mosquitto_bridge_never_connects_to_an_ipv6_address() -> None:
    six = {**BROKERS, "v6": BrokerSpec("v6", "urn:v6", "V6", "mosquitto", "::1", 1883)}
    classes = {**CLASSES, "v6": MQTT}
    with pytest.raises(BridgeNotSupportedError, match="'v6' at the IPv6 address ::1"):
        pair_bridges([d("a", "v6", "t")], six, classes, {})
    # pushing from the IPv6 broker to an IPv4 one is fine, and a two-way pair picks that carrier
    [one_way] = pair_bridges([d("v6", "a", "t")], six, classes, {})
    [two_way] = pair_bridges([d("a", "v6", "t"), d("v6", "a", "t")], six, classes, {})
    assert one_way.local.id == two_way.local.id == "v6"
    assert two_way.routes[0].direction is BridgeDirection.BOTH


def test_two_kafka_brokers_are_mirrored_by_the_target() -> None:
    """MirrorMaker 2 consumes remotely and produces locally: the target carries it."""
    [spec] = pair_bridges([d("k", "k2", "t", asserted=False)], BROKERS, CLASSES, {})
    assert (spec.local.id, spec.remote.id, spec.mechanism) == ("k2", "k", BridgeMechanism.MIRROR)
    assert routes(spec) == [("t", "in", 1, "mqtt-topic")]
    [back] = pair_bridges([d("k2", "k", "t")], BROKERS, CLASSES, {})
    assert (back.local.id, back.remote.id) == ("k", "k2")


def test_a_kafka_mirror_both_ways_is_refused_by_name() -> None:
    with pytest.raises(BridgeNotSupportedError, match="k -> k2: MirrorMaker 2 bridges two Kafka brokers one way only"):
        pair_bridges([d("k", "k2", "t"), d("k2", "k", "u")], BROKERS, CLASSES, {})


def test_a_kafka_mirror_is_not_carried_by_an_external_target() -> None:
    with pytest.raises(BridgeNotSupportedError, match="pk:external"):
        pair_bridges([d("k", "k2", "t")], BROKERS, CLASSES, {}, external=frozenset({"k2"}))


def test_brokers_of_no_known_class_are_refused() -> None:
    with pytest.raises(BridgeNotSupportedError, match="not both of such classes"):
        pair_bridges([d("a", "b", "t")], BROKERS, {"a": MQTT}, {})


# --- context brokers (pk:ContextBroker) and external brokers ---------------------------------

NGSI = frozenset({"pk:ContextBroker"})
CB = {**BROKERS,
      "cb": BrokerSpec("cb", "urn:cb", "CB", "ngsi-v2", "127.0.0.6", 1026, allow_anonymous=False),
      "cb2": BrokerSpec("cb2", "urn:cb2", "CB2", "ngsi-v2", "127.0.0.7", 1026)}
CB_CLASSES = {**CLASSES, "cb": NGSI, "cb2": NGSI}
ENTITY = {"status": TopicOptions(qos=0, entity_id="urn:ngsi-ld:AGV:agv:1", entity_type="AGV"),
          "motion": TopicOptions(entity_id="urn:ngsi-ld:Thing:motion", entity_type="Thing")}


def test_mqtt_and_context_broker_get_an_ngsi_worker_beside_the_mqtt_broker() -> None:
    [spec] = pair_bridges([d("a", "cb", "status", asserted=False), d("cb", "a", "motion", asserted=False)],
                          CB, CB_CLASSES, ENTITY)
    assert (spec.local.id, spec.remote.id, spec.mechanism) == ("a", "cb", BridgeMechanism.NGSI)
    assert (spec.remote.kind, spec.remote.host, spec.remote.port) == ("ngsi-v2", "127.0.0.6", 1026)
    assert [(r.topic, r.direction.value, r.qos, r.entity_id, r.entity_type) for r in spec.routes] == [
        ("motion", "in", 1, "urn:ngsi-ld:Thing:motion", "Thing"),
        ("status", "out", 0, "urn:ngsi-ld:AGV:agv:1", "AGV")]


def test_the_mqtt_side_carries_an_ngsi_bridge_whichever_way_it_was_stated() -> None:
    [spec] = pair_bridges([d("cb", "b", "motion")], CB, CB_CLASSES, ENTITY)
    assert (spec.local.id, spec.remote.id) == ("b", "cb")
    assert spec.routes[0].direction is BridgeDirection.IN


def test_entity_fields_only_go_to_ngsi_routes() -> None:
    [spec] = pair_bridges([d("a", "k", "status")], CB, CB_CLASSES, ENTITY)
    assert spec.mechanism is BridgeMechanism.WORKER
    assert (spec.routes[0].entity_id, spec.routes[0].entity_type) == (None, None)


@pytest.mark.parametrize(("pair", "other"), [(("k", "cb"), "a Kafka broker"),
                                             (("cb", "cb2"), "another context broker")])
def test_a_context_broker_bridges_to_mqtt_only(pair: tuple[str, str], other: str) -> None:
    with pytest.raises(BridgeNotSupportedError, match=f"MQTT broker only, not to {other}") as info:
        pair_bridges([d(*pair, "t")], CB, CB_CLASSES, {})
    assert "route the topic through an MQTT broker" in (info.value.hint or "")


def test_an_external_broker_is_a_far_end_but_never_a_carrier() -> None:
    [spec] = pair_bridges([d("a", "cb", "status")], CB, CB_CLASSES, ENTITY, external=frozenset({"cb"}))
    assert (spec.local.id, spec.remote.id) == ("a", "cb")
    [two_way] = pair_bridges([d("a", "b", "t"), d("b", "a", "t")], CB, CB_CLASSES, {},
                             external=frozenset({"a"}))
    assert two_way.local.id == "b"  # not the smaller id: that broker is external
    with pytest.raises(BridgeNotSupportedError, match="'a', which is pk:external"):
        pair_bridges([d("a", "cb", "status")], CB, CB_CLASSES, ENTITY, external=frozenset({"a"}))
    with pytest.raises(BridgeNotSupportedError, match="'a', which is pk:external"):
        pair_bridges([d("a", "b", "t")], CB, CB_CLASSES, {}, external=frozenset({"a"}))


# --- an MQTT broker of another type (a plugin's class, a subclass of pk:MqttBroker) ------------

OTHER = {**BROKERS,
         "r": BrokerSpec("r", "urn:r", "R", "othermq", "127.0.0.6", 5672, mqtt_port=1885),
         "r2": BrokerSpec("r2", "urn:r2", "R2", "othermq", "127.0.0.7", 5672, mqtt_port=1886),
         "r6": BrokerSpec("r6", "urn:r6", "R6", "othermq", "::1", 5672, mqtt_port=1887)}
OTHER_CLASSES = {**CLASSES, "r": MQTT, "r2": MQTT, "r6": MQTT}


@pytest.mark.parametrize(("directed", "local", "remote", "direction"), [
    ([("a", "r")], "a", "r", "out"),   # Mosquitto pushes to it
    ([("r", "a")], "a", "r", "in"),    # Mosquitto pulls from it: the other type carries nothing
])
def test_a_bridge_to_another_mqtt_type_is_carried_by_the_mosquitto(directed, local, remote, direction) -> None:
    [spec] = pair_bridges([d(s, t, "t") for s, t in directed], OTHER, OTHER_CLASSES, {})
    assert (spec.local.id, spec.remote.id, spec.mechanism) == (local, remote, BridgeMechanism.MOSQUITTO)
    assert routes(spec) == [("t", direction, 1, "mqtt-topic")]
    # reached at its MQTT port, not at pk:port (AMQP's, say); a Mosquitto end keeps its port
    assert (spec.remote.kind, spec.remote.port, spec.local.port) == ("othermq", 1885, 1883)


@pytest.mark.parametrize(("directed", "match"), [
    ([("a", "r"), ("r", "a")], "two-way bridge needs Mosquitto's bridge flag"),
    ([("r", "r2")], "neither broker is a Mosquitto"),
    ([("a", "r6")], "'r6' at the IPv6 address ::1"),
    ([("r", "k")], "the bridge worker runs beside a Mosquitto"),
])
def test_bridges_to_another_mqtt_type_that_cannot_run_are_refused(directed, match) -> None:
    with pytest.raises(BridgeNotSupportedError, match=match):
        pair_bridges([d(s, t, "t") for s, t in directed], OTHER, OTHER_CLASSES, {})


def test_an_external_mosquitto_cannot_carry_a_bridge_to_another_mqtt_type() -> None:
    with pytest.raises(BridgeNotSupportedError, match="pk:external"):
        pair_bridges([d("a", "r", "t")], OTHER, OTHER_CLASSES, {}, external=frozenset({"a"}))


def test_the_mqtt_port_is_used_only_for_an_mqtt_class() -> None:
    """A Kafka broker with an mqtt_port (the wire allows it) is still reached at its pk:port."""
    brokers = {**BROKERS, "k": BrokerSpec("k", "urn:k", "K", "kafka", "127.0.0.4", 9092, mqtt_port=1999)}
    [spec] = pair_bridges([d("a", "k", "t")], brokers, CLASSES, {})
    assert spec.remote.port == 9092

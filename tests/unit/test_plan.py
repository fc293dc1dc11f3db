"""plan() details the data cases do not show, and the text and JSON renderings of a plan."""

from __future__ import annotations

import json
from dataclasses import replace

from engine.model import (
    Action,
    BrokerSpec,
    BrokerStatus,
    DesiredState,
    ObservedBroker,
    ObservedState,
    ObservedTopic,
    TopicSpec,
)
from engine.plan import TOPIC_SETTINGS, destroy_plan, plan
from engine.render.plan import NO_CHANGES, plan_dict, plan_json, render_plan, summary_line
from tests.unit.plan_data import load_case

MQ = BrokerSpec("mq", "urn:x:mq", "mq", "mosquitto", "127.0.0.2", 1883)
KF = BrokerSpec("kf", "urn:x:kf", "kf", "kafka", "127.0.0.3", 9092)


def running(spec: BrokerSpec, *topics: ObservedTopic) -> ObservedBroker:
    return ObservedBroker(spec, BrokerStatus.RUNNING, topics, pid=1)


def test_topic_settings_agree_with_the_drivers() -> None:
    base = __import__("pytest").importorskip("engine.drivers.base")
    assert TOPIC_SETTINGS["kafka"] == base.KAFKA_TOPIC_FIELDS
    assert TOPIC_SETTINGS["mosquitto"] == base.MQTT_TOPIC_FIELDS


def test_kind_change_replaces_and_recreates_topics() -> None:
    as_kafka = BrokerSpec("mq", "urn:x:mq", "mq", "kafka", "127.0.0.2", 1883)
    desired = DesiredState((as_kafka,), (TopicSpec("mq", "t", "urn:x:t", partitions=2),))
    observed = ObservedState((running(MQ, ObservedTopic("t", qos=1, retain=False)),))
    result = plan(desired, observed)
    assert [(c.address, c.action) for c in result.changes] == [
        ("broker.mq", Action.REPLACE), ("topic.mq.t", Action.CREATE)]
    assert "kind" in result.changes[0].reason


def test_setting_the_plant_leaves_open_is_not_drift() -> None:
    """A Kafka topic without retentionMs in the plant accepts whatever retention the broker has."""
    desired = DesiredState((KF,), (TopicSpec("kf", "t", "urn:x:t", partitions=3),))
    observed = ObservedState((running(KF, ObservedTopic("t", 3, 1, 604800000)),))
    assert plan(desired, observed).empty


def test_stopped_broker_is_started_and_starting_one_is_left_alone() -> None:
    desired = DesiredState((MQ,))
    stopped = ObservedState((ObservedBroker(MQ, BrokerStatus.STOPPED),))
    starting = ObservedState((ObservedBroker(MQ, BrokerStatus.STARTING, pid=5),))
    assert [c.action for c in plan(desired, stopped).pending] == [Action.UPDATE]
    assert plan(desired, starting).empty


def test_destroy_plan_touches_only_the_plants_brokers() -> None:
    other = BrokerSpec("other", "urn:y:o", "o", "mosquitto", "127.0.0.2", 1999)
    desired = DesiredState((MQ, KF), (TopicSpec("kf", "t", "urn:x:t", partitions=1),))
    observed = ObservedState((running(KF, ObservedTopic("t", 1, 1, 5)), running(MQ), running(other)))
    result = destroy_plan(desired, observed)
    assert [(c.address, c.action) for c in result.changes] == [
        ("topic.kf.t", Action.DELETE), ("broker.kf", Action.DELETE), ("broker.mq", Action.DELETE)]


def test_destroy_plan_deletes_the_plants_bridges_before_their_broker() -> None:
    desired, observed, _ = load_case("no-change")
    result = destroy_plan(desired, observed)
    addresses = [c.address for c in result.changes]
    assert addresses.index("bridge.mosquitto.kafka") < addresses.index("broker.mosquitto")
    assert {c.action for c in result.changes} == {Action.DELETE}


def test_a_bridge_whose_broker_starts_anew_is_created_again() -> None:
    desired, observed, _ = load_case("no-change")
    moved = replace(desired.brokers[1], host="127.0.0.9")
    assert moved.id == "mosquitto"
    desired = replace(desired, brokers=(desired.brokers[0], moved))
    changes = {c.address: c.action for c in plan(desired, observed).changes}
    assert changes["broker.mosquitto"] is Action.REPLACE
    assert changes["bridge.mosquitto.kafka"] is Action.CREATE


def test_a_worker_whose_kafka_closes_or_opens_is_put_again() -> None:
    desired, observed, _ = load_case("no-change")
    kafka = desired.brokers[0]
    assert kafka.id == "kafka" and kafka.allow_anonymous is None  # the case's Kafka: open
    [bridge] = desired.bridges
    assert bridge.remote.id == "kafka" and not bridge.remote.closed
    closed = replace(desired, brokers=(replace(kafka, allow_anonymous=False), desired.brokers[1]),
                     bridges=(replace(bridge, remote=replace(bridge.remote, closed=True)),))
    for want, have in ((closed, observed), (desired, _observed_as(observed, closed))):
        result = plan(want, have)
        changes = {c.address: c for c in result.changes}
        assert changes["broker.kafka"].action is Action.REPLACE
        change = changes["bridge.mosquitto.kafka"]
        assert change.action is Action.UPDATE and change.reason.startswith("remote changed")
        assert change.after["remote"].get("closed", False) is (want is closed)  # an open end reads as before
    assert all(c.action is Action.NOOP for c in plan(closed, _observed_as(observed, closed)).changes)


def _observed_as(observed: ObservedState, desired: DesiredState) -> ObservedState:
    """``observed`` with each broker and bridge running the spec ``desired`` gives it."""
    bridges = {b.address: b for b in desired.bridges}
    return replace(observed, brokers=tuple(replace(b, spec=desired.broker(b.spec.id) or b.spec)
                                           for b in observed.brokers),
                   bridges=tuple(replace(b, spec=bridges.get(b.spec.address, b.spec)) for b in observed.bridges))


def test_a_bridge_on_an_unreachable_host_is_not_planned() -> None:
    desired, observed, _ = load_case("no-change")
    observed = replace(observed, unreachable=("127.0.0.2",),
                       brokers=tuple(b for b in observed.brokers if b.spec.host != "127.0.0.2"))
    result = plan(desired, observed)
    assert not any(c.address.startswith("bridge.") for c in result.changes)
    assert not result.applicable


def test_a_new_save_policy_restarts_the_broker() -> None:
    durable = replace(MQ, persist_every=1)
    result = plan(DesiredState((durable,)), ObservedState((running(MQ),)))
    (change,) = result.pending
    assert change.action is Action.REPLACE and "persist_every null → 1 forces replacement" in change.reason


def test_unreachable_host_blocks_the_plan() -> None:
    result = plan(DesiredState((MQ,)), ObservedState(unreachable=("127.0.0.2",)))
    assert not result.applicable and result.unreachable == ("127.0.0.2",)
    assert result.changes == ()


# ------------------------------------------------------------------------------------ rendering

def test_render_signs_and_summary() -> None:
    desired, observed, _ = load_case("empty-all-create")
    text = render_plan(plan(desired, observed))
    assert "  + broker.kafka will be created" in text
    assert '+ port = 9092' in text
    assert "  + bridge.mosquitto.kafka will be created" in text
    assert "persist_every" not in text  # unset optional fields are not listed
    assert '+ mechanism = "mqtt-kafka"' in text
    assert text.splitlines()[-1] == "Plan: 6 to create, 0 to update, 0 to replace, 0 to destroy."


def test_render_replace_shows_the_field_and_why() -> None:
    desired, observed, _ = load_case("port-change-replace")
    text = render_plan(plan(desired, observed))
    assert "  -/+ broker.kafka must be replaced" in text
    assert "~ port: 9092 → 9093   # forces replacement" in text
    assert "# port 9092 → 9093 forces replacement (the agent restarts the broker)" in text


def test_render_update_and_delete() -> None:
    desired, observed, _ = load_case("retention-change-update")
    assert "~ retention_ms: 604800000 → 86400000" in render_plan(plan(desired, observed))
    desired, observed, _ = load_case("broker-removed-delete")
    text = render_plan(plan(desired, observed))
    assert "  - broker.kafka will be destroyed" in text
    assert text.index("topic.kafka.robot.abb-irb120.energy") < text.index("  - broker.kafka")
    assert text.splitlines()[-1] == "Plan: 0 to create, 0 to update, 0 to replace, 3 to destroy."


def test_render_no_changes() -> None:
    desired, observed, _ = load_case("volatile-fields-no-op")
    result = plan(desired, observed)
    assert summary_line(result) == NO_CHANGES
    assert render_plan(result).splitlines()[-1] == NO_CHANGES


def test_render_refusal_and_unreachable() -> None:
    desired, observed, _ = load_case("partitions-down-refused")
    text = render_plan(plan(desired, observed))
    assert "! topic.kafka.robot.abb-irb120.energy: partitions 3 → 2" in text
    assert "This plan cannot be applied" in text and NO_CHANGES not in text
    desired, observed, _ = load_case("unreachable-host")
    text = render_plan(plan(desired, observed))
    assert "! 127.0.0.3" in text and "cannot be applied" in text


def test_render_colour_only_when_asked() -> None:
    desired, observed, _ = load_case("empty-all-create")
    result = plan(desired, observed)
    assert "\x1b[" not in render_plan(result)
    assert "\x1b[" in render_plan(result, color=True)


def test_plan_json_round_trips_the_plan() -> None:
    desired, observed, _ = load_case("host-change-replace")
    result = plan(desired, observed)
    data = json.loads(plan_json(result))
    assert data == json.loads(json.dumps(plan_dict(result)))
    assert data["summary"] == {"create": 2, "update": 1, "replace": 1, "delete": 0}
    assert data["applicable"] is True and data["empty"] is False
    first = data["changes"][0]
    assert first["address"] == "broker.kafka" and first["action"] == "replace"
    assert first["before"]["host"] == "127.0.0.3" and first["after"]["host"] == "127.0.0.4"


def test_a_certificate_listener_and_its_users_show_in_the_plan_never_a_secret() -> None:
    """Opening a certificate listener replaces the broker (its config changes); a certificate user
    shows ``"certificate": true`` and no secret reference, a password user its reference only."""
    from engine.model import BrokerUser  # noqa: PLC0415
    users = (BrokerUser("cam1", None, write=("cell/pose",), certificate=True), BrokerUser("hmi", "env:HMI_PW"))
    tls = replace(MQ, tls=True, port=8883, allow_anonymous=False)
    wanted = replace(tls, certificate_port=8884, users=users)
    result = plan(DesiredState((wanted,)), ObservedState((running(tls),)))
    [change] = result.changes
    assert change.action is Action.REPLACE and "certificate_port" in change.reason
    text = render_plan(result)
    assert "~ certificate_port: (none) → 8884   # forces replacement" in text
    assert '{"name": "cam1", "write": ["cell/pose"], "read": [], "certificate": true}' in text
    assert '"secret_ref": "env:HMI_PW"' in text and '"secret_ref": null' not in text
    assert plan(DesiredState((wanted,)), ObservedState((running(wanted),))).empty

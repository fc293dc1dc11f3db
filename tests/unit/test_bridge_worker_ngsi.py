"""The pure parts of the MQTT <-> NGSI bridge worker: payload -> attributes (names mapped or the
message refused), the loop rule, the subscription body and its reconciliation, worker.json."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from engine.bridge_worker.__main__ import load
from engine.bridge_worker.config import WorkerConfig
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiRoute, NgsiWorkerConfig, is_ngsi_config
from engine.bridge_worker.ngsi_mapping import (
    Refused,
    attribute_name,
    attributes,
    iso_time,
    is_notification,
    upsert_body,
)
from engine.bridge_worker.ngsi_subscriptions import description, reconcile, subscription_body
from engine.errors import ConfigValueError

T0 = 1795536000.25  # 2026-11-24T16:00:00.250Z
STAMP = {"type": "DateTime", "value": "2026-11-24T16:00:00.250Z"}


# --- payload -> attributes ---------------------------------------------------------------------

TYPED = [
    (b'{"speed": 1.5}', {"speed": {"type": "Number", "value": 1.5}}),
    (b'{"count": 3}', {"count": {"type": "Number", "value": 3}}),
    (b'{"state": "moving"}', {"state": {"type": "Text", "value": "moving"}}),
    (b'{"ok": true}', {"ok": {"type": "Boolean", "value": True}}),
    (b'{"pose": {"x": 1, "y": 2}}', {"pose": {"type": "StructuredValue", "value": {"x": 1, "y": 2}}}),
    (b'{"path": [1, 2]}', {"path": {"type": "StructuredValue", "value": [1, 2]}}),
    (b'{"gone": null}', {"gone": {"type": "None", "value": None}}),
    (b"hello robot", {"value": {"type": "Text", "value": "hello robot"}}),
    (b"42", {"value": {"type": "Text", "value": "42"}}),
    (b"[1, 2]", {"value": {"type": "Text", "value": "[1, 2]"}}),
    (b'"moving"', {"value": {"type": "Text", "value": "moving"}}),
    (b"", {"value": {"type": "Text", "value": ""}}),
]


@pytest.mark.parametrize(("payload", "expected"), TYPED, ids=[p.decode() or "empty" for p, _ in TYPED])
def test_payload_becomes_typed_attributes_and_a_receive_time(payload: bytes, expected: dict) -> None:
    assert attributes(payload, T0) == {**expected, "TimeInstant": STAMP}


def test_upsert_body_names_the_entity() -> None:
    body = upsert_body("urn:agv:7", "AGV", b'{"battery": 80}', T0)
    assert body == {"id": "urn:agv:7", "type": "AGV", "battery": {"type": "Number", "value": 80},
                    "TimeInstant": STAMP}


def test_receive_time_is_iso_8601_utc_with_milliseconds() -> None:
    assert iso_time(0.0) == "1970-01-01T00:00:00.000Z"
    assert iso_time(T0 + 0.0009) == "2026-11-24T16:00:00.250Z"


NAMES = [
    ("speed", "speed"),
    ("a b", "a_b"),
    ("a/b#c", "a_b_c"),
    ("x(1)", "x_1_"),
    ("id", "id_"),
    ("type", "type_"),
    ("TimeInstant", "TimeInstant_"),
    ("dateModified", "dateModified_"),
]


@pytest.mark.parametrize(("field", "name"), NAMES)
def test_field_names_ngsi_refuses_are_mapped(field: str, name: str) -> None:
    assert attribute_name(field) == name


REFUSED_PAYLOADS = [
    (b'{"": 1}', "empty field name"),
    (b'{"temp\\u00e9rature": 1}', "character"),
    ('{"' + "x" * 257 + '": 1}', "1 to 256"),
    (b'{"a b": 1, "a_b": 2}', "same attribute name"),
    (b'{"note": "say \\"hi\\""}', "character '\"'"),
    (b'{"deep": {"k": ["ok", "x=1"]}}', "attribute 'deep'.k[1]"),
    (b"a=b", "character '='"),
    (b"\xff\xfe", "not UTF-8"),
]


@pytest.mark.parametrize(("payload", "reason"), REFUSED_PAYLOADS, ids=[r for _, r in REFUSED_PAYLOADS])
def test_what_ngsi_would_refuse_is_refused_with_a_reason(payload: bytes | str, reason: str) -> None:
    raw = payload.encode() if isinstance(payload, str) else payload
    with pytest.raises(Refused) as exc:
        attributes(raw, T0)
    assert reason in exc.value.reason


# --- the loop rule ------------------------------------------------------------------------------

LOOP = [
    (b'{"subscriptionId": "5f1", "data": [{"id": "e", "type": "T"}]}', True),
    (b' {"subscriptionId": "5f1", "data": []}', True),
    (b'{"subscriptionId": 5, "data": []}', False),         # not Orion's: the id is a string
    (b'{"subscriptionId": "5f1"}', False),                 # no data array
    (b'{"data": [], "seq": 1}', False),
    (b"subscriptionId", False),
    (b'{"subscriptionId": "5f1", "data": [}', False),      # not JSON
]


@pytest.mark.parametrize(("payload", "notification"), LOOP)
def test_loop_rule_recognises_context_broker_notifications(payload: bytes, notification: bool) -> None:
    assert is_notification(payload) is notification


# --- config ---------------------------------------------------------------------------------------

def config(tmp_path: Path, *routes: NgsiRoute, **extra: object) -> NgsiWorkerConfig:
    routes = routes or (NgsiRoute("cell/agv7", "urn:agv:7", "AGV", NgsiDirection.MQTT_TO_NGSI),
                        NgsiRoute("cell/agv7", "urn:agv:7", "AGV", NgsiDirection.NGSI_TO_MQTT))
    return NgsiWorkerConfig("mqtt--orion", "127.0.0.2", 1883, "http://127.0.0.5:1026", routes,
                            tmp_path / "w", **extra)  # type: ignore[arg-type]


def test_config_round_trips_through_json(tmp_path: Path) -> None:
    cfg = config(tmp_path, token_file=tmp_path / "w" / "remote.token", stats_interval=0.1, check_every=2)
    text = cfg.to_json()
    assert is_ngsi_config(text)
    assert NgsiWorkerConfig.from_json(text) == cfg
    open_cfg = config(tmp_path)
    assert NgsiWorkerConfig.from_json(open_cfg.to_json()) == open_cfg
    tls_cfg = replace(open_cfg, ngsi_url="https://127.0.0.5:1026", ngsi_ca_file=tmp_path / "ca.pem")
    assert NgsiWorkerConfig.from_json(tls_cfg.to_json()) == tls_cfg
    assert json.loads(open_cfg.to_json())["token_file"] is None


def test_main_reads_either_kind_of_worker_json(tmp_path: Path) -> None:
    ngsi = tmp_path / "ngsi.json"
    ngsi.write_text(config(tmp_path).to_json())
    assert isinstance(load(str(ngsi)), NgsiWorkerConfig)
    from engine.bridge_worker.config import Direction, Route
    kafka = tmp_path / "kafka.json"
    kafka.write_text(WorkerConfig("b", "127.0.0.1", 1883, "127.0.0.1:9092",
                                  (Route("t", "t", Direction.MQTT_TO_KAFKA),), tmp_path).to_json())
    assert isinstance(load(str(kafka)), WorkerConfig)


BAD_CONFIGS = [
    ({"ngsi_url": "https://127.0.0.5:1026"}, "ngsi_ca_file"),  # https without the CA to verify it
    ({"ngsi_url": "ftp://127.0.0.5:1026"}, "ngsi_url"),
    ({"ngsi_ca_file": "/ca.pem"}, "ngsi_ca_file"),  # a CA for a plain http:// broker
    ({"ngsi_url": "http://orion:1026"}, "ngsi_url"),
    ({"ngsi_url": "http://127.0.0.5"}, "ngsi_url"),
    ({"ngsi_url": "http://127.0.0.5:1026/v2"}, "ngsi_url"),
    ({"mqtt_port": 0}, "mqtt_port"),
    ({"token_file": "relative/token"}, "token_file"),
    ({"routes": [{"mqtt_topic": "a/#", "entity_id": "e", "entity_type": "T",
                  "direction": "mqtt-to-ngsi"}]}, "mqtt_topic"),
    ({"routes": [{"mqtt_topic": "a", "entity_id": "has space", "entity_type": "T",
                  "direction": "mqtt-to-ngsi"}]}, "entity_id"),
    ({"routes": [{"mqtt_topic": "a", "entity_id": "e", "entity_type": "T/x",
                  "direction": "mqtt-to-ngsi"}]}, "entity_type"),
    ({"routes": [{"mqtt_topic": "a", "entity_id": "e", "entity_type": "T",
                  "direction": "sideways"}]}, "direction"),
    ({"routes": [{"mqtt_topic": "a", "entity_id": "e", "entity_type": "T",
                  "direction": "mqtt-to-ngsi", "qos": 2}]}, "qos"),
    ({"routes": [{"mqtt_topic": "a", "entity_id": "e", "entity_type": "T", "direction": "mqtt-to-ngsi"},
                 {"mqtt_topic": "a", "entity_id": "f", "entity_type": "T", "direction": "mqtt-to-ngsi"}]},
     "routes"),
    ({"check_every": 0}, "check_every"),
    ({"stats_interval": True}, "stats_interval"),
    ({"surprise": 1}, "surprise"),
]


@pytest.mark.parametrize(("change", "field"), BAD_CONFIGS, ids=[f for _, f in BAD_CONFIGS])
def test_bad_worker_json_is_refused_naming_the_field(tmp_path: Path, change: dict, field: str) -> None:
    data = json.loads(config(tmp_path).to_json())
    data.update(change)
    with pytest.raises(ConfigValueError) as exc:
        NgsiWorkerConfig.from_json(json.dumps(data))
    assert exc.value.field == field


# --- subscriptions ----------------------------------------------------------------------------

def test_subscription_body_is_orions_mqtt_notification_in_key_values(tmp_path: Path) -> None:
    cfg = config(tmp_path)
    route = cfg.routes_of(NgsiDirection.NGSI_TO_MQTT)[0]
    assert subscription_body(cfg, route) == {
        "description": "plantkg bridge mqtt--orion cell/agv7",
        "subject": {"entities": [{"id": "urn:agv:7", "type": "AGV"}]},
        "notification": {"mqtt": {"url": "mqtt://127.0.0.2:1883", "topic": "cell/agv7", "qos": 1},
                         "attrsFormat": "keyValues"},
    }


def as_stored(body: dict, sub_id: str, **changes: object) -> dict:
    """A subscription as a context broker lists it: with an id, status and counters."""
    stored = json.loads(json.dumps(body))
    stored.update({"id": sub_id, "status": "active"})
    stored["notification"].update({"timesSent": 12, "attrs": [], "onlyChangedAttrs": False})
    stored.update(changes)
    return stored


def test_reconcile_creates_what_is_missing_and_keeps_what_is_right(tmp_path: Path) -> None:
    cfg = config(tmp_path)
    body = subscription_body(cfg, cfg.routes_of(NgsiDirection.NGSI_TO_MQTT)[0])
    first = reconcile(cfg, [])
    assert (first.delete, first.create, first.kept) == ((), (body,), 0)
    again = reconcile(cfg, [as_stored(body, "s1")])
    assert (again.delete, again.create, again.kept) == ((), (), 1)


def test_reconcile_replaces_a_changed_one_and_drops_stale_and_duplicates(tmp_path: Path) -> None:
    cfg = config(tmp_path)
    body = subscription_body(cfg, cfg.routes_of(NgsiDirection.NGSI_TO_MQTT)[0])
    moved = json.loads(json.dumps(body))
    moved["notification"]["mqtt"]["url"] = "mqtt://127.0.0.9:1883"
    stale = {**json.loads(json.dumps(body)), "description": description("mqtt--orion", "old/topic")}
    foreign = {**json.loads(json.dumps(body)), "description": "someone else's"}
    other_bridge = {**json.loads(json.dumps(body)), "description": description("mqtt--orion2", "cell/agv7")}
    plan = reconcile(cfg, [as_stored(moved, "moved"), as_stored(stale, "stale"), as_stored(body, "ok"),
                           as_stored(body, "dup"), as_stored(foreign, "foreign"),
                           as_stored(other_bridge, "other")])
    assert set(plan.delete) == {"moved", "stale", "dup"}
    assert plan.create == () and plan.kept == 1


def test_reconcile_replaces_an_inactive_one_and_remove_all_deletes_only_ours(tmp_path: Path) -> None:
    cfg = config(tmp_path)
    body = subscription_body(cfg, cfg.routes_of(NgsiDirection.NGSI_TO_MQTT)[0])
    inactive = reconcile(cfg, [as_stored(body, "s1", status="inactive")])
    assert inactive.delete == ("s1",) and inactive.create == (body,)
    foreign = {**json.loads(json.dumps(body)), "description": "someone else's"}
    gone = reconcile(cfg, [as_stored(body, "s1"), as_stored(foreign, "f")], remove_all=True)
    assert (gone.delete, gone.create) == (("s1",), ())


def test_a_one_way_bridge_wants_no_subscription(tmp_path: Path) -> None:
    cfg = config(tmp_path, NgsiRoute("t", "e", "T", NgsiDirection.MQTT_TO_NGSI))
    assert reconcile(cfg, []).create == ()


def test_at_a_closed_tls_broker_the_context_broker_publishes_over_mqtts_as_the_notify_principal(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PLANTKG_PRINCIPAL_KEY", str(tmp_path / "principal-key"))
    cfg = config(tmp_path, mqtt_username="plantkg.bridge.mqtt.orion", mqtt_ca_file=tmp_path / "ca.pem",
                 notify_username="plantkg.notify.mqtt.orion")
    assert NgsiWorkerConfig.from_json(cfg.to_json()) == cfg
    mqtt = subscription_body(cfg, cfg.routes_of(NgsiDirection.NGSI_TO_MQTT)[0])["notification"]["mqtt"]
    assert mqtt["url"] == "mqtts://127.0.0.2:1883" and mqtt["user"] == "plantkg.notify.mqtt.orion"
    assert mqtt["passwd"] and mqtt["passwd"] != "plantkg.notify.mqtt.orion"
    with pytest.raises(ConfigValueError, match="notify_username"):
        config(tmp_path, notify_username="robot1")

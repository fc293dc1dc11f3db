"""Parsing and validating subscription JSON: good documents become the right dataclasses, bad ones
are refused with 400 and a description that starts with the offending field."""

from __future__ import annotations

from typing import Any

import pytest

from engine.context_broker.contract import NgsiError, Tenant
from engine.context_broker.q import parse_q
from engine.context_broker.subscriptions.model import (
    Alteration, AttrsFormat, DeliveryStatus, HttpTarget, KafkaTarget, MqttTarget, Status, render,
)
from engine.context_broker.subscriptions.parse import merge_patch, parse_subscription

from .sub_helpers import doc

HTTP = {"http": {"url": "http://127.0.0.1:1028/accumulate"}}


def parse(d: Any):
    return parse_subscription(d, sub_id="0" * 24, tenant=Tenant("acme", "/plant"), parse_q=parse_q)


# (name, document, check on the parsed subscription)
GOOD: list[tuple[str, dict[str, Any], Any]] = [
    ("minimal http", doc(), lambda s: isinstance(s.notification.target, HttpTarget)
     and s.status is Status.ACTIVE and s.throttling == 0 and s.expires is None),
    ("idPattern and typePattern", doc(subject={"entities": [{"idPattern": "^AGV-[0-9]+$", "typePattern": "A.*"}]}),
     lambda s: s.entities[0].id_pattern == "^AGV-[0-9]+$" and s.entities[0].type_pattern == "A.*"),
    ("no type means any type", doc(subject={"entities": [{"id": "Room1"}]}),
     lambda s: s.entities[0].type is None),
    ("condition attrs and q", doc(subject={"entities": [{"id": "R"}], "condition": {
        "attrs": ["temperature"], "expression": {"q": "temperature>40"}}}),
     lambda s: s.condition.attrs == ("temperature",) and s.condition.q == "temperature>40"),
    ("q and mq", doc(subject={"entities": [{"id": "R"}], "condition": {"expression": {"q": "a", "mq": "a.unit=='C'"}}}),
     lambda s: (s.condition.q, s.condition.mq) == ("a", "a.unit=='C'")),
    ("empty condition attrs = any", doc(subject={"entities": [{"id": "R"}], "condition": {"attrs": []}}),
     lambda s: s.condition.attrs == ()),
    ("alteration types", doc(subject={"entities": [{"id": "R"}], "condition": {
        "alterationTypes": ["entityDelete", "entityCreate"]}}),
     lambda s: s.condition.alterations == {Alteration.DELETE, Alteration.CREATE}),
    ("httpCustom headers qs method", doc(notification={"httpCustom": {
        "url": "http://h:1/n", "headers": {"X-A": "1"}, "qs": {"k": "v"}, "method": "PUT"}}),
     lambda s: s.notification.target == HttpTarget("http://h:1/n", True, (("X-A", "1"),), (("k", "v"),), "PUT")),
    ("mqtt defaults", doc(notification={"mqtt": {"url": "mqtt://127.0.0.1:1883", "topic": "plant/agv"}}),
     lambda s: s.notification.target == MqttTarget("mqtt://127.0.0.1:1883", "127.0.0.1", 1883, "plant/agv")),
    ("mqtt port defaults to 1883", doc(notification={"mqtt": {"url": "mqtt://broker", "topic": "t"}}),
     lambda s: s.notification.target.port == 1883),
    ("mqtts is MQTT over TLS, port 8883 by default", doc(notification={"mqtt": {"url": "mqtts://broker", "topic": "t"}}),
     lambda s: (s.notification.target.port, s.notification.target.tls) == (8883, True)),
    ("mqtt is plain", doc(notification={"mqtt": {"url": "mqtt://broker:1884", "topic": "t"}}),
     lambda s: s.notification.target.tls is False),
    ("mqtt qos retain user", doc(notification={"mqtt": {"url": "mqtt://h:1884", "topic": "t", "qos": 2,
                                                        "retain": True, "user": "u", "passwd": "p w"}}),
     lambda s: (s.notification.target.qos, s.notification.target.retain, s.notification.target.user) == (2, True, "u")),
    ("kafka", doc(notification={"kafka": {"url": "kafka://h1:9092,h2:9093", "topic": "agv.state"}}),
     lambda s: s.notification.target == KafkaTarget("kafka://h1:9092,h2:9093", "h1:9092,h2:9093", "agv.state")),
    ("attrs format keyValues and attrs", doc(notification={**HTTP, "attrs": ["a", "b"], "attrsFormat": "keyValues"}),
     lambda s: s.notification.attrs == ("a", "b") and s.notification.attrs_format is AttrsFormat.KEY_VALUES),
    ("exceptAttrs, onlyChangedAttrs", doc(notification={**HTTP, "exceptAttrs": ["x"], "onlyChangedAttrs": True}),
     lambda s: s.notification.except_attrs == ("x",) and s.notification.only_changed_attrs),
    ("covered with attrs", doc(notification={**HTTP, "attrs": ["a"], "covered": True}),
     lambda s: s.notification.covered),
    ("expires Z", doc(expires="2030-01-01T00:00:00.000Z"), lambda s: s.expires == 1893456000.0),
    ("expires offset", doc(expires="2030-01-01T01:00:00+01:00"), lambda s: s.expires == 1893456000.0),
    ("expires naive is UTC", doc(expires="2030-01-01T00:00:00"), lambda s: s.expires == 1893456000.0),
    ("status oneshot, throttling", doc(status="oneshot", throttling=5),
     lambda s: s.status is Status.ONESHOT and s.throttling == 5),
    ("FiLiP's defaults and echoed read-only fields", doc(status="active", notification={
        **HTTP, "attrsFormat": "normalized", "onlyChangedAttrs": False, "covered": False,
        "timesSent": 3, "lastNotification": "2026-01-01T00:00:00Z"}),
     lambda s: s.notification.attrs_format is AttrsFormat.NORMALIZED),
    ("description and maxFailsLimit", doc(description="AGV state to the MES", notification={**HTTP, "maxFailsLimit": 3}),
     lambda s: s.description == "AGV state to the MES" and s.notification.max_fails_limit == 3),
]


@pytest.mark.parametrize("name,document,check", GOOD, ids=[g[0] for g in GOOD])
def test_good_subscriptions_parse(name: str, document: dict[str, Any], check: Any) -> None:
    assert check(parse(document)), name


# (name, document, the start of the description: the field named)
BAD: list[tuple[str, Any, str]] = [
    ("not an object", [], "subscription: must be a JSON object"),
    ("empty", {}, "empty payload"),
    ("no subject", {"notification": HTTP}, "subject: missing"),
    ("no notification", {"subject": {"entities": [{"id": "a"}]}}, "notification: missing"),
    ("no entities", doc(subject={}), "subject.entities: missing"),
    ("empty entities", doc(subject={"entities": []}), "subject.entities: must not be empty"),
    ("id and idPattern", doc(subject={"entities": [{"id": "a", "idPattern": "a"}]}), "subject.entities[0]: give exactly one"),
    ("neither id nor idPattern", doc(subject={"entities": [{"type": "a"}]}), "subject.entities[0]: give exactly one"),
    ("type and typePattern", doc(subject={"entities": [{"id": "a", "type": "T", "typePattern": "T"}]}), "subject.entities[0]: give at most one"),
    ("bad regex", doc(subject={"entities": [{"idPattern": "a("}]}), "subject.entities[0].idPattern: not a valid regular expression"),
    ("forbidden char in id", doc(subject={"entities": [{"id": "a<b"}]}), "subject.entities[0].id: forbidden character '<' at position 1"),
    ("id not a string", doc(subject={"entities": [{"id": 7}]}), "subject.entities[0].id: must be a string"),
    ("unknown subject field", doc(subject={"entities": [{"id": "a"}], "foo": 1}), "subject.foo: unknown field"),
    ("empty condition", doc(subject={"entities": [{"id": "a"}], "condition": {}}), "subject.condition: must not be empty"),
    ("empty expression", doc(subject={"entities": [{"id": "a"}], "condition": {"expression": {}}}), "subject.condition.expression: must not be empty"),
    ("bad q", doc(subject={"entities": [{"id": "a"}], "condition": {"expression": {"q": "temperature>"}}}),
     "subject.condition.expression.q: q: statement 'temperature>' at character 0: no value after"),
    ("bad mq", doc(subject={"entities": [{"id": "a"}], "condition": {"expression": {"mq": "a.b==1;;"}}}), "subject.condition.expression.mq: mq: empty statement"),
    ("geo not supported", doc(subject={"entities": [{"id": "a"}], "condition": {"expression": {"georel": "near"}}}), "subject.condition.expression.georel: not supported"),
    ("jexl not supported", doc(subject={"entities": [{"id": "a"}], "condition": {"jexlExpression": "a"}}), "subject.condition.jexlExpression: not supported"),
    ("notifyOnMetadataChange false", doc(subject={"entities": [{"id": "a"}], "condition": {"notifyOnMetadataChange": False}}),
     "subject.condition.notifyOnMetadataChange: false is not supported"),
    ("bad alteration", doc(subject={"entities": [{"id": "a"}], "condition": {"alterationTypes": ["entityMoved"]}}), "subject.condition.alterationTypes[0]: unknown alteration type"),
    ("no transport", doc(notification={"attrs": []}), "notification: give exactly one of http"),
    ("two transports", doc(notification={**HTTP, "mqtt": {"url": "mqtt://h", "topic": "t"}}), "notification: give exactly one of http, httpCustom, mqtt, kafka (got http, mqtt)"),
    ("http url not a url", doc(notification={"http": {"url": "localhost:1028"}}), "notification.http.url:"),
    ("query in http url", doc(notification={"http": {"url": "http://h/n?token=1"}}),
     "notification.http.url: forbidden character '=' in the query of 'http://h/n?token=1': give query parameters in notification.httpCustom.qs"),
    ("mqtt url in http", doc(notification={"http": {"url": "mqtt://h:1883"}}), "notification.http.url: mqtt URL cannot be used"),
    ("http without url", doc(notification={"http": {}}), "notification.http.url: missing"),
    ("http timeout too big", doc(notification={"http": {"url": "http://h", "timeout": 1800001}}), "notification.http.timeout: must be an integer from 0 to 1800000"),
    ("httpCustom empty headers", doc(notification={"httpCustom": {"url": "http://h", "headers": {}}}), "notification.httpCustom.headers: must not be empty"),
    ("httpCustom header not string", doc(notification={"httpCustom": {"url": "http://h", "headers": {"X": 1}}}), "notification.httpCustom.headers.X: must be a string"),
    ("httpCustom header newline", doc(notification={"httpCustom": {"url": "http://h", "headers": {"X": "a\r\nB: c"}}}), "notification.httpCustom.headers.X: must not contain a line break"),
    ("httpCustom bad method", doc(notification={"httpCustom": {"url": "http://h", "method": "FETCH"}}), "notification.httpCustom.method: unknown method"),
    ("httpCustom payload", doc(notification={"httpCustom": {"url": "http://h", "payload": "x"}}), "notification.httpCustom.payload: not supported"),
    ("mqttCustom", doc(notification={"mqttCustom": {"url": "mqtt://h", "topic": "t"}}), "notification.mqttCustom: not supported"),
    ("mqtt http url", doc(notification={"mqtt": {"url": "http://h:1883", "topic": "t"}}), "notification.mqtt.url: 'http://h:1883' must start with mqtt://"),
    ("mqtt path", doc(notification={"mqtt": {"url": "mqtt://h:1883/x", "topic": "t"}}), "notification.mqtt.url: path cannot be used"),
    ("mqtt bad port", doc(notification={"mqtt": {"url": "mqtt://h:99999", "topic": "t"}}), "notification.mqtt.url: bad port"),
    ("mqtt no topic", doc(notification={"mqtt": {"url": "mqtt://h"}}), "notification.mqtt.topic: missing"),
    ("mqtt wildcard topic", doc(notification={"mqtt": {"url": "mqtt://h", "topic": "a/+/b"}}), "notification.mqtt.topic: '+' at position 2"),
    ("mqtt qos 3", doc(notification={"mqtt": {"url": "mqtt://h", "topic": "t", "qos": 3}}), "notification.mqtt.qos: must be an integer from 0 to 2, got 3"),
    ("mqtt qos bool", doc(notification={"mqtt": {"url": "mqtt://h", "topic": "t", "qos": True}}), "notification.mqtt.qos: must be an integer"),
    ("mqtt retain string", doc(notification={"mqtt": {"url": "mqtt://h", "topic": "t", "retain": "yes"}}), "notification.mqtt.retain: must be true or false"),
    ("mqtt user without passwd", doc(notification={"mqtt": {"url": "mqtt://h", "topic": "t", "user": "u"}}), "notification.mqtt: user and passwd go together"),
    ("kafka no port", doc(notification={"kafka": {"url": "kafka://h", "topic": "t"}}), "notification.kafka.url: 'h' needs a port"),
    ("kafka bad topic", doc(notification={"kafka": {"url": "kafka://h:9092", "topic": "a/b"}}), "notification.kafka.topic: 'a/b' is not a Kafka topic name"),
    ("kafka sasl", doc(notification={"kafka": {"url": "kafka://h:9092", "topic": "t", "user": "u"}}), "notification.kafka.user: not supported"),
    ("attrs and exceptAttrs", doc(notification={**HTTP, "attrs": ["a"], "exceptAttrs": ["b"]}), "notification: give at most one of attrs and exceptAttrs"),
    ("empty exceptAttrs", doc(notification={**HTTP, "exceptAttrs": []}), "notification.exceptAttrs: must not be empty"),
    ("attrs not a list", doc(notification={**HTTP, "attrs": "a"}), "notification.attrs: must be an array"),
    ("bad attrsFormat", doc(notification={**HTTP, "attrsFormat": "compact"}), "notification.attrsFormat: 'compact' is not one of"),
    ("covered without attrs", doc(notification={**HTTP, "covered": True}), "notification.covered: covered true cannot be used"),
    ("maxFailsLimit 0", doc(notification={**HTTP, "maxFailsLimit": 0}), "notification.maxFailsLimit: must be an integer at least 1"),
    ("unknown notification field", doc(notification={**HTTP, "foo": 1}), "notification.foo: unknown field"),
    ("bad expires", doc(expires="tomorrow"), "expires: 'tomorrow' is not an ISO 8601 date-time"),
    ("expires number", doc(expires=5), "expires: must be an ISO 8601 date-time string"),
    ("status failed", doc(status="failed"), "status: 'failed' is not valid: it has to be either active, inactive or oneshot"),
    ("negative throttling", doc(throttling=-1), "throttling: must be an integer at least 0"),
    ("fractional throttling", doc(throttling=0.5), "throttling: must be an integer"),
    ("long description", doc(description="x" * 1025), "description: at most 1024 characters"),
    ("description with quote", doc(description='say "hi"'), "description: forbidden character '\"' at position 4"),
    ("unknown top field", doc(colour="red"), "colour: unknown field"),
]


@pytest.mark.parametrize("name,document,start", BAD, ids=[b[0] for b in BAD])
def test_bad_subscriptions_are_refused_naming_the_field(name: str, document: Any, start: str) -> None:
    with pytest.raises(NgsiError) as info:
        parse(document)
    assert info.value.status == 400 and info.value.error == "BadRequest"
    assert info.value.description.startswith(start), info.value.description


def test_patch_replaces_top_level_fields_and_is_validated_again() -> None:
    stored = doc(throttling=5, description="old")
    merged = merge_patch(stored, {"description": "new", "notification": {"mqtt": {"url": "mqtt://h", "topic": "t"}}})
    sub = parse(merged)
    assert sub.description == "new" and sub.throttling == 5
    assert isinstance(sub.notification.target, MqttTarget)
    with pytest.raises(NgsiError, match="empty payload"):
        merge_patch(stored, {})
    with pytest.raises(NgsiError, match="status: 'paused'"):
        parse(merge_patch(stored, {"status": "paused"}))


def test_render_round_trips_through_parse() -> None:
    """What GET shows can be posted again and means the same subscription (FiLiP does this)."""
    original = parse(doc(description="d", subject={"entities": [{"idPattern": ".*", "type": "Room"}],
                                                   "condition": {"attrs": ["t"], "expression": {"q": "t==1"}}},
                         notification={"httpCustom": {"url": "http://h:1/n", "headers": {"A": "b"}},
                                       "attrs": ["t"], "attrsFormat": "values"},
                         expires="2031-02-03T04:05:06.000Z", throttling=2))
    shown = render(original, DeliveryStatus(times_sent=2), now=0.0)
    again = parse({k: v for k, v in shown.items() if k != "id"})
    assert again == original
    assert shown["notification"]["timesSent"] == 2 and shown["status"] == "active"


def test_mqtt_password_is_never_shown() -> None:
    sub = parse(doc(notification={"mqtt": {"url": "mqtt://h", "topic": "t", "user": "u", "passwd": "secret"}}))
    shown = render(sub, DeliveryStatus(), now=0.0)
    assert shown["notification"]["mqtt"]["passwd"] == "*****"
    assert "secret" not in repr(shown)

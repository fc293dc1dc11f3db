"""Which changes trigger a subscription (matcher), and what the notification says (render)."""

from __future__ import annotations

import json
from typing import Any

import pytest

from engine.context_broker.contract import NgsiError, Tenant
from engine.context_broker.q import parse_q
from engine.context_broker.subscriptions import matcher, render
from engine.context_broker.subscriptions.model import Subscription
from engine.context_broker.subscriptions.parse import parse_subscription

from .sub_helpers import change, doc, entity, queries

HTTP = {"http": {"url": "http://127.0.0.1:1028/accumulate"}}


def sub(tenant: Tenant = Tenant(), **overrides: Any) -> Subscription:
    return parse_subscription(doc(**overrides), sub_id="a" * 24, tenant=tenant, parse_q=parse_q)


def triggers(s: Subscription, c) -> bool:
    return matcher.triggers(s, c, queries(s))


ROOM = {"entities": [{"id": "Room1", "type": "Room"}]}

# (name, subject, change, expected)
MATCH_CASES: list[tuple[str, dict[str, Any], Any, bool]] = [
    ("id and type", ROOM, change(), True),
    ("other id", {"entities": [{"id": "Room2", "type": "Room"}]}, change(), False),
    ("other type", {"entities": [{"id": "Room1", "type": "Office"}]}, change(), False),
    ("any type", {"entities": [{"id": "Room1"}]}, change(), True),
    ("idPattern found anywhere (regexec)", {"entities": [{"idPattern": "oom"}]}, change(), True),
    ("idPattern anchored miss", {"entities": [{"idPattern": "^oom"}]}, change(), False),
    ("typePattern", {"entities": [{"idPattern": ".*", "typePattern": "^Ro+m$"}]}, change(), True),
    ("second selector matches", {"entities": [{"id": "X"}, {"idPattern": "Room[0-9]"}]}, change(), True),
    ("condition attr changed", {**ROOM, "condition": {"attrs": ["temperature"]}}, change(changed={"temperature"}), True),
    ("condition attr not changed", {**ROOM, "condition": {"attrs": ["pressure"]}}, change(changed={"temperature"}), False),
    ("empty condition attrs: any change", {**ROOM, "condition": {"attrs": []}}, change(changed={"humidity"}), True),
    ("nothing written", ROOM, change(changed=set()), False),
    ("forced update with nothing written", ROOM, change(changed=set(), forced=True), True),
    ("q matches after the change", {**ROOM, "condition": {"expression": {"q": "temperature==23"}}}, change(), True),
    ("q does not match", {**ROOM, "condition": {"expression": {"q": "temperature>40"}}}, change(), False),
    ("q range and a second statement", {**ROOM, "condition": {"expression": {"q": "temperature==20..25;humidity<80"}}}, change(), True),
    ("mq on metadata", {**ROOM, "condition": {"expression": {"mq": "temperature.unit=='C'"}}},
     change(entity(temperature=23) | {"temperature": {"type": "Number", "value": 23, "metadata": {"unit": {"type": "Text", "value": "C"}}}}), True),
    ("mq miss", {**ROOM, "condition": {"expression": {"mq": "temperature.unit=='F'"}}}, change(), False),
    ("attrs and q both needed", {**ROOM, "condition": {"attrs": ["humidity"], "expression": {"q": "temperature==23"}}},
     change(changed={"temperature"}), False),
    ("create fires by default", ROOM, change(created=True), True),
    ("delete does not fire by default", ROOM, change(deleted=True), False),
    ("delete fires when asked", {**ROOM, "condition": {"alterationTypes": ["entityDelete"]}}, change(deleted=True), True),
    ("delete ignores condition attrs", {**ROOM, "condition": {"attrs": ["pressure"], "alterationTypes": ["entityDelete"]}},
     change(deleted=True), True),
    ("only creates wanted, update given", {**ROOM, "condition": {"alterationTypes": ["entityCreate"]}}, change(), False),
    ("entityUpdate fires on update", {**ROOM, "condition": {"alterationTypes": ["entityUpdate"]}}, change(), True),
]


@pytest.mark.parametrize("name,subject,chg,expected", MATCH_CASES, ids=[m[0] for m in MATCH_CASES])
def test_matching(name: str, subject: dict[str, Any], chg: Any, expected: bool) -> None:
    assert triggers(sub(subject=subject), chg) is expected


def test_tenant_must_be_equal() -> None:
    s = sub(tenant=Tenant("acme", "/plant"))
    assert triggers(s, change(tenant=Tenant("acme", "/plant")))
    assert not triggers(s, change(tenant=Tenant("acme", "/other")))
    assert not triggers(s, change(tenant=Tenant("other", "/plant")))
    assert not triggers(s, change(tenant=Tenant()))


def test_liveness_expiry_and_throttling() -> None:
    s = sub(expires="2030-01-01T00:00:00Z", throttling=5)
    assert matcher.is_live(s, 1893455999.0) and not matcher.is_live(s, 1893456000.0)
    assert not matcher.is_live(sub(status="inactive"), 0.0) and matcher.is_live(sub(status="oneshot"), 0.0)
    assert not matcher.throttled(s, None, 100.0)
    assert matcher.throttled(s, 100.0, 104.9) and not matcher.throttled(s, 100.0, 105.0)
    assert not matcher.throttled(sub(), 100.0, 100.0)


ENT = {"id": "Room1", "type": "Room",
       "temperature": {"type": "Number", "value": 23, "metadata": {"unit": {"type": "Text", "value": "C"},
                                                                   "accuracy": {"type": "Number", "value": 0.5}}},
       "humidity": {"type": "percentage", "value": 70, "metadata": {}},
       "pressure": {"type": "Number", "value": 1013, "metadata": {}}}

# (name, notification extras, changed, expected entity in data[0] (or the whole payload for simplified))
RENDER_CASES: list[tuple[str, dict[str, Any], set[str], Any]] = [
    ("normalized, all", {}, {"temperature"}, ENT),
    ("attrs order", {"attrs": ["pressure", "humidity"]}, {"temperature"},
     {"id": "Room1", "type": "Room", "pressure": ENT["pressure"], "humidity": ENT["humidity"]}),
    ("missing attr left out", {"attrs": ["humidity", "brightness"]}, set(),
     {"id": "Room1", "type": "Room", "humidity": ENT["humidity"]}),
    ("covered: missing attr as None", {"attrs": ["humidity", "brightness"], "covered": True}, set(),
     {"id": "Room1", "type": "Room", "humidity": ENT["humidity"],
      "brightness": {"type": "None", "value": None, "metadata": {}}}),
    ("exceptAttrs", {"exceptAttrs": ["temperature"]}, set(),
     {"id": "Room1", "type": "Room", "humidity": ENT["humidity"], "pressure": ENT["pressure"]}),
    ("onlyChangedAttrs", {"onlyChangedAttrs": True}, {"humidity"},
     {"id": "Room1", "type": "Room", "humidity": ENT["humidity"]}),
    ("onlyChangedAttrs with attrs", {"attrs": ["temperature", "pressure"], "onlyChangedAttrs": True}, {"humidity", "pressure"},
     {"id": "Room1", "type": "Room", "pressure": ENT["pressure"]}),
    ("keyValues", {"attrsFormat": "keyValues"}, set(),
     {"id": "Room1", "type": "Room", "temperature": 23, "humidity": 70, "pressure": 1013}),
    ("values in attrs order", {"attrsFormat": "values", "attrs": ["humidity", "temperature"]}, set(), [70, 23]),
    ("metadata filter", {"attrs": ["temperature"], "metadata": ["unit"]}, set(),
     {"id": "Room1", "type": "Room", "temperature": {"type": "Number", "value": 23,
                                                     "metadata": {"unit": {"type": "Text", "value": "C"}}}}),
]


@pytest.mark.parametrize("name,extra,changed,expected", RENDER_CASES, ids=[r[0] for r in RENDER_CASES])
def test_rendering(name: str, extra: dict[str, Any], changed: set[str], expected: Any) -> None:
    s = sub(notification={**HTTP, **extra})
    body = render.payload(s, change(ENT, changed))
    assert body == {"subscriptionId": "a" * 24, "data": [expected]}


def test_simplified_formats_have_no_wrapper() -> None:
    s = sub(notification={**HTTP, "attrs": ["humidity"], "attrsFormat": "simplifiedKeyValues"})
    assert render.payload(s, change(ENT, set())) == {"id": "Room1", "type": "Room", "humidity": 70}
    s = sub(notification={**HTTP, "attrs": ["humidity"], "attrsFormat": "simplifiedNormalized"})
    assert render.payload(s, change(ENT, set())) == {"id": "Room1", "type": "Room", "humidity": ENT["humidity"]}


def test_outgoing_carries_tenant_format_and_entity() -> None:
    s = sub(tenant=Tenant("acme", "/plant"), notification={**HTTP, "attrsFormat": "keyValues"})
    out = render.outgoing(s, change(entity(temperature=1), tenant=Tenant("acme", "/plant")))
    assert (out.service, out.service_path, out.attrs_format, out.entity_id) == ("acme", "/plant", "keyValues", "Room1")
    assert json.loads(out.body) == {"subscriptionId": "a" * 24, "data": [{"id": "Room1", "type": "Room", "temperature": 1}]}
    assert out.correlator != render.outgoing(s, change(entity(temperature=1))).correlator


# (Fiware-ServicePath at creation, None = no header; entity's path; fires)
SCOPES: list[tuple[str | None, str, bool]] = [
    (None, "/", True), (None, "/plant/cell", True),             # no header: /# (every path)
    ("/", "/", True), ("/", "/plant", False),                    # "/" exactly
    ("/#", "/plant/cell", True),
    ("/plant", "/plant", True), ("/plant", "/plant/cell", False),
    ("/plant/#", "/plant", True), ("/plant/#", "/plant/cell", True), ("/plant/#", "/plantx", False),
    ("/plant/#", "/other", False),
    ("/a, /plant/#", "/a", True), ("/a, /plant/#", "/plant/x", True), ("/a, /plant/#", "/b", False),
]


@pytest.mark.parametrize("header,path,fires", SCOPES)
def test_service_path_scope_as_orion(header: str | None, path: str, fires: bool) -> None:
    from engine.context_broker.subscriptions.scope import subscription_tenant

    headers = {"Fiware-Service": "acme"} | ({"Fiware-ServicePath": header} if header is not None else {})
    s = parse_subscription(doc(), sub_id="a" * 24, tenant=subscription_tenant(headers), parse_q=parse_q)
    assert triggers(s, change(tenant=Tenant("acme", path))) is fires
    assert not triggers(s, change(tenant=Tenant("other", path)))


def test_canonical_service_path_queries() -> None:
    from engine.context_broker.subscriptions.scope import subscription_tenant

    assert subscription_tenant({}).service_path == "/#"
    assert subscription_tenant({"Fiware-ServicePath": "/a/#, /b"}).service_path == "/a/#,/b"
    with pytest.raises(NgsiError):
        subscription_tenant({"Fiware-ServicePath": "/a-b"})

"""Any JSON at all, as a subscription: refused with a 400 naming a field, or accepted and then
shown and read back as the same subscription; never another exception (which would be a 500).

Hypothesis (a dependency of the schemathesis test extra) generates whole documents and, more
usefully, valid subscriptions with one field anywhere replaced by arbitrary JSON.
"""

from __future__ import annotations

import copy
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from engine.context_broker.contract import NgsiError, Tenant
from engine.context_broker.q import parse_q
from engine.context_broker.subscriptions.model import DeliveryStatus, render
from engine.context_broker.subscriptions.parse import parse_subscription

JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=12,
)

VALID: dict[str, Any] = {
    "description": "AGV state",
    "subject": {"entities": [{"idPattern": "^AGV", "type": "AGV"}],
                "condition": {"attrs": ["state"], "expression": {"q": "battery<20"},
                              "alterationTypes": ["entityCreate", "entityChange"]}},
    "notification": {"mqtt": {"url": "mqtt://127.0.0.1:1883", "topic": "fleet/agv", "qos": 1},
                     "attrs": ["state", "battery"], "attrsFormat": "keyValues",
                     "onlyChangedAttrs": True, "maxFailsLimit": 3},
    "expires": "2040-01-01T00:00:00.000Z",
    "status": "active",
    "throttling": 2,
}


VALIDS: list[dict[str, Any]] = [
    VALID,
    {"subject": {"entities": [{"id": "AGV1"}, {"idPattern": ".*", "typePattern": "^A"}]},
     "notification": {"httpCustom": {"url": "http://127.0.0.1:1028/n", "headers": {"X-A": "1"},
                                     "qs": {"k": "v"}, "method": "PUT", "timeout": 500},
                      "attrs": ["a", "b"], "covered": True, "metadata": ["unit"]}},
    {"subject": {"entities": [{"id": "AGV1", "type": "AGV"}], "condition": {"expression": {"mq": "a.unit=='C'"}}},
     "notification": {"kafka": {"url": "kafka://127.0.0.1:9092,127.0.0.2:9093", "topic": "agv.state", "key": "k"},
                      "exceptAttrs": ["secret"], "attrsFormat": "values"},
     "status": "oneshot"},
    {"subject": {"entities": [{"id": "R"}]}, "notification": {"http": {"url": "https://example.org/n"}}},
]


def paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for key, value in doc.items():
            out += paths(value, prefix + (key,))
    elif isinstance(doc, list):
        for i, value in enumerate(doc):
            out += paths(value, prefix + (i,))
    return out


ALL_PATHS = [(i, path) for i, doc in enumerate(VALIDS) for path in paths(doc)]


def check(doc: Any) -> None:
    try:
        sub = parse_subscription(doc, sub_id="f" * 24, tenant=Tenant("acme", "/plant"), parse_q=parse_q)
    except NgsiError as err:
        assert err.status == 400 and err.description
        return
    shown = render(sub, DeliveryStatus(), now=0.0)
    again = parse_subscription({k: v for k, v in shown.items() if k not in ("id", "status")}
                               | {"status": sub.status.value},
                               sub_id=sub.id, tenant=sub.tenant, parse_q=parse_q)
    assert again == sub


@settings(max_examples=200, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(JSON)
def test_any_json_document(doc: Any) -> None:
    check(doc)


@settings(max_examples=800, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
@given(st.sampled_from(ALL_PATHS), JSON)
def test_a_valid_subscription_with_one_field_replaced(where: tuple[int, tuple[Any, ...]], value: Any) -> None:
    index, path = where
    doc = copy.deepcopy(VALIDS[index])
    node = doc
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    check(doc)


def test_the_valid_documents_are_valid() -> None:
    subs = [parse_subscription(d, sub_id="f" * 24, tenant=Tenant(), parse_q=parse_q) for d in VALIDS]
    assert subs[0].notification.max_fails_limit == 3 and subs[0].condition.q == "battery<20"
    assert [type(s.notification.target).__name__ for s in subs] == [
        "MqttTarget", "HttpTarget", "KafkaTarget", "HttpTarget"]

"""The context broker's OpenAPI document lists 403 exactly where a closed broker refuses a
principal (engine/context_broker/openapi.py, access.py, subscriptions/ownership.py).

Each operation of the document is sent through the app (a closed broker with subscriptions) by a
known principal, naming an entity it may neither read nor write (a subscription id: one of its
own). Whether the app answered 403 is what the code does; the test checks the document says the
same for every operation, both ways, and that the body answered is the documented one: Orion's
``{"error": "Forbidden", "description": ...}``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine.context_broker.openapi import openapi_document
from tests.unit.context_broker.test_access_subscriptions import ROBOT, Broker, sub

OTHER = "urn:other:1"  # robot1 may neither read nor write it
PARAMS = {"entityId": OTHER, "attrName": "speed", "entityType": "Thing"}
ATTRS = {"speed": {"type": "Number", "value": 1}}
BODIES: dict[tuple[str, str], Any] = {  # (method, path) -> the body of the request; none: no body
    ("post", "/v2/entities"): {"id": OTHER, "type": "Thing", **ATTRS},
    ("post", "/v2/entities/{entityId}/attrs"): ATTRS,
    ("patch", "/v2/entities/{entityId}/attrs"): ATTRS,
    ("put", "/v2/entities/{entityId}/attrs"): ATTRS,
    ("put", "/v2/entities/{entityId}/attrs/{attrName}"): {"type": "Number", "value": 2},
    ("put", "/v2/entities/{entityId}/attrs/{attrName}/value"): 3,
    ("post", "/v2/op/update"): {"actionType": "append", "entities": [{"id": OTHER, "type": "Thing", **ATTRS}]},
    ("post", "/v2/op/query"): {"entities": [{"id": OTHER}]},
    ("post", "/v2/subscriptions"): sub({"id": OTHER}),
    ("patch", "/v2/subscriptions/{subscriptionId}"): {"subject": {"entities": [{"id": OTHER}]}},
}
QUERIES = {("get", "/v2/entities"): f"?id={OTHER}"}  # a list names its ids (else: 403 for another reason)


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    found = Broker(tmp_path)
    try:
        yield found
    finally:
        found.close()


def operations() -> list[tuple[str, str, dict[str, Any]]]:
    doc = openapi_document(with_subscriptions=True)
    return [(method, path, op) for path, ops in doc["paths"].items() for method, op in ops.items()]


def request_path(broker: Broker, path: str) -> str:
    """``path`` with its parameters filled (a subscription: a fresh one of robot1's, on an
    entity it may read)."""
    params = dict(PARAMS)
    if "{subscriptionId}" in path:
        params["subscriptionId"] = broker.create(sub({"id": "urn:task:1"}), ROBOT)
    return re.sub(r"\{(\w+)\}", lambda m: params[m.group(1)], path)


def test_the_table_covers_the_documents_operations() -> None:
    documented = {(m, p) for m, p, _ in operations()}
    assert set(BODIES) <= documented and set(QUERIES) <= documented  # no stale row


@pytest.mark.parametrize(("method", "path"), [(m, p) for m, p, _ in operations()],
                         ids=[f"{m.upper()} {p}" for m, p, _ in operations()])
def test_403_is_documented_where_the_code_refuses_a_principal(broker: Broker, method: str, path: str) -> None:
    operation = next(op for m, p, op in operations() if (m, p) == (method, path))
    reply = broker.send(method.upper(), request_path(broker, path) + QUERIES.get((method, path), ""),
                        BODIES.get((method, path)), ROBOT)
    documented = "403" in operation["responses"]
    assert (reply.status_code == 403) == documented, (reply.status_code, reply.get_data(as_text=True)[:300])
    if documented:
        schema = operation["responses"]["403"]["content"]["application/json"]["schema"]
        error = openapi_document()["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]
        body = reply.json
        assert set(error["required"]) <= set(body) <= set(error["properties"]), body
        assert body["error"] == "Forbidden" and "robot1" in body["description"], body

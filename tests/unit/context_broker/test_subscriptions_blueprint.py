"""``/v2/subscriptions`` over Flask's test client: status codes, headers and bodies as Orion's."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from flask import Flask
from flask.testing import FlaskClient

from engine.context_broker.subscriptions import SubscriptionService

from .sub_helpers import doc

ACME = {"Fiware-Service": "acme", "Fiware-ServicePath": "/plant"}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[FlaskClient]:
    service = SubscriptionService(tmp_path)
    app = Flask("test")
    app.register_blueprint(service.blueprint())
    yield app.test_client()
    service.close()


def create(client: FlaskClient, headers: dict[str, str] | None = None, **overrides: Any) -> str:
    resp = client.post("/v2/subscriptions", json=doc(**overrides), headers=headers or {})
    assert resp.status_code == 201, resp.json
    location = resp.headers["Location"]
    assert location.startswith("/v2/subscriptions/") and resp.data == b""
    sub_id = location.rsplit("/", 1)[1]
    assert len(sub_id) == 24 and int(sub_id, 16) >= 0
    return sub_id


def test_create_get_patch_delete(client: FlaskClient) -> None:
    sub_id = create(client, ACME, description="AGV state")
    got = client.get(f"/v2/subscriptions/{sub_id}", headers=ACME)
    assert got.status_code == 200 and got.mimetype == "application/json"
    assert got.json["id"] == sub_id and got.json["description"] == "AGV state"
    assert got.json["notification"]["http"] == {"url": "http://127.0.0.1:1028/accumulate"}
    assert got.json["status"] == "active"
    patched = client.patch(f"/v2/subscriptions/{sub_id}", json={"throttling": 3}, headers=ACME)
    assert patched.status_code == 204
    assert client.get(f"/v2/subscriptions/{sub_id}", headers=ACME).json["throttling"] == 3
    assert client.delete(f"/v2/subscriptions/{sub_id}", headers=ACME).status_code == 204
    gone = client.get(f"/v2/subscriptions/{sub_id}", headers=ACME)
    assert gone.status_code == 404
    assert gone.json == {"error": "NotFound",
                         "description": "The requested subscription has not been found. Check id"}


def test_list_paging_count_and_trailing_slash(client: FlaskClient) -> None:
    ids = [create(client, ACME, description=f"s{i}") for i in range(5)]
    page = client.get("/v2/subscriptions?limit=2&offset=1&options=count", headers=ACME)
    assert page.status_code == 200 and page.headers["Fiware-Total-Count"] == "5"
    assert [s["id"] for s in page.json] == ids[1:3]
    filip = client.get("/v2/subscriptions/?options=count&limit=1000", headers=ACME)
    assert [s["id"] for s in filip.json] == ids and filip.headers["Fiware-Total-Count"] == "5"
    assert "Fiware-Total-Count" not in client.get("/v2/subscriptions", headers=ACME).headers


def test_tenancy(client: FlaskClient) -> None:
    acme = create(client, ACME)
    other = create(client, {"Fiware-Service": "other"})
    assert [s["id"] for s in client.get("/v2/subscriptions", headers=ACME).json] == [acme]
    assert client.get("/v2/subscriptions", headers={"Fiware-Service": "acme",
                                                    "Fiware-ServicePath": "/elsewhere"}).json == []
    # no service path header: all of the service's subscriptions
    assert [s["id"] for s in client.get("/v2/subscriptions", headers={"Fiware-Service": "acme"}).json] == [acme]
    assert client.get(f"/v2/subscriptions/{other}", headers=ACME).status_code == 404
    assert client.delete(f"/v2/subscriptions/{other}", headers=ACME).status_code == 404
    assert client.get(f"/v2/subscriptions/{other}", headers={"Fiware-Service": "other"}).status_code == 200


# (name, method, path, kwargs, status, error, description start)
ERRORS: list[tuple[str, str, str, dict[str, Any], int, str, str]] = [
    ("malformed id", "get", "/v2/subscriptions/123", {}, 400, "BadRequest", "Invalid subscription ID"),
    ("unknown id", "get", "/v2/subscriptions/" + "0" * 24, {}, 404, "NotFound", "The requested subscription"),
    ("patch unknown id", "patch", "/v2/subscriptions/" + "0" * 24, {"json": {"throttling": 1}}, 404, "NotFound", ""),
    ("invalid subscription", "post", "/v2/subscriptions", {"json": doc(throttling="soon")}, 400, "BadRequest", "throttling:"),
    ("not json", "post", "/v2/subscriptions", {"data": "{", "content_type": "application/json"}, 400, "ParseError", "Errors found"),
    ("wrong content type", "post", "/v2/subscriptions", {"data": "x", "content_type": "text/plain"}, 415,
     "UnsupportedMediaType", "not supported content type: text/plain"),
    ("empty body", "post", "/v2/subscriptions", {"data": "", "content_type": "application/json"}, 400, "BadRequest", "empty payload"),
    ("bad limit", "get", "/v2/subscriptions?limit=0", {}, 400, "BadRequest", "Bad pagination limit"),
    ("limit over 1000", "get", "/v2/subscriptions?limit=1001", {}, 400, "BadRequest", "Bad pagination limit"),
    ("bad offset", "get", "/v2/subscriptions?offset=-1", {}, 400, "BadRequest", "Bad pagination offset"),
    ("bad option", "get", "/v2/subscriptions?options=keyValues", {}, 400, "BadRequest", "Invalid value for URI param /options/"),
    ("bad service header", "get", "/v2/subscriptions", {"headers": {"Fiware-Service": "a-b"}}, 400, "BadRequest",
     "bad character for Fiware-Service"),
]


@pytest.mark.parametrize("name,method,path,kwargs,status,error,start", ERRORS, ids=[e[0] for e in ERRORS])
def test_errors(client: FlaskClient, name: str, method: str, path: str, kwargs: dict[str, Any],
                status: int, error: str, start: str) -> None:
    resp = getattr(client, method)(path, **kwargs)
    assert resp.status_code == status, resp.data
    assert resp.json["error"] == error and resp.json["description"].startswith(start), resp.json


def test_invalid_patch_changes_nothing(client: FlaskClient) -> None:
    sub_id = create(client, throttling=2)
    bad = client.patch(f"/v2/subscriptions/{sub_id}", json={"throttling": 5, "status": "paused"})
    assert bad.status_code == 400 and bad.json["description"].startswith("status:")
    assert client.get(f"/v2/subscriptions/{sub_id}").json["throttling"] == 2

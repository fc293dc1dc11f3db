"""A closed context broker (engine.context_broker.access) through Flask's test client over a real
store: anonymous requests refused (reads too) with Orion's error body, each principal writes and
reads exactly its entities (by path, create body, batch and query bodies), plantkg's own token
keeps every right; and the principals file (engine.security.ngsi_principals) holds digests only."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine.context_broker.access import Gate
from engine.context_broker.app import create_app
from engine.context_broker.store import ContextStore
from engine.security.ngsi_principals import PrincipalsFileError, load_principals, render_principals

AGENT = "agent-token-1"
ROBOT, PLANNER = "robot-secret", "planner-secret"
PRINCIPALS = {"robot1": (ROBOT, ("urn:pose:1",), ()),
              "planner": (PLANNER, ("urn:task:1",), ("urn:pose:1",))}


def entity(eid: str, value: int = 1) -> dict[str, Any]:
    return {"id": eid, "type": "T", "v": {"type": "Number", "value": value}}


@pytest.fixture
def client(tmp_path: Path) -> Iterator[Any]:
    file = tmp_path / "principals.json"
    file.write_text(render_principals(PRINCIPALS), encoding="utf-8")
    store = ContextStore(tmp_path / "data")
    app = create_app(store, token=AGENT, gate=Gate(AGENT, load_principals(file)))
    yield app.test_client()
    store.close()


def send(client: Any, method: str, path: str, body: Any = None, token: str | None = None,
         header: str = "Authorization") -> Any:
    headers = {}
    if token is not None:
        headers[header] = f"Bearer {token}" if header == "Authorization" else token
    if body is not None:
        headers["Content-Type"] = "application/json"
    return client.open(path, method=method, data=None if body is None else json.dumps(body), headers=headers)


def refusal(reply: Any) -> tuple[int, str]:
    assert reply.mimetype == "application/json", reply.data
    assert set(reply.json) == {"error", "description"}, reply.json
    return reply.status_code, reply.json["error"]


def test_the_file_holds_digests_not_tokens(tmp_path: Path) -> None:
    text = render_principals(PRINCIPALS)
    assert ROBOT not in text and PLANNER not in text
    file = tmp_path / "p.json"
    file.write_text(text, encoding="utf-8")
    got = {p.name: p for p in load_principals(file)}
    assert got["planner"].read == frozenset({"urn:pose:1"}) and got["robot1"].write == frozenset({"urn:pose:1"})


@pytest.mark.parametrize("text", ["not json", "[]", '{"principals": [{"name": "x"}]}',
                                  '{"principals": [{"name": "x", "sha256": "ab", "write": [], "read": []}]}'])
def test_a_bad_principals_file_is_refused_naming_it(tmp_path: Path, text: str) -> None:
    file = tmp_path / "p.json"
    file.write_text(text, encoding="utf-8")
    with pytest.raises(PrincipalsFileError, match=str(file)):
        load_principals(file)


@pytest.mark.parametrize(("method", "path", "body"), [
    ("GET", "/v2/entities", None), ("GET", "/v2/entities/urn:pose:1", None), ("GET", "/v2/types", None),
    ("POST", "/v2/entities", entity("urn:pose:1")), ("POST", "/v2/op/query", {"entities": [{"id": "urn:pose:1"}]}),
    ("GET", "/v2/subscriptions", None), ("GET", "/plantkg/v1/graph", None)])
def test_anonymous_and_unknown_tokens_are_refused_401(client: Any, method: str, path: str, body: Any) -> None:
    assert refusal(send(client, method, path, body)) == (401, "Unauthorized")
    assert refusal(send(client, method, path, body, token="guess")) == (401, "Unauthorized")


def test_version_stays_public(client: Any) -> None:
    assert send(client, "GET", "/version").status_code == 200


def test_each_principal_writes_exactly_its_entities(client: Any) -> None:
    assert send(client, "POST", "/v2/entities", entity("urn:pose:1"), ROBOT).status_code == 201
    assert refusal(send(client, "POST", "/v2/entities", entity("urn:task:1"), ROBOT)) == (403, "Forbidden")
    assert send(client, "POST", "/v2/entities", entity("urn:task:1"), PLANNER).status_code == 201
    assert refusal(send(client, "POST", "/v2/entities", entity("urn:pose:2"), PLANNER)) == (403, "Forbidden")
    assert send(client, "PATCH", "/v2/entities/urn:pose:1/attrs", {"v": {"value": 2}}, ROBOT).status_code == 204
    assert refusal(send(client, "PATCH", "/v2/entities/urn:pose:1/attrs", {"v": {"value": 3}}, PLANNER))[0] == 403
    assert refusal(send(client, "DELETE", "/v2/entities/urn:task:1", None, ROBOT))[0] == 403
    batch = {"actionType": "append", "entities": [entity("urn:pose:1", 5), entity("urn:task:1", 5)]}
    assert refusal(send(client, "POST", "/v2/op/update", batch, ROBOT))[0] == 403  # one not its own
    batch["entities"] = [entity("urn:pose:1", 6)]
    assert send(client, "POST", "/v2/op/update", batch, ROBOT).status_code == 204
    # nothing refused was written
    got = send(client, "GET", "/v2/entities?options=keyValues", None, AGENT).json
    assert sorted((e["id"], e["v"]) for e in got) == [("urn:pose:1", 6), ("urn:task:1", 1)]


def test_each_principal_reads_exactly_its_entities(client: Any) -> None:
    for eid in ("urn:pose:1", "urn:task:1", "urn:other:1"):
        assert send(client, "POST", "/v2/entities", entity(eid), AGENT).status_code == 201
    assert send(client, "GET", "/v2/entities/urn:pose:1", None, PLANNER).status_code == 200
    assert send(client, "GET", "/v2/entities/urn:task:1/attrs/v/value", None, PLANNER).status_code == 200
    assert refusal(send(client, "GET", "/v2/entities/urn:other:1", None, PLANNER))[0] == 403
    assert refusal(send(client, "GET", "/v2/entities", None, PLANNER))[0] == 403  # not by id
    listed = send(client, "GET", "/v2/entities?id=urn:pose:1,urn:task:1", None, PLANNER)
    assert listed.status_code == 200 and len(listed.json) == 2
    assert refusal(send(client, "GET", "/v2/entities?id=urn:pose:1,urn:other:1", None, PLANNER))[0] == 403
    query = {"entities": [{"id": "urn:pose:1"}]}
    assert send(client, "POST", "/v2/op/query", query, PLANNER).status_code == 200
    assert refusal(send(client, "POST", "/v2/op/query", {"entities": [{"idPattern": ".*"}]}, PLANNER))[0] == 403
    assert refusal(send(client, "GET", "/v2/types", None, PLANNER))[0] == 403


def test_the_wilma_header_is_taken_and_the_agent_token_keeps_every_right(client: Any) -> None:
    assert send(client, "POST", "/v2/entities", entity("urn:pose:1"), ROBOT, header="X-Auth-Token").status_code == 201
    assert refusal(send(client, "GET", "/v2/types", None, "nope", header="X-Auth-Token"))[0] == 401
    for method, path, body in [("POST", "/v2/entities", entity("urn:x:1")), ("GET", "/v2/types", None),
                               ("GET", "/plantkg/v1/graph", None), ("DELETE", "/v2/entities/urn:pose:1", None)]:
        assert send(client, method, path, body, AGENT).status_code < 300, (method, path)

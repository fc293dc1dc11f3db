"""The fast path (engine/context_broker/fastpath.py) answers exactly as Flask does: each case is
sent to an app with it and to one without it (same seed entities, same clock), and the status,
headers, body, the entities afterwards and the change events must be equal. The cases are
the hot writes, good and bad, and near-misses that must fall through to Flask."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from werkzeug.test import EnvironBuilder, run_wsgi_app

from engine.context_broker.app import create_app
from engine.context_broker.contract import EntityChange
from engine.context_broker.store import ContextStore

TOKEN = "tok"
GOOD = f"Bearer {TOKEN}"
SEED = [{"id": "R1", "type": "Room", "t": {"value": 21.5}, "s": {"value": "on", "metadata": {"u": {"value": "C"}}}},
        {"id": "R1", "type": "Hall", "t": {"value": 1}},
        {"id": "urn:ngsi-ld:AGV:1", "type": "AGV", "state": {"value": "idle"}}]
J = "application/json"

# (method, path, query, content type, authorization, body)
CASES: list[tuple[str, str, str, str | None, str | None, bytes]] = [
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"state": {"value": "moving"}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"nope": {"value": 1}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"state": {"value": 1}, "x": {"value": 2}}'),
    ("PATCH", "/v2/entities/R1/attrs", "", J, GOOD, b'{"t": {"value": 3}}'),  # 409: two types
    ("PATCH", "/v2/entities/R1/attrs", "type=Room", J, GOOD, b'{"t": {"value": 3}}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=Room&options=keyValues", J, GOOD, b'{"t": 4}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=Room&options=overrideMetadata", J, GOOD, b'{"s": {"value": "off"}}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=Room&options=bogus", J, GOOD, b'{"t": 4}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=Ro<om", J, GOOD, b'{"t": 4}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=", J, GOOD, b'{"t": 4}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=Room&type=Hall", J, GOOD, b'{"t": 4}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=R%6Fom", J, GOOD, b'{"t": 5}'),
    ("PATCH", "/v2/entities/R1/attrs", "type=Room&q=x", J, GOOD, b'{"t": 5}'),
    ("PATCH", "/v2/entities/Missing/attrs", "", J, GOOD, b'{"t": {"value": 3}}'),
    ("PATCH", "/v2/entities/Bad<id/attrs", "", J, GOOD, b'{"t": {"value": 3}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"state": '),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b''),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'[1, 2]'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"state": {"value": NaN}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"st<ate": {"value": 1}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"state": {"value": "a<b"}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", "text/plain", GOOD, b'{"state": {"value": 1}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", "application/json; charset=utf-8", GOOD,
     b'{"state": {"value": 7}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, None, b'{"state": {"value": 1}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, "Bearer wrong", b'{"state": {"value": 1}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, f"bearer  {TOKEN} ", b'{"state": {"value": 8}}'),
    ("PATCH", "/v2/entities/urn:ngsi-ld:AGV:1/attrs/", "", J, GOOD, b'{"state": {"value": 9}}'),
    ("POST", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"battery": {"value": 90}}'),
    ("POST", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "options=append", J, GOOD, b'{"battery": {"value": 80}}'),
    ("POST", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "options=append", J, GOOD, b'{"speed": {"value": 1.5}}'),
    ("PUT", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "", J, GOOD, b'{"only": {"value": true}}'),
    ("PUT", "/v2/entities/urn:ngsi-ld:AGV:1/attrs", "options=upsert", J, GOOD, b'{"only": {"value": true}}'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room", J, GOOD, b'{"a": [1, 2]}'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room", "text/plain", GOOD, b'"text"'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room", "text/plain", GOOD, b'42.5'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room", "text/plain", GOOD, b'not json'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room&options=forcedUpdate", J, GOOD, b'7'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room&options=keyValues", J, GOOD, b'7'),
    ("PUT", "/v2/entities/R1/attrs/missing/value", "type=Room", J, GOOD, b'7'),
    ("PUT", "/v2/entities/R1/attrs/id/value", "type=Room", J, GOOD, b'7'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "", J, GOOD, b'7'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room", "application/xml", GOOD, b'<a/>'),
    ("PATCH", "/v2/entities/R1/attrs/t/value", "type=Room", J, GOOD, b'7'),
    ("PUT", "/v2/entities/R1/attrs/t/value", "type=Room", J, None, b'7'),
    ("POST", "/v2/entities", "", J, GOOD, b'{"id": "New", "type": "AGV", "s": {"value": 1}}'),
    ("POST", "/v2/entities", "", J, GOOD, b'{"id": "New", "s": {"value": 1}}'),
    ("POST", "/v2/entities", "", J, GOOD, b'{"id": "R1", "type": "Room", "t": {"value": 1}}'),
    ("POST", "/v2/entities", "options=upsert", J, GOOD, b'{"id": "R1", "type": "Room", "t": {"value": 2}}'),
    ("POST", "/v2/entities", "options=upsert", J, GOOD, b'{"id": "New2", "type": "Room", "t": {"value": 2}}'),
    ("POST", "/v2/entities", "options=upsert,keyValues", J, GOOD, b'{"id": "R1", "type": "Room", "t": 3, "z": "a"}'),
    ("POST", "/v2/entities", "options=upsert&options=keyValues", J, GOOD, b'{"id": "R1", "type": "Room", "t": 3}'),
    ("POST", "/v2/entities", "options=upsert,overrideMetadata", J, GOOD, b'{"id": "R1", "type": "Room", "s": {"value": 1}}'),
    ("POST", "/v2/entities", "options=upsert,append", J, GOOD, b'{"id": "R1", "type": "Room"}'),
    ("POST", "/v2/entities", "type=Room", J, GOOD, b'{"id": "N3", "type": "Room"}'),
    ("POST", "/v2/entities", "", J, GOOD, b'{"type": "Room"}'),
    ("POST", "/v2/entities", "", J, GOOD, b'{"id": "Bad id", "type": "Room"}'),
    ("POST", "/v2/entities", "", J, GOOD, b'{"id": "N4", "type": "Room", "t": {"type": "DateTime", "value": "no"}}'),
    ("POST", "/v2/entities", "", "text/plain", GOOD, b'{"id": "N5"}'),
    ("POST", "/v2/entities", "", J, None, b'{"id": "N6"}'),
    ("POST", "/v2/entities/", "options=upsert", J, GOOD, b'{"id": "R1", "type": "Room", "t": {"value": 9}}'),
]


def _app(tmp_path: Path, name: str, fast: bool) -> tuple[Any, list[EntityChange], ContextStore]:
    store = ContextStore(tmp_path / name)
    changes: list[EntityChange] = []

    class Listener:
        def entity_changed(self, change: EntityChange) -> None:
            changes.append(change)

    app = create_app(store, token=TOKEN, listeners=[Listener()], clock=lambda: 1_700_000_000.0, fast=fast)
    for entity in SEED:
        assert _send(app, "POST", "/v2/entities", "", J, GOOD, json.dumps(entity).encode())[0] == 201
    return app, changes, store


def _send(app: Any, method: str, path: str, query: str, ctype: str | None, auth: str | None,
          body: bytes) -> tuple[int, list[tuple[str, str]], Any]:
    headers = {"Authorization": auth} if auth else {}
    builder = EnvironBuilder(method=method, path=path, query_string=query, headers=headers, data=body,
                             content_type=ctype)
    app_iter, status, response_headers = run_wsgi_app(app, builder.get_environ())
    data = b"".join(app_iter)
    ctype_out = dict(response_headers).get("Content-Type", "")
    return (int(status.split()[0]), sorted(response_headers.items()),
            json.loads(data) if ctype_out == J and data else data)


def _entities(app: Any) -> Any:
    return [_send(app, "GET", "/v2/entities", f"limit=100&orderBy=id,type{h}", None, None, b"")[2]
            for h in ("", "&attrs=*,dateModified,dateCreated")]


@pytest.mark.parametrize("case", CASES, ids=[f"{c[0]} {c[1]}?{c[2]} {c[3]} {c[5][:20]!r}" for c in CASES])
def test_fast_path_answers_as_flask(tmp_path: Path, case: tuple[Any, ...]) -> None:
    fast, fast_changes, s1 = _app(tmp_path, "fast", True)
    slow, slow_changes, s2 = _app(tmp_path, "slow", False)
    try:
        assert _send(fast, *case) == _send(slow, *case)
        assert _entities(fast) == _entities(slow)
        assert fast_changes == slow_changes
    finally:
        s1.close()
        s2.close()


def test_fast_path_serves_the_hot_writes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A plain PATCH never reaches Flask's dispatch; a near-miss does."""
    from flask import Flask
    app, _, store = _app(tmp_path, "d", True)
    seen: list[str] = []
    original = Flask.dispatch_request
    monkeypatch.setattr(Flask, "dispatch_request", lambda self: seen.append("flask") or original(self))
    try:
        assert _send(app, *CASES[0])[0] == 204 and seen == []
        assert _send(app, "PATCH", CASES[0][1], "", "application/json; charset=utf-8", GOOD,
                     b'{"state": {"value": 2}}')[0] == 204 and seen == ["flask"]
    finally:
        store.close()

"""The context broker app through Flask's test client, over a real (temporary) store: every route,
every status code Orion uses, Orion's error bodies, tenancy, the token, listeners, the
subscriptions blueprint's errors, and a store reopened after writes."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from flask import Blueprint
from werkzeug.test import EnvironBuilder, run_wsgi_app

from engine.context_broker.app import MAX_BODY, create_app
from engine.context_broker.contract import EntityChange, NgsiError
from engine.context_broker.store import ContextStore, StoreLocked

TOKEN = "s3cret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
ROOM = {"id": "Room1", "type": "Room", "temperature": {"value": 21.5},
        "pressure": {"value": 720, "type": "Number", "metadata": {"unit": {"value": "hPa"}}}}


class Recorder:
    def __init__(self) -> None:
        self.changes: list[EntityChange] = []

    def entity_changed(self, change: EntityChange) -> None:
        self.changes.append(change)


def _subs_blueprint() -> Blueprint:
    bp = Blueprint("fake_subscriptions", __name__)

    @bp.get("/v2/subscriptions")
    def listing() -> Any:
        raise NgsiError(400, "BadRequest", "raised inside the blueprint")

    @bp.post("/v2/subscriptions")
    def create() -> Any:
        return "", 201

    return bp


@pytest.fixture
def store(tmp_path: Path) -> Iterator[ContextStore]:
    s = ContextStore(tmp_path / "data")
    yield s
    s.close()


@pytest.fixture
def recorder() -> Recorder:
    return Recorder()


@pytest.fixture
def client(store: ContextStore, recorder: Recorder) -> Any:
    app = create_app(store, token=TOKEN, listeners=[recorder], subscriptions_blueprint=_subs_blueprint())
    return app.test_client()


def send(client: Any, method: str, path: str, body: Any = None, *, raw: bytes | None = None,
         ctype: str | None = "application/json", auth: bool = True, headers: dict[str, str] | None = None) -> Any:
    h = {**(AUTH if auth else {}), **(headers or {})}
    if ctype is not None and (body is not None or raw is not None):
        h["Content-Type"] = ctype
    data = raw if raw is not None else (json.dumps(body) if body is not None else None)
    return client.open(path, method=method, data=data, headers=h)


def error_of(reply: Any) -> tuple[int, str]:
    assert reply.mimetype == "application/json", reply.data
    return reply.status_code, reply.json["error"]


@pytest.fixture
def seeded(client: Any) -> Any:
    assert send(client, "POST", "/v2/entities", ROOM).status_code == 201
    return client


# --- success paths ---------------------------------------------------------------------------

def test_version_and_resources(client: Any) -> None:
    version = client.get("/version").json
    assert version["orion"]["version"].startswith("3.") and "plantkg" in version
    assert client.get("/v2").json["entities_url"] == "/v2/entities"
    assert client.get("/v2/").status_code == 200


def test_create_get_and_location(client: Any, recorder: Recorder) -> None:
    reply = send(client, "POST", "/v2/entities/", ROOM)
    assert reply.status_code == 201 and reply.headers["Location"] == "/v2/entities/Room1?type=Room"
    got = client.get("/v2/entities/Room1").json
    assert got["temperature"] == {"type": "Number", "value": 21.5, "metadata": {}}
    assert got["pressure"]["metadata"] == {"unit": {"type": "Text", "value": "hPa"}}
    assert client.get("/v2/entities/Room1/?options=keyValues").json == {
        "id": "Room1", "type": "Room", "temperature": 21.5, "pressure": 720}
    assert client.get("/v2/entities/Room1?options=values&attrs=pressure,temperature").json == [720, 21.5]
    [change] = recorder.changes
    assert change.created and change.entity_id == "Room1" and change.changed == {"temperature", "pressure"}


def test_upsert_is_204_and_updates(seeded: Any, recorder: Recorder) -> None:
    reply = send(seeded, "POST", "/v2/entities?options=upsert", {"id": "Room1", "type": "Room", "co2": {"value": 400}})
    assert reply.status_code == 204
    assert seeded.get("/v2/entities/Room1/attrs/co2/value").json == 400
    assert seeded.get("/v2/entities/Room1/attrs/temperature/value").json == 21.5
    assert send(seeded, "POST", "/v2/entities?options=upsert,keyValues", {"id": "New", "n": 1}).status_code == 204
    assert seeded.get("/v2/entities/New").json["type"] == "Thing"
    assert not recorder.changes[-2].created and recorder.changes[-1].created


def test_list_filters_paging_count_and_order(client: Any) -> None:
    for k in range(30):
        body = {"id": f"S{k:02d}", "type": "Sensor" if k % 2 else "Meter", "level": {"value": k},
                "zone": {"value": {"hall": k % 3}}}
        assert send(client, "POST", "/v2/entities", body).status_code == 201
    reply = client.get("/v2/entities/?options=count")
    assert reply.headers["Fiware-Total-Count"] == "30" and len(reply.json) == 20
    assert [e["id"] for e in client.get("/v2/entities?limit=3&offset=28").json] == ["S28", "S29"]
    assert client.get("/v2/entities?offset=100").json == []
    assert len(client.get("/v2/entities?type=Sensor&limit=100").json) == 15
    assert len(client.get("/v2/entities?type=Sensor,Meter&limit=100").json) == 30
    assert [e["id"] for e in client.get("/v2/entities?id=S01,S03").json] == ["S01", "S03"]
    assert len(client.get("/v2/entities?idPattern=^S1&limit=100").json) == 10
    assert len(client.get("/v2/entities?typePattern=^M&limit=100").json) == 15
    q = client.get("/v2/entities?q=level%3E=10;level%3C20;zone.hall==1&options=keyValues&attrs=level").json
    assert q == [{"id": f"S{k}", "type": "Sensor" if k % 2 else "Meter", "level": k} for k in (10, 13, 16, 19)]
    ordered = client.get("/v2/entities?orderBy=!level&limit=3&options=values&attrs=level").json
    assert ordered == [[29], [28], [27]]
    by_type = client.get("/v2/entities?orderBy=type,!id&limit=2&attrs=none").json
    assert [e["id"] for e in by_type] == ["S28", "S26"]
    assert client.get("/v2/entities?q=dateModified%3E2000-01-01&options=count").headers["Fiware-Total-Count"] == "30"


def test_attrs_routes(seeded: Any, recorder: Recorder) -> None:
    assert set(seeded.get("/v2/entities/Room1/attrs").json) == {"temperature", "pressure"}
    assert send(seeded, "POST", "/v2/entities/Room1/attrs", {"co2": {"value": 1}}).status_code == 204
    assert recorder.changes[-1].changed == {"co2"}
    assert send(seeded, "PATCH", "/v2/entities/Room1/attrs", {"co2": {"value": 2}}).status_code == 204
    assert seeded.get("/v2/entities/Room1/attrs/co2/value").json == 2
    assert send(seeded, "PUT", "/v2/entities/Room1/attrs/", {"only": {"value": "x"}}).status_code == 204
    assert seeded.get("/v2/entities/Room1/attrs?options=keyValues").json == {"only": "x"}
    assert send(seeded, "PUT", "/v2/entities/Room1/attrs/only",
                {"value": 5, "metadata": {"m": {"value": 1}}}).status_code == 204
    assert seeded.get("/v2/entities/Room1/attrs/only").json == {
        "type": "Number", "value": 5, "metadata": {"m": {"type": "Number", "value": 1}}}
    assert send(seeded, "DELETE", "/v2/entities/Room1/attrs/only").status_code == 204
    assert seeded.get("/v2/entities/Room1/attrs").json == {}


def test_value_routes_json_and_text_plain(seeded: Any) -> None:
    cases = [('"moving"', "text/plain", "moving"), ("12.5", "text/plain", 12.5), ("true", "text/plain", True),
             ('{"a": [1]}', "application/json", {"a": [1]}), ("3", "application/json", 3)]
    for raw, ctype, value in cases:
        reply = send(seeded, "PUT", "/v2/entities/Room1/attrs/temperature/value", raw=raw.encode(), ctype=ctype)
        assert reply.status_code == 204, (raw, reply.data)
        assert seeded.get("/v2/entities/Room1/attrs/temperature/value").json == value
    text = seeded.get("/v2/entities/Room1/attrs/temperature/value", headers={"Accept": "text/plain"})
    assert text.mimetype == "text/plain" and text.data == b"3"
    assert seeded.get("/v2/entities/Room1/attrs/temperature").json["type"] == "Number"


def test_types(seeded: Any) -> None:
    send(seeded, "POST", "/v2/entities", {"id": "Room2", "type": "Room", "temperature": {"value": "warm"}})
    send(seeded, "POST", "/v2/entities", {"id": "Car1", "type": "Car"})
    types = seeded.get("/v2/types?options=count")
    assert types.headers["Fiware-Total-Count"] == "2"
    assert types.json == [{"type": "Car", "attrs": {}, "count": 1},
                          {"type": "Room", "attrs": {"pressure": {"types": ["Number"]},
                                                     "temperature": {"types": ["Number", "Text"]}}, "count": 2}]
    assert seeded.get("/v2/types?options=values").json == ["Car", "Room"]
    assert seeded.get("/v2/types/Room").json["count"] == 2
    assert seeded.get("/v2/types/Room?options=noAttrDetail").json["attrs"]["pressure"] == {"types": []}


def test_batch_update_actions_and_query(seeded: Any) -> None:
    def op(action: str, entities: list[dict[str, Any]], query: str = "") -> Any:
        return send(seeded, "POST", "/v2/op/update" + query, {"actionType": action, "entities": entities})

    assert op("append", [{"id": "B1", "type": "T", "a": {"value": 1}}, {"id": "Room1", "type": "Room", "b": {"value": 2}}]).status_code == 204
    assert seeded.get("/v2/entities/Room1/attrs/b/value").json == 2
    assert error_of(op("appendStrict", [{"id": "B1", "type": "T", "a": {"value": 9}}])) == (422, "Unprocessable")
    assert op("update", [{"id": "B1", "type": "T", "a": {"value": 3}}]).status_code == 204
    assert op("replace", [{"id": "B1", "type": "T", "c": {"value": 4}}]).status_code == 204
    assert seeded.get("/v2/entities/B1?options=keyValues").json == {"id": "B1", "type": "T", "c": 4}
    assert op("update", [{"id": "B1", "c": 5}], "?options=keyValues").status_code == 204
    assert op("delete", [{"id": "Room1", "type": "Room", "b": {}}]).status_code == 204
    assert "b" not in seeded.get("/v2/entities/Room1").json
    assert error_of(op("update", [{"id": "Nope", "type": "T", "a": {"value": 1}}])) == (404, "NotFound")
    assert error_of(op("update", [{"id": "B1", "type": "T", "c": {"value": 6}},
                                  {"id": "Nope", "type": "T", "a": {"value": 1}}])) == (422, "PartialUpdate")
    query = send(seeded, "POST", "/v2/op/query?options=count,keyValues", {
        "entities": [{"idPattern": ".*", "type": "T"}], "attrs": ["c"], "expression": {"q": "c>5"}}, auth=False)
    assert query.status_code == 200 and query.json == [{"id": "B1", "type": "T", "c": 6}]
    assert query.headers["Fiware-Total-Count"] == "1"
    assert op("delete", [{"id": "B1", "type": "T"}]).status_code == 204
    assert seeded.get("/v2/entities/B1").status_code == 404


def test_delete_entity_and_ambiguous_id(seeded: Any, recorder: Recorder) -> None:
    send(seeded, "POST", "/v2/entities", {"id": "Room1", "type": "Hall"})
    assert error_of(seeded.get("/v2/entities/Room1")) == (409, "TooManyResults")
    assert error_of(send(seeded, "DELETE", "/v2/entities/Room1")) == (409, "TooManyResults")
    assert seeded.get("/v2/entities/Room1?type=Hall").status_code == 200
    assert send(seeded, "DELETE", "/v2/entities/Room1?type=Hall").status_code == 204
    assert recorder.changes[-1].deleted and recorder.changes[-1].entity_type == "Hall"
    assert seeded.get("/v2/entities/Room1").status_code == 200


def test_tenants_are_apart_and_service_path_subtrees_are_read(client: Any) -> None:
    for service, path, entity_id in (("", "/", "A"), ("acme", "/", "B"), ("acme", "/hall/a", "C"), ("acme", "/hall", "D")):
        headers = {"Fiware-Service": service, "Fiware-ServicePath": path}
        assert send(client, "POST", "/v2/entities", {"id": entity_id}, headers=headers).status_code == 201

    def ids(**headers: str) -> list[str]:
        return sorted(e["id"] for e in client.get("/v2/entities", headers=headers).json)

    assert ids() == ["A"]
    assert ids(**{"Fiware-Service": "ACME"}) == ["B", "C", "D"]
    assert ids(**{"Fiware-Service": "acme", "Fiware-ServicePath": "/hall"}) == ["D"]
    assert ids(**{"Fiware-Service": "acme", "Fiware-ServicePath": "/hall/#"}) == ["C", "D"]
    assert ids(**{"Fiware-Service": "acme", "Fiware-ServicePath": "/, /hall/a"}) == ["B", "C"]
    assert client.get("/v2/entities/C", headers={"Fiware-Service": "acme", "Fiware-ServicePath": "/"}).status_code == 404


def test_graph_is_nquads_of_the_tenants(seeded: Any) -> None:
    reply = seeded.get("/plantkg/v1/graph")
    assert reply.mimetype == "application/n-quads"
    text = reply.data.decode()
    assert '"Room1"' in text and "<https://w3id.org/plantkg/graph/ngsi/_/>" in text


def test_openapi_lists_every_route(client: Any) -> None:
    doc = client.get("/plantkg/v1/openapi.json").json
    assert doc["openapi"].startswith("3.")
    served = {str(rule) for rule in client.application.url_map.iter_rules()} - {"/static/<path:filename>"}
    documented = {p.replace("{entityId}", "<raw_id>").replace("{attrName}", "<raw_name>")
                  .replace("{entityType}", "<raw_type>").replace("{subscriptionId}", "<sub_id>")
                  for p in doc["paths"]}
    assert {s.rstrip("/") or "/" for s in served} <= documented | {"/v2/subscriptions/<sub_id>"}


# --- refusals ---------------------------------------------------------------------------------

def test_errors_as_orion(seeded: Any) -> None:
    cases = [
        (send(seeded, "POST", "/v2/entities", raw=b"{bad"), (400, "ParseError")),
        (send(seeded, "POST", "/v2/entities", {"id": "a<b"}), (400, "BadRequest")),
        (seeded.get("/v2/entities?q=a%3E"), (400, "BadRequest")),
        (seeded.get("/v2/entities?limit=0"), (400, "BadRequest")),
        (seeded.get("/v2/entities?options=bogus"), (400, "BadRequest")),
        (seeded.get("/v2/entities?id=a&idPattern=b"), (400, "BadRequest")),
        (seeded.get("/v2/entities?idPattern=("), (400, "BadRequest")),
        (seeded.get("/v2/entities?georel=near"), (400, "BadRequest")),
        (seeded.get("/v2/entities?options=keyValues,values"), (400, "BadRequest")),
        (seeded.get("/v2/entities/a%3Cb"), (400, "BadRequest")),
        (send(seeded, "POST", "/v2/entities", {"id": "X"}, auth=False), (401, "Unauthorized")),
        (send(seeded, "DELETE", "/v2/entities/Room1", headers={"Authorization": "Bearer nope"}, auth=False),
         (401, "Unauthorized")),
        (seeded.get("/v2/entities/Nope"), (404, "NotFound")),
        (seeded.get("/v2/nothing"), (404, "NotFound")),
        (seeded.get("/v2/types/Nope"), (404, "NotFound")),
        (seeded.get("/v2/entities/Room1/attrs/nope/value"), (404, "NotFound")),
        (send(seeded, "PUT", "/v2/entities/Room1/attrs/nope", {"value": 1}), (404, "NotFound")),
        (send(seeded, "PATCH", "/v2/entities/Nope/attrs", {"a": {"value": 1}}), (404, "NotFound")),
        (send(seeded, "POST", "/v2/entities", {"id": "Room1", "type": "Room"}), (422, "Unprocessable")),
        (send(seeded, "PATCH", "/v2/entities/Room1/attrs", {"nope": {"value": 1}}), (422, "Unprocessable")),
        (send(seeded, "POST", "/v2/entities/Room1/attrs?options=append", {"temperature": {"value": 1}}),
         (422, "Unprocessable")),
        (send(seeded, "POST", "/v2/entities", {"id": "X"}, ctype="text/plain"), (415, "UnsupportedMediaType")),
        (send(seeded, "PUT", "/v2/entities/Room1/attrs/temperature/value", raw=b"1", ctype="text/xml"),
         (415, "UnsupportedMediaType")),
        (send(seeded, "PUT", "/v2/entities/Room1/attrs/temperature/value", raw=b"moving", ctype="text/plain"),
         (400, "BadRequest")),
        (send(seeded, "POST", "/v2/entities", raw=b'{"id": "' + b"x" * MAX_BODY + b'"}'),
         (413, "RequestEntityTooLarge")),
        (seeded.get("/v2/subscriptions"), (400, "BadRequest")),
        (send(seeded, "POST", "/v2/subscriptions", {}, auth=False), (401, "Unauthorized")),
    ]
    for reply, expected in cases:
        assert error_of(reply) == expected, reply.data
        assert reply.json["description"]


def test_partial_updates_apply_what_they_can_as_orion(seeded: Any, recorder: Recorder) -> None:
    reply = send(seeded, "PATCH", "/v2/entities/Room1/attrs", {"temperature": {"value": 1}, "nope": {"value": 1}})
    assert error_of(reply) == (422, "PartialUpdate") and "nope" in reply.json["description"]
    assert seeded.get("/v2/entities/Room1/attrs/temperature/value").json == 1
    assert recorder.changes[-1].changed == {"temperature"}
    reply = send(seeded, "POST", "/v2/entities/Room1/attrs?options=append", {"temperature": {"value": 2}, "co2": {"value": 3}})
    assert error_of(reply) == (422, "PartialUpdate") and "temperature" in reply.json["description"]
    assert seeded.get("/v2/entities/Room1?options=keyValues&attrs=temperature,co2").json == {
        "id": "Room1", "type": "Room", "temperature": 1, "co2": 3}
    reply = send(seeded, "POST", "/v2/op/update", {"actionType": "update", "entities": [
        {"id": "Room1", "type": "Room", "co2": {"value": 4}, "nope": {"value": 1}}]})
    assert error_of(reply) == (422, "PartialUpdate")
    assert seeded.get("/v2/entities/Room1/attrs/co2/value").json == 4
    reply = send(seeded, "POST", "/v2/op/update", {"actionType": "append", "entities": []})
    assert error_of(reply) == (400, "BadRequest") and "empty" in reply.json["description"]


def test_limits_of_json_and_url_parameters(seeded: Any) -> None:
    deep = b'{"id": "D", "v": {"value": ' + b"[" * 60 + b"]" * 60 + b"}}"
    assert error_of(send(seeded, "POST", "/v2/entities", raw=deep)) == (400, "ParseError")
    deeper = b'{"id": "D", "v": {"value": ' + b"[" * 5000 + b"]" * 5000 + b"}}"
    assert error_of(send(seeded, "POST", "/v2/entities", raw=deeper)) == (400, "ParseError")
    ok = b'{"id": "D", "v": {"value": ' + b"[" * 45 + b"]" * 45 + b"}}"
    assert send(seeded, "POST", "/v2/entities", raw=ok).status_code == 201
    assert error_of(send(seeded, "POST", "/v2/entities", raw=b'{"id": "N", "v": {"value": 1e999}}')) == (400, "ParseError")
    reply = seeded.get("/v2/entities?orderBy=tem%3Bp")
    assert error_of(reply) == (400, "BadRequest") and "';'" in reply.json["description"]
    assert seeded.get("/v2/entities?q=temperature%3E1;pressure==720").status_code == 200


def test_method_not_allowed_lists_allow(seeded: Any) -> None:
    for method, path, allowed in (("PUT", "/v2/entities", {"GET", "POST"}), ("POST", "/v2/entities/Room1/", {"GET", "DELETE"}),
                                  ("DELETE", "/v2/types", {"GET"}), ("GET", "/v2/op/update", {"POST"})):
        reply = seeded.open(path, method=method, headers=AUTH, data=b"{}", content_type="application/json")
        assert error_of(reply) == (405, "MethodNotAllowed")
        assert allowed <= {m.strip() for m in reply.headers["Allow"].split(",")}


def test_write_without_content_length_is_411(client: Any) -> None:
    environ = EnvironBuilder(path="/v2/entities", method="POST", data=b'{"id": "X"}',
                             headers={**AUTH, "Content-Type": "application/json"}).get_environ()
    del environ["CONTENT_LENGTH"]  # the test client would put it back: call the WSGI app itself
    body, status, headers = run_wsgi_app(client.application, environ)
    assert status.startswith("411 ")
    assert json.loads(b"".join(body))["error"] == "ContentLengthRequired"
    assert client.get("/v2/entities/X").status_code == 404


def test_refused_writes_change_nothing_and_tell_no_listener(seeded: Any, recorder: Recorder) -> None:
    before = seeded.get("/v2/entities").json
    count = len(recorder.changes)
    send(seeded, "PATCH", "/v2/entities/Room1/attrs", {"nope": {"value": 1}})
    send(seeded, "POST", "/v2/op/update", {"actionType": "append", "entities": [
        {"id": "Room1", "type": "Room", "temperature": {"value": 2}}, {"id": "x(y"}]})
    send(seeded, "POST", "/v2/entities/Room1/attrs", {"temperature": {"value": "<b>"}})
    assert seeded.get("/v2/entities").json == before and len(recorder.changes) == count


def test_unexpected_exception_is_logged_500(store: ContextStore, caplog: pytest.LogCaptureFixture) -> None:
    class Broken:
        def entity_changed(self, change: EntityChange) -> None:
            raise RuntimeError("listener bug")

    app = create_app(store, token=None, listeners=[Broken()])

    @app.get("/boom")
    def boom() -> Any:
        raise ValueError("bug")

    client = app.test_client()
    assert send(client, "POST", "/v2/entities", {"id": "L1"}, auth=False).status_code == 201  # listener bug logged
    assert "listener bug" in caplog.text
    assert error_of(client.get("/boom")) == (500, "InternalServerError")
    [record] = [r for r in caplog.records if "unexpected error on GET /boom" in r.getMessage()]
    assert record.exc_info is not None and record.exc_info[0] is ValueError


def test_open_app_needs_no_token(store: ContextStore) -> None:
    client = create_app(store).test_client()
    assert send(client, "POST", "/v2/entities", {"id": "O1"}, auth=False).status_code == 201


# --- durability -------------------------------------------------------------------------------

def test_store_reopens_with_every_write_and_locks_its_folder(tmp_path: Path) -> None:
    store = ContextStore(tmp_path / "d")
    with pytest.raises(StoreLocked, match="in use"):
        ContextStore(tmp_path / "d")
    client = create_app(store, token=None).test_client()
    send(client, "POST", "/v2/entities", {"id": "urn:ngsi-ld:AGV:1", "type": "AGV", "s": {"value": "idle"},
                                          "t": {"type": "DateTime", "value": "2024-05-01T10:00:00Z"}})
    send(client, "POST", "/v2/entities", {"id": "urn:ngsi-ld:AGV:1", "type": "Robot"})
    send(client, "PUT", "/v2/entities/urn:ngsi-ld:AGV:1/attrs/s/value?type=AGV", raw=b'"moving"', ctype="text/plain")
    send(client, "POST", "/v2/entities", {"id": "G"}, headers={"Fiware-Service": "acme", "Fiware-ServicePath": "/x"})
    send(client, "POST", "/v2/entities", {"id": "Gone"})
    send(client, "DELETE", "/v2/entities/Gone")
    before = {h: client.get("/v2/entities?orderBy=id,type", headers=hh).json
              for h, hh in (("default", {}), ("acme", {"Fiware-Service": "acme"}))}
    store.close()
    again = ContextStore(tmp_path / "d")
    try:
        client = create_app(again, token=None).test_client()
        after = {h: client.get("/v2/entities?orderBy=id,type", headers=hh).json
                 for h, hh in (("default", {}), ("acme", {"Fiware-Service": "acme"}))}
        assert after == before
        assert client.get("/v2/entities/urn:ngsi-ld:AGV:1/attrs/s/value?type=AGV").json == "moving"
    finally:
        again.close()

"""The context broker, judged from outside: every malformed request of
``tests/cases/ngsi/bad-requests.json`` against the real process.

Each case says what Orion answers (status, ``error`` name) and, where plantkg must say more than
Orion does, which words the description has to hold (the forbidden character, its field, its
position). A case whose answer differs from Orion carries ``xfail`` in the data: a disagreement
the server's owner has to fix, kept visible as ``xfail(strict=True)`` so the fix is noticed.

The cases share one server (a known disagreement may leave an entity behind there); the checks
of state each start a fresh one: after every case the server should get right, its store holds
exactly the seed (no half-done write) and its log no traceback; batches are all-or-nothing for a
malformed payload and Orion's PartialUpdate for a missing entity.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from benchmarks.context_broker_rig import ContextBroker, Reply, raw_request

pytestmark = pytest.mark.integration

CASES_FILE = Path(__file__).resolve().parents[1] / "cases" / "ngsi" / "bad-requests.json"
DATA = json.loads(CASES_FILE.read_text(encoding="utf-8"))
SEED: list[dict[str, Any]] = DATA["seed"]


def _params() -> list[Any]:
    out = []
    for case in DATA["cases"]:
        marks = [pytest.mark.xfail(strict=True, reason=case["xfail"])] if "xfail" in case else []
        out.append(pytest.param(case, id=case["name"], marks=marks))
    return out


def body_of(case: dict[str, Any]) -> bytes | None:
    if "body_json" in case:
        return json.dumps(case["body_json"]).encode("utf-8")
    if "body_fill" in case:
        fill = case["body_fill"]
        prefix, suffix = fill["prefix"].encode(), fill["suffix"].encode()
        return prefix + fill["fill"].encode() * (fill["size"] - len(prefix) - len(suffix)) + suffix
    if "body_bytes_hex" in case:
        return bytes.fromhex(case["body_bytes_hex"])
    if "body" in case:
        return case["body"].encode("utf-8")
    return None


def send(broker: ContextBroker, case: dict[str, Any]) -> Reply:
    headers = dict(case["headers"])
    auth = case.get("auth", True)
    if auth is True:
        headers.update(broker.auth)
    elif auth == "wrong":
        headers["Authorization"] = "Bearer " + "x" * 43
    body = body_of(case)
    if case.get("raw"):
        head = "\r\n".join([f"{case['method']} {case['path']} HTTP/1.1", f"Host: {broker.host}:{broker.port}",
                            *(f"{k}: {v}" for k, v in headers.items())])
        return raw_request(broker.host, broker.port, head, body or b"")
    http = broker.http()
    try:
        return http.request(case["method"], case["path"], body, headers)
    finally:
        http.close()


def seed(broker: ContextBroker) -> None:
    http = broker.http()
    try:
        for entity in SEED:
            reply = http.request("POST", "/v2/entities", json.dumps(entity),
                                 {"Content-Type": "application/json", **broker.auth})
            assert reply.status == 201, (reply.status, reply.body)
    finally:
        http.close()


def entities(broker: ContextBroker) -> list[dict[str, Any]]:
    http = broker.http()
    try:
        reply = http.request("GET", "/v2/entities?limit=1000", headers=broker.auth)
    finally:
        http.close()
    assert reply.status == 200, (reply.status, reply.body)
    return sorted(strict_json(reply.body), key=lambda e: e["id"])


def strict_json(data: bytes) -> Any:
    """JSON as the standard defines it: Python's ``json`` would also take NaN and Infinity."""
    def refuse(name: str) -> None:
        raise ValueError(f"{name} is not JSON")

    return json.loads(data, parse_constant=refuse)


def comparable(entity: dict[str, Any]) -> dict[str, Any]:
    """An entity as seeded: id, type, and each attribute's type and value (metadata aside)."""
    return {k: (v if k in ("id", "type") else {"type": v.get("type"), "value": v.get("value")})
            for k, v in entity.items()}


def running(folder: Path) -> Iterator[ContextBroker]:
    rig = ContextBroker(folder).start()
    try:
        seed(rig)
        yield rig
    finally:
        child = rig.child
        rig.stop()
        assert child is None or not child.group_alive(), "the context broker survived stop()"


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ContextBroker]:
    yield from running(tmp_path_factory.mktemp("context-broker"))


@pytest.fixture
def fresh_broker(tmp_path: Path) -> Iterator[ContextBroker]:
    yield from running(tmp_path / "context-broker")


def check(case: dict[str, Any], reply: Reply) -> None:
    expect = case["expect"]
    where = f"{case['method']} {case['path'][:80]} -> {reply.status} {reply.body[:300]!r}"
    assert reply.status == expect["status"], where
    assert (reply.header("content-type") or "").startswith("application/json"), where
    body = strict_json(reply.body)
    assert isinstance(body, dict) and isinstance(body.get("error"), str), where
    if "allow" in expect:
        allow = {m.strip().upper() for m in (reply.header("allow") or "").split(",") if m.strip()}
        assert set(expect["allow"]) <= allow, f"Allow {allow}: {where}"
    if "error" in expect:
        accepted = expect["error"] if isinstance(expect["error"], list) else [expect["error"]]
        assert body["error"] in accepted, where
        assert isinstance(body.get("description"), str) and body["description"], where
    for part in expect.get("description", []):
        assert part.lower() in body["description"].lower(), f"description lacks {part!r}: {where}"


@pytest.mark.parametrize("case", _params())
def test_bad_request_is_refused_as_orion_does(broker: ContextBroker, case: dict[str, Any]) -> None:
    check(case, send(broker, case))


def test_store_unchanged_and_no_traceback_after_every_case(fresh_broker: ContextBroker) -> None:
    """Every case the server is meant to get right (the known disagreements aside: each fails on
    its own above), in a row on a fresh server: the store still answers exactly the seed (as
    standard JSON), and the server logged no traceback. A PartialUpdate writes part of its
    request by definition (Orion's semantics), so those cases are left out here."""
    for case in DATA["cases"]:
        if "xfail" in case or case["expect"].get("error") == "PartialUpdate":
            continue
        reply = send(fresh_broker, case)
        assert reply.status < 500, f"{case['name']}: {reply.status} {reply.body[:300]!r}"
    assert [comparable(e) for e in entities(fresh_broker)] == [comparable(e) for e in SEED]
    log = fresh_broker.log_text()
    assert "Traceback" not in log, log[-4000:]


def test_batch_with_one_bad_entity_changes_nothing(fresh_broker: ContextBroker) -> None:
    """Orion parses the whole batch before writing any entity: one entity with a forbidden
    character in its id is a 400, and the good entity next to it is not written either."""
    case = next(c for c in DATA["cases"] if c["name"] == "batch-one-bad-entity")
    before = entities(fresh_broker)
    check(case, send(fresh_broker, case))
    assert entities(fresh_broker) == before


def test_batch_update_with_a_missing_entity_is_a_partial_update(fresh_broker: ContextBroker) -> None:
    """Orion's ``update`` batch is one PATCH per entity: an entity that does not exist makes the
    answer 422 ``PartialUpdate`` naming it, and the entities that exist are updated
    (orion-api.md, "Update POST /v2/op/update")."""
    broker = fresh_broker
    http = broker.http()
    try:
        reply = http.request("POST", "/v2/op/update", json.dumps({"actionType": "update", "entities": [
            {"id": "Room2", "type": "Room", "pressure": {"type": "Number", "value": 712}},
            {"id": "NoSuchRoom", "type": "Room", "pressure": {"type": "Number", "value": 1}}]}),
            {"Content-Type": "application/json", **broker.auth})
        assert reply.status == 422, (reply.status, reply.body)
        body = reply.json()
        assert body["error"] == "PartialUpdate" and "NoSuchRoom" in body["description"], body
        room2 = http.request("GET", "/v2/entities/Room2/attrs/pressure/value", headers=broker.auth)
        assert room2.status == 200 and room2.json() == 712, (room2.status, room2.body)
        assert http.request("GET", "/v2/entities/NoSuchRoom", headers=broker.auth).status == 404
    finally:
        http.close()


SLOW_CLIENTS = 32  # four times the server's default worker threads (8)


def test_slow_clients_do_not_stop_the_others(fresh_broker: ContextBroker) -> None:
    """Clients that send a request's headers and then only part of its body (a slow or stalled
    device, or a slowloris) must not keep a well-behaved client from being answered promptly.
    (Under cheroot, 16 such clients held every worker and a GET waited 7-17 s; fixed by
    ed51755, back on waitress, which reads a request whole before a worker runs it.)"""
    import socket
    import time

    head = (b"POST /v2/entities HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
            b"Content-Length: 100\r\n\r\n{\"id\": ")
    stalled = []
    try:
        for _ in range(SLOW_CLIENTS):
            sock = socket.create_connection((fresh_broker.host, fresh_broker.port), timeout=5)
            sock.sendall(head)
            stalled.append(sock)
        http = fresh_broker.http()
        http.timeout = 30.0
        http.reconnect()
        started = time.monotonic()
        reply = http.request("GET", "/v2/entities/Room1", headers=fresh_broker.auth)
        waited = time.monotonic() - started
        http.close()
    finally:
        for sock in stalled:
            sock.close()
    assert reply.status == 200, (reply.status, reply.body)
    assert waited < 2.0, f"a GET waited {waited:.1f} s behind {SLOW_CLIENTS} stalled clients"


def test_concurrent_creates_of_one_id_make_one_entity(fresh_broker: ContextBroker) -> None:
    """Ten rounds of 24 clients creating the same entity at once: each round exactly one 201, every
    other answer 422 ``Unprocessable`` (Orion's ``Already Exists``), one entity per round stored.

    A connection the server resets is not an answer: the invariant is checked without it, and a
    run that saw resets ends as xfail naming them (seen on ~1% of such connections on
    2026-11-24 while the server ran on cheroot)."""
    import http.client
    import threading
    from collections import Counter

    rounds, clients = 10, 24
    resets: Counter[str] = Counter()
    for r in range(rounds):
        answers: Counter[tuple[int, str]] = Counter()
        lock = threading.Lock()

        def create(n: int, entity_id: str = f"Race{r}") -> None:
            # one attempt on a connection of its own (Http.request would retry a POST on a reset)
            conn = http.client.HTTPConnection(fresh_broker.host, fresh_broker.port, timeout=60)
            try:
                conn.request("POST", "/v2/entities", json.dumps(
                    {"id": entity_id, "type": "Room", "n": {"type": "Number", "value": n}}),
                    {"Content-Type": "application/json", **fresh_broker.auth})
                resp = conn.getresponse()
                body = resp.read()
                answer = (resp.status, strict_json(body).get("error", "") if body else "")
            except (OSError, http.client.HTTPException) as err:
                with lock:
                    resets[type(err).__name__] += 1
                return
            finally:
                conn.close()
            with lock:
                answers[answer] += 1

        threads = [threading.Thread(target=create, args=(n,)) for n in range(clients)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert answers[(201, "")] == 1, (r, answers)
        assert set(answers) <= {(201, ""), (422, "Unprocessable")}, (r, answers)
    assert [e["id"] for e in entities(fresh_broker)] == sorted([f"Race{r}" for r in range(rounds)] + ["Room1", "Room2"])
    if resets:
        pytest.xfail(f"the server reset {sum(resets.values())} of {rounds * clients} connections of concurrent "
                     f"creates ({dict(resets)}); a burst of new connections should all be answered")

"""The SPARQL endpoint's worker processes (engine.web.sparql_pool): a query past its timeout is
killed with its worker and the slot is free at once; the workers' copy of the store follows the
served one; a dead worker is replaced; the per-client limit answers 429 with Retry-After.

Real worker processes, no broker; each test closes what it started."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pyoxigraph as ox
import pytest
from flask.testing import FlaskClient

from engine import process
from engine.web.plant_state import PlantState
from engine.web.sparql_protocol import Dataset, Limits, QueryRunner, SparqlError
from kg.namespaces import GRAPH_OBSERVED, NGSI_GRAPH_BASE
from tests.web.conftest import TOKEN, make_app

#: A join of three triple patterns counted: Oxigraph computes it inside Store.query, before the
#: first row, ~1.6e9 combinations on the robot cell (hours); only a kill stops it.
SLOW = "SELECT (COUNT(*) AS ?n) WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i }"
CHEAP = 'SELECT ?b WHERE { ?b pk:id "kafka" }'
EX = "http://example.org/"


def alive(pid: int) -> bool:
    """Whether a thread of process ``pid`` still runs (a zombie awaiting its reaper does not)."""
    states = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            states.append((task / "stat").read_text().rsplit(")", 1)[1].split()[0])
        except OSError:
            continue
    return any(state not in ("Z", "X") for state in states)


@pytest.fixture
def runner() -> Iterator[QueryRunner]:
    r = QueryRunner(Limits(timeout_s=1.0, workers=2, per_client=1))
    yield r
    pids = r.pool.pids()
    r.close()
    assert not [p for p in pids if alive(p)], "close() left a worker process"


def ask(runner: QueryRunner, state: PlantState, query: str, client: str = "address 127.0.0.1") -> list[str]:
    snap = state.snapshot
    answer = runner.execute(snap.plant.store, query, version=snap.version, client=client)
    return [str(t.value) for row in answer.rows for t in row if t is not None]


def test_a_timed_out_query_is_killed_and_its_slot_is_free(runner: QueryRunner, state: PlantState) -> None:
    assert ask(runner, state, CHEAP) == ["https://w3id.org/plantkg/examples/robot-cell#kafka"]
    (worker,) = runner.pool.pids()
    started = time.monotonic()
    with pytest.raises(SparqlError) as info:
        ask(runner, state, SLOW)
    elapsed = time.monotonic() - started
    assert info.value.status == 503 and "timeout of 1 s" in info.value.message
    assert elapsed < 5.0, f"the timeout took {elapsed:.1f} s"
    assert not alive(worker), "the worker that ran the slow query still runs"
    assert runner.pool.pids() == [] and runner.limiter.running() == {}
    # per_client=1: this answer needs the very slot the slow query held
    assert ask(runner, state, CHEAP) == ["https://w3id.org/plantkg/examples/robot-cell#kafka"]


def test_a_worker_killed_mid_query_is_a_500_and_is_replaced(runner: QueryRunner, state: PlantState) -> None:
    errors: list[SparqlError] = []

    def slow() -> None:
        try:
            ask(runner, state, SLOW)
        except SparqlError as exc:
            errors.append(exc)

    thread = threading.Thread(target=slow)
    thread.start()
    (pid,) = process.wait_until(runner.pool.pids, 30.0, 0.01, what="a worker")
    os.kill(pid, 9)
    thread.join(timeout=30)
    assert [(e.status, "killed by signal 9" in e.message) for e in errors] == [(500, True)]
    assert ask(runner, state, CHEAP) and runner.pool.pids() != [pid]


def test_a_worker_that_died_idle_is_replaced_silently(runner: QueryRunner, state: PlantState) -> None:
    ask(runner, state, CHEAP)
    (pid,) = runner.pool.pids()
    os.kill(pid, 9)
    process.wait_until(lambda: not alive(pid), 10.0, 0.01, what="the killed worker to die")
    assert ask(runner, state, CHEAP) == ["https://w3id.org/plantkg/examples/robot-cell#kafka"]
    assert pid not in runner.pool.pids()


def test_the_workers_copy_follows_the_served_store(runner: QueryRunner) -> None:
    store = ox.Store()
    p = ox.NamedNode(EX + "p")
    store.add(ox.Quad(ox.NamedNode(EX + "plant"), p, ox.Literal("base"), ox.NamedNode(EX + "file")))
    store.add(ox.Quad(ox.NamedNode(EX + "b"), p, ox.Literal("seen-1"), ox.NamedNode(GRAPH_OBSERVED)))
    query = f"SELECT ?o WHERE {{ ?s <{EX}p> ?o }} ORDER BY ?o"

    def values(s: ox.Store, version: int) -> list[str]:
        answer = runner.execute(s, query, version=version, client="address 127.0.0.1")
        return [row[0].value for row in answer.rows]

    assert values(store, 1) == ["base", "seen-1"]
    # The server rewrites the observed and context graphs in place, then publishes a new version.
    store.remove_graph(ox.NamedNode(GRAPH_OBSERVED))
    store.add(ox.Quad(ox.NamedNode(EX + "b"), p, ox.Literal("seen-2"), ox.NamedNode(GRAPH_OBSERVED)))
    store.add(ox.Quad(ox.NamedNode(EX + "e"), p, ox.Literal("context"), ox.NamedNode(NGSI_GRAPH_BASE + "cb")))
    assert values(store, 1) == ["base", "seen-1"]  # same version: the copy is not taken again
    assert values(store, 2) == ["base", "context", "seen-2"]
    # A re-read of the files makes a new store: the whole copy is replaced.
    other = ox.Store()
    other.add(ox.Quad(ox.NamedNode(EX + "plant"), p, ox.Literal("reloaded"), ox.NamedNode(EX + "file")))
    assert values(other, 3) == ["reloaded"]


def test_blank_nodes_keep_their_labels(runner: QueryRunner) -> None:
    store = ox.Store()
    node = ox.BlankNode("kept")
    store.add(ox.Quad(node, ox.NamedNode(EX + "p"), ox.Literal("x"), ox.NamedNode(EX + "g")))
    answer = runner.execute(store, "SELECT ?s WHERE { ?s ?p ?o }", Dataset(), version=1, client="c")
    assert answer.rows == ((node,),)


def test_the_limit_is_per_client(runner: QueryRunner, state: PlantState) -> None:
    assert runner.limiter.acquire("address 127.0.0.2").name == "ADMIT"  # its one query runs
    try:
        with pytest.raises(SparqlError) as info:
            ask(runner, state, CHEAP, client="address 127.0.0.2")
        assert info.value.status == 429 and info.value.retry_after_s == 1
        assert ask(runner, state, CHEAP, client="address 127.0.0.3")  # another client is answered
    finally:
        runner.limiter.release("address 127.0.0.2")


def test_close_kills_the_workers_and_later_queries_get_503(state: PlantState) -> None:
    runner = QueryRunner(Limits(timeout_s=5.0, workers=2))
    ask(runner, state, CHEAP)
    pids = runner.pool.pids()
    runner.close()
    assert pids and not [p for p in pids if alive(p)]
    with pytest.raises(SparqlError) as info:
        ask(runner, state, CHEAP)
    assert info.value.status == 503 and "shutting down" in info.value.message


# ------------------------------------------------------------------------------- over HTTP (app)

@pytest.fixture
def app_client(state: PlantState) -> Iterator[FlaskClient]:
    app = make_app(state, Limits(timeout_s=3.0, workers=4, per_client=2))
    yield app.test_client()
    app.extensions["plantkg_sparql"].close()


@pytest.mark.parametrize("who, headers", [
    ("address 127.0.0.1", {}),                                   # anonymous: the remote address
    ("user operator", {"Authorization": f"Bearer {TOKEN}"}),     # authenticated: the user
])
def test_over_the_client_limit_is_429_with_retry_after(app_client: FlaskClient, who: str,
                                                        headers: dict[str, str]) -> None:
    runner: QueryRunner = app_client.application.extensions["plantkg_sparql"]
    for _ in range(2):
        assert runner.limiter.acquire(who).name == "ADMIT"
    try:
        r = app_client.get("/sparql", query_string={"query": CHEAP}, headers=headers)
        body = r.get_data(as_text=True)
        assert r.status_code == 429 and r.headers["Retry-After"] == "3" and r.mimetype == "text/plain"
        assert f"from {who}" in body and "at most 2 per client" in body and "hint: wait" in body, body
        other = {} if headers else {"Authorization": f"Bearer {TOKEN}"}  # the other identity
        assert app_client.get("/sparql", query_string={"query": CHEAP}, headers=other).status_code == 200
    finally:
        for _ in range(2):
            runner.limiter.release(who)


def test_over_the_global_limit_is_503_with_retry_after(app_client: FlaskClient) -> None:
    runner: QueryRunner = app_client.application.extensions["plantkg_sparql"]
    busy = [f"address 127.0.0.{i}" for i in range(2, 6)]
    for client in busy:
        runner.limiter.acquire(client)
    try:
        r = app_client.get("/sparql", query_string={"query": CHEAP})
        assert r.status_code == 503 and r.headers["Retry-After"] == "3"
        assert "4 queries are running" in r.get_data(as_text=True)
    finally:
        for client in busy:
            runner.limiter.release(client)
    assert app_client.get("/sparql", query_string={"query": CHEAP}).status_code == 200


# ----------------------------------------------------------------------------- plantkg serve options

def test_serve_passes_the_query_limits(monkeypatch: pytest.MonkeyPatch, plant_file: Path) -> None:
    from engine.cli import main
    from engine.web import server

    got: list[Limits] = []
    monkeypatch.setattr(server, "run_server", lambda *a, **kw: got.append(kw["limits"]) or 0)
    assert main(["serve", str(plant_file)]) == 0
    assert main(["serve", str(plant_file), "--max-queries", "8", "--max-client-queries", "3",
                 "--query-timeout", "2.5"]) == 0
    assert got == [Limits(timeout_s=10.0, max_rows=10_000, workers=4, per_client=2),
                   Limits(timeout_s=2.5, max_rows=10_000, workers=8, per_client=3)]


@pytest.mark.parametrize("option, value", [("--max-queries", "0"), ("--max-client-queries", "0"),
                                           ("--max-client-queries", "many")])
def test_serve_refuses_a_bad_limit(capsys: pytest.CaptureFixture[str], plant_file: Path, option: str,
                                   value: str) -> None:
    from engine.cli import main

    assert main(["serve", str(plant_file), option, value]) == 2
    assert option in capsys.readouterr().err

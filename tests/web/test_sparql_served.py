"""Issue 13, over real HTTP: 20 slow SPARQL queries from one client do not stop a cheap query from
another being answered, and a timed-out query is really stopped (its worker process is gone and
its slot is free again).

``plantkg serve`` runs as its own process with its default limits (4 queries at once, 2 per
client) and a short --query-timeout. Clients are told apart by their address: the slow one sends
from 127.0.0.2, the cheap one from 127.0.0.1 (both reach the server on 127.0.0.1). Its agents are
closed loopback ports (no broker is needed), asked every second, so the observed graph — which the
workers copy — changes while the queries run.
"""

from __future__ import annotations

import http.client
import os
import threading
import time
import urllib.parse
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from engine import netutil, process
from engine.agent.local import plantkg_command
from tests.web.conftest import ROOT

pytestmark = pytest.mark.integration

TIMEOUT_S = 8.0  # long enough that a cheap query answered on a loaded machine still finds both slow ones running
#: Counted before its first row: Oxigraph spends hours on it inside Store.query; only a kill stops it.
SLOW = "SELECT (COUNT(*) AS ?n) WHERE { ?a ?b ?c . ?d ?e ?f . ?g ?h ?i }"
CHEAP = 'SELECT ?b WHERE { ?b pk:id "kafka" }'
KAFKA = "https://w3id.org/plantkg/examples/robot-cell#kafka"
SLOW_CLIENT, CHEAP_CLIENT = "127.0.0.2", "127.0.0.1"


@dataclass(frozen=True)
class Reply:
    status: int
    headers: dict[str, str]
    body: str
    seconds: float


@dataclass(frozen=True)
class Server:
    port: int
    child: process.Child

    def query(self, text: str, source: str, timeout: float = 60.0) -> Reply:
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout, source_address=(source, 0))
        started = time.monotonic()
        try:
            conn.request("GET", "/sparql?" + urllib.parse.urlencode({"query": text}),
                         headers={"Accept": "text/csv"})
            answer = conn.getresponse()
            body = answer.read().decode()
            return Reply(answer.status, {k.lower(): v for k, v in answer.getheaders()}, body,
                         time.monotonic() - started)
        finally:
            conn.close()

    def workers(self) -> dict[int, set[str]]:
        """The server's child processes (its query workers) → the states of their threads."""
        found: dict[int, set[str]] = {}
        for entry in Path("/proc").iterdir():
            if not entry.name.isdigit():
                continue
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
                if int(fields[1]) != self.child.pid:
                    continue
                found[int(entry.name)] = {(t / "stat").read_text().rsplit(")", 1)[1].split()[0]
                                          for t in (entry / "task").iterdir()}
            except (OSError, IndexError):
                continue
        return found


def _running(server: Server, count: int) -> list[int] | None:
    """The server's workers with a running thread, once there are ``count`` of them."""
    running = [pid for pid, states in server.workers().items() if "R" in states]
    return running if len(running) == count else None


def _closed_agents(directory: Path) -> Path:
    port = netutil.free_port()
    path = directory / "agents.toml"
    path.write_text("".join(f'[agents."{h}"]\nurl = "http://127.0.0.1:{port}"\ntoken = "{"x" * 20}"\n\n'
                            for h in ("127.0.0.2", "127.0.0.3")))
    os.chmod(path, 0o600)
    return path


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Server]:
    """One server for the module (its start is most of a test's setup)."""
    tmp_path = tmp_path_factory.mktemp("served")
    token = tmp_path / "web-token"
    token.write_text("served-sparql-test-token-0123456789\n")
    os.chmod(token, 0o600)
    port = netutil.free_port()
    child = process.spawn([*plantkg_command(), "serve", ROOT / "ontology" / "examples" / "robot-cell.ttl",
                           "--listen", f"127.0.0.1:{port}", "--agents", _closed_agents(tmp_path),
                           "--token-file", token, "--observe-interval", "1", "--query-timeout", str(TIMEOUT_S)],
                          log_dir=tmp_path / "logs", name="serve")
    try:
        served = Server(port, child)
        process.wait_until(lambda: served.query(CHEAP, CHEAP_CLIENT, 5.0).status == 200, 120.0, 0.1,
                           what="plantkg serve to answer SPARQL", child=child, ignore=(OSError,))
        yield served
    finally:
        process.stop(child)


@pytest.fixture
def server(served: Server) -> Server:
    """The module's server once no query of an earlier test still runs (a failed test's slow
    queries end at their timeout): each test starts with every slot free, as on a fresh server."""
    process.wait_until(lambda: not any("R" in states for states in served.workers().values()), TIMEOUT_S + 30, 0.1,
                       what="the earlier tests' queries to end", child=served.child)
    return served


def test_twenty_slow_queries_from_one_client_do_not_stop_another(server: Server) -> None:
    replies: list[Reply] = []
    lock = threading.Lock()

    def slow() -> None:
        reply = server.query(SLOW, SLOW_CLIENT)
        with lock:
            replies.append(reply)

    threads = [threading.Thread(target=slow, name=f"slow-{i}") for i in range(20)]
    for t in threads:
        t.start()
    # Over its limit of 2, the slow client is refused at once: 18 answers come back, 2 queries run.
    process.wait_until(lambda: len(replies) >= 18, 10.0, 0.02, what="18 refusals of the slow client")
    with lock:
        refused = list(replies)
    assert len(refused) == 18, [(r.status, r.body) for r in refused]
    for reply in refused:
        assert reply.status == 429 and reply.headers["retry-after"] == f"{TIMEOUT_S:.0f}", reply
        assert f"from address {SLOW_CLIENT}" in reply.body and "at most 2 per client" in reply.body, reply.body
    busy = process.wait_until(lambda: _running(server, 2), 10.0, 0.02, what="the two slow queries' workers to run")

    cheap = server.query(CHEAP, CHEAP_CLIENT)
    with lock:
        still_running = 20 - len(replies)
    assert cheap.status == 200 and cheap.body.split() == ["b", KAFKA], cheap
    # Answered while both slow queries still held their slots: the cheap one did not wait for them
    # (how long it took otherwise, a fresh worker's start on a loaded machine, is not the point).
    assert still_running == 2, "the slow queries ended before the cheap one was answered: nothing was shown"

    for t in threads:
        t.join(timeout=TIMEOUT_S + 30)
    timed_out = [r for r in replies if r.status != 429]
    assert [(r.status, f"timeout of {TIMEOUT_S:g} s" in r.body) for r in timed_out] == [(503, True)] * 2
    # Stopped at the timeout, not run to their end (hours): a generous margin for a loaded machine.
    assert all(r.seconds < TIMEOUT_S + 15 for r in timed_out), [r.seconds for r in timed_out]
    # Really stopped: the workers that ran them are gone, nothing of the server still computes...
    assert not set(busy) & set(server.workers()), "a slow query's worker process survived its timeout"
    # ...and the slots are free again: the slow client's next queries are answered.
    for _ in range(2):
        again = server.query(CHEAP, SLOW_CLIENT)
        assert again.status == 200 and again.body.split() == ["b", KAFKA], again


def test_a_timed_out_query_frees_its_slot_for_the_next(server: Server) -> None:
    """Four timeouts from one client, two at once (its limit) then a cheap query of the same client,
    twice: a slot a timeout kept would refuse the next pair's second query or the cheap one (429)."""
    for _ in range(2):
        pair: list[Reply] = []
        threads = [threading.Thread(target=lambda: pair.append(server.query(SLOW, SLOW_CLIENT)), name=f"slow-{i}")
                   for i in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=TIMEOUT_S + 60)
        assert [r.status for r in pair] == [503, 503], pair
        after = server.query(CHEAP, SLOW_CLIENT)
        assert after.status == 200 and after.body.split() == ["b", KAFKA], after  # not 429: the slots are free
    assert len(server.workers()) <= 4

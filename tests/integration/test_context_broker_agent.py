"""A context broker (pk:brokerType "ngsi-v2") applied through real agents, like any broker.

One ``plantkg agent`` serves 127.0.0.3; the plant is a context broker on a free port with one
topic (an entity). The tests run in file order on one deployment: apply -> ``status`` shows it
running and its health (GET /version) passes -> writes and reads need the agent's token (401
without or with a wrong one) -> the context broker is SIGKILLed while writes stream: the agent restarts it and
every write it answered 2xx is there afterwards -> the agent itself is SIGKILLed and restarted on
the same state dir: it re-adopts the running context broker (same pid) -> destroy leaves no
broker and no process. The module fixture checks that no broker process survived.
"""

from __future__ import annotations

import http.client
import json
import os
import signal
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

from engine import netutil, process
from engine.agent.local import AGENT_READY_S, LocalAgent, plantkg_command
from engine.cli import main
from engine.drivers.ngsi import NgsiDriver
from engine.errors import DispatchError
from engine.model import BrokerStatus
from tests.integration.agents import AgentFleet, _alive, start_agents

pytestmark = pytest.mark.integration

HOST = "127.0.0.3"
BROKER = "cb"
ENTITY_TYPE = "AgvStatus"

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix :   <https://example.org/cb-test#> .
:cb a pk:Broker ; pk:id "cb" ; pk:name "fleet context broker" ; pk:brokerType "ngsi-v2" ;
    pk:ip "127.0.0.3" ; pk:port {port} ; pk:hasTopic :status .
:status a pk:Topic ; pk:id "status" ; pk:name "agv/1/status" ; pk:entityType "AgvStatus" .
:planner a pk:Resource ; pk:id "planner" ; pk:name "Task planner" ; pk:sendsTo :cb ; pk:subscribes :status .
"""


@dataclass
class Deployment:
    fleet: AgentFleet
    plant: Path
    port: int
    tmp: Path

    def run(self, capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str]:
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out + out.err

    @property
    def agent(self) -> LocalAgent:
        return self.fleet.agents[HOST]

    def broker(self):  # noqa: ANN201 - an ObservedBroker
        found = self.fleet.brokers()[BROKER]
        return found

    def request(self, method: str, path: str, body: object = None, token: str | None = None,
                timeout: float = 5.0) -> tuple[int, bytes]:
        conn = http.client.HTTPConnection(HOST, self.port, timeout=timeout)
        try:
            headers = {"Accept": "application/json"}
            data = None
            if body is not None:
                data = json.dumps(body).encode()
                headers["Content-Type"] = "application/json"
            if token is not None:
                headers["Authorization"] = f"Bearer {token}"
            conn.request(method, path, body=data, headers=headers)
            answer = conn.getresponse()
            return answer.status, answer.read()
        finally:
            conn.close()


@pytest.fixture(scope="module")
def dep(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    tmp = tmp_path_factory.mktemp("context-broker")
    fleet = start_agents([HOST], tmp)
    try:
        port = netutil.free_port(HOST)
        plant = tmp / "plant.ttl"
        plant.write_text(PLANT.replace("{port}", str(port)), encoding="utf-8")
        yield Deployment(fleet, plant, port, tmp)
    finally:
        fleet.stop()


def entity(i: int) -> dict[str, object]:
    return {"id": f"urn:ngsi-ld:{ENTITY_TYPE}:w{i}", "type": ENTITY_TYPE,
            "seq": {"type": "Number", "value": i}, "state": {"type": "Text", "value": "driving"}}


def test_apply_starts_the_context_broker(dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = dep.run(capsys, "apply", dep.plant, "--agents", dep.fleet.agents_file, "--yes")
    assert code == 0, out
    assert "Apply complete: 2 changed, 0 failed" in out
    code, out = dep.run(capsys, "status", dep.plant, "--agents", dep.fleet.agents_file)
    assert code == 0, out
    row = next(line for line in out.splitlines() if line.startswith(f"{BROKER} "))
    assert "ngsi-v2" in row and f"{HOST}:{dep.port}" in row and "running" in row
    observed = dep.broker()
    assert observed.status is BrokerStatus.RUNNING and observed.spec.allow_anonymous is False
    assert [(t.name, t.entity_id, t.entity_type) for t in observed.topics] == [
        ("agv/1/status", "urn:ngsi-ld:AgvStatus:agv:1:status", ENTITY_TYPE)]
    assert NgsiDriver().health(observed.spec, 2.0)
    status, body = dep.request("GET", "/version")
    assert status == 200 and "orion" in json.loads(body)


def test_plan_after_apply_has_no_changes(dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = dep.run(capsys, "plan", dep.plant, "--agents", dep.fleet.agents_file, "--detailed-exitcode")
    assert code == 0, out


def test_requests_need_the_agents_token_reads_included(dep: Deployment) -> None:
    """Closed by default (no pk:allowAnonymous): writes and reads need the agent's token."""
    token = dep.agent.token
    assert dep.request("POST", "/v2/entities", entity(0))[0] == 401
    assert dep.request("POST", "/v2/entities", entity(0), token="not-" + token)[0] == 401
    assert dep.request("GET", f"/v2/entities/{entity(0)['id']}", token=token)[0] == 404  # nothing half-written
    assert dep.request("POST", "/v2/entities", entity(0), token=token)[0] == 201
    status, body = dep.request("GET", f"/v2/entities/{entity(0)['id']}?options=keyValues", token=token)
    assert status == 200 and json.loads(body)["seq"] == 0
    for path in (f"/v2/entities/{entity(0)['id']}", "/v2/entities", "/v2/subscriptions", "/plantkg/v1/graph"):
        assert dep.request("GET", path)[0] == 401, path  # reads are closed too
        assert dep.request("GET", path, token="not-" + token)[0] == 401, path


def test_a_killed_context_broker_is_restarted_and_keeps_every_acknowledged_write(dep: Deployment) -> None:
    """SIGKILL the context broker while one writer streams creates: the agent restarts it, and
    every create it answered 201 is there afterwards (refused or unanswered ones may be lost)."""
    token = dep.agent.token
    before = dep.broker()
    acknowledged: list[int] = []
    stop = threading.Event()

    def writer() -> None:
        i = 1
        while not stop.is_set():
            try:
                status, _ = dep.request("POST", "/v2/entities", entity(i), token=token, timeout=2.0)
            except OSError:
                status = 0
            if status == 201:
                acknowledged.append(i)
            elif status == 0:
                stop.wait(0.02)  # down: try the next id shortly
            i += 1

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    try:
        process.wait_until(lambda: len(acknowledged) >= 50, 30.0, 0.01, what="50 acknowledged writes")
        os.kill(before.pid, signal.SIGKILL)
        killed, killed_at = time.monotonic(), len(acknowledged)
        process.wait_until(
            lambda: (lambda b: b.status is BrokerStatus.RUNNING and b.pid != before.pid)(dep.broker()),
            60.0, 0.1, what="the agent to restart the context broker")
        back_after = time.monotonic() - killed
        process.wait_until(lambda: len(acknowledged) >= killed_at + 50, 30.0, 0.01,
                           what="50 more acknowledged writes after the restart")
    finally:
        stop.set()
        thread.join(10)
    after = dep.broker()
    assert after.restarts >= before.restarts + 1 and after.pid != before.pid
    missing = [i for i in acknowledged
               if dep.request("GET", f"/v2/entities/{entity(i)['id']}?type={ENTITY_TYPE}", token=token)[0] != 200]
    assert missing == [], f"{len(missing)} of {len(acknowledged)} acknowledged writes lost: {missing[:10]}"
    print(f"context broker SIGKILLed after {killed_at} acknowledged creates, running again after "
          f"{back_after:.1f} s, {len(acknowledged)} acknowledged in all, none lost")


def test_an_agent_restart_re_adopts_the_running_context_broker_then_destroy_leaves_nothing(
        dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    """One test, because the restarted agent is a child of this test and must end in it."""
    old = dep.agent
    running = dep.broker()
    os.kill(old.child.pid, signal.SIGKILL)
    old.child.popen.wait(10)
    assert dep.request("GET", "/version")[0] == 200  # the broker outlives its agent
    port = int(old.url.rsplit(":", 1)[1])
    child = process.spawn(
        [*plantkg_command(), "agent", "--listen", f"{HOST}:{port}", "--state-dir", old.state_dir,
         "--stop-brokers-on-exit"],
        log_dir=dep.tmp / "logs", name=f"agent-{HOST}-again",
    )
    again = LocalAgent(HOST, old.url, old.state_dir, child)
    dep.fleet.local.agents[HOST] = again
    try:
        process.wait_until(lambda: again.client().health(), AGENT_READY_S, 0.05, child=child,
                           what="the restarted agent", ignore=(DispatchError, OSError))
        adopted = again.client().get_broker(BROKER)
        assert adopted.pid == running.pid and adopted.status is BrokerStatus.RUNNING
        assert adopted.restarts == running.restarts  # adopted, not restarted
        # the re-adopted broker still takes writes with the same token
        assert dep.request("POST", "/v2/entities", entity(10**6), token=again.token)[0] == 201

        code, out = dep.run(capsys, "destroy", dep.plant, "--agents", dep.fleet.agents_file, "--yes")
        assert code == 0, out
        assert dep.fleet.brokers() == {}
        process.wait_until(lambda: not _alive(running.pid), 10.0, 0.05,
                           what="the context broker process to end")
        assert not netutil.port_open(HOST, dep.port)
        assert not (again.state_dir / "brokers" / BROKER).exists()
    finally:
        dep.fleet.brokers()  # remember any pid for the fixture's final check
        process.stop(child, grace=30.0)  # with --stop-brokers-on-exit: nothing outlives it
        del dep.fleet.local.agents[HOST]  # stopped: the fixture has nothing left to ask it


def test_an_agent_with_its_own_token_file_gives_it_to_its_context_broker(tmp_path: Path) -> None:
    """``plantkg agent --token-file F`` (F outside the state dir): the context broker it runs
    takes writes with the token in F, and refuses any other."""
    from engine.agent.client import AgentClient
    from engine.model import BrokerSpec

    host = "127.0.0.4"
    agent_port, cb_port = netutil.free_port(host), netutil.free_port(host)
    token_file = tmp_path / "secrets" / "agent.token"
    token_file.parent.mkdir()
    child = process.spawn([*plantkg_command(), "agent", "--listen", f"{host}:{agent_port}",
                           "--state-dir", tmp_path / "state", "--token-file", token_file,
                           "--stop-brokers-on-exit"], log_dir=tmp_path / "logs", name="agent")
    try:
        process.wait_until(lambda: token_file.is_file(), AGENT_READY_S, 0.05, what="the token file",
                           child=child)
        client = AgentClient(f"http://{host}:{agent_port}", token_file.read_text().strip(), timeout=30.0)
        process.wait_until(client.health, AGENT_READY_S, 0.05, what="the agent", child=child,
                           ignore=(DispatchError, OSError))
        spec = BrokerSpec(id="cb", iri="https://example.org/x#cb", name="cb", kind="ngsi-v2",
                          host=host, port=cb_port)
        assert client.put_broker(spec).status is BrokerStatus.RUNNING
        body = json.dumps({"id": "urn:ngsi-ld:Thing:1", "type": "Thing"})
        for token, expected in (("wrong-token", 401), (token_file.read_text().strip(), 201)):
            conn = http.client.HTTPConnection(host, cb_port, timeout=10)
            conn.request("POST", "/v2/entities", body, {"Content-Type": "application/json",
                                                        "Authorization": f"Bearer {token}"})
            assert conn.getresponse().status == expected
            conn.close()
        assert _read_status(host, cb_port) == 401  # closed by default: reads need the token too
        # pk:allowAnonymous true opens it: reads (and writes) without a token; the agent restarts it
        assert client.put_broker(replace(spec, allow_anonymous=True)).status is BrokerStatus.RUNNING
        process.wait_until(lambda: _read_status(host, cb_port) == 200, 30.0, 0.1, what="the opened broker",
                           ignore=(OSError,))
        client.delete_broker("cb")
    finally:
        process.stop(child, grace=30.0)
    assert not netutil.port_open(host, cb_port)


def _read_status(host: str, port: int) -> int:
    """The status of an anonymous read of the context broker's entities."""
    conn = http.client.HTTPConnection(host, port, timeout=10)
    try:
        conn.request("GET", "/v2/entities/urn:ngsi-ld:Thing:1")
        return conn.getresponse().status
    finally:
        conn.close()

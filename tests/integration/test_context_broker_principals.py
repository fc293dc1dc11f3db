"""Per-principal tokens on a context broker, end to end: ``plantkg apply`` of a plant file whose
resources have a ``pk:secretRef``, a real agent and context broker over HTTP.

Anonymous requests (reads too) are refused with 401 and Orion's error body; each principal writes
exactly the entities of the topics it publishes, reads those it subscribes to, and nothing else
(403); the agent's token keeps every right; FiLiP, unchanged, works with a principal's token (its
``authorization`` header) and is refused outside it; no token is in the plan's output or in any
file of the agent's state dir (only the 0600 principals file's digests).
"""

from __future__ import annotations

import json
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import requests

from engine import netutil
from engine.cli import main
from engine.security.ngsi_principals import token_digest
from tests.integration.agents import AgentFleet, secret_files, start_agents

filip_cb = pytest.importorskip("filip.clients.ngsi_v2")
from filip.clients.exceptions import BaseHttpClientException  # noqa: E402
from filip.models.base import FiwareHeader  # noqa: E402
from filip.models.ngsi_v2.context import ContextEntity  # noqa: E402

pytestmark = pytest.mark.integration

HOST = "127.0.0.3"
ROBOT_TOKEN, PLANNER_TOKEN = "robot1-Token-7f3a9c", "planner-Token-51be02"

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix :   <https://example.org/cb-principals#> .
:cb a pk:Broker ; pk:id "cb" ; pk:name "fleet context broker" ; pk:brokerType "ngsi-v2" ;
    pk:ip "127.0.0.3" ; pk:port {port} ; pk:hasTopic :status, :task .
:status a pk:Topic ; pk:id "status" ; pk:name "agv/1/status" ; pk:entityType "AgvStatus" .
:task a pk:Topic ; pk:id "task" ; pk:name "agv/1/task" ; pk:entityType "AgvTask" .
:robot1 a pk:Resource ; pk:id "robot1" ; pk:name "AGV 1" ; pk:sendsTo :cb ;
    pk:publishes :status ; pk:subscribes :task ; pk:secretRef "file:{secrets}/robot1" .
:planner a pk:Resource ; pk:id "planner" ; pk:name "Task planner" ; pk:sendsTo :cb ;
    pk:publishes :task ; pk:subscribes :status ; pk:secretRef "file:{secrets}/planner" .
"""


@dataclass
class Deployment:
    fleet: AgentFleet
    plant: Path
    port: int
    status_id: str = ""
    task_id: str = ""

    def request(self, method: str, path: str, body: object = None, token: str | None = None,
                header: str = "Authorization") -> tuple[int, object]:
        headers = {"Accept": "application/json"}
        if token is not None:
            headers[header] = f"Bearer {token}" if header == "Authorization" else token
        answer = requests.request(method, f"http://{HOST}:{self.port}{path}", json=body, headers=headers,
                                  timeout=10)
        return answer.status_code, answer.json() if answer.content else None


@pytest.fixture(scope="module")
def dep(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    tmp = tmp_path_factory.mktemp("cb-principals")
    secrets = secret_files(tmp / "secrets", {"robot1": ROBOT_TOKEN, "planner": PLANNER_TOKEN})
    fleet = start_agents([HOST], tmp / "agents")
    try:
        port = netutil.free_port(HOST)
        plant = tmp / "plant.ttl"
        plant.write_text(PLANT.replace("{port}", str(port)).replace("{secrets}", str(secrets)), encoding="utf-8")
        yield Deployment(fleet, plant, port)
    finally:
        fleet.stop()


def entity(eid: str, etype: str, value: int) -> dict[str, object]:
    return {"id": eid, "type": etype, "seq": {"type": "Number", "value": value}}


def test_apply_closes_the_context_broker_without_showing_a_token(dep: Deployment,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["plan", str(dep.plant), "--agents", str(dep.fleet.agents_file)])
    code2 = main(["apply", str(dep.plant), "--agents", str(dep.fleet.agents_file), "--yes"])
    code3 = main(["status", str(dep.plant), "--agents", str(dep.fleet.agents_file)])
    out = capsys.readouterr()
    text = out.out + out.err
    assert (code, code2, code3) in ((0, 0, 0), (2, 0, 0)), text
    assert "principals (2)" in text, text
    assert ROBOT_TOKEN not in text and PLANNER_TOKEN not in text
    topics = {t.name: t.entity_id for t in dep.fleet.brokers()["cb"].topics}
    dep.status_id, dep.task_id = topics["agv/1/status"], topics["agv/1/task"]
    assert dep.status_id and dep.task_id


def test_anonymous_and_wrong_tokens_are_refused_reads_included(dep: Deployment) -> None:
    for method, path, body in [("GET", "/v2/entities", None), ("GET", f"/v2/entities/{dep.status_id}", None),
                               ("POST", "/v2/entities", entity(dep.status_id, "AgvStatus", 0))]:
        for token in (None, "guess", ROBOT_TOKEN + "x"):
            status, answer = dep.request(method, path, body, token)
            assert status == 401, (method, path, token, answer)
            assert isinstance(answer, dict) and set(answer) == {"error", "description"}
    assert dep.request("GET", "/version")[0] == 200  # the health check stays public


def test_each_principal_writes_exactly_its_entities(dep: Deployment) -> None:
    assert dep.request("POST", "/v2/entities", entity(dep.status_id, "AgvStatus", 1), ROBOT_TOKEN)[0] == 201
    assert dep.request("POST", "/v2/entities", entity(dep.task_id, "AgvTask", 1), PLANNER_TOKEN,
                       header="X-Auth-Token")[0] == 201
    for token, other in ((ROBOT_TOKEN, dep.task_id), (PLANNER_TOKEN, dep.status_id)):
        status, answer = dep.request("PATCH", f"/v2/entities/{other}/attrs", {"seq": {"value": 9}}, token)
        assert status == 403 and answer["error"] == "Forbidden", answer
        assert dep.request("POST", "/v2/entities", entity("urn:ngsi-ld:X:1", "X", 1), token)[0] == 403
        assert dep.request("DELETE", f"/v2/entities/{other}", None, token)[0] == 403
        assert dep.request("POST", "/v2/op/update", {"actionType": "append", "entities": [
            entity(other, "X", 9)]}, token)[0] == 403
    assert dep.request("PATCH", f"/v2/entities/{dep.status_id}/attrs", {"seq": {"value": 2}}, ROBOT_TOKEN)[0] == 204
    # reads: each its own and what it subscribes to, nothing else
    assert dep.request("GET", f"/v2/entities/{dep.status_id}?options=keyValues", None, PLANNER_TOKEN)[1]["seq"] == 2
    assert dep.request("GET", f"/v2/entities/{dep.task_id}", None, ROBOT_TOKEN)[0] == 200
    assert dep.request("GET", "/v2/entities", None, ROBOT_TOKEN)[0] == 403
    assert dep.request("GET", "/v2/types", None, PLANNER_TOKEN)[0] == 403
    # the agent's token keeps every right, and nothing refused was written
    status, listed = dep.request("GET", "/v2/entities?options=keyValues", None, dep.fleet.agents[HOST].token)
    assert status == 200
    assert sorted((e["id"], e["seq"]) for e in listed) == [(dep.status_id, 2), (dep.task_id, 1)]


def test_filip_works_with_a_principals_token_and_only_within_it(dep: Deployment) -> None:
    def client(token: str) -> filip_cb.ContextBrokerClient:
        session = requests.Session()
        session.headers.update({"authorization": f"Bearer {token}"})
        return filip_cb.ContextBrokerClient(url=f"http://{HOST}:{dep.port}", session=session,
                                            fiware_header=FiwareHeader())
    robot = client(ROBOT_TOKEN)

    got = robot.get_entity(entity_id=dep.status_id)
    assert got.get_attribute("seq").value == 2
    got.seq.value = 3  # type: ignore[attr-defined]
    robot.update_entity(got)
    assert robot.get_entity(entity_id=dep.status_id).get_attribute("seq").value == 3
    with pytest.raises((BaseHttpClientException, requests.HTTPError)):
        robot.post_entity(ContextEntity(id="urn:ngsi-ld:X:2", type="X"))
    with pytest.raises((BaseHttpClientException, requests.HTTPError)):
        client("wrong").get_entity(entity_id=dep.status_id)


def test_no_token_is_in_any_file_but_as_a_digest(dep: Deployment) -> None:
    state = dep.fleet.agents[HOST].state_dir
    files = [p for p in state.rglob("*") if p.is_file()]
    principals = [p for p in files if p.name == "principals.json"]
    assert len(principals) == 1 and stat.S_IMODE(principals[0].stat().st_mode) == 0o600
    assert token_digest(ROBOT_TOKEN) in principals[0].read_text(encoding="utf-8")
    for path in files:
        data = path.read_bytes()
        assert ROBOT_TOKEN.encode() not in data and PLANNER_TOKEN.encode() not in data, path


def test_destroy_leaves_nothing(dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["destroy", str(dep.plant), "--agents", str(dep.fleet.agents_file), "--yes"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    assert "cb" not in dep.fleet.brokers()

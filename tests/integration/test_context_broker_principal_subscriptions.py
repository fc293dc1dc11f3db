"""Subscriptions by a principal of a closed context broker, end to end: ``plantkg apply`` of a
plant file whose resources have a ``pk:secretRef``, a real agent and context broker over HTTP,
FiLiP's ContextBrokerClient with a principal's token.

A principal subscribes to an entity it may read and its notification arrives at an HTTP receiver
this test runs; subscribing to an entity it may not read, or with a ``kafka://`` notification, is
403 with Orion's error body naming the principal; it lists only its own subscriptions (FiLiP's
"already exists" check included) and cannot see or delete another principal's (404); plantkg's
token sees every one. When the plant takes the right away, ``apply`` restarts the broker with the
new principals file and the subscription stops notifying (plantkg's own on the same entity goes on).
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
import requests

from engine import netutil, process
from engine.cli import main
from tests.integration.agents import AgentFleet, secret_files, start_agents
from tests.integration.test_context_broker_principals import PLANT

filip_cb = pytest.importorskip("filip.clients.ngsi_v2")
from filip.clients.exceptions import BaseHttpClientException  # noqa: E402
from filip.models.base import FiwareHeader  # noqa: E402
from filip.models.ngsi_v2.subscriptions import Subscription  # noqa: E402

pytestmark = pytest.mark.integration

HOST = "127.0.0.3"
RECEIVER_HOST = "127.0.0.1"
ROBOT_TOKEN, PLANNER_TOKEN = "robot1-Sub-Token-3c9e", "planner-Sub-Token-8d21"
NOT_ITS_OWN = "urn:ngsi-ld:Secret:1"  # an entity neither principal may read
REFUSED = (BaseHttpClientException, requests.HTTPError)

# robot1 writes its status and reads its task; the planner the other way round (the plant of
# test_context_broker_principals)


class Receiver:
    """An HTTP receiver on a free port: records each notification's JSON body."""

    def __init__(self) -> None:
        self.port = netutil.free_port(RECEIVER_HOST)
        self.bodies: list[dict[str, Any]] = []
        self.lock = threading.Lock()
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                with receiver.lock:
                    receiver.bodies.append(json.loads(body))
                self.send_response(200)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                return None

        self.server = ThreadingHTTPServer((RECEIVER_HOST, self.port), Handler)
        self.server.daemon_threads = True
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    @property
    def url(self) -> str:
        return f"http://{RECEIVER_HOST}:{self.port}/notify"

    def seqs(self, entity_id: str, sub_id: str | None = None) -> list[int]:
        with self.lock:
            return [e["seq"]["value"] for b in self.bodies for e in b["data"]
                    if e["id"] == entity_id and sub_id in (None, b["subscriptionId"])]

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@dataclass
class Deployment:
    fleet: AgentFleet
    plant: Path
    port: int
    receiver: Receiver
    ids: dict[str, str] = field(default_factory=dict)   # topic name -> entity id
    subs: dict[str, str] = field(default_factory=dict)  # who -> subscription id

    @property
    def agent_token(self) -> str:
        return self.fleet.agents[HOST].token

    def request(self, method: str, path: str, body: object = None, token: str | None = None) -> tuple[int, Any]:
        headers = {"Accept": "application/json"}
        if token is not None:
            headers["Authorization"] = f"Bearer {token}"
        answer = requests.request(method, f"http://{HOST}:{self.port}{path}", json=body, headers=headers,
                                  timeout=10)
        return answer.status_code, answer.json() if answer.content else None

    def filip(self, token: str) -> Any:
        session = requests.Session()
        session.headers.update({"authorization": f"Bearer {token}"})
        return filip_cb.ContextBrokerClient(url=f"http://{HOST}:{self.port}", session=session,
                                            fiware_header=FiwareHeader())

    def subscription(self, entity_id: str, entity_type: str, url: str | None = None) -> Subscription:
        return Subscription(**{"description": "seq", "subject": {
            "entities": [{"id": entity_id, "type": entity_type}], "condition": {"attrs": ["seq"]}},
            "notification": {"http": {"url": url or self.receiver.url}, "attrs": ["seq"]}})


@pytest.fixture(scope="module")
def dep(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    tmp = tmp_path_factory.mktemp("cb-principal-subs")
    secrets = secret_files(tmp / "secrets", {"robot1": ROBOT_TOKEN, "planner": PLANNER_TOKEN})
    fleet = start_agents([HOST], tmp / "agents")
    receiver = Receiver()
    try:
        port = netutil.free_port(HOST)
        plant = tmp / "plant.ttl"
        plant.write_text(PLANT.replace("{port}", str(port)).replace("{secrets}", str(secrets)), encoding="utf-8")
        yield Deployment(fleet, plant, port, receiver)
    finally:
        receiver.stop()
        fleet.stop()


def test_apply_deploys_the_closed_context_broker(dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["apply", str(dep.plant), "--agents", str(dep.fleet.agents_file), "--yes"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    dep.ids.update({t.name: t.entity_id for t in dep.fleet.brokers()["cb"].topics})
    status = {"id": dep.ids["agv/1/status"], "type": "AgvStatus", "seq": {"type": "Number", "value": 0}}
    assert dep.request("POST", "/v2/entities", status, ROBOT_TOKEN)[0] == 201


def test_a_principal_subscribes_to_what_it_may_read_and_is_notified(dep: Deployment) -> None:
    status_id = dep.ids["agv/1/status"]
    planner = dep.filip(PLANNER_TOKEN)
    dep.subs["planner"] = planner.post_subscription(dep.subscription(status_id, "AgvStatus"))
    for seq in (1, 2, 3):
        code, _ = dep.request("PATCH", f"/v2/entities/{status_id}/attrs", {"seq": {"type": "Number", "value": seq}},
                              ROBOT_TOKEN)
        assert code == 204
    process.wait_until(lambda: dep.receiver.seqs(status_id)[-1:] == [3], 20, 0.05,
                       what="the planner's notifications of the robot's status")
    assert dep.receiver.seqs(status_id) == [1, 2, 3]
    shown = planner.get_subscription(dep.subs["planner"])
    assert shown.notification.timesSent == 3 and shown.status == "active"


def test_a_principal_may_not_subscribe_to_what_it_may_not_read(dep: Deployment) -> None:
    planner = dep.filip(PLANNER_TOKEN)
    with pytest.raises(REFUSED):
        planner.post_subscription(dep.subscription(NOT_ITS_OWN, "Secret"))
    doc = {"subject": {"entities": [{"id": NOT_ITS_OWN}]}, "notification": {"http": {"url": dep.receiver.url}}}
    status, answer = dep.request("POST", "/v2/subscriptions", doc, PLANNER_TOKEN)
    assert status == 403 and set(answer) == {"error", "description"} and answer["error"] == "Forbidden"
    assert "'planner'" in answer["description"] and repr(NOT_ITS_OWN) in answer["description"], answer
    # a pattern, or a notification that would reach the plant's Kafka as plantkg: refused too
    pattern = {**doc, "subject": {"entities": [{"idPattern": ".*"}]}}
    kafka = {"subject": {"entities": [{"id": dep.ids["agv/1/status"]}]},
             "notification": {"kafka": {"url": "kafka://127.0.0.3:9092", "topic": "t"}}}
    for body in (pattern, kafka):
        status, answer = dep.request("POST", "/v2/subscriptions", body, PLANNER_TOKEN)
        assert status == 403 and "'planner'" in answer["description"], answer
    assert [s.id for s in planner.get_subscription_list()] == [dep.subs["planner"]]


def test_a_principal_sees_only_its_own_subscriptions_and_plantkg_sees_all(dep: Deployment) -> None:
    robot = dep.filip(ROBOT_TOKEN)
    # the same subscription as the planner's: FiLiP looks for it in the robot's listing, which
    # holds only the robot's own, so it creates one instead of returning the planner's id
    dep.subs["robot"] = robot.post_subscription(dep.subscription(dep.ids["agv/1/status"], "AgvStatus"))
    assert dep.subs["robot"] != dep.subs["planner"]
    assert [s.id for s in robot.get_subscription_list()] == [dep.subs["robot"]]
    with pytest.raises(REFUSED):
        robot.get_subscription(dep.subs["planner"])
    with pytest.raises(REFUSED):
        robot.delete_subscription(dep.subs["planner"])
    status, answer = dep.request("DELETE", f"/v2/subscriptions/{dep.subs['planner']}", None, ROBOT_TOKEN)
    assert (status, answer["error"]) == (404, "NotFound")
    # the planner's is still there, and plantkg's token sees both
    assert [s.id for s in dep.filip(PLANNER_TOKEN).get_subscription_list()] == [dep.subs["planner"]]
    status, listed = dep.request("GET", "/v2/subscriptions", None, dep.agent_token)
    assert status == 200 and {s["id"] for s in listed} == {dep.subs["planner"], dep.subs["robot"]}
    robot.delete_subscription(dep.subs["robot"])
    assert robot.get_subscription_list() == []


def test_a_right_taken_away_silences_the_subscription(dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    status_id, planners = dep.ids["agv/1/status"], dep.subs["planner"]
    text = dep.plant.read_text(encoding="utf-8")
    dep.plant.write_text(text.replace("pk:publishes :task ; pk:subscribes :status ;", "pk:publishes :task ;"),
                         encoding="utf-8")
    code = main(["apply", str(dep.plant), "--agents", str(dep.fleet.agents_file), "--yes"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    # (another URL: FiLiP with plantkg's token, which sees every subscription, would find the planner's)
    plantkgs = dep.filip(dep.agent_token).post_subscription(
        dep.subscription(status_id, "AgvStatus", url=dep.receiver.url + "/plantkg"))
    assert dep.request("PATCH", f"/v2/entities/{status_id}/attrs", {"seq": {"type": "Number", "value": 10}},
                       ROBOT_TOKEN)[0] == 204
    # the match (and its log line) happens before the write is answered
    log = dep.fleet.agents[HOST].state_dir / "brokers" / "cb" / "logs" / "ngsi-v2.log"
    assert f"subscription {planners} of principal 'planner' does not notify" in log.read_text(encoding="utf-8")
    process.wait_until(lambda: dep.receiver.seqs(status_id, plantkgs) == [10], 20, 0.05,
                       what="plantkg's notification of seq 10")
    assert 10 not in dep.receiver.seqs(status_id, planners)
    # still the planner's to see and delete
    planner = dep.filip(PLANNER_TOKEN)
    assert [s.id for s in planner.get_subscription_list()] == [planners]
    planner.delete_subscription(planners)


def test_destroy_leaves_nothing(dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["destroy", str(dep.plant), "--agents", str(dep.fleet.agents_file), "--yes"])
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    assert "cb" not in dep.fleet.brokers()

"""Subscriptions by a principal of a closed context broker (engine.context_broker.access and
.subscriptions.ownership), through Flask's test client over a real store and subscription service:
a principal subscribes only to entities it names by id and may read, with HTTP notifications only
(403 with Orion's body, naming the principal and the entity or target); it sees, changes, deletes
and lists only its own subscriptions (another's is 404); plantkg's token sees every one; the
owner is stored with the subscription and read back by the next start; a subscription whose owner
lost the right (or is gone) does not notify."""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from engine.context_broker.access import Gate
from engine.context_broker.app import create_app
from engine.context_broker.store import ContextStore
from engine.context_broker.contract import EntityChange, Tenant
from engine.context_broker.subscriptions import SubscriptionService
from engine.context_broker.subscriptions.model import HttpTarget
from engine.context_broker.subscriptions.outbox import Outbox
from engine.context_broker.subscriptions.ownership import PLANTKG, Requester, lapsed
from engine.context_broker.subscriptions.registry import SUBSCRIPTIONS_FILE
from engine.context_broker.subscriptions.result import Result
from engine.security.ngsi_principals import load_principals, render_principals

AGENT = "agent-token-1"
ROBOT, PLANNER = "robot-secret", "planner-secret"
# robot1 writes the pose and reads the task; the planner writes the task and reads the pose
PRINCIPALS = {"robot1": (ROBOT, ("urn:pose:1",), ("urn:task:1",)),
              "planner": (PLANNER, ("urn:task:1",), ("urn:pose:1",))}
HTTP = {"http": {"url": "http://127.0.0.1:9/notify"}}


def sub(*entities: dict[str, str], notification: dict[str, Any] | None = None) -> dict[str, Any]:
    return {"subject": {"entities": list(entities)}, "notification": notification or HTTP}


class Broker:
    """A closed context broker's app with subscriptions, restartable over the same folder."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        file = folder / "principals.json"
        file.write_text(render_principals(PRINCIPALS), encoding="utf-8")
        self.gate = Gate(AGENT, load_principals(file))
        self._open()

    def _open(self) -> None:
        self.store = ContextStore(self.folder / "data")
        self.service = SubscriptionService(self.folder / "subs", owners=self.gate.owners())
        app = create_app(self.store, token=AGENT, gate=self.gate, listeners=[self.service],
                         subscriptions_blueprint=self.service.blueprint())
        self.client = app.test_client()

    def close(self) -> None:
        self.service.close()
        self.store.close()

    def restart(self) -> None:
        self.close()
        self._open()

    def send(self, method: str, path: str, body: Any = None, token: str = AGENT) -> Any:
        headers = {"Authorization": f"Bearer {token}"}
        if body is not None:
            headers["Content-Type"] = "application/json"
        return self.client.open(path, method=method, headers=headers,
                                data=None if body is None else json.dumps(body))

    def create(self, body: dict[str, Any], token: str) -> str:
        reply = self.send("POST", "/v2/subscriptions", body, token)
        assert reply.status_code == 201, reply.json
        return reply.headers["Location"].rsplit("/", 1)[1]

    def listed(self, token: str) -> list[str]:
        reply = self.send("GET", "/v2/subscriptions?limit=1000", None, token)
        assert reply.status_code == 200, reply.json
        return [s["id"] for s in reply.json]


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    b = Broker(tmp_path)
    yield b
    b.close()


def forbidden(reply: Any, *words: str) -> None:
    assert reply.status_code == 403, (reply.status_code, reply.data)
    assert reply.mimetype == "application/json" and set(reply.json) == {"error", "description"}
    assert reply.json["error"] == "Forbidden"
    for word in words:
        assert word in reply.json["description"], (word, reply.json)


# (token, subscription, what the answer is: 201, or 403 and the words its description holds)
CREATE_CASES = [
    ("reads what it may read", ROBOT, sub({"id": "urn:task:1"}), 201, ()),
    ("reads its own entity", ROBOT, sub({"id": "urn:pose:1", "type": "Pose"}), 201, ()),
    ("each of several ids", PLANNER, sub({"id": "urn:pose:1"}, {"id": "urn:task:1"}), 201, ()),
    ("https and httpCustom", PLANNER, sub({"id": "urn:pose:1"}, notification={"httpCustom": {
        "url": "https://planner.example:8443/n", "headers": {"X-A": "1"}}}), 201, ()),
    ("an entity it may not read", ROBOT, sub({"id": "urn:other:1"}), 403, ("'robot1'", "'urn:other:1'")),
    ("one of two it may not read", ROBOT, sub({"id": "urn:task:1"}, {"id": "urn:secret:1"}), 403,
     ("'robot1'", "'urn:secret:1'")),
    ("an idPattern", PLANNER, sub({"idPattern": ".*"}), 403, ("'planner'", "by id", "'.*'")),
    ("a typePattern only", PLANNER, sub({"idPattern": "urn:pose:.*", "typePattern": ".*"}), 403, ("by id",)),
    ("an MQTT notification", PLANNER, sub({"id": "urn:pose:1"}, notification={"mqtt": {
        "url": "mqtt://127.0.0.1:1883", "topic": "t"}}), 403, ("'planner'", "mqtt://", "http://")),
    ("a Kafka notification", PLANNER, sub({"id": "urn:pose:1"}, notification={"kafka": {
        "url": "kafka://127.0.0.1:9092", "topic": "t"}}), 403, ("'planner'", "kafka://", "plantkg's own")),
    ("plantkg: a pattern", AGENT, sub({"idPattern": ".*"}), 201, ()),
    ("plantkg: Kafka", AGENT, sub({"id": "urn:x:1"}, notification={"kafka": {
        "url": "kafka://127.0.0.1:9092", "topic": "t"}}), 201, ()),
]


@pytest.mark.parametrize(("token", "body", "status", "words"), [c[1:] for c in CREATE_CASES],
                         ids=[c[0] for c in CREATE_CASES])
def test_what_a_principal_may_subscribe_to(broker: Broker, token: str, body: dict[str, Any], status: int,
                                           words: tuple[str, ...]) -> None:
    reply = broker.send("POST", "/v2/subscriptions", body, token)
    if status == 403:
        forbidden(reply, *words)
        assert broker.listed(AGENT) == []  # nothing refused was stored
    else:
        assert reply.status_code == status, reply.json


def test_a_principal_sees_changes_and_deletes_only_its_own(broker: Broker) -> None:
    robots = broker.create(sub({"id": "urn:task:1"}), ROBOT)
    planners = broker.create(sub({"id": "urn:pose:1"}), PLANNER)
    plantkgs = broker.create(sub({"idPattern": ".*"}), AGENT)
    assert broker.listed(ROBOT) == [robots] and broker.listed(PLANNER) == [planners]
    assert broker.listed(AGENT) == [robots, planners, plantkgs]
    count = broker.send("GET", "/v2/subscriptions?options=count", None, ROBOT)
    assert count.headers["Fiware-Total-Count"] == "1"
    for other in (planners, plantkgs):  # another's is not found, whatever the verb
        for method, body in (("GET", None), ("PATCH", {"throttling": 5}), ("DELETE", None)):
            reply = broker.send(method, f"/v2/subscriptions/{other}", body, ROBOT)
            assert (reply.status_code, reply.json["error"]) == (404, "NotFound"), (method, reply.json)
    assert broker.send("GET", f"/v2/subscriptions/{robots}", None, ROBOT).json["id"] == robots
    assert broker.send("PATCH", f"/v2/subscriptions/{robots}", {"throttling": 5}, ROBOT).status_code == 204
    # a change is checked as the subscription it makes: no entity or target it may not hold
    forbidden(broker.send("PATCH", f"/v2/subscriptions/{robots}", {"subject": {"entities": [
        {"id": "urn:other:1"}]}}, ROBOT), "'urn:other:1'")
    forbidden(broker.send("PATCH", f"/v2/subscriptions/{robots}", {"notification": {"kafka": {
        "url": "kafka://127.0.0.1:9092", "topic": "t"}}}, ROBOT), "kafka://")
    shown = broker.send("GET", f"/v2/subscriptions/{robots}", None, AGENT).json
    assert shown["throttling"] == 5 and shown["subject"]["entities"] == [{"id": "urn:task:1"}]
    assert "http" in shown["notification"] and "owner" not in shown  # Orion's shape, no owner
    # plantkg's token changes and deletes any
    assert broker.send("PATCH", f"/v2/subscriptions/{planners}", {"throttling": 7}, AGENT).status_code == 204
    assert broker.send("DELETE", f"/v2/subscriptions/{planners}", None, AGENT).status_code == 204
    assert broker.send("DELETE", f"/v2/subscriptions/{robots}", None, ROBOT).status_code == 204
    assert broker.listed(AGENT) == [plantkgs] and broker.listed(ROBOT) == []


def test_the_owner_is_stored_with_the_subscription_and_kept_by_a_restart(broker: Broker) -> None:
    robots = broker.create(sub({"id": "urn:task:1"}), ROBOT)
    plantkgs = broker.create(sub({"id": "urn:task:1"}), AGENT)
    broker.send("PATCH", f"/v2/subscriptions/{robots}", {"throttling": 3}, AGENT)  # plantkg's change keeps it
    stored = json.loads((broker.folder / "subs" / SUBSCRIPTIONS_FILE).read_text(encoding="utf-8"))
    assert {s["id"]: s.get("owner") for s in stored["subscriptions"]} == {robots: "robot1", plantkgs: None}
    broker.restart()
    assert broker.listed(ROBOT) == [robots] and broker.listed(PLANNER) == []
    assert broker.listed(AGENT) == [robots, plantkgs]
    assert broker.send("GET", f"/v2/subscriptions/{robots}", None, PLANNER).status_code == 404


def test_a_principals_tokens_are_still_checked_first(broker: Broker) -> None:
    for token in ("guess", ROBOT + "x"):
        reply = broker.send("POST", "/v2/subscriptions", sub({"id": "urn:task:1"}), token)
        assert (reply.status_code, reply.json["error"]) == (401, "Unauthorized")
        assert broker.send("GET", "/v2/subscriptions", None, token).status_code == 401


ROBOT_NOW = Requester("robot1", frozenset({"urn:pose:1", "urn:task:1"}))
# (owner of a subscription to urn:task:1, the broker's principals as it runs, why it lapsed or None)
LAPSE_CASES = [
    ("plantkg's own", None, {}, None),
    ("its owner still reads it", "robot1", {"robot1": ROBOT_NOW}, None),
    ("its owner lost the right", "robot1", {"robot1": Requester("robot1", frozenset({"urn:pose:1"}))},
     "may not read entity 'urn:task:1'"),
    ("its owner is gone", "robot1", {"planner": Requester("planner", frozenset({"urn:task:1"}))},
     "no principal of this context broker"),
]


@pytest.mark.parametrize(("owner", "owners", "why"), [c[1:] for c in LAPSE_CASES], ids=[c[0] for c in LAPSE_CASES])
def test_a_subscription_lapses_when_its_owner_may_no_longer_hold_it(tmp_path: Path, owner: str | None,
                                                                    owners: dict[str, Requester],
                                                                    why: str | None) -> None:
    service = SubscriptionService(tmp_path)
    try:
        who = PLANTKG if owner is None else ROBOT_NOW
        made = service.create(Tenant(), sub({"id": "urn:task:1"}), who)
        got = lapsed(made, owners)
        assert (got is None) if why is None else (why in (got or "")), got
    finally:
        service.close()


class Recorder:
    """The HTTP sender's place: records each notification's URL (no receiver needed); ``down``:
    each attempt fails, to be retried (what is queued stays in the outbox at close)."""

    def __init__(self, down: bool = False) -> None:
        self.urls: list[str] = []
        self.down = down
        self.lock = threading.Lock()

    def send(self, target: HttpTarget, msg: Any) -> Result:
        with self.lock:
            self.urls.append(target.url)
        return Result.temporary("receiver down") if self.down else Result.success(204)

    def close(self) -> None:
        return None


def test_a_lapsed_subscription_does_not_notify_and_plantkgs_still_does(tmp_path: Path,
                                                                       caplog: pytest.LogCaptureFixture) -> None:
    recorder = Recorder()
    # the robot's right to read the task is gone from the principals the broker runs with
    service = SubscriptionService(tmp_path, senders={HttpTarget: recorder},
                                  owners={"robot1": Requester("robot1", frozenset({"urn:pose:1"}))})
    service.start()
    try:
        robots = service.create(Tenant(), sub({"id": "urn:task:1"}, notification={"http": {
            "url": "http://127.0.0.1:9/robot"}}), ROBOT_NOW)
        service.create(Tenant(), sub({"id": "urn:task:1"}, notification={"http": {
            "url": "http://127.0.0.1:9/plantkg"}}))
        task = {"id": "urn:task:1", "type": "T", "v": {"type": "Number", "value": 1, "metadata": {}}}
        with caplog.at_level(logging.WARNING):
            for _ in range(2):
                service.entity_changed(EntityChange(tenant=Tenant(), entity=task, changed=frozenset({"v"}),
                                                    created=True))
        lapsed_lines = [r.getMessage() for r in caplog.records if "does not notify" in r.getMessage()]
        assert len(lapsed_lines) == 1 and robots.id in lapsed_lines[0], lapsed_lines  # logged once
        process.wait_until(lambda: len(recorder.urls) == 2, 10, 0.01, what="plantkg's notifications")
        assert recorder.urls == ["http://127.0.0.1:9/plantkg"] * 2
        assert service.registry.status_of(robots.id).times_sent == 0
    finally:
        service.close()


def test_what_a_lapsed_subscription_left_undelivered_is_not_sent_after_the_restart(tmp_path: Path) -> None:
    task = {"id": "urn:task:1", "type": "T", "v": {"type": "Number", "value": 1, "metadata": {}}}
    down = Recorder(down=True)
    service = SubscriptionService(tmp_path, senders={HttpTarget: down}, backoff=lambda attempt: 600.0,
                                  owners={"robot1": ROBOT_NOW})
    service.start()
    try:
        service.create(Tenant(), sub({"id": "urn:task:1"}, notification={"http": {
            "url": "http://127.0.0.1:9/robot"}}), ROBOT_NOW)
        plantkgs = service.create(Tenant(), sub({"id": "urn:task:1"}, notification={"http": {
            "url": "http://127.0.0.1:9/plantkg"}}))
        service.entity_changed(EntityChange(tenant=Tenant(), entity=task, changed=frozenset({"v"}), created=True))
        process.wait_until(lambda: len(down.urls) == 2, 10, 0.01, what="the first attempts")
    finally:
        service.close()  # both notifications stay in the outbox
    # the robot's right to read the task is gone when the broker starts again
    again = SubscriptionService(tmp_path, senders={HttpTarget: Recorder(down=True)}, backoff=lambda attempt: 600.0,
                                owners={"robot1": Requester("robot1", frozenset({"urn:pose:1"}))})
    try:
        assert again.outbox.pending() == 2  # both read back
        again.start()
        # the robot's is let go at once (settled); plantkg's is queued again and, its receiver
        # still down, stays in the outbox
        assert again.outbox.pending() == 1
    finally:
        again.close()
    left = Outbox(tmp_path)
    try:
        assert [m.subscription_id for m in left.recover()] == [plantkgs.id]
    finally:
        left.close()

"""The manager's hooks for the task planner, through its real loopback HTTP API (the MQTT link is
the recording one of test_manager_service): ``agvPosition`` in the vehicle rows and status.json,
``POST /v1/instantActions`` (checked field by field, 409 unless ONLINE) and 503 ``NotReady``
until the records are loaded; and :func:`fleet.manager.instant.parse` as cases."""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from fleet.discovery.inbox import AgvPosition, StateSeen, classify
from fleet.manager import apply_step, instant
from fleet.manager.api import ApiServer
from fleet.manager.plant import binding_and_address
from fleet.manager.service import FleetManager, ManagerConfig
from tests.unit.fleet import discovery_data as d
from tests.unit.fleet.test_manager_service import PLANT, RecordingLink

POSITION = {"x": 3.5, "y": 6.25, "theta": 1.5, "mapId": "hall-1", "positionInitialized": True}


def call(api: ApiServer, method: str, path: str, body: Any = None, token: str | None = None) -> tuple[int, Any]:
    token = token if token is not None else (api.data_dir / "manager.token").read_text().strip()
    data = json.dumps(body).encode() if body is not None else None
    request = urllib.request.Request(api.url + path, data=data, method=method,
                                     headers={"Authorization": f"Bearer {token}"})
    try:
        with urllib.request.urlopen(request, timeout=10) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[FleetManager, RecordingLink, ApiServer]]:
    binding, address = binding_and_address([PLANT])
    config = ManagerConfig((PLANT,), tmp_path, address, binding, batch_window=0.1, poll_interval=0.1,
                           status_interval=0.05, resync=3600)
    link = RecordingLink()
    manager = FleetManager(config, apply_step.check, link=link)  # type: ignore[arg-type]
    api = ApiServer(manager, tmp_path)
    api.start(0)
    try:
        yield manager, link, api  # each test runs the manager's loop itself (and stops it)
    finally:
        api.stop()


def start(manager: FleetManager) -> threading.Thread:
    thread = threading.Thread(target=manager.run)
    thread.start()
    return thread


def join(manager: FleetManager, link: RecordingLink, serial: str) -> None:
    link.put(d.topic("connection", "acme", serial), d.connection("ONLINE", "acme", serial), retained=True)
    link.put(d.topic("factsheet", "acme", serial), d.factsheet("acme", serial))
    process.wait_until(lambda: any(v["serial"] == serial and v["readySeconds"] is not None
                                   for v in manager.snapshot), 20.0, what=f"{serial} joined")


def test_vehicles_answer_503_until_the_records_are_loaded_then_the_list(served: Any) -> None:
    manager, link, api = served
    status, body = call(api, "GET", "/v1/vehicles")
    assert (status, body["error"]) == (503, "NotReady") and "ask again" in body["description"]
    assert call(api, "GET", "/v1/vehicles/v-1")[0] == 503
    assert call(api, "POST", "/v1/instantActions", {"serial": "v-1", "actionType": "cancelOrder"})[0] == 503
    thread = start(manager)
    try:
        status, body = process.wait_until(lambda: (r := call(api, "GET", "/v1/vehicles"))[0] == 200 and r, 10.0,
                                          what="the list after loading")
        assert body == []
    finally:
        manager.stop()
        thread.join(20)


def test_the_state_position_reaches_the_rows_and_status_json(served: Any) -> None:
    manager, link, api = served
    thread = start(manager)
    try:
        join(manager, link, "v-1")
        link.put(d.topic("state", "acme", "v-1"), d.state("acme", "v-1", agvPosition=POSITION))
        row = process.wait_until(lambda: (r := call(api, "GET", "/v1/vehicles/v-1")[1]) and r.get("state") and r,
                                 10.0, what="v-1's state")
        assert row["state"]["agvPosition"] == POSITION
        listed = call(api, "GET", "/v1/vehicles")[1]
        assert listed[0]["state"]["agvPosition"] == POSITION
        saved = process.wait_until(lambda: (s := json.loads((manager.data.root / "status.json").read_text()))
                                   ["vehicles"][0]["state"] and s, 10.0, what="status.json with the state")
        assert saved["vehicles"][0]["state"]["agvPosition"] == POSITION
    finally:
        manager.stop()
        thread.join(20)


def test_a_state_without_a_position_has_none() -> None:
    event = classify(d.topic("state", "acme", "v-1"), d.wire(d.state("acme", "v-1")))
    assert isinstance(event, StateSeen) and event.state.position is None
    assert event.state.to_json()["agvPosition"] is None
    event = classify(d.topic("state", "acme", "v-1"), d.wire(d.state("acme", "v-1", agvPosition=POSITION)))
    assert event.state.position == AgvPosition(3.5, 6.25, 1.5, "hall-1", True)


def test_instant_actions_are_checked_and_sent_only_to_online_vehicles(served: Any) -> None:
    manager, link, api = served
    thread = start(manager)
    try:
        join(manager, link, "v-1")
        join(manager, link, "v-2")
        before = list(link.sent)
        for body, status, fragment in [
            ([], 400, "JSON object"),
            ({"actionType": "cancelOrder"}, 400, "serial"),
            ({"serial": "v-1"}, 400, "actionType"),
            ({"serial": "v-1", "actionType": "pick"}, 400, "actionType: 'pick' is not a predefined"),
            ({"serial": "v-1", "actionType": "cancelOrder", "actionParameters": {"a": 1}}, 400, "actionParameters"),
            ({"serial": "v-1", "actionType": "cancelOrder", "actionParameters": [{"key": ""}]}, 400,
             "actionParameters[0]"),
            ({"serial": "v-1", "actionType": "cancelOrder", "priority": 1}, 400, "priority"),
            ({"serial": "nobody", "actionType": "cancelOrder"}, 404, "nobody"),
        ]:
            got, answer = call(api, "POST", "/v1/instantActions", body)
            assert (got, answer["error"] != "InternalError") == (status, True), (body, answer)
            assert fragment in answer["description"], (body, answer)
        assert link.sent == before  # nothing sent for a refused request
        got, answer = call(api, "POST", "/v1/instantActions",
                           {"serial": "v-1", "manufacturer": "acme", "actionType": "startPause",
                            "actionParameters": [{"key": "reason", "value": "test"}]})
        assert got == 201 and answer["actionType"] == "startPause" and answer["vehicle"] == "acme/v-1"
        assert answer["topic"] == "uagv/v2/acme/v-1/instantActions"
        assert link.sent[-1] == ("acme", "v-1", "startPause") and link.parameters[0].key == "reason"
        link.put(d.topic("connection", "acme", "v-2"), d.connection("CONNECTIONBROKEN", "acme", "v-2"))
        process.wait_until(lambda: call(api, "GET", "/v1/vehicles/v-2")[1]["connectionState"] == "CONNECTIONBROKEN",
                           10.0, what="v-2 unavailable")
        got, answer = call(api, "POST", "/v1/instantActions", {"serial": "v-2", "actionType": "cancelOrder"})
        assert got == 409 and "CONNECTIONBROKEN" in answer["description"]
        assert link.sent[-1] == ("acme", "v-1", "startPause")
    finally:
        manager.stop()
        thread.join(20)


@pytest.mark.parametrize("body, fragment", [
    (None, "JSON object"),
    ({"serial": 5, "actionType": "cancelOrder"}, "serial: expected a non-empty string, got 5"),
    ({"serial": "a", "manufacturer": "", "actionType": "cancelOrder"}, "manufacturer"),
    ({"serial": "a", "actionType": "drop"}, "'drop' is not a predefined VDA 5050 2.1 instant action"),
    ({"serial": "a", "actionType": "waitForTrigger"}, "waitForTrigger"),
    ({"serial": "a", "actionType": "cancelOrder", "actionParameters": [{"key": 1, "value": 2}]},
     "actionParameters[0].key"),
    ({"serial": "a", "actionType": "cancelOrder", "actionParameters": [{"key": "k"}] * 51}, "at most 50"),
])
def test_bad_instant_action_requests_name_the_field(body: Any, fragment: str) -> None:
    with pytest.raises(instant.InstantActionError) as caught:
        instant.parse(body)
    assert fragment in caught.value.message


@pytest.mark.parametrize("action_type", instant.INSTANT_ACTIONS)
def test_every_instant_action_is_accepted(action_type: str) -> None:
    request = instant.parse({"serial": "a", "actionType": action_type})
    assert request.action("id-1").to_json() == {"actionType": action_type, "actionId": "id-1", "blockingType": "NONE"}


def test_the_mqtt_link_checks_an_instant_action_against_the_official_schema_before_sending() -> None:
    from fleet.manager.mqtt_link import MqttLink
    from fleet.vda5050.errors import SchemaError
    from fleet.vda5050.messages import ActionParameter

    link = MqttLink("127.0.0.1", 1)  # never connected: nothing leaves this process
    sent: list[tuple[str, dict[str, Any]]] = []
    link.publish = lambda topic, message, subtopic: sent.append((topic, message))  # type: ignore[method-assign]
    with pytest.raises(SchemaError) as caught:
        link.instant_action("acme", "v-1", "startPause", (ActionParameter("k", None),))
    assert "actionParameters/0/value" in caught.value.message and sent == []
    action_id = link.instant_action("acme", "v-1", "cancelOrder")
    [(topic, message)] = sent
    assert topic == "uagv/v2/acme/v-1/instantActions"
    assert message["actions"] == [{"actionType": "cancelOrder", "actionId": action_id, "blockingType": "NONE"}]

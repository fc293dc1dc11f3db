"""The planner's event sources, their pure parts as cases (an MQTT topic and payload -> an event,
an Orion notification -> events, each refusal naming its field), and the way in: a real planner
(vehicles as data) fires, types and journals what a source delivers, counts what it refuses, and
the notification endpoint answers over HTTP (400 naming the field, the refused entities listed)."""

from __future__ import annotations

import json
import socket
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine.process import wait_until
from fleet.planner.__main__ import main
from fleet.planner.api import ApiServer, NotifyServer
from fleet.planner.event_sources import EventMessageError, Refusal, Tally
from fleet.planner.events_mqtt import check_prefix, client_id, event_of
from fleet.planner.events_ngsi import NgsiEvents, description_for, differs, events_of, subscription
from fleet.planner.plantview import PlantView
from fleet.planner.service import Planner
from tests.unit.fleet.planner_data import JOBS
from tests.unit.fleet.test_planner_cli import EXAMPLE, MAP
from tests.unit.fleet.test_planner_service import GivenFleet, planner_on
from tests.unit.fleet.test_planner_service import plant as plant  # noqa: F401 - the module's fixture

PREFIX = "plantkg/events"

MQTT_GOOD = [  # (id, topic, payload, (name, value))
    ("true", "plantkg/events/Loaded", b"true", ("Loaded", True)),
    ("a number", "plantkg/events/count", b"3.5", ("count", 3.5)),
    ("an integer", "plantkg/events/count", b"7", ("count", 7)),
    ("a string", "plantkg/events/mode", b'"manual"', ("mode", "manual")),
    ("an object with value", "plantkg/events/Loaded", b'{"value": false}', ("Loaded", False)),
    ("spaces around", "plantkg/events/Loaded", b" true\n", ("Loaded", True)),
]

MQTT_BAD = [  # (id, topic, payload, field, in the reason)
    ("not JSON", "plantkg/events/Loaded", b"yes", "payload", "not JSON"),
    ("empty", "plantkg/events/Loaded", b"", "payload", "not JSON"),
    ("not UTF-8", "plantkg/events/Loaded", b"\xff\xfe", "payload", "not JSON"),
    ("null", "plantkg/events/Loaded", b"null", "payload", "boolean, number or string"),
    ("a list", "plantkg/events/Loaded", b"[true]", "payload", "boolean, number or string"),
    ("an object without value", "plantkg/events/Loaded", b'{"v": 1}', "payload", "must be {\"value\": ...}"),
    ("an object with more keys", "plantkg/events/Loaded", b'{"value": 1, "at": 2}', "payload", "['at', 'value']"),
    ("a nested value", "plantkg/events/Loaded", b'{"value": {"a": 1}}', "payload", "boolean, number or string"),
    ("another prefix", "other/events/Loaded", b"true", "topic", "is not plantkg/events/<event name>"),
    ("a deeper topic", "plantkg/events/a/Loaded", b"true", "topic", "is not plantkg/events/<event name>"),
    ("no name", "plantkg/events/", b"true", "topic", "is not plantkg/events/<event name>"),
]


@pytest.mark.parametrize(("topic", "payload", "expected"), [c[1:] for c in MQTT_GOOD], ids=[c[0] for c in MQTT_GOOD])
def test_mqtt_message_to_event(topic: str, payload: bytes, expected: tuple[str, Any]) -> None:
    assert event_of(topic, payload, PREFIX) == expected


@pytest.mark.parametrize(("topic", "payload", "field", "text"), [c[1:] for c in MQTT_BAD], ids=[c[0] for c in MQTT_BAD])
def test_mqtt_message_refused_naming_the_field(topic: str, payload: bytes, field: str, text: str) -> None:
    with pytest.raises(EventMessageError) as caught:
        event_of(topic, payload, PREFIX)
    assert caught.value.field == field and text in caught.value.reason, str(caught.value)


@pytest.mark.parametrize(("given", "expected"), [("plantkg/events", "plantkg/events"), ("a/b/", "a/b"),
                                                 ("site-1", "site-1")])
def test_prefix(given: str, expected: str) -> None:
    assert check_prefix(given) == expected


@pytest.mark.parametrize("given", ["", "/", "a/+", "a/#", "a//b", "/a"])
def test_prefix_refused(given: str) -> None:
    with pytest.raises(EventMessageError, match="--events-topic"):
        check_prefix(given)


def test_client_id_and_description_are_stable_per_data_dir() -> None:
    assert client_id(Path("/a")) == client_id(Path("/a")) != client_id(Path("/b"))
    assert description_for(Path("/a")) == description_for(Path("/a")) != description_for(Path("/b"))
    assert not set(description_for(Path("/a"))) & set("<>\"'=;()")  # NGSI-v2's forbidden characters


def entity(eid: Any, value: Any, etype: Any = "Event") -> dict[str, Any]:
    return {"id": eid, "type": etype, "value": {"type": "Boolean", "value": value, "metadata": {}}}


def test_notification_fires_each_entity_and_refuses_the_bad_ones_one_by_one() -> None:
    body = {"subscriptionId": "5f0c", "data": [
        entity("Loaded", True), 7, entity("x", True, "Task"), {"id": "y", "type": "Event"},
        {"id": "z", "type": "Event", "value": 3}, entity("", True), entity("w", None), entity("count", 4)]}
    fire, refused = events_of(body)
    assert fire == [("Loaded", True), ("count", 4)]
    assert refused == [
        ("data[1]", "data[1]: expected an entity object, got int"),
        ("x", "data[2].type: expected 'Event', got 'Task'"),
        ("y", "data[3].value: expected a normalized attribute {\"type\", \"value\"}, got None"),
        ("z", "data[4].value: expected a normalized attribute {\"type\", \"value\"}, got 3"),
        ("data[5]", "data[5].id: expected the Event's name, got ''"),
        ("w", "data[6].value.value: an event's value is a boolean, number or string, got None"),
    ]


NOTIFY_BAD = [  # (id, body, field)
    ("a list", [1], "body"),
    ("no subscriptionId", {"data": []}, "subscriptionId"),
    ("a number as subscriptionId", {"subscriptionId": 3, "data": []}, "subscriptionId"),
    ("no data", {"subscriptionId": "a"}, "data"),
    ("data an object", {"subscriptionId": "a", "data": {"id": "Loaded"}}, "data"),
]


@pytest.mark.parametrize(("body", "field"), [c[1:] for c in NOTIFY_BAD], ids=[c[0] for c in NOTIFY_BAD])
def test_notification_body_refused_as_a_whole(body: Any, field: str) -> None:
    with pytest.raises(EventMessageError) as caught:
        events_of(body)
    assert caught.value.field == field


def stored(wanted: dict[str, Any], **changes: Any) -> dict[str, Any]:
    """``wanted`` as the context broker lists it: with an id, a status and its delivery counters."""
    out = json.loads(json.dumps(wanted))
    out.update({"id": "0123456789abcdef01234567", "status": "active"})
    out["notification"].update({"timesSent": 3, "lastSuccess": "2026-01-01T00:00:00.000Z"})
    for path, value in changes.items():
        node = out
        *parents, last = path.split(".")
        for key in parents:
            node = node[key]
        node[last] = value
    return out


DIFFS = [  # (id, changes, fields that differ)
    ("the same", {}, []),
    ("failed is still active", {"status": "failed"}, []),
    ("moved", {"notification.httpCustom.url": "http://127.0.0.1:9/v1/ngsi/notify"}, ["notification.httpCustom.url"]),
    ("another token", {"notification.httpCustom.headers": {"Authorization": "Bearer x"}},
     ["notification.httpCustom.headers"]),
    ("inactive", {"status": "inactive"}, ["status"]),
    ("keyValues", {"notification.attrsFormat": "keyValues"}, ["notification.attrsFormat"]),
    ("another condition", {"subject.condition.attrs": []}, ["subject.condition.attrs"]),
]


@pytest.mark.parametrize(("changes", "fields"), [c[1:] for c in DIFFS], ids=[c[0] for c in DIFFS])
def test_a_stored_subscription_is_reused_or_patched(changes: dict[str, Any], fields: list[str]) -> None:
    wanted = subscription("plantkg task planner events 1", "http://127.0.0.1:8/v1/ngsi/notify", "t")
    assert differs(stored(wanted, **changes), wanted) == fields


# ---------------------------------------------------------------------- through a real planner
@pytest.fixture
def planner(tmp_path: Path, plant: PlantView) -> Iterator[Planner]:  # noqa: F811
    p = planner_on(tmp_path / "data", GivenFleet(), plant, [])
    try:
        yield p
    finally:
        p.journal.close()


def test_tally_fires_through_the_planner_and_counts_refusals(planner: Planner, tmp_path: Path) -> None:
    tally = Tally("mqtt", planner.fire)
    record = tally.deliver("plantkg/events/Loaded", "Loaded", True)
    assert isinstance(record, dict) and record["event"] == "loaded" and record["number"] == 1
    unknown = tally.deliver("plantkg/events/nope", "nope", True)
    typed = tally.deliver("plantkg/events/Loaded", "Loaded", "yes")
    assert isinstance(unknown, Refusal) and "'nope' is no Event" in unknown.reason
    assert isinstance(typed, Refusal) and "value: Event loaded is of type Boolean" in typed.reason
    tally.refuse("plantkg/events/x", "payload: not JSON")
    status = tally.status()
    assert (status["received"], status["fired"], status["refused"]) == (4, 1, 3)
    assert [r["where"] for r in status["lastRefusals"]] == ["plantkg/events/nope", "plantkg/events/Loaded",
                                                              "plantkg/events/x"]
    lines = [json.loads(x) for x in (tmp_path / "data" / "journal.jsonl").read_text().splitlines()]
    assert [(x["kind"], x["event"], x["value"]) for x in lines if x["kind"] == "event"] == [("event", "loaded", True)]


def post(url: str, token: str | None, body: bytes) -> tuple[int, Any]:
    headers = {"Content-Type": "application/json", **({"Authorization": f"Bearer {token}"} if token else {})}
    request = urllib.request.Request(url, data=body, method="POST", headers=headers)
    try:
        with urllib.request.urlopen(request, timeout=5) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def test_the_notification_endpoint_over_http(planner: Planner, tmp_path: Path) -> None:
    data = tmp_path / "data"
    events = NgsiEvents("http://127.0.0.1:9", None, planner.fire, description_for(data), "unused")
    notify = NotifyServer(events.notify, data)
    api = ApiServer(planner, data, sources={"ngsi": events.status})
    notify.start(pid=0)
    api.start(pid=0)
    try:
        token = (data / "planner-notify.token").read_text().strip()
        assert token != (data / "planner.token").read_text().strip()
        body = {"subscriptionId": "s1", "data": [entity("Unloaded", True), entity("Loaded", "yes"), entity("ghost", 1)]}
        status, answer = post(notify.notify_url, token, json.dumps(body).encode())
        assert status == 200, answer
        assert [(e["event"], e["value"]) for e in answer["fired"]] == [("unloaded", True)]
        assert [r["id"] for r in answer["refused"]] == ["Loaded", "ghost"]
        assert "value: Event loaded is of type Boolean" in answer["refused"][0]["reason"]
        # the whole body bad: 400 naming the field, nothing fired
        status, answer = post(notify.notify_url, token, b'{"subscriptionId": "s1", "data": 5}')
        assert status == 400 and answer["description"].startswith("data:"), answer
        assert post(notify.notify_url, token, b"{nope")[0] == 400
        # the planner's own token is not this one, and this one opens nothing else
        assert post(notify.notify_url, (data / "planner.token").read_text().strip(), b"{}")[0] == 401
        assert post(notify.url + "/v1/events", token, b'{"event": "Loaded", "value": true}')[0] == 404
        # the counts in GET /v1/tasks
        request = urllib.request.Request(api.url + "/v1/tasks", headers={
            "Authorization": f"Bearer {(data / 'planner.token').read_text().strip()}"})
        with urllib.request.urlopen(request, timeout=5) as reply:
            snapshot = json.loads(reply.read())
        ngsi = snapshot["eventSources"]["ngsi"]
        assert (snapshot["events"], ngsi["received"], ngsi["fired"], ngsi["refused"]) == (1, 3, 1, 2)
    finally:
        notify.stop()
        api.stop()


def test_without_a_context_broker_the_subscription_is_retried_and_the_reason_shown(planner: Planner,
                                                                                   tmp_path: Path) -> None:
    with socket.socket() as probe:  # a port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    events = NgsiEvents(f"http://127.0.0.1:{port}", None, planner.fire, "d", "t", timeout=1.0, retry=0.05)
    events.start("http://127.0.0.1:9/v1/ngsi/notify")
    try:
        status = wait_until(lambda: (s := events.status())["lastError"] and s, 10.0, 0.01, what="the reason shown")
        assert status["subscription"] is None and status["lastError"].startswith("GET /v2/subscriptions"), status
    finally:
        events.stop()
    assert not events._thread.is_alive()


# ---------------------------------------------------------------------- the command line
CLI_BAD = [  # (id, extra arguments, in stderr)
    ("--events-ngsi without a context broker", ["--events-ngsi"], "--events-ngsi needs --ngsi-url"),
    ("--events-mqtt without a port", ["--events-mqtt", "127.0.0.1"], "expected HOST:PORT"),
    ("--events-mqtt port 0", ["--events-mqtt", "127.0.0.1:0"], "a port from 1 to 65535"),
    ("a wildcard prefix", ["--events-mqtt", "127.0.0.1:1883", "--events-topic", "plantkg/#"], "--events-topic"),
    ("--events-ngsi-listen not HOST:PORT", ["--events-ngsi-listen", "here"], "expected HOST:PORT"),
]


@pytest.mark.parametrize(("extra", "expected"), [c[1:] for c in CLI_BAD], ids=[c[0] for c in CLI_BAD])
def test_unusable_event_options_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str],
                                       expected: str) -> None:
    (tmp_path / "jobs.tl").write_text(JOBS, encoding="utf-8")
    (tmp_path / "map.json").write_text(MAP, encoding="utf-8")
    data = tmp_path / "planner-data"
    argv = ["--plant", str(EXAMPLE), "--lotlan", str(tmp_path / "jobs.tl"), "--data-dir", str(data),
            "--manager-data-dir", str(tmp_path / "no-manager"), "--map", str(tmp_path / "map.json"), *extra]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's refusal
        code = exc.code
    assert code == 2
    assert expected in capsys.readouterr().err
    assert not data.exists()

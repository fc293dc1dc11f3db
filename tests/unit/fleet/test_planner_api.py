"""The planner's HTTP API on loopback (a real server in the test process, the vehicles given as
data): the token, and every bad request answered with a JSON 4xx naming the field, never a 500."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from fleet.planner.api import ApiServer
from fleet.planner.plantview import PlantView
from tests.unit.fleet.test_planner_service import GivenFleet, planner_on
from tests.unit.fleet.test_planner_service import plant as plant  # noqa: F401 - the module's fixture


@pytest.fixture
def api(tmp_path: Path, plant: PlantView) -> Iterator[tuple[str, str]]:  # noqa: F811
    planner = planner_on(tmp_path / "data", GivenFleet(), plant, [])
    server = ApiServer(planner, tmp_path / "data")
    server.start(pid=0)
    try:
        yield server.url, (tmp_path / "data" / "planner.token").read_text().strip()
    finally:
        server.stop()
        planner.journal.close()


def call(api: tuple[str, str], method: str, path: str, body: bytes | None = None,
         token: str | None = None) -> tuple[int, Any]:
    url, good = api
    request = urllib.request.Request(url + path, data=body, method=method,
                                     headers={"Authorization": f"Bearer {good if token is None else token}"})
    try:
        with urllib.request.urlopen(request, timeout=5) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


BAD = [  # (id, method, path, body, status, in the description)
    ("not JSON", "POST", "/v1/events", b"{nope", 400, "not JSON"),
    ("a list, not an object", "POST", "/v1/events", b"[1]", 400, "must be a JSON object"),
    ("no value", "POST", "/v1/events", b'{"event": "loaded"}', 400, "value: missing"),
    ("an unknown event", "POST", "/v1/events", b'{"event": "x", "value": true}', 404, "'x' is no Event"),
    ("tasks not a list", "POST", "/v1/jobs", b'{"tasks": "first"}', 400, "tasks: expected a list"),
    ("an unknown task", "POST", "/v1/jobs", b'{"tasks": ["ghost"]}', 400, "'ghost' is no Task"),
    ("an unknown task id", "GET", "/v1/tasks/j9-x-1", None, 404, "no task 'j9-x-1'"),
    ("withdraw an unknown task", "POST", "/v1/tasks/j9-x-1/withdraw", b"{}", 404, "no task"),
    ("an unknown path", "GET", "/v1/nothing", None, 404, "no such resource"),
    ("a wrong method", "POST", "/v1/tasks", b"{}", 405, "no such resource"),
]


@pytest.mark.parametrize(("method", "path", "body", "status", "text"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_requests(api: tuple[str, str], method: str, path: str, body: bytes | None, status: int, text: str) -> None:
    got, answer = call(api, method, path, body)
    assert got == status and text in answer["description"], answer
    assert call(api, "GET", "/v1/tasks")[1]["tasks"] == []  # nothing half-done


def test_the_token_is_required(api: tuple[str, str]) -> None:
    status, answer = call(api, "GET", "/v1/tasks", token="wrong")
    assert status == 401 and "planner.token" in answer["description"]


def test_a_job_its_tasks_an_event_and_a_withdrawal(api: tuple[str, str]) -> None:
    # the start tasks: third follows chain (OnDone), so it is not one
    assert call(api, "POST", "/v1/jobs", b"{}") == (201, {"job": "j1", "tasks": ["j1-first-1", "j1-second-1", "j1-chain-1"]})
    status, task = call(api, "GET", "/v1/tasks/j1-first-1")
    assert status == 200 and [leg["station"] for leg in task["legs"]] == ["load-1", "unload-1"]
    status, event = call(api, "POST", "/v1/events", b'{"event": "Loaded", "value": true}')
    assert status == 201 and event["event"] == "loaded" and event["number"] == 1
    assert call(api, "POST", "/v1/tasks/j1-first-1/withdraw", b"{}")[1]["state"] == "WITHDRAWN"
    assert call(api, "POST", "/v1/tasks/j1-first-1/withdraw", b"{}")[0] == 409

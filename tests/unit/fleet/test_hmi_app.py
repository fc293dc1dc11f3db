"""The HMI's Flask app with Flask's test client, against a real planner API and a real manager API
on loopback (fleet.planner.api / fleet.manager.api servers in the test process; the planner's
vehicles and the manager's rows given as data): the login, the CSRF refusal of every POST, bad
input answered 400/404/409 naming the field, a planner or manager that does not answer shown on
the page (never a 500), and a job started, its pick waiting, **Loaded** pressed, the pick done."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from flask.testing import FlaskClient

import fleet.lotlan
from fleet.hmi.app import HmiConfig, create_app
from fleet.hmi.errors import UpstreamDown
from fleet.hmi.upstream import ManagerLink, PlannerLink, Recent
from fleet.manager.api import ApiServer as ManagerApi
from fleet.planner.api import ApiServer as PlannerApi
from fleet.planner.journal import Journal
from fleet.planner.machine import SendOrder
from fleet.planner.plantview import PlantView
from fleet.planner.service import Planner, PlannerConfig
from tests.unit.fleet.planner_data import JOBS, SITE
from tests.unit.fleet.test_planner_service import GivenFleet
from tests.unit.fleet.test_planner_service import plant as plant  # noqa: F401 - the module's fixture

TOKEN = "hmi-test-token-0123456789"


class GivenManager:
    """The manager's vehicle rows as data (what fleet.manager.service would list)."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = [
            {"topicManufacturer": "t", "serial": "a-1", "connectionState": "ONLINE",
             "state": {"batteryCharge": 90.0, "driving": False}}]

    def vehicles(self) -> list[dict[str, Any]]:
        return self.rows

    def send_order(self, body: Any) -> dict[str, Any]:
        raise AssertionError("the HMI sends no orders")

    def request_reconcile(self) -> None:
        raise AssertionError("the HMI reconciles nothing")


@dataclass
class Rig:
    client: FlaskClient
    planner: Planner
    given: GivenFleet
    sent: list[SendOrder]
    planner_dir: Path
    manager_dir: Path


def make_client(tmp: Path, planner_dir: Path, manager_dir: Path) -> FlaskClient:
    lotlan = tmp / "jobs.tl"
    lotlan.write_text(JOBS, encoding="utf-8")
    config = HmiConfig(fleet.lotlan.load(lotlan), SITE, PlannerLink(data_dir=planner_dir, timeout=2.0),
                       ManagerLink(manager_dir, timeout=2.0), TOKEN, share=0.0)  # every call asks (Recent: below)
    app = create_app(config)
    app.config["TESTING"] = True
    return app.test_client()


@pytest.fixture
def rig(tmp_path: Path, plant: PlantView) -> Iterator[Rig]:  # noqa: F811
    given, sent = GivenFleet(), []
    given.put("a-1", 5.0, 4.0)
    planner = Planner(PlannerConfig(SITE, settle=0.0), fleet.lotlan.parse(JOBS, "jobs.tl"),
                      Journal(tmp_path / "planner"), given, plant, lambda order, vehicle: sent.append(order))
    planner_api = PlannerApi(planner, tmp_path / "planner")
    manager_api = ManagerApi(GivenManager(), tmp_path / "manager")
    planner_api.start(pid=0)
    manager_api.start(pid=0)
    try:
        yield Rig(make_client(tmp_path, tmp_path / "planner", tmp_path / "manager"), planner, given, sent,
                  tmp_path / "planner", tmp_path / "manager")
    finally:
        planner_api.stop()
        manager_api.stop()
        planner.journal.close()


def login(client: FlaskClient) -> str:
    page = client.get("/login").get_data(as_text=True)
    csrf = re.search(r'name="csrf_token" value="([^"]+)"', page).group(1)  # type: ignore[union-attr]
    reply = client.post("/login", data={"token": TOKEN, "csrf_token": csrf, "next": "/stations/load-1"})
    assert reply.status_code == 302 and reply.headers["Location"] == "/stations/load-1"
    page = client.get("/stations/load-1").get_data(as_text=True)
    return re.search(r'name="csrf-token" content="([^"]+)"', page).group(1)  # type: ignore[union-attr]


def test_everything_needs_the_login(rig: Rig) -> None:
    assert rig.client.get("/").status_code == 302 and "/login" in rig.client.get("/").headers["Location"]
    assert rig.client.get("/stations/load-1").status_code == 302
    for path in ("/api/fleet", "/api/site", "/api/stations/load-1"):
        reply = rig.client.get(path)
        assert reply.status_code == 401 and reply.json["error"] == "authentication required"


def test_a_wrong_token_does_not_log_in(rig: Rig) -> None:
    page = rig.client.get("/login").get_data(as_text=True)
    csrf = re.search(r'name="csrf_token" value="([^"]+)"', page).group(1)  # type: ignore[union-attr]
    reply = rig.client.post("/login", data={"token": "not-the-token-at-all", "csrf_token": csrf})
    assert reply.status_code == 401 and "not the token" in reply.get_data(as_text=True)
    assert rig.client.get("/api/fleet").status_code == 401


def test_every_post_needs_the_csrf_token(rig: Rig) -> None:
    csrf = login(rig.client)
    for headers in ({}, {"X-CSRF-Token": "wrong"}):
        for path, data in (("/api/stations/load-1/jobs", {"task": "first"}), ("/api/stations/load-1/loaded", {}),
                           ("/api/tasks/j1-first-1/withdraw", {})):
            reply = rig.client.post(path, data=data, headers=headers)
            assert reply.status_code == 403 and "CSRF" in reply.json["error"], reply.json
    assert rig.client.post("/logout").status_code == 403  # a page form too
    assert rig.planner.jobs == {} and rig.planner.events == []  # nothing was done
    assert rig.client.post("/api/stations/load-1/jobs", data={"task": "first"},
                           headers={"X-CSRF-Token": csrf}).status_code == 201


BAD = [  # (id, method, path, data, status, field, in the error)
    ("a task of another station", "POST", "/api/stations/load-1/jobs", {"task": "second"}, 400, "task",
     "'second' is no LoTLan task of station load-1"),
    ("no task", "POST", "/api/stations/load-1/jobs", {}, 400, "task", "None"),
    ("an unknown station", "POST", "/api/stations/nowhere/jobs", {"task": "first"}, 404, "station", "no station 'nowhere'"),
    ("a station without jobs", "GET", "/api/stations/park-1", None, 404, "station", "no station 'park-1'"),
    ("Loaded before the vehicle is there", "POST", "/api/stations/load-1/loaded", {}, 409, "button",
     "nothing at load-1 is ready to load"),
    ("no such button", "POST", "/api/stations/load-1/dance", {}, 404, "button", "the buttons are loaded, unloaded"),
    ("a task id with other characters", "POST", "/api/tasks/j1%21x/withdraw", {}, 400, "task", "'j1!x' is no task id"),
    ("a wrong state filter", "GET", "/api/fleet?state=DONE", None, 400, "state", "'DONE' is no task state"),
    ("a wrong vehicle filter", "GET", "/api/fleet?vehicle=a%20b", None, 400, "vehicle", "letters, digits"),
]


@pytest.mark.parametrize(("method", "path", "data", "status", "field", "text"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_bad_input_names_the_field(rig: Rig, method: str, path: str, data: dict[str, str] | None, status: int,
                                   field: str, text: str) -> None:
    csrf = login(rig.client)
    reply = rig.client.open(path, method=method, data=data, headers={"X-CSRF-Token": csrf})
    assert reply.status_code == status and reply.json["field"] == field and text in reply.json["error"], reply.json
    assert rig.planner.jobs == {} and rig.planner.events == []  # nothing half-done


def test_a_job_started_at_a_station_waits_for_loaded_and_the_button_finishes_the_pick(rig: Rig) -> None:
    csrf = login(rig.client)
    reply = rig.client.post("/api/stations/load-1/jobs", data={"task": "first"}, headers={"X-CSRF-Token": csrf})
    assert reply.status_code == 201 and reply.json == {"job": "j1", "tasks": ["j1-first-1"]}
    for _ in range(5):
        rig.planner.tick()
    assert [s.station for s in rig.sent] == ["load-1"]
    view = rig.client.get("/api/stations/load-1").json
    assert view["ready"] == "" and view["approaching"][0]["vehicle"] == "t/a-1"
    assert view["jobs"] == [{"job": "j1", "state": "BEING_PROCESSED", "tasks": [view["jobs"][0]["tasks"][0]]}]
    fleet = rig.client.get("/api/fleet?state=open&vehicle=a-1").json
    assert fleet["planner"] == {"ok": True} and fleet["manager"] == {"ok": True}
    assert [t["id"] for t in fleet["tasks"]] == ["j1-first-1"]
    assert fleet["vehicles"][0]["task"] == "j1-first-1" and fleet["vehicles"][0]["battery"] == 90.0
    rig.given.finish(rig.sent.pop(0))  # the vehicle arrived and picked
    rig.planner.tick()
    view = rig.client.get("/api/stations/load-1").json
    assert (view["ready"], view["loadReady"], view["unloadReady"]) == ("ready to load", True, False)
    assert rig.client.get("/api/stations/unload-1").json["ready"] == ""
    reply = rig.client.post("/api/stations/load-1/loaded", headers={"X-CSRF-Token": csrf})
    assert reply.status_code == 201 and [e["event"] for e in reply.json["fired"]] == ["loaded"]
    rig.planner.tick()
    task = rig.planner.task_json("j1-first-1")
    assert task["legs"][0]["state"] == "DONE" and [s.station for s in rig.sent] == ["unload-1"]
    assert rig.client.get("/api/stations/load-1").json["ready"] == ""


def test_pages_render_for_a_logged_in_operator(rig: Rig) -> None:
    login(rig.client)
    fleet = rig.client.get("/").get_data(as_text=True)
    assert '<svg id="map"' in fleet and 'href="/stations/unload-2"' in fleet
    station = rig.client.get("/stations/load-1").get_data(as_text=True)
    assert 'data-station="load-1"' in station and '<option value="first">' in station and 'id="loaded"' in station
    assert rig.client.get("/stations/park-1").status_code == 404
    site = rig.client.get("/api/site").json
    assert site["mapId"] == "hall-t" and {"task": "first", "from": "load-1", "to": "unload-1"} in site["routes"]
    reply = rig.client.get("/")
    assert "default-src 'self'" in reply.headers["Content-Security-Policy"]


def test_a_planner_or_manager_that_does_not_answer_is_shown_not_a_500(rig: Rig, tmp_path: Path) -> None:
    client = make_client(tmp_path, tmp_path / "no-planner", tmp_path / "no-manager")
    csrf = login(client)
    fleet = client.get("/api/fleet")
    assert fleet.status_code == 200
    assert fleet.json["planner"]["ok"] is False and "no task planner is running" in fleet.json["planner"]["error"]
    assert fleet.json["manager"]["ok"] is False and "no fleet manager runs" in fleet.json["manager"]["error"]
    station = client.get("/api/stations/load-1")
    assert station.status_code == 200 and station.json["planner"]["ok"] is False and station.json["jobs"] == []
    for path in ("/api/stations/load-1/jobs", "/api/stations/load-1/loaded"):
        reply = client.post(path, data={"task": "first"}, headers={"X-CSRF-Token": csrf})
        assert reply.status_code == 503 and reply.json["upstream"] == "planner", reply.json
    # a planner that was there and stopped: its address is known but nobody answers
    (tmp_path / "gone").mkdir()
    (tmp_path / "gone" / "planner.json").write_text('{"url": "http://127.0.0.1:9", "pid": 1}')
    (tmp_path / "gone" / "planner.token").write_text("x" * 20)
    client = make_client(tmp_path, tmp_path / "gone", rig.manager_dir)
    csrf = login(client)
    fleet = client.get("/api/fleet").json
    assert "does not answer" in fleet["planner"]["error"] and fleet["manager"] == {"ok": True}
    assert fleet["vehicles"][0]["key"] == "t/a-1"  # the manager's part still shows
    reply = client.post("/api/stations/load-1/jobs", data={"task": "first"}, headers={"X-CSRF-Token": csrf})
    assert reply.status_code == 503 and "does not answer" in reply.json["error"]


def test_a_refusal_of_the_planner_is_passed_on_a_wrong_planner_token_is_a_502(rig: Rig) -> None:
    (rig.planner_dir / "planner.token").write_text("a-token-the-planner-does-not-have")  # read per call
    csrf = login(rig.client)
    reply = rig.client.post("/api/stations/load-1/jobs", data={"task": "first"}, headers={"X-CSRF-Token": csrf})
    assert reply.status_code == 502 and reply.json["upstream"] == "planner" and "planner.token" in reply.json["error"]
    assert rig.client.get("/api/fleet").json["planner"]["ok"] is False


def test_recent_answers_are_shared_errors_too_and_forgotten_after_a_button() -> None:
    now = [0.0]
    calls: list[str] = []
    answers: list[Any] = [{"tasks": [1]}, UpstreamDown("planner", "the planner at x does not answer"), {"tasks": [2]}]

    def fetch() -> Any:
        calls.append("call")
        answer = answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer
    recent = Recent(fetch, ttl=0.25, clock=lambda: now[0])
    assert [recent.get() for _ in range(10)] == [{"tasks": [1]}] * 10 and len(calls) == 1
    now[0] = 0.3
    for _ in range(3):  # a planner that is down is asked once per ttl, not once per screen
        with pytest.raises(UpstreamDown, match="does not answer"):
            recent.get()
    assert len(calls) == 2
    recent.forget()  # a button was pressed: the next poll asks at once
    assert recent.get() == {"tasks": [2]} and len(calls) == 3


def test_a_hung_planner_costs_a_poll_at_most_its_timeout(rig: Rig, tmp_path: Path) -> None:
    import socket
    import time

    with socket.socket() as hung:  # accepts connections (backlog) and never answers
        hung.bind(("127.0.0.1", 0))
        hung.listen(8)
        (tmp_path / "hung").mkdir()
        (tmp_path / "hung" / "planner.json").write_text(f'{{"url": "http://127.0.0.1:{hung.getsockname()[1]}"}}')
        (tmp_path / "hung" / "planner.token").write_text("x" * 20)
        client = make_client(tmp_path, tmp_path / "hung", rig.manager_dir)
        login(client)
        start = time.monotonic()
        fleet = client.get("/api/fleet")
        took = time.monotonic() - start
    assert fleet.status_code == 200 and fleet.json["planner"]["ok"] is False and "does not answer" in fleet.json["planner"]["error"]
    assert fleet.json["manager"] == {"ok": True} and 1.5 < took < 4.0, took  # the 2 s timeout, not forever


def test_withdraw_a_task_and_the_planners_409_passed_on(rig: Rig) -> None:
    csrf = login(rig.client)
    assert rig.client.post("/api/stations/load-1/jobs", data={"task": "first"}, headers={"X-CSRF-Token": csrf}).status_code == 201
    reply = rig.client.post("/api/tasks/j1-first-1/withdraw", headers={"X-CSRF-Token": csrf})
    assert reply.status_code == 200 and reply.json["state"] == "WITHDRAWN"
    assert rig.planner.task_json("j1-first-1")["state"] == "WITHDRAWN"
    again = rig.client.post("/api/tasks/j1-first-1/withdraw", headers={"X-CSRF-Token": csrf})
    assert again.status_code == 409 and "WITHDRAWN already" in again.json["error"]
    unknown = rig.client.post("/api/tasks/j9-x-1/withdraw", headers={"X-CSRF-Token": csrf})
    assert unknown.status_code == 404 and "no task 'j9-x-1'" in unknown.json["error"]
    assert rig.client.get("/api/stations/load-1").json["jobs"][0]["state"] == "WITHDRAWN"


def test_the_fleet_page_lists_refused_vehicles_with_their_reason(rig: Rig) -> None:
    """Plug and play's refusals (the manager's status.json) are on the fleet page, as issue 11 asks."""
    login(rig.client)
    assert rig.client.get("/api/fleet").json["refused"] == []  # no status.json yet: nothing, no error
    (rig.manager_dir / "status.json").write_text(json.dumps({"refused": [
        {"vehicle": "acme/v-9", "reason": "the plant would be invalid with this vehicle: serial in use"},
        {"vehicle": 7, "reason": "malformed: left out"}, "junk"]}), encoding="utf-8")
    fleet = rig.client.get("/api/fleet").json
    assert fleet["refused"] == [{"vehicle": "acme/v-9",
                                 "reason": "the plant would be invalid with this vehicle: serial in use"}]
    assert {"interface", "pinned"} <= set(fleet["vehicles"][0])
    page = rig.client.get("/").get_data(as_text=True)
    assert 'id="refused"' in page

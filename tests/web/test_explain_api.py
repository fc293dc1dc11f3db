"""The dashboard's "why?" on a plan change: ``/api/explain`` gives what ``plantkg explain`` says."""

from __future__ import annotations

import re
from pathlib import Path

from flask.testing import FlaskClient

from engine.web.plant_state import PlantState
from tests.unit.fake_agents import FakeFleet
from tests.web.conftest import make_app

R1 = "R1 publisher and subscriber on different brokers require a bridge"


def test_explain_json_names_r1_and_both_resources(client: FlaskClient) -> None:
    r = client.get("/api/explain", query_string={"address": "bridge.mosquitto.kafka"})
    assert r.status_code == 200, r.get_data(as_text=True)
    body = r.get_json()
    assert body["required"] is True
    r1 = [x for x in body["reasons"] if x["rule"] == R1]
    assert len(r1) == 1
    subjects = {p["subject"] for p in r1[0]["premises"]}
    assert {"ROS machine (ros-machine)", "Historian database (historian)"} <= subjects


def test_explain_text_and_errors(client: FlaskClient) -> None:
    text = client.get("/api/explain", query_string={"address": "broker.kafka", "format": "text"})
    assert text.status_code == 200 and text.mimetype == "text/plain"
    assert text.get_data(as_text=True).startswith("broker.kafka is required:")
    gone = client.get("/api/explain", query_string={"address": "broker.nope"})
    assert gone.status_code == 200 and gone.get_json()["required"] is False
    assert "no broker has pk:id 'nope'" in gone.get_json()["note"]
    bad = client.get("/api/explain", query_string={"address": "bridge.mosquitto"})
    assert bad.status_code == 400 and "is not a plan address" in bad.get_json()["error"]
    missing = client.get("/api/explain")
    assert missing.status_code == 400


def test_explain_follows_the_plant_file(client: FlaskClient, plant_file: Path, state: PlantState) -> None:
    text = plant_file.read_text(encoding="utf-8")
    text, n = re.subn(r"\nrc:historian\n(?:    .*\n)+", "\n", text)
    assert n == 1
    text = text.replace("    pk:hasTopic rc:robot-position ;\n    pk:bridgesTo rc:kafka .\n",
                        "    pk:hasTopic rc:robot-position .\n")
    plant_file.write_text(text, encoding="utf-8")
    body = client.get("/api/explain", query_string={"address": "bridge.mosquitto.kafka"}).get_json()
    assert body["required"] is False and "no rule concludes pk:requiresBridge" in body["note"]


def test_plan_page_links_each_change_to_its_explanation(plant_file: Path) -> None:
    fleet = FakeFleet()  # agents that answer and run nothing: every item of the plant is to create
    state = PlantState([str(plant_file)], None, directory_loader=lambda _p: fleet.directory())
    state.reload()
    try:
        client = make_app(state).test_client()
        html = client.get("/plan").get_data(as_text=True)
        links = re.findall(r'<a class="why" href="([^"]+)">why\?</a>', html)
        assert len(links) == len(state.snapshot.plan.changes), html
        bridge = next(h for h in links if "bridge.mosquitto.kafka" in h)
        page = client.get(bridge.replace("&amp;", "&"))
        assert page.status_code == 200 and R1 in page.get_data(as_text=True)
    finally:
        state.close()

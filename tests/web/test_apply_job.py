"""Apply from the web, in the background, against the in-test agent double (orchestration only;
tests/web/test_browser.py does it with real agents and brokers): the job's progress and summary,
and --auto-apply after a re-read."""

from __future__ import annotations

from pathlib import Path

from flask.testing import FlaskClient

from engine import process
from engine.web.plant_state import PlantState
from tests.unit.fake_agents import FakeFleet
from tests.web.conftest import TOKEN, make_app


def finished(state: PlantState) -> str:
    return process.wait_until(lambda: state.snapshot.apply.state != "running" and state.snapshot.apply.state,
                              30.0, 0.02, what="the apply to finish")


def test_apply_runs_in_the_background_and_reports(plant_file: Path) -> None:
    fleet = FakeFleet()
    state = PlantState([str(plant_file)], None, directory_loader=lambda _p: fleet.directory())
    state.reload()
    client: FlaskClient = make_app(state).test_client()
    plan = client.get("/api/plan").json
    assert plan["plan"]["summary"]["create"] >= 2 and not fleet.brokers
    r = client.post("/api/apply", json={"fingerprint": plan["fingerprint"]}, headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 202
    assert finished(state) == "done"
    status = client.get("/api/status").json
    assert status["apply"]["summary"][0].startswith("Apply complete")
    assert any(line.startswith("done broker.kafka") for line in status["apply"]["progress"])
    assert {b["id"]: b["status"] for b in status["brokers"]} == {"kafka": "running", "mosquitto": "running"}
    assert status["plan"]["empty"] and set(fleet.brokers) == {"kafka", "mosquitto"}
    state.close()


def test_auto_apply_after_a_reread(plant_file: Path) -> None:
    fleet = FakeFleet()
    state = PlantState([str(plant_file)], None, auto_apply=True, directory_loader=lambda _p: fleet.directory())
    state.reload()
    assert finished(state) == "done" and state.snapshot.apply.by == "auto-apply"
    assert set(fleet.brokers) == {"kafka", "mosquitto"} and state.snapshot.plan.empty
    state.close()


def test_without_auto_apply_nothing_is_applied(plant_file: Path) -> None:
    fleet = FakeFleet()
    state = PlantState([str(plant_file)], None, directory_loader=lambda _p: fleet.directory())
    state.reload()
    assert state.snapshot.apply.state == "idle" and not fleet.brokers and not state.snapshot.plan.empty
    assert fleet.calls and {verb for _h, verb, _k in fleet.calls} <= {"list_brokers", "list_bridges"}  # only asked
    state.close()

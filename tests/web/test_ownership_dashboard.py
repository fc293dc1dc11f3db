"""The dashboard and ownership, against the in-test agent double: another plant's broker is shown
as foreign and never offered for deletion, and ``serve --auto-apply`` runs the reconcile loop
(a broker deleted behind its back comes back, a file dropped into a watched folder is applied)."""

from __future__ import annotations

import shutil
from pathlib import Path

from flask.testing import FlaskClient

from engine import process
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker
from engine.web.plant_state import PlantState
from tests.unit.fake_agents import FakeFleet
from tests.web.conftest import ROOT, TOKEN, make_app

ROBOT_CELL = "https://w3id.org/plantkg/examples/robot-cell"
OTHER = BrokerSpec("other", "urn:other:b", "other plant's", "mosquitto", "127.0.0.2", 1999)
EXTRA = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix rc: <https://w3id.org/plantkg/examples/robot-cell#> .
rc:extra a pk:Broker ; pk:id "extra" ; pk:name "dropped in" ; pk:brokerType "mosquitto" ;
    pk:ip "127.0.0.2" ; pk:port 1890 ; pk:hasTopic rc:extra-state .
rc:extra-state a pk:Topic ; pk:id "extra-state" ; pk:name "extra/state" ; pk:qos 0 .
"""


def test_another_plants_broker_is_foreign_and_never_deleted(plant_file: Path) -> None:
    fleet = FakeFleet()
    fleet.brokers["other"] = ObservedBroker(OTHER, BrokerStatus.RUNNING, pid=7, owner="plant-b")
    state = PlantState([str(plant_file)], None, directory_loader=lambda _p: fleet.directory())
    state.reload()
    client: FlaskClient = make_app(state).test_client()
    plan = client.get("/api/status").json["plan"]
    assert "broker.other" not in plan["pending"]
    assert {"address": "broker.other", "owner": "plant-b",
            "reason": "owned by plant plant-b: left alone"} in plan["foreign"]
    r = client.post("/api/apply", json={"fingerprint": state.snapshot.fingerprint},
                    headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 202
    process.wait_until(lambda: state.snapshot.apply.state in ("done", "failed"), 30.0, 0.02,
                       what="the apply")
    assert state.snapshot.apply.state == "done"
    assert fleet.brokers["other"].pid == 7 and fleet.brokers["mosquitto"].owner == ROBOT_CELL
    state.close()


def test_auto_apply_runs_the_reconcile_loop_on_files_and_folders(tmp_path: Path) -> None:
    plant, folder = tmp_path / "robot-cell.ttl", tmp_path / "found"
    shutil.copy(ROOT / "ontology" / "examples" / "robot-cell.ttl", plant)
    folder.mkdir()
    fleet = FakeFleet()
    state = PlantState([str(plant), str(folder)], None, auto_apply=True, observe_interval=0.3,
                       poll_interval=0.05, directory_loader=lambda _p: fleet.directory())
    state.start()
    try:
        process.wait_until(lambda: {"kafka", "mosquitto"} <= set(fleet.brokers), 30.0, 0.02,
                           what="the first apply")
        with fleet.lock:
            del fleet.brokers["mosquitto"]  # behind its back
        process.wait_until(lambda: "mosquitto" in fleet.brokers, 30.0, 0.02,
                           what="the loop to put the broker back")
        (folder / "extra.ttl").write_text(EXTRA)
        process.wait_until(lambda: "extra" in fleet.brokers, 30.0, 0.02,
                           what="the dropped file's broker")
        assert fleet.brokers["extra"].owner == ROBOT_CELL
        process.wait_until(lambda: state.snapshot.reconcile is not None, 10.0, 0.02,
                           what="the loop's run in the snapshot")
        assert state.snapshot.status["reconcile"]["error"] is None
        assert str(folder / "extra.ttl") in state.snapshot.files
    finally:
        state.close()

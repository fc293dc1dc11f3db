"""The fleet manager is plantkg's principal ``plantkg.fleet`` on its closed Mosquitto, with exactly
the VDA 5050 and paper topics the fleet rules (F1, F2) and the access rules (A1, A2) give it; a
vehicle with a ``pk:secretRef`` is a user with exactly its own channels (docs/security.md)."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.derive import derive
from engine.reasoning.reason import reason
from fleet.manager.mqtt_link import PRINCIPAL
from kg.load import load_plant
from kg.query import run_query

ROOT = Path(__file__).resolve().parents[3]
PLANT = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
VDA = "uagv/v2/plantkg-sim/sim-0001/"
CART = "cart-1/"


def closed_fleet(tmp_path: Path, extra: str = "") -> Path:
    """agv-fleet.ttl without pk:allowAnonymous on its Mosquitto (closed) and with ``extra``."""
    text = PLANT.read_text(encoding="utf-8").replace("    pk:allowAnonymous true ;\n", "")
    path = tmp_path / "agv-fleet.ttl"
    path.write_text(text + extra, encoding="utf-8")
    return path


@pytest.mark.parametrize("engine", ["fast", "owlready2"])
def test_the_fleet_manager_and_a_vehicle_get_exactly_their_topics(tmp_path: Path, engine: str) -> None:
    plant = load_plant([closed_fleet(tmp_path, 'af:agv-sim-0001 pk:secretRef "env:AGV_SIM_0001_PASSWORD" .\n')])
    reason(plant, engine=engine)  # type: ignore[arg-type]
    mqtt = derive(plant).broker("fleet-mqtt")
    assert mqtt is not None and mqtt.allow_anonymous is False
    users = {u.name: u for u in mqtt.users}
    fleet = users[PRINCIPAL]
    assert fleet.secret_ref == "plantkg:principal-key"
    # F2 + A1: the VDA 5050 master writes the vehicle's commands (the paper's go through the context broker)
    assert fleet.write == (VDA + "instantActions", VDA + "order")
    # F1 + A2: it reads what every vehicle publishes
    assert fleet.read == tuple(sorted([VDA + c for c in ("connection", "factsheet", "state", "visualization")]
                                      + [CART + c for c in ("description_channel", "movement_channel",
                                                            "status_channel")]))
    vehicle = users["agv-sim-0001"]
    assert (vehicle.secret_ref, vehicle.write, vehicle.read) == (
        "env:AGV_SIM_0001_PASSWORD",
        tuple(sorted(VDA + c for c in ("connection", "factsheet", "state", "visualization"))),
        (VDA + "instantActions", VDA + "order"))
    # cart-1 has no secret: no user, it cannot connect; nothing else but bridges' principals
    assert set(users) - {PRINCIPAL, "agv-sim-0001"} == {u for u in users if u.startswith("plantkg.bridge.")
                                                          or u.startswith("plantkg.notify.")}


def test_the_manager_logs_in_as_the_principal_its_type_names() -> None:
    result = run_query(load_plant([PLANT]), "SELECT ?name WHERE { fleet:fleet-manager pk:principalName ?name }")
    assert [str(row[0].value) for row in result.rows] == [PRINCIPAL]  # type: ignore[union-attr]

"""The fleet on a closed Mosquitto, end to end (issue 13): real agents, Mosquitto, the context
broker and its bridge worker, the fleet manager (``python -m fleet.manager``) and a simulated
vehicle (``python -m fleet.sim``) as processes.

One plant for the module: ontology/examples/agv-fleet.ttl on free ports, its Mosquitto closed (no
``pk:allowAnonymous``), its two vehicles given a ``pk:secretRef`` to a 0600 file of throwaway
password. What must hold:

- the fleet manager logs in as plantkg's principal ``plantkg.fleet`` (password from the principal
  key); the VDA 5050 vehicle logs in with its own password, joins by plug and play (its factsheet
  asked, written, applied) and executes an order sent through the manager;
- an anonymous client is refused;
- a vehicle cannot write the other vehicle's topics (its messages are dropped by the broker),
  while its own arrive;
- a vehicle in no plant file, admitted by a person (``plantkg fleet admit``), gets its user from
  the manager's next reconcile, joins, and loses its user again on ``plantkg fleet remove``.
"""

from __future__ import annotations

import json
import secrets
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from engine.cli import main
from engine.security import mqtt_client
from fleet.sim import map as site_map
from tests.integration.agents import AgentFleet, plant_copy
from tests.integration.fleet_rig import ROOT, managed_fleet, spawn_manager
from tests.integration.test_fleet_plug_and_play import CB_HOST, MQTT_HOST, Rig
from tests.integration.test_plant_access import Client

pytestmark = pytest.mark.integration

VEHICLES = {"agv-sim-0001": "sim-0001", "agv-cart-1": "cart-1"}  # pk:id -> serial


@pytest.fixture(scope="module")
def closed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Rig, dict[str, str], Path]]:
    tmp = tmp_path_factory.mktemp("fleet-closed")
    plant, ports = plant_copy("agv-fleet.ttl", tmp)
    passwords = {user: secrets.token_urlsafe(16) for user in VEHICLES}
    text = plant.read_text(encoding="utf-8").replace("    pk:allowAnonymous true ;\n", "")
    for user, serial in VEHICLES.items():
        secret = tmp / f"{serial}.pw"
        secret.write_text(passwords[user] + "\n", encoding="utf-8")
        secret.chmod(0o600)
        text += f'\naf:{user} pk:secretRef "file:{secret}" .\n'
    plant.write_text(text, encoding="utf-8")

    def start(agents: AgentFleet) -> Rig:
        manager = spawn_manager(plant, tmp / "fleet-data", agents.agents_file, tmp / "logs", "fleet-manager")
        return Rig(plant, tmp / "fleet-data", agents, manager, ports["fleet-mqtt"], ports["fleet-context"])

    # (its wait_started: connected as plantkg.fleet, for a closed broker refuses anybody else)
    with managed_fleet(plant, [MQTT_HOST, CB_HOST], tmp / "agents", start) as rig:
        yield rig, passwords, tmp


def _vehicles(rig: Rig, tmp: Path, count: int) -> process.Child:
    """Simulated VDA 5050 vehicles sim-0001.. on the closed broker, each logging in as
    ``agv-<serial>`` with the password in ``tmp/<serial>.pw``."""
    return process.spawn(
        [sys.executable, "-m", "fleet.sim", "--broker", f"{MQTT_HOST}:{rig.mqtt_port}", "--manufacturer",
         "plantkg-sim", "--serial-prefix", "sim-", "--count", str(count), "--state-interval", "1",
         "--username", "agv-{serial}", "--secret-ref", f"file:{tmp}/{{serial}}.pw"],
        log_dir=tmp / "logs", name=f"vehicles-{count}", cwd=ROOT)


def test_a_vehicle_with_its_password_joins_by_plug_and_play_and_takes_an_order(
        closed: tuple[Rig, dict[str, str], Path], capsys: pytest.CaptureFixture[str]) -> None:
    rig, _, tmp = closed
    vehicle = _vehicles(rig, tmp, 1)
    try:
        row = rig.wait(lambda: (v := rig.vehicle("sim-0001")) and v.get("readySeconds") is not None and v,
                       60.0, "sim-0001 discovered and applied")
        assert row["connectionState"] == "ONLINE" and "pick" in row["skills"], row
        assert [p.name for p in rig.discovered()] == ["plantkg-sim--sim-0001.ttl"]
        park = site_map.default_map().parking()[0]  # where vehicle 1 starts
        capsys.readouterr()
        code = main(["fleet", "order", "sim-0001", f"n0@{park.x},{park.y}", f"n1@{park.x + 1},{park.y}:pick",
                     "--order-id", "closed-1", "--data-dir", str(rig.data)])
        assert code == 0, capsys.readouterr()

        def finished() -> dict[str, Any] | None:
            state = (rig.vehicle("sim-0001") or {}).get("state") or {}
            actions = {a["actionStatus"] for a in state.get("actionStates", [])}
            return state if state.get("orderId") == "closed-1" and state.get("lastNodeId") == "n1" \
                and actions == {"FINISHED"} else None
        rig.wait(finished, 60.0, "the order executed (lastNodeId n1, pick FINISHED)")
    finally:
        assert process.stop(vehicle, grace=15.0) == 0, vehicle.log_tail()
    assert "refused the connection" not in rig.log() + vehicle.log_path.read_text(encoding="utf-8")


def test_an_anonymous_client_is_refused(closed: tuple[Rig, dict[str, str], Path]) -> None:
    rig, passwords, _ = closed
    anonymous = Client(rig.mqtt_port, host=MQTT_HOST)
    wrong = Client(rig.mqtt_port, "agv-sim-0001", passwords["agv-cart-1"], host=MQTT_HOST)
    try:
        assert anonymous.connack == wrong.connack == ["Not authorized"]
    finally:
        anonymous.close()
        wrong.close()


def test_a_vehicle_cannot_write_the_other_vehicles_topics(closed: tuple[Rig, dict[str, str], Path]) -> None:
    rig, passwords, _ = closed
    login = mqtt_client.principal_login("mosquitto", "plantkg.observer")
    assert login is not None
    observer = Client(rig.mqtt_port, login.username, login.password, host=MQTT_HOST)
    a = Client(rig.mqtt_port, "agv-sim-0001", passwords["agv-sim-0001"], host=MQTT_HOST)
    b = Client(rig.mqtt_port, "agv-cart-1", passwords["agv-cart-1"], host=MQTT_HOST)
    try:
        assert observer.connack == a.connack == b.connack == ["Success"]
        observer.client.subscribe("#", qos=1)
        own_a, own_b = "uagv/v2/plantkg-sim/sim-0001/visualization", "cart-1/movement_channel"
        # the observer's subscription holds once a message a may send arrives
        process.wait_until(lambda: (a.publish(own_a, b"a-ready"), b"a-ready" in observer.messages)[1],
                           15.0, 0.2, what="sim-0001's own message at the observer")
        a.publish("cart-1/status_channel", b'{"forged": "by sim-0001"}')
        a.publish("uagv/v2/plantkg-sim/sim-0002/state", b'{"forged": "by sim-0001"}')  # an unknown vehicle's
        a.publish(own_a, b"a-last")
        b.publish("uagv/v2/plantkg-sim/sim-0001/state", b'{"forged": "by cart-1"}')
        b.publish("uagv/v2/plantkg-sim/sim-0001/order", b'{"forged": "by cart-1"}')
        b.publish(own_b, json.dumps({"marker": "b-last"}).encode())
        process.wait_until(lambda: b"a-last" in observer.messages and any(b"b-last" in m for m in observer.messages),
                           15.0, what="each vehicle's last own message")
        assert not [m for m in observer.messages if b"forged" in m]
    finally:
        for client in (observer, a, b):
            client.close()


def _login(port: int, user: str, password: str) -> str:
    """The CONNACK reason a login gets from the fleet's Mosquitto; "refused" while the broker is
    between two processes (the manager's reconcile restarts it with its new users: since the agent
    wakes a stopping Mosquitto, that gap is no longer hidden by its old process lingering ~0.1 s)."""
    try:
        client = Client(port, user, password, host=MQTT_HOST)
    except ConnectionRefusedError:
        return "refused"
    try:
        return client.connack[0]
    finally:
        client.close()


def test_a_vehicle_the_plant_does_not_know_is_admitted_joins_and_is_taken_back(
        closed: tuple[Rig, dict[str, str], Path], capsys: pytest.CaptureFixture[str]) -> None:
    """``plantkg fleet admit``: sim-0002 is in no plant file; admitted while the manager runs, its
    user exists after the manager's next reconcile, it joins by plug and play (its factsheet fills
    in the admitted record), and ``plantkg fleet remove`` takes its user away."""
    rig, _, tmp = closed
    secret = tmp / "sim-0002.pw"
    assert not secret.exists()
    capsys.readouterr()
    code = main(["fleet", "admit", "sim-0002", str(rig.plant), "--manufacturer", "plantkg-sim",
                 "--secret-file", str(secret), "--data-dir", str(rig.data)])
    out = capsys.readouterr()
    assert code == 0, out.err
    password = secret.read_text(encoding="utf-8").strip()
    assert password not in out.out + out.err
    process.wait_until(lambda: _login(rig.mqtt_port, "agv-sim-0002", password) == "Success", 60.0, 0.2,
                       what="agv-sim-0002's user made by the manager's reconcile", child=rig.manager)
    vehicle = _vehicles(rig, tmp, 2)
    try:
        row = rig.wait(lambda: (v := rig.vehicle("sim-0002")) and v.get("readySeconds") is not None
                       and "pick" in v.get("skills", ()) and v, 60.0, "sim-0002 heard, described and applied")
        assert row["connectionState"] == "ONLINE", row
        text = (rig.data / "discovered" / "plantkg-sim--sim-0002.ttl").read_text(encoding="utf-8")
        assert f'pk:secretRef "file:{secret}"' in text and "fleet:discovered true" in text
        assert main(["fleet", "remove", "sim-0002", "--data-dir", str(rig.data)]) == 0
        process.wait_until(lambda: _login(rig.mqtt_port, "agv-sim-0002", password) == "Not authorized", 60.0,
                           0.2, what="agv-sim-0002's user removed by the manager's next reconcile",
                           child=rig.manager)
    finally:
        process.stop(vehicle, grace=15.0)
    assert _login(rig.mqtt_port, "agv-sim-0001", closed[1]["agv-sim-0001"]) == "Success"

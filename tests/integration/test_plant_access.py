"""Broker users and ACLs from a plant file, end to end (issue 13): ``plantkg plan`` / ``apply`` /
``destroy`` with a real agent and Mosquitto. The robot publishes its pose and reads commands, the
HMI reads the pose; both have a ``pk:secretRef`` to a file of throwaway password, so rules A1/A2
give them their rights and the broker is closed. What must hold: nobody else gets in, each user
does exactly what the plant says, and the password is in no output and no file but the 0600 hash.
"""

from __future__ import annotations

import secrets
import stat
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.drivers.mosquitto import dynsec
from engine.drivers.mosquitto.driver import USERS_FILE
from engine.agent.local import LocalAgents, start_local_agents
from tests.integration.plant_cli import run, secret_files

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/access-cell#> .
ex:m a pk:Broker ; pk:id "cell" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ;
    pk:port {port} ; pk:hasTopic ex:pose , ex:cmd .
ex:pose a pk:Topic ; pk:id "pose" ; pk:name "cell/pose" .
ex:cmd a pk:Topic ; pk:id "cmd" ; pk:name "cell/cmd" .
ex:robot a pk:Resource ; pk:id "robot1" ; pk:name "Robot" ; pk:sendsTo ex:m ; pk:publishes ex:pose ;
    pk:subscribes ex:cmd ; pk:secretRef "file:{robot_file}" .
ex:hmi a pk:Resource ; pk:id "hmi" ; pk:name "HMI" ; pk:sendsTo ex:m ; pk:subscribes ex:pose ;
    pk:secretRef "file:{hmi_file}" .
"""


class Client:
    """A paho client on a background loop recording its CONNACK and the messages it gets."""

    def __init__(self, port: int, user: str | None = None, password: str | None = None, host: str = HOST) -> None:
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"t-{uuid.uuid4().hex[:8]}")
        if user is not None:
            self.client.username_pw_set(user, password)
        self.connack: list[str] = []
        self.messages: list[bytes] = []
        self.client.on_connect = lambda _c, _u, _f, reason, _p: self.connack.append(str(reason))
        self.client.on_message = lambda _c, _u, msg: self.messages.append(msg.payload)
        self.client.connect(host, port, keepalive=10)
        self.client.loop_start()
        process.wait_until(lambda: self.connack, 10.0, what="a CONNACK")

    def publish(self, topic: str, payload: bytes) -> None:
        info = self.client.publish(topic, payload, qos=1)
        info.wait_for_publish(10.0)

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    tmp = tmp_path_factory.mktemp("plant-access")
    passwords = {"robot1": secrets.token_urlsafe(12), "hmi": secrets.token_urlsafe(12)}
    files = secret_files(tmp, passwords)
    port = netutil.free_port(HOST)
    plant = tmp / "cell.ttl"
    plant.write_text(PLANT.format(host=HOST, port=port, robot_file=files["robot1"], hmi_file=files["hmi"]),
                     encoding="utf-8")
    agents: LocalAgents = start_local_agents([HOST], tmp)
    try:
        yield {"plant": plant, "port": port, "agents": agents, "passwords": passwords,
               "folder": agents.agents[HOST].state_dir / "brokers" / "cell"}
    finally:
        try:
            agents.delete_all()
        finally:
            agents.stop()


def test_plan_shows_the_users_and_no_password(cell: dict, capsys) -> None:
    for fmt in ("text", "json"):
        code, out = run(capsys, "plan", cell["plant"], "--agents", cell["agents"].agents_file, "--format", fmt)
        assert code == 0, out
        assert "robot1" in out and "cell/pose" in out and "file:" in out, out
        for password in cell["passwords"].values():
            assert password not in out


def test_apply_closes_the_broker_to_all_but_its_users(cell: dict, capsys) -> None:
    code, out = run(capsys, "apply", cell["plant"], "--agents", cell["agents"].agents_file, "--yes")
    assert code == 0, out
    assert not any(p in out for p in cell["passwords"].values())
    port, pw = cell["port"], cell["passwords"]
    anonymous = Client(port)
    assert anonymous.connack == ["Not authorized"]
    anonymous.close()
    robot, hmi = Client(port, "robot1", pw["robot1"]), Client(port, "hmi", pw["hmi"])
    try:
        assert robot.connack == hmi.connack == ["Success"]
        hmi.client.subscribe("cell/pose", qos=1)
        robot.client.subscribe("cell/cmd", qos=1)
        # wait until hmi's subscription holds: a message robot1 may send arrives
        process.wait_until(lambda: (robot.publish("cell/pose", b"ready"), hmi.messages)[1], 10.0, 0.2,
                           what="robot1's pose at the HMI")
        hmi.publish("cell/pose", b"forged by the hmi")   # the HMI may only read: dropped
        robot.publish("cell/cmd", b"robot1 may only read cell/cmd")  # dropped: no write right
        robot.publish("cell/pose", b"last")
        process.wait_until(lambda: b"last" in hmi.messages, 10.0, what="the last pose")
        assert b"forged by the hmi" not in hmi.messages  # Mosquitto keeps one client's order
        assert robot.messages == []
    finally:
        robot.close()
        hmi.close()
    code, out = run(capsys, "plan", cell["plant"], "--agents", cell["agents"].agents_file)
    assert code == 0 and "No changes" in out, out


def test_no_file_but_the_hash_knows_the_password(cell: dict) -> None:
    folder: Path = cell["folder"]
    texts = {p.name: p.read_bytes() for p in folder.rglob("*") if p.is_file() and p.stat().st_size < 10_000_000}
    for password in cell["passwords"].values():
        assert not [name for name, data in texts.items() if password.encode() in data]
    mode = stat.S_IMODE((folder / USERS_FILE).stat().st_mode)
    assert mode == 0o600, oct(mode)
    assert dynsec.matches(texts[USERS_FILE].decode(), "robot1", cell["passwords"]["robot1"])


def test_destroy_leaves_nothing(cell: dict, capsys) -> None:
    code, out = run(capsys, "destroy", cell["plant"], "--agents", cell["agents"].agents_file, "--yes")
    assert code == 0, out
    assert cell["agents"].agents[HOST].client().list_brokers() == []
    assert not netutil.port_open(HOST, cell["port"])

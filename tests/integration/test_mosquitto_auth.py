"""A Mosquitto closed to anonymous clients, with users and ACLs, run by a real agent (issue 13).

One ``plantkg agent`` subprocess gets a BrokerSpec with the users of a robot cell — robot1 writes
``cell/pose`` and reads ``cell/cmd``, hmi reads ``cell/pose``, and plc writes ``cell/cmd`` (a third
user, so that a topic someone may write is also subscribed to by someone who may not read it) —
whose passwords it reads on its own machine: robot1's from a file, hmi's and plc's from the agent's
environment. Throwaway passwords, made per test run.

The broker's users file (the dynamic security plugin's, engine.drivers.mosquitto.dynsec) grants
every subscription and filters what it delivers, as Mosquitto 2.0's ACL file did (its author,
eclipse/mosquitto#2042): a topic a user may not read is never delivered to it, whatever the
SUBACK said. A publish on a topic a user may not write is acknowledged and dropped (MQTT 3.1.1).
Ordering makes "never delivered" checkable: Mosquitto handles one connection's packets in order and
writes each client's messages in order, so once a later message arrived, an earlier one would have. paho and Debian's ``mosquitto_pub``/``mosquitto_sub`` (independent clients; their ``-P``
shows the throwaway password in ps, acceptable in a test) then check what the broker admits.
"""

from __future__ import annotations

import json
import secrets
import shutil
import stat
import subprocess
import uuid
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.drivers.mosquitto import dynsec
from engine.drivers.mosquitto.driver import CONF_FILE, USERS_FILE, MosquittoDriver
from engine.errors import DispatchError
from engine.model import BrokerSpec, BrokerStatus, BrokerUser
from engine.security import principal_key, principals
from tests.integration.agents import AgentFleet, start_agents

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
HMI_ENV = "PLANTKG_TEST_HMI_PASSWORD"
PLC_ENV = "PLANTKG_TEST_PLC_PASSWORD"


class Mqtt:
    """A paho client on a background loop that records the CONNACK, SUBACKs and messages."""

    def __init__(self, port: int, user: str | None = None, password: str | None = None) -> None:
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"t-{uuid.uuid4().hex[:8]}")
        if user is not None:
            self.client.username_pw_set(user, password)
        self.connack: list[str] = []
        self.subacks: dict[int, list[int]] = {}
        self.messages: list[tuple[str, bytes]] = []
        self.client.on_connect = lambda _c, _u, _f, reason, _p: self.connack.append(str(reason))
        self.client.on_subscribe = lambda _c, _u, mid, codes, _p: self.subacks.__setitem__(
            mid, [c.value for c in codes])
        self.client.on_message = lambda _c, _u, msg: self.messages.append((msg.topic, msg.payload))
        self.client.connect(HOST, port, keepalive=10)
        self.client.loop_start()
        process.wait_until(lambda: self.connack, 10.0, what="a CONNACK")

    @property
    def accepted(self) -> bool:
        return self.connack[0] == "Success"

    def subscribe(self, topic: str) -> int:
        """The SUBACK's code for ``topic``: the granted QoS, or 0x80 (refused)."""
        _, mid = self.client.subscribe(topic, qos=1)
        return process.wait_until(lambda: self.subacks.get(mid), 10.0, what=f"SUBACK {topic}")[0]

    def publish(self, topic: str, payload: bytes) -> None:
        info = self.client.publish(topic, payload, qos=1)
        info.wait_for_publish(10.0)
        assert info.is_published()

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@pytest.fixture
def cell(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[dict]:
    """A closed broker on a real agent; yields its spec, folder and the throwaway passwords."""
    robot_pw, hmi_pw, plc_pw = (secrets.token_urlsafe(12) for _ in range(3))
    secret_file = tmp_path / "secrets" / "robot1"
    secret_file.parent.mkdir()
    secret_file.write_text(robot_pw + "\n")
    secret_file.chmod(0o600)
    monkeypatch.setenv(HMI_ENV, hmi_pw)  # the agent subprocess inherits them
    monkeypatch.setenv(PLC_ENV, plc_pw)
    fleet: AgentFleet = start_agents([HOST], tmp_path)
    try:
        spec = BrokerSpec(
            id="cell", iri="https://example.org/plant#cell", name="Cell", kind="mosquitto",
            host=HOST, port=netutil.free_port(HOST),
            users=(BrokerUser("hmi", f"env:{HMI_ENV}", read=("cell/pose",)),
                   BrokerUser("plc", f"env:{PLC_ENV}", write=("cell/cmd",)),
                   BrokerUser("robot1", f"file:{secret_file}", write=("cell/pose",),
                              read=("cell/cmd",))))
        observed = fleet.client(HOST).put_broker(spec)
        fleet.brokers()  # remembers the pid for the no-survivor check
        yield {"spec": spec, "observed": observed, "robot": robot_pw, "hmi": hmi_pw, "plc": plc_pw,
               "folder": fleet.agents[HOST].state_dir / "brokers" / "cell", "fleet": fleet}
        fleet.client(HOST).delete_broker("cell")
    finally:
        fleet.stop()


def test_closed_broker_admits_its_users_with_their_acls(cell: dict) -> None:
    spec, port = cell["spec"], cell["spec"].port
    # the agent's anonymous health check counts the refusal as an answer: the broker is running
    assert cell["observed"].status is BrokerStatus.RUNNING
    assert MosquittoDriver().health(spec, 2.0)

    anonymous = Mqtt(port)
    assert anonymous.connack == ["Not authorized"]
    anonymous.close()
    wrong = Mqtt(port, "robot1", cell["robot"] + "x")
    assert not wrong.accepted, wrong.connack
    wrong.close()
    unknown = Mqtt(port, "intruder", cell["robot"])
    assert not unknown.accepted, unknown.connack
    unknown.close()

    robot, hmi, plc = (Mqtt(port, "robot1", cell["robot"]), Mqtt(port, "hmi", cell["hmi"]),
                       Mqtt(port, "plc", cell["plc"]))
    try:
        assert robot.accepted and hmi.accepted and plc.accepted
        assert hmi.subscribe("cell/pose") == 1
        assert robot.subscribe("cell/cmd") == 1
        # hmi may not read cell/cmd: Mosquitto may refuse the subscription (0x80) or grant it
        # and deliver nothing (plantkg's users file); what matters is that nothing arrives
        assert hmi.subscribe("cell/cmd") in (1, 0x80)
        robot.publish("cell/cmd", b"robot1 may only read cell/cmd")   # dropped: no write right
        robot.publish("cell/other", b"robot1 may not write here")     # dropped
        hmi.publish("cell/pose", b"hmi may only read cell/pose")     # dropped
        robot.publish("cell/pose", b"x=1")
        process.wait_until(lambda: hmi.messages, 10.0, what="cell/pose at the hmi")
        plc.publish("cell/cmd", b"go")
        process.wait_until(lambda: robot.messages, 10.0, what="cell/cmd at robot1")
        robot.publish("cell/pose", b"x=2")
        process.wait_until(lambda: len(hmi.messages) >= 2, 10.0, what="the second pose")
        assert robot.messages == [("cell/cmd", b"go")]           # not its own refused cell/cmd
        assert hmi.messages == [("cell/pose", b"x=1"), ("cell/pose", b"x=2")]  # no cell/cmd
    finally:
        for client in (robot, hmi, plc):
            client.close()


def test_users_file_is_0600_and_holds_no_password(cell: dict) -> None:
    folder: Path = cell["folder"]
    for name in (USERS_FILE, CONF_FILE):
        assert stat.S_IMODE((folder / name).stat().st_mode) == 0o600, name
    texts = {name: (folder / name).read_text() for name in (USERS_FILE, CONF_FILE)}
    for text in texts.values():
        assert cell["robot"] not in text and cell["hmi"] not in text
    assert "allow_anonymous false" in texts[CONF_FILE].splitlines()
    clients = json.loads(texts[USERS_FILE])["clients"]
    assert [c["username"] for c in clients] == [
        "hmi", "plantkg.agent", "plantkg.check", "plantkg.observer", "plc", "robot1"]  # + plantkg's own
    assert all(c["iterations"] == 101 for c in clients)
    assert dynsec.matches(texts[USERS_FILE], "robot1", cell["robot"])


def test_plantkgs_own_principals_do_exactly_their_job(cell: dict) -> None:
    """plantkg.observer (the dashboard's and check's taps) reads every topic and writes none;
    plantkg.check writes (check's probes) and reads none; plantkg.agent reads only $SYS; each
    logs in with the password derived from the principal key this test run's agent uses."""
    port = cell["spec"].port
    login = {name: (name, principal_key.password_for(name))
             for name in (principals.OBSERVER, principals.CHECK, principals.AGENT)}
    observer, check, agent, hmi = (Mqtt(port, *login[principals.OBSERVER]), Mqtt(port, *login[principals.CHECK]),
                                   Mqtt(port, *login[principals.AGENT]), Mqtt(port, "hmi", cell["hmi"]))
    try:
        assert observer.accepted and check.accepted and agent.accepted and hmi.accepted
        for client in (observer, check, agent, hmi):
            client.subscribe("cell/pose")
        observer.publish("cell/pose", b"the observer may not write")  # dropped
        check.publish("cell/pose", b"probe")                           # delivered
        process.wait_until(lambda: hmi.messages, 10.0, what="the probe at the hmi")
        process.wait_until(lambda: observer.messages, 10.0, what="the probe at the observer")
        assert hmi.messages == observer.messages == [("cell/pose", b"probe")]
        assert check.messages == [] and agent.messages == []
    finally:
        for client in (observer, check, agent, hmi):
            client.close()
    wrong = Mqtt(port, principals.OBSERVER, "not-the-derived-password")
    assert not wrong.accepted
    wrong.close()


def test_a_second_put_keeps_the_broker_running(cell: dict) -> None:
    """Same users and passwords render the same files: no restart (the salts are kept)."""
    again = cell["fleet"].client(HOST).put_broker(cell["spec"])
    assert again.status is BrokerStatus.RUNNING
    assert again.pid == cell["observed"].pid and again.restarts == cell["observed"].restarts


needs_clients = pytest.mark.skipif(shutil.which("mosquitto_pub") is None,
                                   reason="mosquitto-clients not installed (scripts/setup.sh)")


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(list(args), capture_output=True, text=True, timeout=30)


@needs_clients
def test_mosquitto_clients_as_independent_clients(cell: dict) -> None:
    port = str(cell["spec"].port)
    common = ["-h", HOST, "-p", port, "-V", "mqttv311"]
    # a retained pose by robot1, then read by hmi
    published = _cli("mosquitto_pub", *common, "-u", "robot1", "-P", cell["robot"], "-q", "1",
                     "-r", "-t", "cell/pose", "-m", "pose-from-cli")
    assert published.returncode == 0, published.stderr
    read = _cli("mosquitto_sub", *common, "-u", "hmi", "-P", cell["hmi"], "-t", "cell/pose",
                "-C", "1", "-W", "10")
    assert read.returncode == 0 and read.stdout.strip() == "pose-from-cli", (read.stdout, read.stderr)
    # anonymous and a wrong password are refused at CONNECT
    anonymous = _cli("mosquitto_pub", *common, "-t", "cell/pose", "-m", "anon")
    assert anonymous.returncode != 0 and "not authori" in anonymous.stderr.lower(), anonymous.stderr
    wrong = _cli("mosquitto_pub", *common, "-u", "robot1", "-P", "wrong-" + cell["robot"],
                 "-t", "cell/pose", "-m", "x")
    assert wrong.returncode != 0, wrong.stderr
    # a retained command by plc: robot1 may read it, hmi may not (nothing arrives before -W)
    command = _cli("mosquitto_pub", *common, "-u", "plc", "-P", cell["plc"], "-q", "1", "-r",
                   "-t", "cell/cmd", "-m", "cmd-from-cli")
    assert command.returncode == 0, command.stderr
    robot = _cli("mosquitto_sub", *common, "-u", "robot1", "-P", cell["robot"], "-t", "cell/cmd",
                 "-C", "1", "-W", "10")
    assert robot.returncode == 0 and robot.stdout.strip() == "cmd-from-cli", (robot.stdout, robot.stderr)
    denied = _cli("mosquitto_sub", *common, "-u", "hmi", "-P", cell["hmi"], "-t", "cell/cmd",
                  "-C", "1", "-W", "2")
    assert denied.returncode != 0 and "cmd-from-cli" not in denied.stdout, \
        (denied.returncode, denied.stdout, denied.stderr)


def test_a_rotated_password_restarts_the_broker_at_the_next_put(cell: dict, tmp_path: Path) -> None:
    port, rotated = cell["spec"].port, secrets.token_urlsafe(12)
    (tmp_path / "secrets" / "robot1").write_text(rotated + "\n")
    after = cell["fleet"].client(HOST).put_broker(cell["spec"])
    cell["fleet"].brokers()
    assert after.status is BrokerStatus.RUNNING and after.pid != cell["observed"].pid
    old, new, hmi = (Mqtt(port, "robot1", cell["robot"]), Mqtt(port, "robot1", rotated),
                     Mqtt(port, "hmi", cell["hmi"]))
    try:
        assert not old.accepted and new.accepted and hmi.accepted
    finally:
        for client in (old, new, hmi):
            client.close()


def test_a_missing_secret_is_refused_and_the_broker_keeps_running(cell: dict) -> None:
    spec = cell["spec"]
    broken = replace(spec, users=tuple(
        replace(u, secret_ref="env:PLANTKG_TEST_SURELY_UNSET") if u.name == "robot1" else u
        for u in spec.users))
    with pytest.raises(DispatchError) as info:
        cell["fleet"].client(HOST).put_broker(broken)
    message = str(info.value)
    assert "users[robot1].secret_ref" in message and "PLANTKG_TEST_SURELY_UNSET" in message
    assert cell["robot"] not in message and cell["hmi"] not in message
    now = cell["fleet"].brokers()["cell"]
    assert now.status is BrokerStatus.RUNNING and now.pid == cell["observed"].pid

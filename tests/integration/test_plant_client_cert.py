"""Client certificates from a plant file, end to end (issue 13): ``plantkg plan`` / ``apply`` /
``status`` with a real agent over HTTP and a real Mosquitto, ``plantkg cert issue`` for the
devices, then paho and Debian's ``mosquitto_pub``/``mosquitto_sub`` with the issued certificates.

The plant: a TLS Mosquitto with a certificate listener (``pk:certificatePort``). ``cam1`` says
``pk:clientCertificate true`` and has no ``pk:secretRef``: a user without a password, it gets in
only through the certificate listener; it publishes ``cell/pose`` and subscribes to ``cell/cmd``.
``robot1`` has both a certificate and a password (both ways in), publishing ``cell/pose``. ``hmi``
logs in with a password on the TLS port, reading the pose and writing commands. What must hold:
each certificate client publishes exactly its declared topics and reads exactly its subscribed
ones; no certificate, a certificate of another CA, an expired one, a password alone on the
certificate listener and a password for the certificate-only user are refused; password clients keep working on the TLS
port; the key stays 0600 on the device and in no broker file; plan shows "certificate", never a
secret; status shows the certificate listener. One plant for the module.
"""

from __future__ import annotations

import datetime as dt
import json
import secrets
import shutil
import stat
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import NameOID
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.agent.local import LocalAgents, start_local_agents
from engine.cli import main
from tests.integration.plant_cli import run, secret_files
from engine.security import ca, client_cert

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
POSE, CMD = "cell/pose", "cell/cmd"
PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/cert-cell#> .
ex:m a pk:Broker ; pk:id "cell" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ;
    pk:port {port} ; pk:tls true ; pk:certificatePort {cert_port} ; pk:hasTopic ex:pose , ex:cmd .
ex:pose a pk:Topic ; pk:id "pose" ; pk:name "cell/pose" .
ex:cmd a pk:Topic ; pk:id "cmd" ; pk:name "cell/cmd" .
ex:cam a pk:Resource ; pk:id "cam1" ; pk:name "Camera" ; pk:sendsTo ex:m ; pk:publishes ex:pose ;
    pk:subscribes ex:cmd ; pk:clientCertificate true .
ex:robot a pk:Resource ; pk:id "robot1" ; pk:name "Robot" ; pk:sendsTo ex:m ; pk:publishes ex:pose ;
    pk:clientCertificate true ; pk:secretRef "file:{robot_file}" .
ex:hmi a pk:Resource ; pk:id "hmi" ; pk:name "HMI" ; pk:sendsTo ex:m ; pk:subscribes ex:pose ;
    pk:publishes ex:cmd ; pk:secretRef "file:{hmi_file}" .
"""


class Mqtt:
    """A paho TLS client on a background loop: its CONNACK (or failed handshake) and its messages."""

    def __init__(self, ca_file: Path, port: int, cert: client_cert.ClientBundle | None = None,
                 user: str | None = None, password: str | None = None) -> None:
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"t-{uuid.uuid4().hex[:8]}")
        self.client.tls_set(ca_certs=str(ca_file), certfile=None if cert is None else str(cert.cert_file),
                            keyfile=None if cert is None else str(cert.key_file))
        if user is not None:
            self.client.username_pw_set(user, password)
        self.connack: list[str] = []
        self.messages: list[tuple[str, bytes]] = []
        self.client.on_connect = lambda _c, _u, _f, reason, _p: self.connack.append(str(reason))
        self.client.on_message = lambda _c, _u, msg: self.messages.append((msg.topic, msg.payload))
        self.refused: str | None = None
        try:
            self.client.connect(HOST, port, keepalive=10)
        except OSError as exc:  # the TLS handshake failed: no certificate, or one of another CA
            self.refused = f"handshake: {exc}"
            return
        self.client.loop_start()
        # TLS 1.3: a refused client certificate may only show after connect() returned, as a
        # closed connection instead of a CONNACK
        process.wait_until(lambda: self.connack or self.client.socket() is None, 30.0,
                           what="a CONNACK or a closed connection")

    @property
    def accepted(self) -> bool:
        return self.refused is None and self.connack[:1] == ["Success"]

    def publish(self, topic: str, payload: bytes) -> None:
        info = self.client.publish(topic, payload, qos=1)
        info.wait_for_publish(20.0)
        assert info.is_published(), (topic, payload)

    def got(self, payload: bytes) -> bool:
        return any(p == payload for _, p in self.messages)

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    tmp = tmp_path_factory.mktemp("plant-client-cert")
    passwords = {"robot1": secrets.token_urlsafe(12), "hmi": secrets.token_urlsafe(12)}
    files = secret_files(tmp, passwords)
    port, cert_port = netutil.free_ports(2)
    plant = tmp / "cell.ttl"
    plant.write_text(PLANT.format(host=HOST, port=port, cert_port=cert_port, robot_file=files["robot1"],
                                  hmi_file=files["hmi"]), encoding="utf-8")
    agents: LocalAgents = start_local_agents([HOST], tmp)
    try:
        yield {"plant": plant, "port": port, "cert_port": cert_port, "agents": agents, "passwords": passwords,
               "tmp": tmp, "folder": agents.agents[HOST].state_dir / "brokers" / "cell"}
    finally:
        try:
            agents.delete_all()
        finally:
            agents.stop()


@pytest.fixture(scope="module")
def applied(cell: dict) -> dict:
    """The plant applied, and a certificate issued to cam1 and robot1 with ``plantkg cert issue``."""
    assert main(["apply", str(cell["plant"]), "--agents", str(cell["agents"].agents_file), "--yes"]) == 0
    bundles = {}
    for name in ("cam1", "robot1"):
        out = cell["tmp"] / f"device-{name}"
        assert main(["cert", "issue", name, "--out", str(out)]) == 0
        cert = x509.load_pem_x509_certificate((out / f"{name}.pem").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == name
        bundles[name] = client_cert.ClientBundle(name, out / f"{name}.key", out / f"{name}.pem", out / ca.CA_CERT,
                                                 cert.not_valid_after_utc)
    other = ca.load_or_create_ca(cell["tmp"] / "other-ca")
    stranger = client_cert.write_client_bundle(other, "cam1", cell["tmp"] / "stranger")
    return {**cell, "bundles": bundles, "stranger": stranger, "ca_file": bundles["cam1"].ca_file}


def _hmi(cell: dict) -> Mqtt:
    hmi = Mqtt(cell["ca_file"], cell["port"], user="hmi", password=cell["passwords"]["hmi"])
    assert hmi.accepted, (hmi.refused, hmi.connack)
    hmi.client.subscribe([(POSE, 1), (CMD, 1)])
    return hmi


def test_plan_shows_certificate_users_and_no_secret(cell: dict, capsys) -> None:
    code, out = run(capsys, "plan", cell["plant"], "--agents", cell["agents"].agents_file, "--format", "json")
    assert code == 0, out
    [broker] = [c for c in json.loads(out)["changes"] if c["address"] == "broker.cell"]
    assert broker["after"]["certificate_port"] == cell["cert_port"]
    users = {u["name"]: u for u in broker["after"]["users"]}
    assert users["cam1"] == {"name": "cam1", "write": [POSE], "read": [CMD], "certificate": True}
    assert users["robot1"]["certificate"] is True and users["robot1"]["secret_ref"].startswith("file:")
    assert "certificate" not in users["hmi"]
    code, text = run(capsys, "plan", cell["plant"], "--agents", cell["agents"].agents_file)
    assert code == 0 and '"certificate": true' in text and f"certificate_port = {cell['cert_port']}" in text, text
    for password in cell["passwords"].values():
        assert password not in out and password not in text


def test_status_shows_the_certificate_listener(applied: dict, capsys) -> None:
    code, out = run(capsys, "status", applied["plant"], "--agents", applied["agents"].agents_file, "--format", "json")
    assert code == 0, out
    [row] = [b for b in json.loads(out)["brokers"] if b["id"] == "cell"]
    assert (row["tls"], row["certificate_port"], row["users"]) == (True, applied["cert_port"], 3)
    code, out = run(capsys, "status", applied["plant"], "--agents", applied["agents"].agents_file)
    assert code == 0 and f"certificates :{applied['cert_port']}" in out, out


def test_paho_with_the_issued_certificate_publishes_and_reads_exactly_its_topics(applied: dict) -> None:
    hmi = _hmi(applied)
    cam = Mqtt(applied["ca_file"], applied["cert_port"], cert=applied["bundles"]["cam1"])
    try:
        assert cam.accepted, (cam.refused, cam.connack)
        cam.client.subscribe([(POSE, 1), (CMD, 1)])  # granted both; only cell/cmd may reach it
        # subscriptions are acknowledged asynchronously: publish until the first message arrives
        process.wait_until(lambda: (cam.publish(POSE, b"warm-up"), hmi.got(b"warm-up"))[1], 30.0, 0.5,
                           what="cam1's pose at the HMI")
        process.wait_until(lambda: (hmi.publish(CMD, b"go"), cam.got(b"go"))[1], 30.0, 0.5,
                           what="the HMI's command at cam1")
        cam.publish(CMD, b"forged by cam1")  # not declared: acknowledged and dropped (MQTT 3.1.1)
        cam.publish(POSE, b"last pose")
        hmi.publish(CMD, b"last cmd")
        process.wait_until(lambda: hmi.got(b"last pose") and cam.got(b"last cmd"), 30.0, what="the last messages")
        assert not hmi.got(b"forged by cam1")  # Mosquitto keeps one client's order
        assert {t for t, _ in cam.messages} == {CMD}  # its own poses never reach it: it may not read them
    finally:
        cam.close()
        hmi.close()


def test_mosquitto_pub_and_sub_with_the_issued_certificate(applied: dict) -> None:
    pub, sub = shutil.which("mosquitto_pub"), shutil.which("mosquitto_sub")
    if pub is None or sub is None:
        pytest.skip("Debian's mosquitto-clients is not installed (make setup installs it)")
    cam1 = applied["bundles"]["cam1"]

    def tls_args(bundle: client_cert.ClientBundle | None, port: int) -> list[str]:
        argv = ["-h", HOST, "-p", str(port), "--cafile", str(applied["ca_file"]), "-q", "1",
                "-i", f"cli-{uuid.uuid4().hex[:8]}"]
        return argv + ([] if bundle is None else ["--cert", str(bundle.cert_file), "--key", str(bundle.key_file)])

    def send(topic: str, payload: str, bundle: client_cert.ClientBundle | None = cam1,
             port: int | None = None) -> int:
        argv = [pub, *tls_args(bundle, port or applied["cert_port"]), "-t", topic, "-m", payload]
        return subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False).returncode

    hmi = _hmi(applied)
    try:
        process.wait_until(lambda: send(POSE, "cli warm-up") == 0 and hmi.got(b"cli warm-up"), 30.0, 0.5,
                           what="mosquitto_pub's pose at the HMI")
        assert send(CMD, "cli forged") == 0  # acknowledged, and dropped
        assert send(POSE, "cli after") == 0
        process.wait_until(lambda: hmi.got(b"cli after"), 30.0, what="the pose sent after the forged command")
        assert not hmi.got(b"cli forged")
        # mosquitto_sub as cam1, on both topics: the two messages it prints are commands, though a
        # pose is published before each command (it may not read the pose)
        reader = subprocess.Popen([sub, *tls_args(cam1, applied["cert_port"]), "-v", "-C", "2", "-W", "120",
                                   "-t", POSE, "-t", CMD], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            n = 0
            while reader.poll() is None and n < 200:
                n += 1
                assert send(POSE, f"pose {n}") == 0
                hmi.publish(CMD, f"cmd {n}".encode())
            out, err = reader.communicate(timeout=60)
        finally:
            if reader.poll() is None:
                reader.kill()
                reader.communicate()
        lines = out.splitlines()
        assert reader.returncode == 0 and len(lines) == 2, (out, err)
        assert all(line.startswith(f"{CMD} cmd ") for line in lines), lines
        # no certificate, or one of another CA: refused
        assert send(POSE, "no cert", bundle=None) != 0
        assert send(POSE, "stranger", bundle=applied["stranger"]) != 0
    finally:
        hmi.close()


def test_only_the_plant_ca_certificate_gets_in_and_passwords_keep_their_listener(applied: dict) -> None:
    ca_file, port, cert_port, pw = applied["ca_file"], applied["port"], applied["cert_port"], applied["passwords"]
    long_ago = dt.datetime.now(dt.timezone.utc) - dt.timedelta(days=client_cert.LIFETIME_DAYS + 1)
    expired = client_cert.write_client_bundle(ca.load_ca(ca.ca_dir()), "cam1", applied["tmp"] / "expired",
                                              now=long_ago)  # not re-issued in time
    refused = {
        "an expired certificate": Mqtt(ca_file, cert_port, cert=expired),
        "no certificate": Mqtt(ca_file, cert_port),
        "another CA": Mqtt(ca_file, cert_port, cert=applied["stranger"]),
        "a password alone on the certificate listener": Mqtt(ca_file, cert_port, user="hmi", password=pw["hmi"]),
        "cam1 has no password": Mqtt(ca_file, port, user="cam1", password=pw["robot1"]),
        "a certificate on the password listener": Mqtt(ca_file, port, cert=applied["bundles"]["cam1"]),
    }
    for what, client in refused.items():
        assert not client.accepted, (what, client.refused, client.connack)
        client.close()
    # robot1 has both: its password on the TLS port, its certificate on the certificate listener
    accepted = [Mqtt(ca_file, port, user="robot1", password=pw["robot1"]),
                Mqtt(ca_file, cert_port, cert=applied["bundles"]["robot1"]),
                Mqtt(ca_file, port, user="hmi", password=pw["hmi"])]
    for client in accepted:
        assert client.accepted, (client.refused, client.connack)
        client.close()


def test_the_key_is_private_and_only_on_the_device(applied: dict) -> None:
    bundle = applied["bundles"]["cam1"]
    assert stat.S_IMODE(bundle.key_file.stat().st_mode) == 0o600
    body = bundle.key_file.read_text().split("-----")[2].strip().splitlines()[0]
    folder: Path = applied["folder"]
    for path in folder.rglob("*"):
        if path.is_file() and path.stat().st_size < 10_000_000:
            assert body not in path.read_text(errors="replace"), path


def test_a_plant_ca_certificate_of_no_user_or_for_a_server_gets_nothing(applied: dict) -> None:
    """The certificate listener trusts the plant CA, which also signs servers' certificates:
    a broker's own certificate (serverAuth, not clientAuth) is refused at the handshake, and a
    client certificate whose common name is no user of the broker may connect (Mosquitto checks
    no password there) but publishes and reads nothing (the plugin knows no such client)."""
    folder: Path = applied["folder"]
    server = client_cert.ClientBundle("cell", folder / "tls-key.pem", folder / "tls-cert.pem",
                                      applied["ca_file"], applied["bundles"]["cam1"].not_after)
    as_server = Mqtt(applied["ca_file"], applied["cert_port"], cert=server)
    assert not as_server.accepted, (as_server.refused, as_server.connack)
    as_server.close()
    nobody_bundle = client_cert.write_client_bundle(ca.load_ca(ca.ca_dir()), "nobody", applied["tmp"] / "nobody")
    hmi = _hmi(applied)
    nobody = Mqtt(applied["ca_file"], applied["cert_port"], cert=nobody_bundle)
    cam = Mqtt(applied["ca_file"], applied["cert_port"], cert=applied["bundles"]["cam1"])
    try:
        assert nobody.accepted and cam.accepted, (nobody.refused, nobody.connack, cam.connack)
        nobody.client.subscribe([(POSE, 1), (CMD, 1)])
        cam.client.subscribe(CMD, qos=1)
        nobody.publish(POSE, b"pose from nobody")
        nobody.publish(CMD, b"cmd from nobody")
        # later messages of the users arrive; nothing of nobody's, and nothing for it
        process.wait_until(lambda: (hmi.publish(CMD, b"cmd for cam1"), cam.got(b"cmd for cam1"))[1], 30.0, 0.5,
                           what="the HMI's command at cam1")
        process.wait_until(lambda: (cam.publish(POSE, b"pose for hmi"), hmi.got(b"pose for hmi"))[1], 30.0, 0.5,
                           what="cam1's pose at the HMI")
        assert not hmi.got(b"pose from nobody") and not hmi.got(b"cmd from nobody")
        assert not cam.got(b"cmd from nobody")
        assert nobody.messages == []
    finally:
        for client in (nobody, cam, hmi):
            client.close()

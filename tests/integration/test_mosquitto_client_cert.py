"""A real Mosquitto with a listener for client certificates of the plant CA (``cert_port``).

The broker is rendered from ``MosquittoConfig`` (TLS password listener on ``port``, certificate
listener on ``cert_port``) with the dynamic security plugin: robot1 may write ``cell/pose`` only,
scada may read it. robot1 logs in with the certificate ``plantkg cert issue``'s code issues it (its
common name the user name; its password in the users file is a throwaway it never sends), once
with paho and once with Debian's ``mosquitto_pub``. Checked: its declared topic arrives at scada, a
message on another topic does not (a later message on the declared topic proves the order); a
client without a certificate, with a certificate of another CA, or with a password only is refused
on the certificate listener; and the key is 0600 and not in the broker's files.

Not wired from the plant yet (docs/security.md, Client certificates): this drives the renderer.
"""

from __future__ import annotations

import secrets
import shutil
import stat
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, parts, process
from engine.drivers.mosquitto.dynsec import render_dynsec
from engine.drivers.mosquitto.runtime import (MosquittoConfig, MosquittoTls, MosquittoUser, default_run_as,
                                              mosquitto_command, render_mosquitto_conf)
from engine.security import ca, client_cert

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
POSE, OTHER = "cell/pose", "cell/other"


class Broker:
    def __init__(self, root: Path) -> None:
        self.root = root
        self.ca = ca.load_or_create_ca(root / "ca")
        ca.ensure_server_cert(root / "srv", (HOST,), self.ca, name="mqtt1")
        self.device = client_cert.write_client_bundle(self.ca, "robot1", root / "device")
        self.stranger = client_cert.write_client_bundle(ca.load_or_create_ca(root / "other-ca"), "robot1",
                                                        root / "stranger")
        self.scada_password = secrets.token_urlsafe(16)
        users = [MosquittoUser("robot1", write=(POSE,)), MosquittoUser("scada", read=(POSE, OTHER))]
        (root / "dynsec.json").write_text(render_dynsec(
            users, {"robot1": secrets.token_urlsafe(16), "scada": self.scada_password}))
        (root / "dynsec.json").chmod(0o600)
        self.port, self.cert_port = netutil.free_ports(2)
        srv = root / "srv"
        cfg = MosquittoConfig(host=HOST, port=self.port, cert_port=self.cert_port, log_file=root / "broker.log",
                              allow_anonymous=False, run_as=default_run_as(),
                              dynsec_plugin=parts.mosquitto_dynsec_plugin(), dynsec_file=root / "dynsec.json",
                              tls=MosquittoTls(srv / ca.CA_CERT, srv / ca.CERT_FILE, srv / ca.KEY_FILE))
        (root / "mosquitto.conf").write_text(render_mosquitto_conf(cfg))
        self.child = process.spawn(mosquitto_command(parts.mosquitto_binary(), root / "mosquitto.conf"),
                                   log_dir=root, name="mosquitto")
        for port in (self.port, self.cert_port):
            process.wait_until(lambda p=port: netutil.port_open(HOST, p), 30.0, what="the listener",
                               child=self.child)


class Mqtt:
    """A paho TLS client on a background loop: its CONNACK (or failure) and its messages."""

    def __init__(self, broker: Broker, port: int, cert: client_cert.ClientBundle | None = None,
                 user: str | None = None, password: str | None = None) -> None:
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"t-{uuid.uuid4().hex[:8]}")
        self.client.tls_set(ca_certs=str(broker.ca.cert_file),
                            certfile=None if cert is None else str(cert.cert_file),
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
        process.wait_until(lambda: self.connack or not self.client.is_connected() and self._gone(), 15.0,
                           what="a CONNACK or a closed connection")

    def _gone(self) -> bool:
        return bool(self.connack) or self.client.socket() is None

    @property
    def accepted(self) -> bool:
        return self.refused is None and self.connack[:1] == ["Success"]

    def close(self) -> None:
        self.client.loop_stop()
        self.client.disconnect()


@pytest.fixture()
def broker(tmp_path: Path) -> Iterator[Broker]:
    b = Broker(tmp_path)
    yield b
    process.stop(b.child)


def _scada(broker: Broker) -> Mqtt:
    scada = Mqtt(broker, broker.port, user="scada", password=broker.scada_password)
    assert scada.accepted, scada.connack
    scada.client.subscribe([(POSE, 1), (OTHER, 1)])
    return scada


def _wait_for(scada: Mqtt, payload: bytes) -> None:
    process.wait_until(lambda: any(p == payload for _, p in scada.messages), 20.0, what=f"{payload!r} at scada")


def test_paho_with_the_plant_certificate_publishes_exactly_its_topic(broker: Broker) -> None:
    scada = _scada(broker)
    robot = Mqtt(broker, broker.cert_port, cert=broker.device)
    assert robot.accepted, (robot.refused, robot.connack)
    # a subscription is acknowledged asynchronously: publish until the first one arrives
    process.wait_until(lambda: robot.client.publish(POSE, b"warm-up", qos=1) and
                       any(p == b"warm-up" for _, p in scada.messages), 20.0, interval=0.5,
                       what="scada's subscription")
    for topic, payload in ((OTHER, b"forged"), (POSE, b"after")):
        info = robot.client.publish(topic, payload, qos=1)
        info.wait_for_publish(10.0)
        assert info.is_published()
    _wait_for(scada, b"after")
    assert (OTHER, b"forged") not in scada.messages
    assert "robot1" in (broker.root / "broker.log").read_text()  # logged in as its common name
    robot.close()
    scada.close()


def test_mosquitto_pub_with_the_plant_certificate(broker: Broker) -> None:
    pub = shutil.which("mosquitto_pub")
    if pub is None:
        pytest.skip("Debian's mosquitto-clients is not installed (make setup installs it)")
    scada = _scada(broker)
    device = broker.device

    def send(topic: str, payload: str, bundle: client_cert.ClientBundle | None = device,
             port: int | None = None) -> subprocess.CompletedProcess[str]:
        argv = [pub, "-h", HOST, "-p", str(port or broker.cert_port), "--cafile", str(broker.ca.cert_file),
                "-q", "1", "-t", topic, "-m", payload, "-i", f"pub-{uuid.uuid4().hex[:8]}"]
        if bundle is not None:
            argv += ["--cert", str(bundle.cert_file), "--key", str(bundle.key_file)]
        return subprocess.run(argv, capture_output=True, text=True, timeout=60, check=False)

    process.wait_until(lambda: send(POSE, "warm-up").returncode == 0 and
                       any(p == b"warm-up" for _, p in scada.messages), 30.0, interval=0.5,
                       what="scada's subscription")
    assert send(OTHER, "forged").returncode == 0  # acknowledged, and dropped (MQTT 3.1.1)
    assert send(POSE, "after").returncode == 0
    _wait_for(scada, b"after")
    assert (OTHER, b"forged") not in scada.messages
    assert send(POSE, "no-cert", bundle=None).returncode != 0
    assert send(POSE, "stranger", bundle=broker.stranger).returncode != 0
    scada.close()


def test_the_certificate_listener_refuses_every_other_client(broker: Broker) -> None:
    no_cert = Mqtt(broker, broker.cert_port)
    stranger = Mqtt(broker, broker.cert_port, cert=broker.stranger)
    password_only = Mqtt(broker, broker.cert_port, user="scada", password=broker.scada_password)
    for client in (no_cert, stranger, password_only):
        assert not client.accepted, (client.refused, client.connack)
    # the password listener still admits its password users, and no one without a password
    assert Mqtt(broker, broker.port, user="scada", password=broker.scada_password).accepted
    assert not Mqtt(broker, broker.port, cert=broker.device).accepted


def test_the_key_is_private_and_only_on_the_device(broker: Broker) -> None:
    key = broker.device.key_file.read_text()
    assert stat.S_IMODE(broker.device.key_file.stat().st_mode) == 0o600
    body = key.split("-----")[2].strip().splitlines()[0]
    for path in broker.root.rglob("*"):
        if path.is_file() and broker.device.key_file != path and "device" not in path.parts:
            assert body not in path.read_text(errors="replace"), path

"""The Mosquitto listener that takes client certificates of the plant CA (``cert_port``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.drivers.mosquitto.runtime import MosquittoConfig, MosquittoTls, render_mosquitto_conf
from engine.errors import ConfigValueError

TLS = MosquittoTls(Path("/s/ca.pem"), Path("/s/cert.pem"), Path("/s/key.pem"))


def _cfg(**overrides: object) -> MosquittoConfig:
    values: dict[str, object] = {"host": "127.0.0.1", "port": 8883, "log_file": Path("/s/log"), "tls": TLS,
                                 "allow_anonymous": False}
    return MosquittoConfig(**{**values, **overrides})  # type: ignore[arg-type]


def test_a_second_listener_requires_a_certificate_and_takes_its_name() -> None:
    text = render_mosquitto_conf(_cfg(cert_port=8884))
    first, second = text.split("\nlistener 8884 127.0.0.1\n")
    assert "listener 8883 127.0.0.1" in first and "require_certificate" not in first
    block = second.split("\n\n")[0].splitlines()
    assert block[:6] == ["cafile /s/ca.pem", "certfile /s/cert.pem", "keyfile /s/key.pem", "tls_version tlsv1.2",
                         "require_certificate true", "use_identity_as_username true"]


def test_without_it_no_listener_asks_for_a_certificate() -> None:
    text = render_mosquitto_conf(_cfg())
    assert text.count("listener ") == 1 and "require_certificate" not in text and "use_identity" not in text


def test_it_comes_before_the_bridges() -> None:
    """Lines after a ``connection`` belong to that bridge: the listener must precede them."""
    from engine.drivers.mosquitto.runtime import MosquittoBridge, MosquittoBridgeTopic
    bridge = MosquittoBridge(name="b1", remote_host="127.0.0.1", remote_port=1884,
                             topics=(MosquittoBridgeTopic("t", "out"),))
    text = render_mosquitto_conf(_cfg(cert_port=8884, bridges=(bridge,)))
    assert text.index("listener 8884") < text.index("connection b1")


@pytest.mark.parametrize("overrides", [{"cert_port": 8883}, {"cert_port": 8884, "tls": None},
                                       {"cert_port": 0}, {"cert_port": 70000}])
def test_refused(overrides: dict[str, object]) -> None:
    with pytest.raises(ConfigValueError) as caught:
        _cfg(**overrides)
    assert "cert_port" in str(caught.value)


# --- from the spec: the driver renders the listener and users without a password ---------------

def _spec(**changes: object):
    from engine.model import BrokerSpec
    values: dict[str, object] = dict(id="cell", iri="https://example.org/plant#cell", name="Cell",
                                     kind="mosquitto", host="127.0.0.1", port=18831, tls=True,
                                     certificate_port=18832, allow_anonymous=False)
    return BrokerSpec(**{**values, **changes})  # type: ignore[arg-type]


def _driver():
    from engine.drivers.mosquitto.driver import MosquittoDriver
    return MosquittoDriver(run_as=None, dynsec_plugin=Path("/usr/lib/x86_64-linux-gnu/mosquitto_dynamic_security.so"))


def test_the_driver_renders_the_specs_certificate_listener_with_the_brokers_tls_files(tmp_path: Path) -> None:
    from engine.drivers.mosquitto.driver import CONF_FILE, TLS_CA_FILE, TLS_CERT_FILE, TLS_KEY_FILE
    files = _driver().render_config(_spec(), tmp_path / "b")
    conf = files[CONF_FILE]
    block = conf.split("\nlistener 18832 127.0.0.1\n")[1].split("\n\n")[0].splitlines()
    assert block[:6] == [f"cafile {tmp_path / 'b' / TLS_CA_FILE}", f"certfile {tmp_path / 'b' / TLS_CERT_FILE}",
                         f"keyfile {tmp_path / 'b' / TLS_KEY_FILE}", "tls_version tlsv1.2",
                         "require_certificate true", "use_identity_as_username true"]
    assert "require_certificate" not in _driver().render_config(_spec(certificate_port=None), tmp_path / "c")[CONF_FILE]


def test_a_certificate_user_gets_no_password_and_one_with_a_secret_keeps_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """cam1 has only a certificate: its client has no password (the plugin refuses every password
    login for it) and no secret is looked up; robot1 has both: its password hash stays."""
    import base64
    import hashlib
    import json

    from engine.drivers.mosquitto.driver import USERS_FILE
    from engine.model import BrokerUser
    monkeypatch.setenv("PLANTKG_TEST_ROBOT_PW", "robot-pw")
    monkeypatch.delenv("CAM1_PW", raising=False)
    users = (BrokerUser("cam1", None, write=("cell/pose",), certificate=True),
             BrokerUser("robot1", "env:PLANTKG_TEST_ROBOT_PW", read=("cell/cmd",), certificate=True))
    files = _driver().render_config(_spec(users=users), tmp_path / "b")
    data = json.loads(files[USERS_FILE])
    found = {c["username"]: c for c in data["clients"]}
    assert set(found["cam1"]) == {"username", "roles"}
    robot = found["robot1"]
    digest = hashlib.pbkdf2_hmac("sha512", b"robot-pw", base64.b64decode(robot["salt"]), 101)
    assert base64.b64decode(robot["password"]) == digest
    roles = {r["rolename"]: {(a["acltype"], a["topic"]) for a in r["acls"]} for r in data["roles"]}
    assert roles["cam1"] == {("publishClientSend", "cell/pose")}
    # rendering again gives the same file (robot1's salt kept, cam1 still without a password)
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / USERS_FILE).write_text(files[USERS_FILE])
    assert _driver().render_config(_spec(users=users), tmp_path / "b")[USERS_FILE] == files[USERS_FILE]


def test_a_user_without_a_secret_or_a_certificate_is_refused(tmp_path: Path) -> None:
    from engine.drivers.mosquitto.dynsec import render_dynsec
    from engine.drivers.mosquitto.runtime import MosquittoUser
    with pytest.raises(ConfigValueError) as caught:
        render_dynsec([MosquittoUser("cam1")], {})
    assert "users[cam1].password" in str(caught.value)


def test_the_essence_and_the_plan_show_the_listener_and_certificate_users_never_a_secret() -> None:
    from engine.model import BrokerUser
    from engine.plan import broker_essence
    users = (BrokerUser("cam1", None, write=("cell/pose",), certificate=True), BrokerUser("hmi", "env:H"))
    essence = _driver().essence(_spec(users=users))
    assert essence["certificate_port"] == 18832
    assert essence["users"][0] == {"name": "cam1", "secret_ref": None, "write": ["cell/pose"], "read": [],
                                   "certificate": True}
    assert "certificate" not in essence["users"][1]
    assert _driver().essence(_spec(users=users, certificate_port=18833)) != essence
    assert "certificate_port" not in _driver().essence(_spec(certificate_port=None))
    planned = broker_essence(_spec(users=users))
    assert planned["certificate_port"] == 18832
    assert planned["users"] == [{"name": "cam1", "write": ["cell/pose"], "read": [], "certificate": True},
                                {"name": "hmi", "secret_ref": "env:H", "write": [], "read": []}]
    assert "certificate_port" not in broker_essence(_spec(certificate_port=None))

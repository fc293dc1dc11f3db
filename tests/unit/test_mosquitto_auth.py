"""Broker users on Mosquitto (issue 13): the users file (the dynamic security plugin's), the secret
resolution on the agent's machine, the closed ``mosquitto.conf``, the driver's files and essence,
and the 0600 mode of rendered files.

The hashes are checked by recomputing PBKDF2-HMAC-SHA512 from the rendered salt, and against a
line written by Mosquitto's own ``mosquitto_passwd -U`` (which reads the password from a file, so
no password is on a command line). A real closed broker is tests/integration/test_mosquitto_auth.py.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import re
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

from engine.agent.folder import BrokerFolder
from engine.drivers.base import config_hash
from engine.drivers.mosquitto import dynsec
from engine.drivers.mosquitto import runtime as mr
from engine.drivers.mosquitto.driver import (
    CONF_FILE,
    USERS_FILE,
    MosquittoDriver,
    connack_answers,
    is_closed,
    resolve_secret,
)
from engine.errors import ConfigValueError
from engine.security import principal_key
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    BrokerUser,
)

LINE = re.compile(r"(?P<name>[^:]+):\$7\$101\$(?P<salt>[A-Za-z0-9+/=]+)\$(?P<hash>[A-Za-z0-9+/=]+)")
PLUGIN = Path("/usr/lib/x86_64-linux-gnu/mosquitto_dynamic_security.so")


def spec(**changes) -> BrokerSpec:
    values = dict(id="cell", iri="https://example.org/plant#cell", name="Cell", kind="mosquitto",
                  host="127.0.0.1", port=18831)
    return BrokerSpec(**{**values, **changes})


def robot_users(robot_ref: str, hmi_ref: str) -> tuple[BrokerUser, ...]:
    return (BrokerUser("hmi", hmi_ref, read=("cell/pose",)),
            BrokerUser("robot1", robot_ref, write=("cell/pose",), read=("cell/cmd",)))


def clients(text: str) -> dict[str, dict]:
    return {c["username"]: c for c in json.loads(text)["clients"]}


def recomputed(client: dict, password: str) -> bool:
    """The plugin's stored hash is PBKDF2-HMAC-SHA512 of ``password`` with the stored salt."""
    salt = base64.b64decode(client["salt"])
    assert len(salt) == 12 and client["iterations"] == 101
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, 101)
    return base64.b64decode(client["password"]) == digest


def users(*pairs: tuple[str, str]) -> tuple[list[mr.MosquittoUser], dict[str, str]]:
    return [mr.MosquittoUser(name) for name, _ in pairs], dict(pairs)


# --- the users file (dynamic security plugin) -----------------------------------------------

@pytest.mark.parametrize("password", ["s3cret", "pässwörd with blanks", "a:b$c", "x" * 65_535])
def test_a_users_hash_is_pbkdf2_sha512_of_its_salt(password: str) -> None:
    text = dynsec.render_dynsec(*users(("robot1", password)))
    client = clients(text)["robot1"]
    assert recomputed(client, password) and not recomputed(client, password + "x")
    assert dynsec.matches(text, "robot1", password) and not dynsec.matches(text, "robot1", "other")


def test_users_sorted_each_with_its_own_role_and_fresh_salts() -> None:
    text = dynsec.render_dynsec(*users(("robot1", "pw-r"), ("hmi", "pw-h")))
    data = json.loads(text)
    assert [c["username"] for c in data["clients"]] == ["hmi", "robot1"]
    assert [c["roles"] for c in data["clients"]] == [[{"rolename": "hmi"}], [{"rolename": "robot1"}]]
    assert recomputed(data["clients"][0], "pw-h") and recomputed(data["clients"][1], "pw-r")
    assert text.endswith("\n") and dynsec.render_dynsec(*users(("robot1", "pw-r"), ("hmi", "pw-h"))) != text


def test_the_hashes_that_still_match_are_kept() -> None:
    first = dynsec.render_dynsec(*users(("hmi", "pw-h"), ("robot1", "pw-r")))
    assert dynsec.render_dynsec(*users(("hmi", "pw-h"), ("robot1", "pw-r")), first) == first
    rotated = dynsec.render_dynsec(*users(("hmi", "pw-h"), ("robot1", "new")), first)
    assert clients(rotated)["hmi"] == clients(first)["hmi"]
    assert clients(rotated)["robot1"] != clients(first)["robot1"] and recomputed(clients(rotated)["robot1"], "new")
    # a renamed user gets a new hash; an unreadable previous file is ignored
    renamed = dynsec.render_dynsec(*users(("hmi2", "pw-h")), first)
    assert clients(renamed)["hmi2"]["salt"] != clients(first)["hmi"]["salt"]
    assert dynsec.matches(dynsec.render_dynsec(*users(("hmi", "pw")), "{not json"), "hmi", "pw")


def test_salt_source_is_used_and_checked() -> None:
    salt = bytes(range(12))
    text = dynsec.render_dynsec(*users(("hmi", "pw")), salt=lambda: salt)
    assert clients(text)["hmi"]["salt"] == base64.b64encode(salt).decode()
    with pytest.raises(ConfigValueError):
        dynsec.render_dynsec(*users(("hmi", "pw")), salt=lambda: b"short")


@pytest.mark.skipif(shutil.which("mosquitto_passwd") is None, reason="mosquitto_passwd not installed")
def test_mosquitto_passwd_hashes_the_same_way(tmp_path: Path) -> None:
    """Mosquitto's own tool hashes a plain-text file (-U): its salt and hash, put in a users file,
    are what we verify (and keep) for that password."""
    path = tmp_path / "pw"
    path.write_text("robot1:hunter2\n")
    subprocess.run(["mosquitto_passwd", "-U", str(path)], check=True, capture_output=True, timeout=30)
    match = LINE.fullmatch(path.read_text().strip())
    assert match
    theirs = json.dumps({"clients": [{"username": "robot1", "salt": match["salt"],
                                      "password": match["hash"], "iterations": 101}]})
    assert dynsec.matches(theirs, "robot1", "hunter2") and not dynsec.matches(theirs, "robot1", "hunter3")
    kept = clients(dynsec.render_dynsec(*users(("robot1", "hunter2")), theirs))["robot1"]
    assert (kept["salt"], kept["password"]) == (match["salt"], match["hash"])


@pytest.mark.parametrize("password, problem", [
    ("", "non-empty"),
    ("ab\0cd-TOPSECRET", "NUL"),
    ("TOPSECRET" + "x" * 65_536, "65535"),
    ("TOPSECRET\udcff", "UTF-8"),
])
def test_bad_passwords_are_refused_without_showing_them(password: str, problem: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        dynsec.render_dynsec(*users(("robot1", password)))
    assert info.value.field == "users[robot1].password" and problem in str(info.value)
    assert "TOPSECRET" not in str(info.value) and "TOPSECRET" not in repr(info.value.value)


def test_duplicate_users_are_refused() -> None:
    with pytest.raises(ConfigValueError) as info:
        dynsec.render_dynsec([mr.MosquittoUser("a"), mr.MosquittoUser("a")], {"a": "x"})
    assert info.value.field == "users"


# What each user may do: its role's ACLs; anonymous clients of a broker that still admits them.
SEND, RECEIVE = "publishClientSend", "publishClientReceive"
ACL_CASES = [
    pytest.param(
        [mr.MosquittoUser("robot1", write=("cell/pose",), read=("cell/cmd",)),
         mr.MosquittoUser("hmi", read=("cell/pose",))], False,
        {"hmi": [(RECEIVE, "cell/pose")], "robot1": [(SEND, "cell/pose"), (RECEIVE, "cell/cmd")]},
        id="robot-cell"),
    pytest.param(
        [mr.MosquittoUser("plc", write=("b", "a"), read=("a", "c"))], False,
        {"plc": [(SEND, "a"), (SEND, "b"), (RECEIVE, "a"), (RECEIVE, "c")]},
        id="read-and-write-sorted"),
    pytest.param([mr.MosquittoUser("idle")], False, {"idle": []}, id="user-without-topics"),
    pytest.param(
        [mr.MosquittoUser("plantkg.check", filters=(("write", "#"),)),
         mr.MosquittoUser("plantkg.agent", filters=(("read", "$SYS/#"),))], False,
        {"plantkg.agent": [(RECEIVE, "$SYS/#")], "plantkg.check": [(SEND, "#")]},
        id="plantkg-principals-with-filters"),
    pytest.param(
        [mr.MosquittoUser("hmi", read=("cell/pose",))], True,
        {"hmi": [(RECEIVE, "cell/pose")],
         "anonymous": [(SEND, "#"), (RECEIVE, "#"), (RECEIVE, "$SYS/#")]},
        id="anonymous-still-allowed"),
]


@pytest.mark.parametrize("acl_users, anonymous, expected", ACL_CASES)
def test_each_user_may_do_what_its_role_says(acl_users: list[mr.MosquittoUser], anonymous: bool,
                                             expected: dict) -> None:
    data = json.loads(dynsec.render_dynsec(acl_users, {u.name: "pw" for u in acl_users}, anonymous=anonymous))
    roles = {r["rolename"]: [(a["acltype"], a["topic"]) for a in r["acls"] if a["allow"]] for r in data["roles"]}
    assert roles == expected
    # nothing but what a role grants: no publishing, no delivery; subscribing is free, delivery filtered
    assert data["defaultACLAccess"] == {"publishClientSend": False, "publishClientReceive": False,
                                        "subscribe": True, "unsubscribe": True}
    assert (data.get("anonymousGroup") == "anonymous") is anonymous
    assert not any("$CONTROL" in topic for acls in roles.values() for _, topic in acls)


@pytest.mark.parametrize("kwargs, field", [
    (dict(name="robot 1"), "users.name"),
    (dict(name="robot1\nuser admin"), "users.name"),
    (dict(name="robot:1"), "users.name"),
    (dict(name=""), "users.name"),
    (dict(name="r", write=("cell/+",)), "users[r].write"),
    (dict(name="r", read=("cell/#",)), "users[r].read"),
    (dict(name="r", read=("#",)), "users[r].read"),
    (dict(name="r", write=("cell pose",)), "users[r].write"),
    (dict(name="r", write=("cell/pose\ntopic readwrite #",)), "users[r].write"),
    (dict(name="r", read=("a\x7fb",)), "users[r].read"),
    (dict(name="r", read=("",)), "users[r].read"),
    (dict(name="r", read=["a"]), "users[r].read"),
])
def test_acl_users_are_validated(kwargs: dict, field: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        mr.MosquittoUser(**kwargs)
    assert info.value.field == field


# --- mosquitto.conf --------------------------------------------------------------------------

def test_closed_conf_loads_the_plugin_with_its_users_file(tmp_path: Path) -> None:
    cfg = mr.MosquittoConfig(host="127.0.0.1", port=1883, log_file=tmp_path / "m.log",
                             allow_anonymous=False, dynsec_plugin=PLUGIN, dynsec_file=tmp_path / USERS_FILE)
    lines = mr.render_mosquitto_conf(cfg).splitlines()
    assert "allow_anonymous false" in lines and "allow_anonymous true" not in lines
    assert f"plugin {PLUGIN}" in lines
    assert f"plugin_opt_config_file {tmp_path / USERS_FILE}" in lines
    open_cfg = mr.MosquittoConfig(host="127.0.0.1", port=1883, log_file=tmp_path / "m.log")
    text = mr.render_mosquitto_conf(open_cfg)
    assert "allow_anonymous true" in text and "plugin" not in text


@pytest.mark.parametrize("changes, field", [
    (dict(dynsec_plugin=PLUGIN, dynsec_file=Path("relative")), "dynsec_file"),
    (dict(dynsec_plugin=Path("/a b/p.so"), dynsec_file=Path("/f")), "dynsec_plugin"),
    (dict(dynsec_plugin=PLUGIN, dynsec_file=Path("/a\n/p")), "dynsec_file"),
    (dict(dynsec_plugin=PLUGIN), "dynsec_file"),
    (dict(allow_anonymous="no"), "allow_anonymous"),
])
def test_conf_refuses_bad_auth_values(changes: dict, field: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        mr.MosquittoConfig(host="127.0.0.1", port=1883, log_file=Path("/tmp/m.log"), **changes)
    assert info.value.field == field


# --- secrets on the agent's machine ----------------------------------------------------------

def test_secret_from_env_and_file(tmp_path: Path) -> None:
    environ = {"ROBOT1_PW": "from-env"}
    assert resolve_secret(BrokerUser("r", "env:ROBOT1_PW"), environ) == "from-env"
    for content, expected in [("from-file\n", "from-file"), ("from-file", "from-file"),
                              ("crlf\r\n", "crlf"), ("  blanks kept  \n", "  blanks kept  ")]:
        path = tmp_path / "pw"
        path.write_text(content, newline="")
        assert resolve_secret(BrokerUser("r", f"file:{path}"), {}) == expected


def test_secret_from_the_process_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PLANTKG_TEST_ROBOT_PW", "process-env")
    assert resolve_secret(BrokerUser("r", "env:PLANTKG_TEST_ROBOT_PW")) == "process-env"


SECRET = "TOPSECRET-4711"


@pytest.mark.parametrize("ref, content, environ, problem", [
    ("env:ROBOT1_PW", None, {}, "not set"),
    ("env:ROBOT1_PW", None, {"ROBOT1_PW": ""}, "empty"),
    ("file:{dir}/absent", None, {}, "cannot read"),
    ("file:{dir}", None, {}, "cannot read"),                 # a folder
    ("file:{dir}/pw", "", {}, "empty"),
    ("file:{dir}/pw", "\n", {}, "empty"),
    ("file:{dir}/pw", SECRET + "\n\n", {}, "line break"),    # only one newline is stripped
    ("file:{dir}/pw", SECRET + "\nsecond line\n", {}, "line break"),
    ("file:{dir}/pw", SECRET + "\0", {}, "NUL"),
    ("file:{dir}/pw", b"\xff\xfe" + SECRET.encode(), {}, "UTF-8"),
    ("env:ROBOT1_PW", None, {"ROBOT1_PW": SECRET + "\nx"}, "line break"),
    (SECRET, None, {}, "env:NAME or file:"),                # a pasted secret is not a reference
])
def test_secret_errors_name_user_and_reference_never_the_secret(
        tmp_path: Path, ref: str, content: str | bytes | None, environ: dict, problem: str) -> None:
    ref = ref.format(dir=tmp_path)
    if content is not None:
        data = content if isinstance(content, bytes) else content.encode()
        (tmp_path / "pw").write_bytes(data)
    with pytest.raises(ConfigValueError) as info:
        resolve_secret(BrokerUser("robot1", ref), environ)
    message = str(info.value)
    assert info.value.field == "users[robot1].secret_ref" and problem in message
    assert SECRET not in message and SECRET not in repr(info.value.value)
    if ref.startswith(("env:", "file:")):
        assert ref in message


def test_unreadable_secret_file(tmp_path: Path) -> None:
    path = tmp_path / "pw"
    path.write_text(SECRET)
    path.chmod(0)
    if os.access(path, os.R_OK):
        pytest.skip("running as root: a mode-0 file is still readable")
    with pytest.raises(ConfigValueError) as info:
        resolve_secret(BrokerUser("robot1", f"file:{path}"), {})
    assert "cannot read" in str(info.value) and SECRET not in str(info.value)


# --- the driver ------------------------------------------------------------------------------

def test_driver_renders_closed_broker_with_hashes_only(tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "r").write_text("robot-pw\n")
    users = robot_users(f"file:{tmp_path / 'r'}", "env:PLANTKG_TEST_HMI_PW")
    monkeypatch.setenv("PLANTKG_TEST_HMI_PW", "hmi-pw")
    files = MosquittoDriver(run_as=None, dynsec_plugin=PLUGIN).render_config(spec(users=users), tmp_path / "b")
    assert set(files) == {CONF_FILE, USERS_FILE}
    conf = files[CONF_FILE].splitlines()
    assert "allow_anonymous false" in conf
    assert f"plugin {PLUGIN}" in conf and f"plugin_opt_config_file {tmp_path / 'b' / USERS_FILE}" in conf
    everything = "".join(files.values())
    assert "robot-pw" not in everything and "hmi-pw" not in everything
    found = clients(files[USERS_FILE])
    # the plant's users, and plantkg's own principals (their passwords derive from the key)
    assert sorted(found) == ["hmi", "plantkg.agent", "plantkg.check", "plantkg.observer", "robot1"]
    assert recomputed(found["hmi"], "hmi-pw") and recomputed(found["robot1"], "robot-pw")
    assert recomputed(found["plantkg.agent"], principal_key.password_for("plantkg.agent"))
    assert principal_key.password_for("plantkg.agent") not in everything
    roles = {r["rolename"]: {(a["acltype"], a["topic"]) for a in r["acls"]}
             for r in json.loads(files[USERS_FILE])["roles"]}
    assert roles["robot1"] == {("publishClientSend", "cell/pose"), ("publishClientReceive", "cell/cmd")}
    assert roles["plantkg.agent"] == {("publishClientReceive", "$SYS/#")}
    assert roles["plantkg.observer"] == {("publishClientReceive", "#")}
    assert roles["plantkg.check"] == {("publishClientSend", "#")}
    assert "anonymous" not in roles


@pytest.mark.parametrize("allow_anonymous, with_users, closed", [
    (None, False, False), (True, False, False), (False, False, True),
    (None, True, True), (False, True, True), (True, True, False),
])
def test_when_a_broker_is_closed(tmp_path: Path, allow_anonymous: bool | None, with_users: bool,
                                 closed: bool) -> None:
    (tmp_path / "pw").write_text("x")
    users = (BrokerUser("hmi", f"file:{tmp_path / 'pw'}", read=("t",)),) if with_users else ()
    s = spec(users=users, allow_anonymous=allow_anonymous)
    assert is_closed(s) is closed
    files = MosquittoDriver(run_as=None, dynsec_plugin=PLUGIN).render_config(s, tmp_path / "b")
    assert f"allow_anonymous {'false' if closed else 'true'}" in files[CONF_FILE].splitlines()
    files_expected = with_users or closed  # a closed broker still admits plantkg's principals
    assert (USERS_FILE in files) is files_expected
    if with_users:
        # a broker that still admits anonymous clients keeps them able to do what they did
        assert ("anonymousGroup" in json.loads(files[USERS_FILE])) is not closed


def test_a_bridge_logs_in_to_a_mosquitto_remote_as_its_principal(tmp_path: Path) -> None:
    """Closed or open, the carrying broker renders the bridge with its principal's login at the
    remote (derived from the principal key); towards another MQTT broker kind, no login."""
    (tmp_path / "pw").write_text("x")
    bridge = BridgeSpec(local=BridgeEnd("cell", "mosquitto", "127.0.0.1", 18831),
                        remote=BridgeEnd("plant", "mosquitto", "127.0.0.1", 18832),
                        mechanism=BridgeMechanism.MOSQUITTO,
                        routes=(BridgeRoute("cell/pose", BridgeDirection.OUT),))
    password = principal_key.password_for("plantkg.bridge.cell.plant")
    for broker in (spec(users=(BrokerUser("hmi", f"file:{tmp_path / 'pw'}"),)), spec(allow_anonymous=False),
                   spec(allow_anonymous=True)):
        conf = MosquittoDriver(run_as=None).render_config(broker, tmp_path / "b", (bridge,))[CONF_FILE]
        assert "connection plantkg.cell.plant" in conf
        assert f"remote_username plantkg.bridge.cell.plant\nremote_password {password}\n" in conf
    other = BridgeSpec(local=bridge.local, remote=BridgeEnd("plant", "othermq", "127.0.0.1", 18832),
                       mechanism=BridgeMechanism.MOSQUITTO, routes=bridge.routes)
    conf = MosquittoDriver(run_as=None).render_config(spec(), tmp_path / "b", (other,))[CONF_FILE]
    assert "remote_username" not in conf and "remote_password" not in conf


def test_validate_refuses_a_missing_secret_naming_user_and_reference() -> None:
    s = spec(users=(BrokerUser("robot1", "env:PLANTKG_TEST_SURELY_UNSET"),))
    with pytest.raises(ConfigValueError) as info:
        MosquittoDriver(run_as=None).validate(s)
    assert info.value.field == "users[robot1].secret_ref" and "PLANTKG_TEST_SURELY_UNSET" in str(info.value)


def test_same_passwords_render_the_same_files_and_a_rotation_changes_them(tmp_path: Path) -> None:
    """The agent restarts a broker whose rendered files changed (config_hash): re-rendering with
    unchanged passwords must not change them; a rotated password must."""
    (tmp_path / "r").write_text("one")
    (tmp_path / "h").write_text("two")
    s = spec(users=robot_users(f"file:{tmp_path / 'r'}", f"file:{tmp_path / 'h'}"))
    driver, folder = MosquittoDriver(run_as=None, dynsec_plugin=PLUGIN), BrokerFolder(tmp_path / "b")
    first = driver.render_config(s, folder.path)
    folder.write_rendered(first)
    assert config_hash(driver.render_config(s, folder.path)) == config_hash(first)
    (tmp_path / "r").write_text("rotated")
    rotated = driver.render_config(s, folder.path)
    assert config_hash(rotated) != config_hash(first)
    assert clients(rotated[USERS_FILE])["hmi"] == clients(first[USERS_FILE])["hmi"]  # hmi kept


def test_essence_follows_users_and_survives_pid_json(tmp_path: Path) -> None:
    driver = MosquittoDriver(run_as=None)
    base = spec(users=robot_users("env:A", "env:B"))
    essence = driver.essence(base)
    assert json.loads(json.dumps(essence)) == essence  # kept in pid.json, compared after a restart
    changes = [
        spec(users=robot_users("env:A2", "env:B")),
        spec(users=(BrokerUser("hmi", "env:B", read=("cell/pose", "cell/cmd")),
                    BrokerUser("robot1", "env:A", write=("cell/pose",), read=("cell/cmd",)))),
        spec(users=robot_users("env:A", "env:B"), allow_anonymous=True),
        spec(),
    ]
    for changed in changes:
        assert driver.essence(changed) != essence, changed
    assert driver.essence(spec()) != driver.essence(spec(allow_anonymous=False))


def test_prepare_removes_the_files_of_users_no_longer_there(tmp_path: Path) -> None:
    for name in (USERS_FILE, "passwords", "acl"):  # the last two: an earlier plantkg's
        (tmp_path / name).write_text("old")
    driver = MosquittoDriver(run_as=None)
    driver.prepare(spec(users=(BrokerUser("hmi", "env:X"),)), tmp_path)
    assert (tmp_path / USERS_FILE).exists()
    assert not (tmp_path / "passwords").exists() and not (tmp_path / "acl").exists()
    driver.prepare(spec(), tmp_path)
    assert not (tmp_path / USERS_FILE).exists()


def test_rendered_files_are_0600(tmp_path: Path) -> None:
    folder = BrokerFolder(tmp_path / "b")
    folder.write_rendered({CONF_FILE: "a\n", USERS_FILE: "{}\n"})
    for name in (CONF_FILE, USERS_FILE):
        assert stat.S_IMODE((folder.path / name).stat().st_mode) == 0o600, name
    # an existing file with a wider mode is replaced by a 0600 one
    (folder.path / USERS_FILE).chmod(0o644)
    folder.write_rendered({USERS_FILE: "x\n"})
    assert stat.S_IMODE((folder.path / USERS_FILE).stat().st_mode) == 0o600


@pytest.mark.parametrize("reason, answers", [
    ("Success", True),
    ("Bad user name or password", True),   # MQTT 3.1.1 return code 4
    ("Not authorized", True),              # 5: a closed broker refusing the agent
    ("Server unavailable", False),
    ("Unsupported protocol version", False),
    ("Client identifier not valid", False),
])
def test_which_connacks_prove_a_broker_answers(reason: str, answers: bool) -> None:
    assert connack_answers(reason) is answers

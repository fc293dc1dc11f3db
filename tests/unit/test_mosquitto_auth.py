"""Broker users on Mosquitto (issue 13): the password and ACL file renderers, the secret
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

from engine.drivers.mosquitto import runtime as mr
from engine.agent.folder import BrokerFolder
from engine.drivers.base import config_hash
from engine.drivers.mosquitto.driver import (
    ACL_FILE,
    CONF_FILE,
    PASSWORD_FILE,
    MosquittoDriver,
    connack_answers,
    is_closed,
    resolve_secret,
)
from engine.errors import ConfigValueError
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


def spec(**changes) -> BrokerSpec:
    values = dict(id="cell", iri="https://example.org/plant#cell", name="Cell", kind="mosquitto",
                  host="127.0.0.1", port=18831)
    return BrokerSpec(**{**values, **changes})


def robot_users(robot_ref: str, hmi_ref: str) -> tuple[BrokerUser, ...]:
    return (BrokerUser("hmi", hmi_ref, read=("cell/pose",)),
            BrokerUser("robot1", robot_ref, write=("cell/pose",), read=("cell/cmd",)))


def recomputed(line: str, password: str) -> bool:
    match = LINE.fullmatch(line)
    assert match, line
    salt = base64.b64decode(match["salt"])
    assert len(salt) == 12
    digest = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, 101)
    return base64.b64decode(match["hash"]) == digest


# --- password file ---------------------------------------------------------------------------

@pytest.mark.parametrize("password", ["s3cret", "pässwörd with blanks", "a:b$c", "x" * 65_535])
def test_password_line_is_pbkdf2_sha512_of_its_salt(password: str) -> None:
    line = mr.password_line("robot1", password, os.urandom(12))
    assert line.startswith("robot1:$7$101$")
    assert recomputed(line, password)
    assert not recomputed(line, password + "x")
    assert mr.password_matches(line, password) and not mr.password_matches(line, "other")


def test_password_file_sorted_one_line_per_user_with_fresh_salts() -> None:
    text = mr.render_password_file([("robot1", "pw-r"), ("hmi", "pw-h")])
    lines = text.splitlines()
    assert [line.split(":")[0] for line in lines] == ["hmi", "robot1"]
    assert text.endswith("\n") and recomputed(lines[0], "pw-h") and recomputed(lines[1], "pw-r")
    again = mr.render_password_file([("robot1", "pw-r"), ("hmi", "pw-h")])
    assert again != text  # random salts when nothing is kept


def test_password_file_keeps_the_lines_whose_hash_still_matches() -> None:
    first = mr.render_password_file([("hmi", "pw-h"), ("robot1", "pw-r")])
    same = mr.render_password_file([("hmi", "pw-h"), ("robot1", "pw-r")], previous=first)
    assert same == first
    rotated = mr.render_password_file([("hmi", "pw-h"), ("robot1", "new")], previous=first)
    assert rotated.splitlines()[0] == first.splitlines()[0]
    assert rotated.splitlines()[1] != first.splitlines()[1] and recomputed(rotated.splitlines()[1], "new")
    # a renamed user gets a new hash, garbage in the previous file is ignored
    renamed = mr.render_password_file([("hmi2", "pw-h")], previous=first + "junk\nhmi2:$7$x$y$z\n")
    assert renamed.startswith("hmi2:$7$101$") and renamed.split(":", 1)[1] != first.splitlines()[0].split(":", 1)[1]


def test_salt_source_is_used_and_checked() -> None:
    salt = bytes(range(12))
    text = mr.render_password_file([("hmi", "pw")], salt=lambda: salt)
    assert LINE.fullmatch(text.strip())["salt"] == base64.b64encode(salt).decode()
    with pytest.raises(ConfigValueError):
        mr.render_password_file([("hmi", "pw")], salt=lambda: b"short")


@pytest.mark.skipif(shutil.which("mosquitto_passwd") is None, reason="mosquitto_passwd not installed")
def test_mosquitto_passwd_writes_lines_we_verify(tmp_path: Path) -> None:
    """Mosquitto's own tool hashes a plain-text file (-U): our verification accepts its line."""
    path = tmp_path / "pw"
    path.write_text("robot1:hunter2\n")
    subprocess.run(["mosquitto_passwd", "-U", str(path)], check=True, capture_output=True, timeout=30)
    line = path.read_text().strip()
    assert LINE.fullmatch(line) and mr.password_matches(line, "hunter2")
    assert not mr.password_matches(line, "hunter3")
    # and a file rendered with that line as the previous one keeps it
    assert mr.render_password_file([("robot1", "hunter2")], previous=line + "\n") == line + "\n"


@pytest.mark.parametrize("password, problem", [
    ("", "non-empty"),
    ("ab\0cd-TOPSECRET", "NUL"),
    ("TOPSECRET" + "x" * 65_536, "65535"),
    ("TOPSECRET\udcff", "UTF-8"),
])
def test_bad_passwords_are_refused_without_showing_them(password: str, problem: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        mr.render_password_file([("robot1", password)])
    assert info.value.field == "users[robot1].password" and problem in str(info.value)
    assert "TOPSECRET" not in str(info.value) and "TOPSECRET" not in repr(info.value.value)


def test_duplicate_users_are_refused() -> None:
    with pytest.raises(ConfigValueError) as info:
        mr.render_password_file([("a", "x"), ("a", "y")])
    assert info.value.field == "users"
    with pytest.raises(ConfigValueError):
        mr.render_acl_file([mr.MosquittoUser("a"), mr.MosquittoUser("a")])


# --- ACL file --------------------------------------------------------------------------------

ACL_CASES = [
    pytest.param(
        [mr.MosquittoUser("robot1", write=("cell/pose",), read=("cell/cmd",)),
         mr.MosquittoUser("hmi", read=("cell/pose",))], False,
        "# Rendered by plantkg; edits are overwritten.\n\n"
        "user hmi\ntopic read cell/pose\n\n"
        "user robot1\ntopic read cell/cmd\ntopic write cell/pose\n",
        id="robot-cell"),
    pytest.param(
        [mr.MosquittoUser("plc", write=("b", "a"), read=("a", "c"))], False,
        "# Rendered by plantkg; edits are overwritten.\n\n"
        "user plc\ntopic readwrite a\ntopic write b\ntopic read c\n",
        id="readwrite-and-sorted"),
    pytest.param(
        [mr.MosquittoUser("idle")], False,
        "# Rendered by plantkg; edits are overwritten.\n\nuser idle\n",
        id="user-without-topics"),
    pytest.param(
        [mr.MosquittoUser("hmi", read=("cell/pose",))], True,
        "# Rendered by plantkg; edits are overwritten.\n"
        "# anonymous clients: every topic, as on a broker without users\n"
        "topic readwrite #\ntopic read $SYS/#\n\n"
        "user hmi\ntopic read cell/pose\n",
        id="anonymous-still-allowed"),
]


@pytest.mark.parametrize("users, anonymous, expected", ACL_CASES)
def test_acl_file(users: list[mr.MosquittoUser], anonymous: bool, expected: str) -> None:
    assert mr.render_acl_file(users, anonymous=anonymous) == expected


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

def test_closed_conf_names_the_password_and_acl_files(tmp_path: Path) -> None:
    cfg = mr.MosquittoConfig(host="127.0.0.1", port=1883, log_file=tmp_path / "m.log",
                             allow_anonymous=False, password_file=tmp_path / "passwords",
                             acl_file=tmp_path / "acl")
    lines = mr.render_mosquitto_conf(cfg).splitlines()
    assert "allow_anonymous false" in lines and "allow_anonymous true" not in lines
    assert f"password_file {tmp_path / 'passwords'}" in lines
    assert f"acl_file {tmp_path / 'acl'}" in lines
    open_cfg = mr.MosquittoConfig(host="127.0.0.1", port=1883, log_file=tmp_path / "m.log")
    text = mr.render_mosquitto_conf(open_cfg)
    assert "allow_anonymous true" in text and "password_file" not in text and "acl_file" not in text


@pytest.mark.parametrize("changes, field", [
    (dict(password_file=Path("relative")), "password_file"),
    (dict(acl_file=Path("/a b/acl")), "acl_file"),
    (dict(password_file=Path("/a\n/p")), "password_file"),
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
    files = MosquittoDriver(run_as=None).render_config(spec(users=users), tmp_path / "b")
    assert set(files) == {CONF_FILE, PASSWORD_FILE, ACL_FILE}
    conf = files[CONF_FILE].splitlines()
    assert "allow_anonymous false" in conf
    assert f"password_file {tmp_path / 'b' / PASSWORD_FILE}" in conf
    assert f"acl_file {tmp_path / 'b' / ACL_FILE}" in conf
    everything = "".join(files.values())
    assert "robot-pw" not in everything and "hmi-pw" not in everything
    hmi, robot = files[PASSWORD_FILE].splitlines()
    assert recomputed(hmi, "hmi-pw") and recomputed(robot, "robot-pw")
    assert "user robot1\ntopic read cell/cmd\ntopic write cell/pose\n" in files[ACL_FILE]
    assert "topic readwrite #" not in files[ACL_FILE]


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
    files = MosquittoDriver(run_as=None).render_config(s, tmp_path / "b")
    assert f"allow_anonymous {'false' if closed else 'true'}" in files[CONF_FILE].splitlines()
    assert (PASSWORD_FILE in files) is with_users and (ACL_FILE in files) is with_users
    if with_users:
        # a broker that still admits anonymous clients keeps them able to do what they did
        assert ("topic readwrite #" in files[ACL_FILE]) is not closed


def test_closed_broker_carries_no_bridge(tmp_path: Path) -> None:
    (tmp_path / "pw").write_text("x")
    bridge = BridgeSpec(local=BridgeEnd("cell", "mosquitto", "127.0.0.1", 18831),
                        remote=BridgeEnd("plant", "mosquitto", "127.0.0.1", 18832),
                        mechanism=BridgeMechanism.MOSQUITTO,
                        routes=(BridgeRoute("cell/pose", BridgeDirection.OUT),))
    for closed in (spec(users=(BrokerUser("hmi", f"file:{tmp_path / 'pw'}"),)),
                   spec(allow_anonymous=False)):
        with pytest.raises(ConfigValueError) as info:
            MosquittoDriver(run_as=None).render_config(closed, tmp_path / "b", (bridge,))
        assert info.value.field == "bridges" and "not supported yet" in str(info.value)
    opened = spec(users=(BrokerUser("hmi", f"file:{tmp_path / 'pw'}"),), allow_anonymous=True)
    files = MosquittoDriver(run_as=None).render_config(opened, tmp_path / "b", (bridge,))
    assert "connection plantkg.cell.plant" in files[CONF_FILE]


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
    driver, folder = MosquittoDriver(run_as=None), BrokerFolder(tmp_path / "b")
    first = driver.render_config(s, folder.path)
    folder.write_rendered(first)
    assert config_hash(driver.render_config(s, folder.path)) == config_hash(first)
    (tmp_path / "r").write_text("rotated")
    rotated = driver.render_config(s, folder.path)
    assert config_hash(rotated) != config_hash(first)
    assert rotated[PASSWORD_FILE].splitlines()[0] == first[PASSWORD_FILE].splitlines()[0]  # hmi kept


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
    for name in (PASSWORD_FILE, ACL_FILE):
        (tmp_path / name).write_text("old")
    driver = MosquittoDriver(run_as=None)
    driver.prepare(spec(users=(BrokerUser("hmi", "env:X"),)), tmp_path)
    assert (tmp_path / PASSWORD_FILE).exists()
    driver.prepare(spec(), tmp_path)
    assert not (tmp_path / PASSWORD_FILE).exists() and not (tmp_path / ACL_FILE).exists()


def test_rendered_files_are_0600(tmp_path: Path) -> None:
    folder = BrokerFolder(tmp_path / "b")
    folder.write_rendered({CONF_FILE: "a\n", PASSWORD_FILE: "hmi:$7$...\n", ACL_FILE: "user hmi\n"})
    for name in (CONF_FILE, PASSWORD_FILE, ACL_FILE):
        assert stat.S_IMODE((folder.path / name).stat().st_mode) == 0o600, name
    # an existing file with a wider mode is replaced by a 0600 one
    (folder.path / PASSWORD_FILE).chmod(0o644)
    folder.write_rendered({PASSWORD_FILE: "x\n"})
    assert stat.S_IMODE((folder.path / PASSWORD_FILE).stat().st_mode) == 0o600


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

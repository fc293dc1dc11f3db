"""The plant's principal key and the passwords derived from it (engine.security.principal_key)."""

from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import pytest

from engine.security import principal_key as pk
from engine.security.mqtt_client import MqttLogin, principal_login


def test_a_new_key_is_random_0600_and_read_back_the_same(tmp_path: Path) -> None:
    path = tmp_path / "state" / "plantkg" / "principal-key"
    key = pk.load_or_create_key(path)
    assert len(key) == pk.KEY_BYTES
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert pk.load_or_create_key(path) == key == pk.load_key(path)
    assert pk.load_or_create_key(tmp_path / "other") != key


def test_processes_starting_together_agree_on_one_key(tmp_path: Path) -> None:
    # Threads of one process share its pid: each writer's file aside must still be its own (the
    # aside named after the pid alone once gave two threads two different keys).
    for round_ in range(10):
        path = tmp_path / f"principal-key-{round_}"
        barrier = threading.Barrier(8)
        keys: list[bytes] = []

        def start(path: Path = path, barrier: threading.Barrier = barrier) -> None:
            barrier.wait()
            keys.append(pk.load_or_create_key(path))

        threads = [threading.Thread(target=start) for _ in range(8)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(keys) == 8 and len(set(keys)) == 1 and keys[0] == pk.load_key(path)
    assert not list(tmp_path.glob(".*"))


def test_passwords_derive_from_key_and_name() -> None:
    one, two = b"\x01" * 32, b"\x02" * 32
    assert pk.principal_password(one, "plantkg.agent") == pk.principal_password(one, "plantkg.agent")
    assert pk.principal_password(one, "plantkg.agent") != pk.principal_password(one, "plantkg.observer")
    assert pk.principal_password(one, "plantkg.agent") != pk.principal_password(two, "plantkg.agent")
    password = pk.principal_password(one, "plantkg.agent")
    assert len(password) == 43 and password.replace("-", "").replace("_", "").isalnum()


@pytest.mark.parametrize(("content", "mode", "problem"), [
    ("ab" * 32, 0o644, "readable by others"),
    ("ab" * 16, 0o600, "not a principal key"),
    ("zz" * 32, 0o600, "not a principal key"),
])
def test_an_unusable_key_file_is_refused_naming_it(tmp_path: Path, content: str, mode: int, problem: str) -> None:
    path = tmp_path / "principal-key"
    path.write_text(content)
    path.chmod(mode)
    with pytest.raises(pk.PrincipalKeyError, match=problem) as info:
        pk.load_or_create_key(path)
    assert str(path) in str(info.value) and content not in str(info.value)


def test_where_the_key_is(tmp_path: Path) -> None:
    assert pk.key_file(tmp_path / "x", {}) == tmp_path / "x"
    assert pk.key_file(None, {pk.KEY_ENV: "/k"}) == Path("/k")
    assert pk.key_file(None, {"XDG_STATE_HOME": "/s"}) == Path("/s/plantkg/principal-key")


def test_plantkg_logs_in_only_where_it_renders_users(tmp_path: Path) -> None:
    key = tmp_path / "k"
    login = principal_login("mosquitto", "plantkg.observer", key)
    assert login == MqttLogin("plantkg.observer", pk.principal_password(pk.load_key(key), "plantkg.observer"))
    assert login.password not in repr(login)
    assert principal_login("rabbitmq", "plantkg.observer", key) is None
    assert os.path.exists(key)

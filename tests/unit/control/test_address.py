"""Where a served plant's control socket is: the same files, agents file and owner meet there."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.control.address import plant_key, run_dir, socket_path


@pytest.fixture(autouse=True)
def clean_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for name in ("PLANTKG_RUN_DIR", "XDG_RUNTIME_DIR", "XDG_STATE_HOME", "PLANTKG_AGENTS"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)


def test_the_folder_follows_the_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert run_dir() == tmp_path / "home" / ".local" / "state" / "plantkg" / "run"
    monkeypatch.setenv("XDG_STATE_HOME", "/state")
    assert run_dir() == Path("/state/plantkg/run")
    monkeypatch.setenv("XDG_RUNTIME_DIR", "/run/user/1000")
    assert run_dir() == Path("/run/user/1000/plantkg")
    monkeypatch.setenv("PLANTKG_RUN_DIR", "/srv/pk")
    assert run_dir() == Path("/srv/pk")


def test_a_relative_and_an_absolute_name_are_the_same_plant(tmp_path: Path) -> None:
    (tmp_path / "plant.ttl").write_text("")
    assert socket_path(["plant.ttl"], None, None) == socket_path([str(tmp_path / "plant.ttl")], None, None)
    assert socket_path(["plant.ttl"], "agents.toml", None) == socket_path(["plant.ttl"], tmp_path / "agents.toml", None)


def test_the_agents_file_of_the_environment_counts(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PLANTKG_AGENTS", str(tmp_path / "agents.toml"))
    assert plant_key(["p.ttl"], None, None)["agents"] == str(tmp_path / "agents.toml")
    assert socket_path(["p.ttl"], None, None) == socket_path(["p.ttl"], tmp_path / "agents.toml", None)


# Each pair differs in one thing that makes it another plant (or another run of it).
DIFFERENT = [
    ((["a.ttl"], None, None), (["b.ttl"], None, None)),
    ((["a.ttl", "b.ttl"], None, None), (["b.ttl", "a.ttl"], None, None)),
    ((["a.ttl"], None, None), (["a.ttl"], "agents.toml", None)),
    ((["a.ttl"], "one.toml", None), (["a.ttl"], "two.toml", None)),
    ((["a.ttl"], None, None), (["a.ttl"], None, "line-2")),
]


@pytest.mark.parametrize(("one", "other"), DIFFERENT)
def test_another_plant_has_another_socket(one: tuple, other: tuple) -> None:  # type: ignore[type-arg]
    assert socket_path(*one) != socket_path(*other)
    assert socket_path(*one).name.startswith("serve-") and socket_path(*one).suffix == ".sock"

"""The agents file: where each host's agent is and which token it takes."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.agents_config import AgentDirectory, AgentsConfigError


def collect(url: str, token: str) -> tuple[str, str]:
    return url, token


def load(tmp_path: Path, text: str, env: dict[str, str] | None = None) -> AgentDirectory:
    path = tmp_path / "agents.toml"
    path.write_text(text, encoding="utf-8")
    return AgentDirectory.load(path, env=env or {}, client_factory=collect)  # type: ignore[arg-type]


def test_token_inline_and_default_url(tmp_path: Path) -> None:
    d = load(tmp_path, '[agents."127.0.0.2"]\nurl = "http://127.0.0.2:7411/"\ntoken = "s3cret"\n'
                       '[agents."127.0.0.3"]\ntoken = "other"\n')
    assert d.client_for("127.0.0.2") == ("http://127.0.0.2:7411", "s3cret")
    assert d.client_for("127.0.0.3") == ("http://127.0.0.3:7300", "other")
    assert d.hosts == ("127.0.0.2", "127.0.0.3")


def test_host_not_in_file_uses_env_token(tmp_path: Path) -> None:
    d = load(tmp_path, "", env={"PLANTKG_TOKEN": "from-env"})
    assert d.client_for("127.0.0.9") == ("http://127.0.0.9:7300", "from-env")
    assert d.url_for("::1") == "http://[::1]:7300"


def test_no_token_anywhere_is_a_typed_error(tmp_path: Path) -> None:
    d = load(tmp_path, "")
    with pytest.raises(AgentsConfigError, match="no token for the agent of 127.0.0.4") as err:
        d.client_for("127.0.0.4")
    assert "PLANTKG_TOKEN" in (err.value.hint or "")


def test_token_file_relative_to_the_agents_file(tmp_path: Path) -> None:
    (tmp_path / "tok").write_text("abc\n")
    (tmp_path / "tok").chmod(0o600)
    d = load(tmp_path, '[agents."127.0.0.2"]\ntoken_file = "tok"\n')
    assert d.client_for("127.0.0.2") == ("http://127.0.0.2:7300", "abc")
    assert d.warnings == []


def test_world_readable_token_file_warns(tmp_path: Path) -> None:
    tok = tmp_path / "tok"
    tok.write_text("abc")
    tok.chmod(0o644)
    d = load(tmp_path, f'[agents."127.0.0.2"]\ntoken_file = "{tok}"\n')
    assert len(d.warnings) == 1 and "chmod 600" in d.warnings[0]
    assert d.client_for("127.0.0.2")[1] == "abc"


@pytest.mark.parametrize(("text", "message"), [
    ("[agents", "not valid TOML"),
    ('[agents."robot"]\ntoken = "x"\n', "is not an IP address"),
    ('[agents."127.0.0.2"]\ntoken = "x"\ntoken_file = "y"\n', "both token and token_file"),
    ('[agents."127.0.0.2"]\nurl = "ftp://x"\ntoken = "x"\n', r"is not an http\(s\) URL"),
    ('[agents."127.0.0.2"]\ntokn = "x"\n', "unknown key"),
    ('[agents."127.0.0.2"]\ntoken_file = "missing"\n', "No such file"),
    ('[other]\n', "unknown top-level key"),
    ('[agents."127.0.0.2"]\ntoken = ""\n', "non-empty"),
])
def test_bad_files_are_refused_with_the_place(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(AgentsConfigError, match=message):
        load(tmp_path, text)


def test_explicit_file_must_exist_default_may_not(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(AgentsConfigError, match="no such agents file"):
        AgentDirectory.load(tmp_path / "nope.toml", env={})
    with pytest.raises(AgentsConfigError, match="no such agents file"):
        AgentDirectory.load(None, env={"PLANTKG_AGENTS": str(tmp_path / "nope.toml")})
    monkeypatch.setenv("HOME", str(tmp_path))
    d = AgentDirectory.load(None, env={"PLANTKG_TOKEN": "t"})
    assert d.entries == {} and d.default_token == "t"


def test_env_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "a.toml"
    path.write_text('[agents."127.0.0.5"]\ntoken = "z"\n')
    d = AgentDirectory.load(None, env={"PLANTKG_AGENTS": str(path)}, client_factory=collect)  # type: ignore[arg-type]
    assert d.client_for("127.0.0.5") == ("http://127.0.0.5:7300", "z")

"""The control socket end to end, on real Unix sockets: a command handed to a server prints what
the server says, answers its question and exits with its code; the socket is private; a bad
request, a silent client, a stale socket and a server that goes away are each handled.

The server runs a handler of the test's (what ``plantkg serve`` runs is
tests/integration/test_apply_through_serve.py); the client is engine.control.client, as
``plantkg apply`` calls it.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from engine.cli.console import Console
from engine.control.address import plant_key, socket_path
from engine.control.client import run_in_server
from engine.control.request import Request
from engine.control.server import ControlServer, ControlUnavailable
from engine.control.wire import receive, send
from engine.errors import EngineError
from tests.unit.test_cli_imports import PROBE

#: PROBE through the console script's entry point (engine.control.entry), not engine.cli.main.
ENTRY_PROBE = PROBE.replace("from engine.cli import main", "from engine.control.entry import main")

ROOT = Path(__file__).resolve().parents[3]
FILES = ["plant.ttl"]
OPTIONS = {"yes": True, "parallelism": 3, "prune": False, "format": "text"}


@pytest.fixture
def run_dir(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Iterator[Path]:
    """A short private folder (a socket path must stay under ~100 bytes)."""
    folder = Path(tempfile.mkdtemp(prefix="pkc-", dir="/tmp"))
    monkeypatch.setenv("PLANTKG_RUN_DIR", str(folder / "run"))
    monkeypatch.delenv("PLANTKG_AGENTS", raising=False)
    monkeypatch.chdir(tmp_path)
    yield folder / "run"
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture
def serve(run_dir: Path) -> Iterator[Callable[..., ControlServer]]:
    started: list[ControlServer] = []

    def start(handler: Callable[[Request, Console], int], files: list[str] = FILES) -> ControlServer:
        server = ControlServer(socket_path(files, None, None), plant_key(files, None, None), handler).start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.close(timeout=10)


def test_a_command_runs_in_the_server_and_prints_what_it_says(serve, capsys) -> None:  # type: ignore[no-untyped-def]
    seen: list[Request] = []

    def handler(request: Request, console: Console) -> int:
        seen.append(request)
        console.echo("the plan")
        console.echo("\x1b[32mgreen\x1b[0m")  # styles go only to a terminal that shows them
        console.echo("a warning", err=True)
        with console.progress() as progress:
            assert callable(progress)
        return 3

    serve(handler)
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 3
    out, err = capsys.readouterr()
    assert out.splitlines() == ["the plan", "green"]
    assert "a warning" in err and "runs in plantkg serve (pid" in err
    assert seen[0].verb == "apply" and seen[0].yes and seen[0].parallelism == 3 and not seen[0].color


def test_the_question_goes_to_the_commands_terminal(serve, capsys, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    answers: list[str] = []
    monkeypatch.setattr("builtins.input", lambda prompt="": "yes")

    def handler(request: Request, console: Console) -> int:
        answers.append(console.prompt("Do you want to perform these actions?"))
        return 0

    serve(handler)
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 0
    assert answers == ["yes"] and "Do you want to perform these actions?" in capsys.readouterr().out


def test_no_answer_cancels(serve, capsys, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    def no_terminal(prompt: str = "") -> str:
        raise EOFError

    monkeypatch.setattr("builtins.input", no_terminal)
    ran: list[str] = []

    def handler(request: Request, console: Console) -> int:
        if console.prompt("Sure?").strip() == "yes":
            ran.append("applied")
        import click  # noqa: PLC0415

        raise click.Abort()

    serve(handler)
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 130
    assert ran == [] and "aborted" in capsys.readouterr().err


def test_without_a_server_the_command_runs_here(run_dir: Path) -> None:
    assert run_in_server("apply", FILES, None, None, OPTIONS) is None
    # a socket left by a killed server: nobody answers, so the command runs here too
    path = socket_path(FILES, None, None)
    path.parent.mkdir(parents=True, mode=0o700)
    left = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    left.bind(str(path))
    left.close()
    assert path.exists() and run_in_server("apply", FILES, None, None, OPTIONS) is None


def test_another_plants_server_is_not_asked(serve) -> None:  # type: ignore[no-untyped-def]
    serve(lambda request, console: 0, files=["other.ttl"])
    assert run_in_server("apply", FILES, None, None, OPTIONS) is None
    assert run_in_server("apply", FILES, None, "another-owner", OPTIONS) is None


def _raw(path: Path) -> tuple[socket.socket, object]:
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    conn.settimeout(10)
    conn.connect(str(path))
    stream = conn.makefile("rwb")
    hello = receive(stream)
    assert hello is not None and hello["hello"]["pid"] == os.getpid()
    return conn, stream


def test_a_bad_request_is_refused_by_field_and_nothing_runs(serve) -> None:  # type: ignore[no-untyped-def]
    ran: list[Request] = []
    server = serve(lambda request, console: ran.append(request) or 0)
    conn, stream = _raw(server.path)
    send(stream, {"request": {"verb": "apply", "key": plant_key(FILES, None, None), "parallelism": 0}})
    said = [receive(stream), receive(stream)]
    conn.close()
    assert said[0] is not None and "'parallelism'" in said[0]["err"] and said[1] == {"exit": 2}
    assert ran == []


def test_a_silent_client_stops_nobody(serve) -> None:  # type: ignore[no-untyped-def]
    server = serve(lambda request, console: 0)
    silent, _ = _raw(server.path)  # connected, says nothing
    try:
        assert run_in_server("apply", FILES, None, None, OPTIONS) == 0
    finally:
        silent.close()


def test_errors_reach_the_user_as_messages_and_exit_codes(serve, capsys) -> None:  # type: ignore[no-untyped-def]
    failures = iter([EngineError("the agent of 127.0.0.2 refused", hint="start it"), RuntimeError("bug")])

    def handler(request: Request, console: Console) -> int:
        raise next(failures)

    serve(handler)
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 2
    err = capsys.readouterr().err
    assert "error: the agent of 127.0.0.2 refused" in err and "start it" in err
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 3
    err = capsys.readouterr().err
    assert "plantkg serve failed while running the command: RuntimeError('bug')" in err
    assert "Traceback" not in err


def test_a_server_that_goes_away_midway_exits_3(serve, capsys) -> None:  # type: ignore[no-untyped-def]
    def handler(request: Request, console: Console) -> int:
        console.echo("started")
        raise BrokenPipeError("gone")

    serve(handler)
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 3
    out, err = capsys.readouterr()
    assert "started" in out and "closed the connection before the end" in err


def test_the_socket_and_its_folder_are_private(serve, run_dir: Path) -> None:  # type: ignore[no-untyped-def]
    server = serve(lambda request, console: 0)
    assert stat.S_IMODE(server.path.stat().st_mode) == 0o600
    assert stat.S_IMODE(run_dir.stat().st_mode) == 0o700
    server.close()
    assert not server.path.exists()


def test_a_folder_others_can_open_is_refused(run_dir: Path) -> None:
    run_dir.mkdir(mode=0o755)
    os.chmod(run_dir, 0o755)
    with pytest.raises(ControlUnavailable, match="only this user can open"):
        ControlServer(socket_path(FILES, None, None), plant_key(FILES, None, None), lambda r, c: 0).start()
    assert list(run_dir.iterdir()) == []


def test_a_live_servers_socket_is_kept_and_a_stale_one_replaced(serve) -> None:  # type: ignore[no-untyped-def]
    first = serve(lambda request, console: 0)
    with pytest.raises(ControlUnavailable, match="another plantkg serve of this plant answers"):
        ControlServer(first.path, plant_key(FILES, None, None), lambda r, c: 1).start()
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 0  # still the first one's
    first.close()
    left = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)  # what a SIGKILL leaves: the file,
    left.bind(str(first.path))                                 # and nobody listening on it
    left.close()
    serve(lambda request, console: 5)
    assert run_in_server("apply", FILES, None, None, OPTIONS) == 5


def test_apply_handed_to_a_server_loads_no_graph_library_nor_click(serve, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    (tmp_path / "plant.ttl").write_text("")
    (tmp_path / "agents.toml").write_text("")
    files = [str(tmp_path / "plant.ttl")]
    seen: list[Request] = []
    server = ControlServer(socket_path(files, tmp_path / "agents.toml", None),
                           plant_key(files, tmp_path / "agents.toml", None),
                           lambda request, console: seen.append(request) or 0).start()
    try:
        out = tmp_path / "probe.json"
        done = subprocess.run([sys.executable, "-c", ENTRY_PROBE, str(out), "apply", "--yes", "--parallelism", "2",
                               "--agents", str(tmp_path / "agents.toml"), *files], cwd=tmp_path,
                              env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True,
                              timeout=120, check=False)
        found = json.loads(out.read_text())
    finally:
        server.close(timeout=10)
    assert found["code"] == 0, done.stderr
    assert seen and seen[0].parallelism == 2 and seen[0].yes
    heavy = [m for m in found["modules"] if m.split(".")[0] in ("rdflib", "pyshacl", "owlready2", "flask", "click")
             or m in ("engine.pipeline", "engine.cli", "engine.cli.reconcile", "engine.apply", "kg.load")]
    assert heavy == []

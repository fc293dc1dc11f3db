"""Running ``plantkg serve``: token file, the plant's watcher, werkzeug's threaded server, signals.

As for the agent (engine/agent/server.py, whose listen parsing, token file and signal wait this
reuses): werkzeug's threaded WSGI server is enough for a handful of people and programs on a
plant network, and needs nothing beyond Flask.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from flask import Flask
from werkzeug.serving import BaseWSGIServer, make_server

from engine.agent.server import ListenAddress, load_or_create_token, wait_for_signal
from engine.agents_config import AgentDirectory
from engine.errors import EngineError
from engine.model import DesiredState, ObservedState
from engine.web.app import WebConfig, create_app
from engine.web.plant_state import PlantState
from engine.web.rates import RateMonitor
from engine.web.sparql_protocol import Limits

if TYPE_CHECKING:
    from engine.control.server import ControlServer

log = logging.getLogger(__name__)


def default_token_file() -> Path:
    """``$XDG_STATE_HOME/plantkg/web-token`` (``~/.local/state/plantkg/web-token``)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path("~/.local/state").expanduser())
    return Path(base) / "plantkg" / "web-token"


@dataclass
class RunningServer:
    """A started server: stop it with :meth:`shutdown`."""

    address: ListenAddress
    server: BaseWSGIServer
    thread: threading.Thread
    state: PlantState
    app: Flask
    rates: RateMonitor | None = None

    def shutdown(self) -> None:
        self.server.shutdown()
        self.thread.join()
        self.server.server_close()
        if self.rates is not None:
            self.rates.stop()
        self.state.close()
        self.app.extensions["plantkg_sparql"].close()


def start_server(listen: ListenAddress, state: PlantState, token: str, limits: Limits, *,
                 rates: bool = True) -> RunningServer:
    """Load the plant once, then serve the app in a thread and watch the files in another; with
    ``rates``, count the messages of the topics on running brokers (engine.web.rates)."""
    monitor = RateMonitor(lambda: _desired_and_observed(state)) if rates else None
    app = create_app(WebConfig(state=state, token=token, limits=limits, rates=monitor))
    try:
        server = make_server(listen.host, listen.port, app, threaded=True)
    except (OSError, SystemExit) as exc:  # werkzeug exits when the port is taken
        raise EngineError(f"cannot listen on {listen.url}: {exc}",
                          hint="pick another --listen port, or stop what uses it") from None
    state.start()
    if monitor is not None:
        monitor.start()
    thread = threading.Thread(target=server.serve_forever, name="plantkg-web-http", daemon=True)
    thread.start()
    return RunningServer(ListenAddress(listen.host, server.server_port), server, thread, state, app, monitor)


def _desired_and_observed(state: PlantState) -> tuple[DesiredState | None, ObservedState | None]:
    snap = state.snapshot  # one snapshot: the two halves agree
    return snap.desired, snap.observed


def open_control(files: list[str], agents_file: Path | None, owner: str | None,
                 state: PlantState) -> tuple[ControlServer | None, str]:
    """The control socket of this plant (engine.control): commands of this user run here, warm.
    None and the reason when it cannot be opened (the server runs on without it)."""
    from engine.control.address import plant_key, socket_path  # noqa: PLC0415
    from engine.control.commands import plant_commands  # noqa: PLC0415
    from engine.control.server import ControlServer, ControlUnavailable  # noqa: PLC0415

    server = ControlServer(socket_path(files, agents_file, owner), plant_key(files, agents_file, owner),
                           plant_commands(state, agents_file, owner))
    try:
        return server.start(), ""
    except ControlUnavailable as exc:
        return None, str(exc)


def run_server(files: list[str], listen: ListenAddress, *, agents_file: Path | None, token_file: Path | None,
               auto_apply: bool, limits: Limits, observe_interval: float, out: IO[str] = sys.stderr,
               owner: str | None = None, control: bool = True) -> int:
    """The ``plantkg serve`` command: start, print where things are, serve until a signal.
    ``control``: open the control socket (``plantkg apply`` of this plant then runs here)."""
    AgentDirectory.load(agents_file)  # a wrong agents file is a start-up error, not a page
    token_path = (token_file or default_token_file()).expanduser().resolve()
    token_path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    token, created = load_or_create_token(token_path)
    state = PlantState(files, agents_file, auto_apply=auto_apply, observe_interval=observe_interval,
                       owner=owner)
    running = start_server(listen, state, token, limits)
    commands, why_not = open_control(files, agents_file, owner, state) if control else (None, "--no-control")

    def ready() -> None:
        snap = state.snapshot
        print(f"plantkg serve listening on {running.address.url}", file=out)
        print(f"  plant:  {', '.join(files)}" + (f" (error: {snap.error})" if snap.error else ""), file=out)
        print(f"  token:  {token_path}" + (" (new)" if created else "") + "  (log in with it to apply)", file=out)
        print(f"  SPARQL: {running.address.url}/sparql", file=out)
        print(f"  apply:  {'automatic after each change of the files, drift put back' if auto_apply else 'on request'}", file=out)
        print(f"  `plantkg apply` of this plant: {'runs here, warm (' + str(commands.path) + ')' if commands else 'runs in its own process: ' + why_not}", file=out)
        out.flush()

    got = wait_for_signal(on_ready=ready)
    log.info("%s received; shutting down", got.name)
    if commands is not None:
        commands.close()
    running.shutdown()
    return 0

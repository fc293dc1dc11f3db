"""Running an agent: listen address, token file, state-dir lock, WSGI server, signals.

The app is served by werkzeug's threaded WSGI server in a thread of its own (werkzeug comes
with Flask; one engine talks to an agent over loopback or a plant network, a handful of requests
at a time, so a production server such as waitress would add a dependency and buy nothing here),
with a request handler of our own that keeps connections open between requests
(:mod:`engine.agent.keepalive`).
The main thread waits for SIGTERM/SIGINT, then stops the server and the supervisor; brokers keep
running unless ``stop_brokers_on_exit`` (they are the plant's, the agent only manages them).
"""

from __future__ import annotations

import fcntl
import ipaddress
import logging
import os
import secrets
import signal
import stat
import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from werkzeug.serving import BaseWSGIServer, make_server

from engine.agent import tls
from engine.agent.app import AgentState, create_app
from engine.agent.keepalive import KeepAliveHandler, close_connections, keep_alive
from engine.agent.manager import BrokerManager
from engine.agent.workers import WorkerManager
from engine.drivers.base import AGENT_TOKEN_FILE_ENV
from engine.drivers.registry import DriverRegistry
from engine.errors import EngineError
from engine.security import ca, principal_key
from engine.whole_file import create_once

log = logging.getLogger(__name__)

DEFAULT_PORT = 7300
TOKEN_FILE = "token"
LOCK_FILE = "agent.lock"


@dataclass(frozen=True)
class ListenAddress:
    host: str
    port: int
    tls: bool = False   # the API speaks HTTPS (engine.agent.tls)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{'https' if self.tls else 'http'}://{host}:{self.port}"


def parse_listen(text: str, *, allow_remote: bool = False) -> ListenAddress:
    """``ADDRESS[:PORT]`` (IPv6 in brackets); refuses a non-loopback address unless allowed."""
    host, port_text = text, str(DEFAULT_PORT)
    if text.startswith("["):
        host, sep, rest = text[1:].partition("]")
        if not sep or (rest and not rest.startswith(":")):
            raise EngineError(f"--listen {text!r}: expected [IPv6]:PORT")
        port_text = rest[1:] or port_text
    elif text.count(":") == 1:
        host, port_text = text.split(":")
    if host == "localhost":
        host = "127.0.0.1"
    try:
        address = ipaddress.ip_address(host)
    except ValueError:
        raise EngineError(f"--listen {text!r}: {host!r} is not an IP address",
                          hint="give an address such as 127.0.0.1:7300") from None
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise EngineError(f"--listen {text!r}: {port_text!r} is not a port (0..65535)")
    if not address.is_loopback and not allow_remote:
        raise EngineError(
            f"--listen {text!r} is not a loopback address; the agent would be reachable from "
            "the network",
            hint="add --allow-remote if that is intended (the token protects every route)",
        )
    return ListenAddress(str(address), int(port_text))


def load_or_create_token(path: Path) -> tuple[str, bool]:
    """The token in ``path``; a new random one (mode 0600) if the file does not exist.
    Returns (token, created). The file appears whole (written aside, then hard-linked), so a
    reader never sees it empty."""
    if path.exists():
        return _read_token(path), False
    token = secrets.token_urlsafe(32)
    try:
        created = create_once(path, token + "\n", mode=0o600)
    except OSError as exc:
        raise EngineError(f"cannot create the token file {path}: {exc.strerror}",
                          hint="give --token-file a path in an existing, writable folder") from None
    return (token, True) if created else (_read_token(path), False)


def _read_token(path: Path) -> str:
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
        token = path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise EngineError(f"cannot read the token file {path}: {exc}",
                          hint="fix its permissions, or delete it to get a new token") from None
    if mode & 0o077:
        log.warning("token file %s is readable by others (mode %o); chmod 600 it", path, mode)
    if len(token) < 16 or any(c.isspace() for c in token):
        raise EngineError(f"{path}: not a usable token (at least 16 characters, no blanks)",
                          hint="delete the file; the agent writes a new random token")
    return token


def lock_state_dir(state_dir: Path) -> IO[str]:
    """An exclusive lock on ``state_dir`` (held while the returned file stays open)."""
    handle = (state_dir / LOCK_FILE).open("a+", encoding="utf-8")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "?"
        handle.close()
        raise EngineError(f"another agent (pid {holder}) uses the state dir {state_dir}",
                          hint="stop it, or give this agent another --state-dir") from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"{os.getpid()}\n")
    handle.flush()
    return handle


@dataclass
class RunningAgent:
    """A started agent: stop it with :meth:`shutdown`."""

    address: ListenAddress
    server: BaseWSGIServer
    thread: threading.Thread
    manager: BrokerManager
    lock: IO[str]
    workers: WorkerManager | None = None
    tls_stop: threading.Event | None = None   # ends the certificate renewer (TLS only)

    def shutdown(self, *, stop_brokers: bool = False) -> None:
        if self.tls_stop is not None:
            self.tls_stop.set()
        self.server.shutdown()
        self.thread.join()
        close_connections(self.server)
        self.server.server_close()
        try:  # a worker that will not stop must not leave the brokers running, nor the lock held
            if self.workers is not None:
                self.workers.close(stop_workers=stop_brokers)
        finally:
            try:
                self.manager.close(stop_brokers=stop_brokers)
            finally:
                self.lock.close()


def start_agent(
    listen: ListenAddress,
    state_dir: Path,
    token: str,
    *,
    registry: DriverRegistry | None = None,
    name: str | None = None,
) -> RunningAgent:
    """Lock the state dir, re-adopt brokers, serve the API in a thread."""
    state_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    lock = lock_state_dir(state_dir)
    try:
        manager = BrokerManager(state_dir, registry or DriverRegistry.from_entry_points()).open()
    except BaseException:
        lock.close()
        raise
    workers = WorkerManager(state_dir).open()
    app = create_app(AgentState(manager, token, name or f"plantkg-agent@{listen.url}", workers))
    try:
        context = tls.server_context(state_dir, listen.host) if listen.tls else None
        server = keep_alive(make_server(listen.host, listen.port, app, threaded=True, ssl_context=context,
                                        request_handler=KeepAliveHandler))
    except (OSError, SystemExit, ca.CaError) as exc:  # werkzeug exits when the port is taken
        workers.close()
        manager.close()
        lock.close()
        raise EngineError(f"cannot listen on {listen.url}: {exc}",
                          hint="pick another --listen port, or stop what uses it") from None
    address = ListenAddress(listen.host, server.server_port, listen.tls)
    thread = threading.Thread(target=server.serve_forever, name="plantkg-http", daemon=True)
    thread.start()
    tls_stop = None
    if context is not None:
        tls_stop = threading.Event()
        tls.start_renewer(context, state_dir, listen.host, tls_stop)
    return RunningAgent(address, server, thread, manager, lock, workers, tls_stop)


def wait_for_signal(signals: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGINT),
                    on_ready: Callable[[], None] | None = None) -> signal.Signals:
    """Block the main thread until one of ``signals`` arrives; return it."""
    received: list[signal.Signals] = []
    done = threading.Event()

    def handler(signum: int, _frame: object) -> None:
        received.append(signal.Signals(signum))
        done.set()

    previous = {s: signal.signal(s, handler) for s in signals}
    try:
        if on_ready:
            on_ready()
        while not done.wait(3600):
            pass
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    return received[0]


def run_agent(listen: ListenAddress, state_dir: Path, token_file: Path | None, *,
              stop_brokers_on_exit: bool = False, name: str | None = None,
              out: IO[str] = sys.stderr, principal_key_file: Path | None = None,
              ca_dir: Path | None = None) -> int:
    """The ``plantkg agent`` command: start, print where things are, serve until a signal."""
    state_dir = state_dir.resolve()
    state_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    token_path = (token_file or state_dir / TOKEN_FILE).resolve()
    token, created = load_or_create_token(token_path)
    os.environ[AGENT_TOKEN_FILE_ENV] = str(token_path)   # brokers that check the agent's token
    key_path = principal_key.key_file(principal_key_file).resolve()
    key_new = not key_path.exists()
    principal_key.load_or_create_key(key_path)            # refuses an unusable key before serving
    os.environ[principal_key.KEY_ENV] = str(key_path)     # drivers, brokers and workers derive logins
    if ca_dir is not None:  # TLS brokers' certificates are issued from it (created on first need)
        os.environ[ca.CA_ENV] = str(ca_dir.resolve())
    agent = start_agent(listen, state_dir, token, name=name)

    def ready() -> None:
        print(f"plantkg agent listening on {agent.address.url}", file=out)
        print(f"  state dir: {state_dir}", file=out)
        print(f"  token:     {token_path}" + (" (new)" if created else ""), file=out)
        print(f"  principal key: {key_path}" + (" (new)" if key_new else ""), file=out)
        print(f"  drivers:   {', '.join(agent.manager.registry.kinds()) or 'none'}", file=out)
        out.flush()

    got = wait_for_signal(on_ready=ready)
    log.info("%s received; shutting down (brokers %s)", got.name,
             "stopped" if stop_brokers_on_exit else "left running")
    agent.shutdown(stop_brokers=stop_brokers_on_exit)
    return 0

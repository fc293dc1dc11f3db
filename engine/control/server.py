"""The server's side of the control socket (in ``plantkg serve``): run its user's commands warm.

Safe by construction:

- the socket lives in a folder only the user can open (created 0700; one that others can open
  is refused), is created 0600, and each connection's peer must be the same user
  (``SO_PEERCRED``): the socket gives nobody more than the files it reads already;
- a request is checked field by field (engine.control.request) before anything runs, and runs
  only for the plant this server serves, with the server's files, agents file and owner;
- each connection has a thread of its own and a deadline for its request, so one slow or silent
  client stops nobody else; at most :data:`MAX_CONNECTIONS` are served at once (more are told so);
- a socket left by a killed server is replaced; one another live server holds is not (this one
  then runs without it, and says why).
"""

from __future__ import annotations

import logging
import os
import socket
import stat
import struct
import threading
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import IO, Any

import click

from engine.cli.console import Console
from engine.control.address import MAX_SOCKET_PATH
from engine.control.request import Request, RequestError, parse_request
from engine.control.wire import PROTOCOL, WireError, receive, send
from engine.errors import EngineError
from kg.errors import PlantKGError

log = logging.getLogger(__name__)

MAX_CONNECTIONS = 16
REQUEST_TIMEOUT_S = 10.0     # from accept to the request
ANSWER_TIMEOUT_S = 600.0     # a person reading the plan before typing yes
EXIT_INTERNAL = 3            # as apply's "did not take effect": the server's log has the traceback

Handler = Callable[[Request, Console], int]


class ControlUnavailable(EngineError):
    """The control socket cannot be opened; the server runs without it."""


class SocketConsole:
    """A :class:`~engine.cli.console.Console` whose terminal is at the other end of the socket."""

    def __init__(self, stream: IO[bytes], conn: socket.socket, request: Request) -> None:
        self.stream = stream
        self.conn = conn
        self.color = request.color
        self.tty = request.tty
        self._lock = threading.Lock()

    def echo(self, text: str = "", *, err: bool = False) -> None:
        line = text if self.color else click.unstyle(text)
        with self._lock:
            send(self.stream, {"err" if err else "out": line})

    @property
    def interactive(self) -> bool:
        return self.tty

    def prompt(self, question: str) -> str:
        with self._lock:
            send(self.stream, {"ask": question})
            self.conn.settimeout(ANSWER_TIMEOUT_S)
            try:
                message = receive(self.stream)
            except (OSError, WireError):
                message = None
            finally:
                self.conn.settimeout(None)
        answer = message.get("answer") if message else None
        if not isinstance(answer, str):
            raise click.Abort()  # gone, silent for too long, or not an answer: nothing is changed
        return answer

    def progress(self) -> AbstractContextManager[Callable[[Any], None]]:
        from engine.cli.progress import Progress  # noqa: PLC0415

        return Progress(_Lines(self), live=False)


class _Lines:
    """A text stream that sends each complete line as an ``out`` message (Progress writes here)."""

    def __init__(self, console: SocketConsole) -> None:
        self.console = console
        self.buffer = ""

    def write(self, text: str) -> int:
        self.buffer += text
        *lines, self.buffer = self.buffer.split("\n")
        for line in lines:
            self.console.echo(line)
        return len(text)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False


def peer_uid(conn: socket.socket) -> int:
    """The user id of the process at the other end of a Unix socket (Linux ``SO_PEERCRED``)."""
    fmt = "3i"
    _pid, uid, _gid = struct.unpack(fmt, conn.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize(fmt)))
    return uid


def _private_folder(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    st = folder.stat()
    if st.st_uid != os.getuid() or stat.S_IMODE(st.st_mode) & 0o077:
        raise ControlUnavailable(
            f"{folder} is not a folder only this user can open (owner uid {st.st_uid}, mode "
            f"{stat.S_IMODE(st.st_mode):o})", hint="set PLANTKG_RUN_DIR to a folder of yours with mode 0700")


def _claim(path: Path) -> None:
    """Remove a socket left by a killed server; refuse one a live server answers on."""
    if not path.exists() and not path.is_symlink():
        return
    if not stat.S_ISSOCK(path.lstat().st_mode):
        raise ControlUnavailable(f"{path} exists and is not a socket", hint="remove it, or set PLANTKG_RUN_DIR")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.settimeout(1.0)
        probe.connect(str(path))
    except (ConnectionRefusedError, FileNotFoundError):
        path.unlink(missing_ok=True)  # its server is gone
        return
    except OSError:
        pass
    finally:
        probe.close()
    raise ControlUnavailable(f"another plantkg serve of this plant answers on {path}",
                             hint="commands go to that one; stop it to have them run here")


class ControlServer:
    """Accepts commands on ``path`` and runs each with ``handler`` in a thread of its own."""

    def __init__(self, path: Path, served_key: dict[str, Any], handler: Handler) -> None:
        self.path = path
        self.served_key = served_key
        self.handler = handler
        self._listener: socket.socket | None = None
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._threads: list[threading.Thread] = []
        self._accepting: threading.Thread | None = None
        self._stopping = threading.Event()

    def start(self) -> ControlServer:
        """Bind and listen (raises ControlUnavailable, nothing left behind, if it cannot)."""
        if len(str(self.path)) > MAX_SOCKET_PATH:
            raise ControlUnavailable(f"the socket path {self.path} is longer than {MAX_SOCKET_PATH} bytes",
                                     hint="set PLANTKG_RUN_DIR to a shorter folder")
        _private_folder(self.path.parent)
        _claim(self.path)
        listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)
        try:
            listener.bind(str(self.path))
        except OSError as exc:
            listener.close()
            raise ControlUnavailable(f"cannot listen on {self.path}: {exc}") from None
        finally:
            os.umask(old)
        os.chmod(self.path, 0o600)
        listener.listen(MAX_CONNECTIONS)
        self._listener = listener
        self._accepting = threading.Thread(target=self._accept, name="plantkg-control", daemon=True)
        self._accepting.start()
        return self

    def _accept(self) -> None:
        listener = self._listener
        assert listener is not None
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return  # closed
            if self._stopping.is_set():
                conn.close()
                return
            if not self._slots.acquire(blocking=False):
                self._refuse(conn, "plantkg serve runs as many commands as it may at once; try again")
                continue
            thread = threading.Thread(target=self._serve, args=(conn,), name="plantkg-control-conn", daemon=True)
            self._threads = [t for t in self._threads if t.is_alive()] + [thread]
            thread.start()

    @staticmethod
    def _refuse(conn: socket.socket, why: str) -> None:
        try:
            stream = conn.makefile("rwb")
            send(stream, {"hello": {"pid": os.getpid(), "protocol": PROTOCOL}})
            send(stream, {"err": f"error: {why}"})
            send(stream, {"exit": 2})
        except OSError:
            pass
        finally:
            conn.close()

    def _serve(self, conn: socket.socket) -> None:
        try:
            if peer_uid(conn) != os.getuid():
                log.warning("control socket: a process of another user was refused")
                return
            stream = conn.makefile("rwb")
            conn.settimeout(REQUEST_TIMEOUT_S)
            send(stream, {"hello": {"pid": os.getpid(), "protocol": PROTOCOL}})
            message = receive(stream)
            conn.settimeout(None)
            if message is None:
                return
            try:
                request = parse_request(message, self.served_key)
            except RequestError as exc:
                send(stream, {"err": f"error: {exc}"})
                send(stream, {"exit": exc.exit_code})
                return
            console = SocketConsole(stream, conn, request)
            code = run_guarded(lambda: self.handler(request, console), console)
            send(stream, {"exit": code})
        except (OSError, WireError) as exc:
            log.info("control socket: a client went away: %s", exc)
        finally:
            conn.close()
            self._slots.release()

    def close(self, timeout: float = 60.0) -> None:
        """Stop accepting, remove the socket, and wait for running commands to finish."""
        listener = self._listener
        if listener is None or self._stopping.is_set():
            return
        self._stopping.set()
        waker = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:  # accept() returns to a connection; closing the socket alone need not wake it
            waker.settimeout(1.0)
            waker.connect(str(self.path))
        except OSError:
            pass
        finally:
            waker.close()
        if self._accepting is not None:
            self._accepting.join(timeout)
        listener.close()
        self.path.unlink(missing_ok=True)
        for thread in list(self._threads):
            thread.join(timeout)


def run_guarded(run: Callable[[], int], console: Console) -> int:
    """``run``'s exit code, with errors told to the command's user as ``plantkg`` tells them."""
    try:
        return run()
    except PlantKGError as error:
        console.echo(click.style("error: ", fg="red", bold=True) + str(error), err=True)
        return error.exit_code
    except click.ClickException as error:
        console.echo(f"error: {error.format_message()}", err=True)
        return error.exit_code
    except click.Abort:
        console.echo("aborted", err=True)
        return 130
    except (OSError, WireError):
        raise  # the client is gone: nothing to tell
    except Exception as exc:  # noqa: BLE001 - the command's user gets a message, the log a traceback
        log.exception("control socket: the command failed")
        console.echo(f"error: plantkg serve failed while running the command: {exc!r} (its log has the "
                     "traceback)", err=True)
        return EXIT_INTERNAL

"""The command's side of the control socket: hand ``apply`` to the ``plantkg serve`` of its plant.

Standard library only, and imported before anything else of ``apply``: a command that a warm
server runs must not pay for the imports it hands over. :func:`run_in_server` returns None —
run here instead — when no server serves exactly these files, agents file and owner, when the
socket is stale (its server was killed), or when the server does not say hello within
:data:`HELLO_TIMEOUT_S`; nothing has been asked of it then, so running alone changes nothing
twice. Once the request is sent, the server's exit code is the command's; if the server goes
away before it says one, the command exits 3 (run it again: what is done is not repeated).
"""

from __future__ import annotations

import os
import socket
import sys
from collections.abc import Sequence
TYPE_CHECKING = False  # typing is not imported: the command starts at once
if TYPE_CHECKING:
    from typing import Any

from engine.control.address import MAX_SOCKET_PATH, plant_key, socket_file
from engine.control.wire import PROTOCOL, WireError, receive, send

HELLO_TIMEOUT_S = 5.0
EXIT_SERVER_GONE = 3  # as apply's "some changes did not take effect": run it again
EXIT_INTERRUPTED = 130


def run_in_server(verb: str, files: Sequence[str], agents_file: str | os.PathLike[str] | None,
                  owner: str | None, options: dict[str, Any]) -> int | None:
    """Run ``verb`` with ``options`` in the server of this plant; its exit code, or None when
    there is no server to run it (see the module docstring)."""
    path = socket_file(files, agents_file, owner)
    if len(path) > MAX_SOCKET_PATH:
        return None
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        conn.settimeout(HELLO_TIMEOUT_S)
        try:
            conn.connect(path)
            stream = conn.makefile("rwb")
            hello = receive(stream)
        except (OSError, WireError):
            return None  # no server, a stale socket, or a server that does not answer: run here
        if not hello or not isinstance(hello.get("hello"), dict) or hello["hello"].get("protocol") != PROTOCOL:
            return None
        conn.settimeout(None)
        request = {"verb": verb, "key": plant_key(files, agents_file, owner), **options,
                   "tty": sys.stdin.isatty(), "color": sys.stdout.isatty()}
        print(f"plantkg: {verb} runs in plantkg serve (pid {hello['hello'].get('pid')}), which serves "
              "this plant; --local runs it in this process", file=sys.stderr)
        return _converse(stream, request)
    finally:
        conn.close()


def _converse(stream: Any, request: dict[str, Any]) -> int:
    """Send the request, then print what the server says and answer its question until its exit code."""
    try:
        send(stream, {"request": request})
        while True:
            message = receive(stream)
            if message is None:
                break
            if "out" in message:
                print(message["out"], flush=True)
            elif "err" in message:
                print(message["err"], file=sys.stderr, flush=True)
            elif "ask" in message:
                send(stream, {"answer": _ask(str(message["ask"]))})
            elif "exit" in message:
                code = message["exit"]
                return code if isinstance(code, int) else EXIT_SERVER_GONE
    except KeyboardInterrupt:
        print("interrupted (plantkg serve finishes a change it started; see plantkg status)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (OSError, WireError) as exc:
        print(f"error: the connection to plantkg serve failed: {exc}", file=sys.stderr)
        return EXIT_SERVER_GONE
    print("error: plantkg serve closed the connection before the end (see its log); run the command "
          "again, or `plantkg status` to see what runs", file=sys.stderr)
    return EXIT_SERVER_GONE


def _ask(question: str) -> str:
    print(question, flush=True)
    try:
        return input("  Enter a value: ")
    except EOFError:
        return ""

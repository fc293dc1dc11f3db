"""The control socket's messages: one JSON object per line, in both directions (standard library only).

Server to client: ``{"hello": {"pid": N, "version": V}}`` first, then any of ``{"out": text}``
(a line for stdout), ``{"err": text}`` (for stderr), ``{"ask": text}`` (show it and send back
``{"answer": line}``) and, last, ``{"exit": code}``. Client to server: the request (after the
hello), then answers. A line longer than :data:`MAX_LINE` is refused, so neither side can be made
to hold an unbounded message.
"""

from __future__ import annotations

import json
TYPE_CHECKING = False  # typing is not imported: the command starts at once
if TYPE_CHECKING:
    from typing import IO, Any

MAX_LINE = 1 << 20
PROTOCOL = 1


class WireError(Exception):
    """The other side sent something that is not a message of this protocol."""


def send(stream: IO[bytes], message: dict[str, Any]) -> None:
    stream.write(json.dumps(message, separators=(",", ":")).encode() + b"\n")
    stream.flush()


def receive(stream: IO[bytes]) -> dict[str, Any] | None:
    """The next message, or None when the other side closed the connection."""
    line = stream.readline(MAX_LINE + 1)
    if not line:
        return None
    if len(line) > MAX_LINE or not line.endswith(b"\n"):
        raise WireError(f"a message longer than {MAX_LINE} bytes, or cut short")
    try:
        message = json.loads(line)
    except ValueError as exc:
        raise WireError(f"not JSON: {exc}") from None
    if not isinstance(message, dict):
        raise WireError(f"not a JSON object: {type(message).__name__}")
    return message

"""A command sent over the control socket, checked field by field before anything runs.

The request names the plant it is for (``key``, engine.control.address.plant_key); a server runs
it only for its own plant, with its own files, agents file and owner — the request's options
(``yes``, ``parallelism``, ``prune``, ``format``) are the only thing the command chooses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from engine.errors import EngineError

VERBS = ("apply", "destroy")
FORMATS = ("text", "json")
MAX_PARALLELISM = 64


class RequestError(EngineError):
    """A request field is missing or holds a value the command line could not have sent."""


@dataclass(frozen=True)
class Request:
    """What the command asks: ``verb`` with its options; ``tty``/``color`` say what its terminal can."""

    verb: str
    key: dict[str, Any]
    yes: bool = False
    parallelism: int = 8
    prune: bool = False
    fmt: str = "text"
    tty: bool = False
    color: bool = False


def _bool(body: dict[str, Any], name: str, default: bool) -> bool:
    value = body.get(name, default)
    if not isinstance(value, bool):
        raise RequestError(f"request field {name!r}: {value!r} is not true or false")
    return value


def parse_request(message: dict[str, Any], served_key: dict[str, Any]) -> Request:
    """The request of ``{"request": {...}}``; RequestError names the field and its value."""
    body = message.get("request")
    if not isinstance(body, dict):
        raise RequestError(f"not a request: {sorted(message)!r}", hint="send {\"request\": {...}} after the hello")
    verb = body.get("verb")
    if verb not in VERBS:
        raise RequestError(f"request field 'verb': {verb!r} is not one of {', '.join(VERBS)}")
    key = body.get("key")
    if key != served_key:
        raise RequestError(f"request field 'key': {key!r} is not the plant this server serves ({served_key!r})",
                           hint="run the command in its own process (--local), or against the server of that plant")
    parallelism = body.get("parallelism", 8)
    if not isinstance(parallelism, int) or isinstance(parallelism, bool) or not 1 <= parallelism <= MAX_PARALLELISM:
        raise RequestError(f"request field 'parallelism': {parallelism!r} is not an integer in 1..{MAX_PARALLELISM}")
    fmt = body.get("format", "text")
    if fmt not in FORMATS:
        raise RequestError(f"request field 'format': {fmt!r} is not one of {', '.join(FORMATS)}")
    return Request(verb=verb, key=key, yes=_bool(body, "yes", False), parallelism=parallelism,
                   prune=_bool(body, "prune", False), fmt=fmt, tty=_bool(body, "tty", False),
                   color=_bool(body, "color", False))

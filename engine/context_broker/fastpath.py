"""The hot writes served before Flask: ``POST /v2/entities`` (the bridges' ``options=upsert``),
``POST``/``PATCH``/``PUT /v2/entities/{id}/attrs`` and ``PUT /v2/entities/{id}/attrs/{name}/value``,
the requests a fleet sends many times a second.

Flask's per-request machinery (request context, URL adapter, routing, response object) costs
more than the write itself. :func:`fast_writes` wraps the Flask app's WSGI callable and serves
these requests directly, with the same functions as the Flask views (:func:`.routes.create`,
:func:`.routes.write_attrs`, :func:`.routes.write_value`, :mod:`.params`) in the same order, so
answers are the same:

- Only a plain request takes the fast path: an ASCII path matching one of the routes, a
  query string of at most ``type`` (not for ``/v2/entities``) and ``options`` (once each, nothing percent-encoded), the
  exact token header (``Bearer <token>``; anything else, e.g. a missing or wrong token, goes to
  Flask's gate for its 401), a ``Content-Length`` within the 1 MB limit and no chunked body, a
  ``Content-Type`` without parameters. Everything else goes to Flask unchanged.
- A refusal is an :class:`NgsiError` answered with Orion's body as Flask's handler does; an
  unexpected exception is logged with its traceback and answered 500, as Flask's handler does.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Callable, Iterable
from typing import Any

from werkzeug.datastructures import EnvironHeaders
from werkzeug.http import HTTP_STATUS_CODES

from engine.context_broker.contract import NgsiError
from engine.context_broker.entities import parse_attrs, parse_entity
from engine.context_broker.names import check_attribute_name, check_identifier
from engine.context_broker.params import (
    check_url_param, json_from, parse_entity_type, parse_options, value_from, write_tenant,
)
from engine.context_broker.routes import (
    ATTRS_WRITES, CREATE_OPTIONS, VALUE_OPTIONS, create, created_location, write_attrs, write_value,
)
from engine.context_broker.store import ContextStore

log = logging.getLogger("engine.context_broker.app")
ATTRS_PATH = re.compile(r"/v2/entities/([^/]+)/attrs")
VALUE_PATH = re.compile(r"/v2/entities/([^/]+)/attrs/([^/]+)/value")
QUERY_KEYS = frozenset({"type", "options"})
ENTITIES_PATH = "/v2/entities"
NO_CONTENT = "204 NO CONTENT"
CREATED = "201 CREATED"
NO_CONTENT_HEADERS = [("Content-Type", "text/html; charset=utf-8")]  # what Flask's 204 carries
CREATED_HEADERS = (("Content-Type", "text/html; charset=utf-8"), ("Content-Length", "0"))  # and its 201

WSGIApp = Callable[[dict[str, Any], Callable[..., Any]], Iterable[bytes]]


def _status(code: int) -> str:
    return f"{code} {HTTP_STATUS_CODES.get(code, 'UNKNOWN').upper()}"


def _query(raw: str) -> dict[str, str] | None:
    """``type`` and ``options`` of a plain query string; None when Flask must read it."""
    if not raw:
        return {}
    if "%" in raw or "+" in raw:
        return None
    out: dict[str, str] = {}
    for item in raw.split("&"):
        key, eq, value = item.partition("=")
        if not eq or key not in QUERY_KEYS or key in out:
            return None
        out[key] = value
    return out


INLINE_BODY = 64 * 1024


def is_hot_write(environ: dict[str, Any]) -> bool:
    """A write the fast path serves with a body of at most 64 KB: cheap enough (~0.2 ms) for the
    HTTP server to run it on its event loop instead of handing it to a worker thread. A guess
    that is wrong costs time, not correctness: whatever runs inline gets the same answer."""
    method = environ.get("REQUEST_METHOD")
    if method not in ATTRS_WRITES:
        return False
    length = environ.get("CONTENT_LENGTH", "")
    if not length.isdigit() or int(length) > INLINE_BODY:
        return False
    path = environ.get("PATH_INFO", "")
    if method == "POST" and path == ENTITIES_PATH:
        return True
    return (ATTRS_PATH.fullmatch(path) is not None
            or (method == "PUT" and VALUE_PATH.fullmatch(path) is not None))


def fast_writes(flask_app: WSGIApp, store: ContextStore, token: str | None, max_body: int,
                clock: Callable[[], float]) -> WSGIApp:
    """``flask_app`` with the hot writes served first (see the module docstring)."""
    auth = None if token is None else f"Bearer {token}"

    def app(environ: dict[str, Any], start_response: Callable[..., Any]) -> Iterable[bytes]:
        method = environ.get("REQUEST_METHOD")
        if method not in ATTRS_WRITES:
            return flask_app(environ, start_response)
        path = environ.get("PATH_INFO", "")
        entities = method == "POST" and path == ENTITIES_PATH
        attrs = None if entities else ATTRS_PATH.fullmatch(path)
        value = VALUE_PATH.fullmatch(path) if attrs is None and method == "PUT" else None
        query = _query(environ.get("QUERY_STRING", ""))
        length = environ.get("CONTENT_LENGTH", "")
        mimetype = environ.get("CONTENT_TYPE", "")
        if ((not entities and attrs is None and value is None) or query is None
                or (entities and "type" in query) or not path.isascii()
                or (auth is not None and environ.get("HTTP_AUTHORIZATION") != auth)
                or not length.isdigit() or int(length) > max_body or "HTTP_TRANSFER_ENCODING" in environ
                or mimetype not in ("application/json", "text/plain")):
            return flask_app(environ, start_response)
        try:
            for name, given in query.items():
                check_url_param(name, given)
            if entities:
                opts = parse_options(query.get("options"), CREATE_OPTIONS)
                parsed = parse_entity(json_from(mimetype, environ["wsgi.input"].read(int(length))),
                                      key_values="keyValues" in opts)
                made = create(store, write_tenant(EnvironHeaders(environ)), clock(), parsed, opts)
                if made is not None:
                    start_response(CREATED, [("Location", created_location(*made)), *CREATED_HEADERS])
                    return [b""]
            elif attrs is not None:
                allowed, mode = ATTRS_WRITES[method]
                opts = parse_options(query.get("options"), allowed)
                eid = check_identifier(attrs.group(1), "entity id")
                etype = parse_entity_type(query.get("type"))
                body = json_from(mimetype, environ["wsgi.input"].read(int(length)))
                changes = parse_attrs(body, key_values="keyValues" in opts)
                write_attrs(store, write_tenant(EnvironHeaders(environ)), clock(), eid, etype,
                            changes, opts, mode)
            else:
                assert value is not None
                opts = parse_options(query.get("options"), VALUE_OPTIONS)
                eid = check_identifier(value.group(1), "entity id")
                etype = parse_entity_type(query.get("type"))
                name = check_attribute_name(value.group(2))
                new = value_from(mimetype, environ["wsgi.input"].read(int(length)))
                write_value(store, write_tenant(EnvironHeaders(environ)), clock(), eid, etype,
                            name, new, opts)
        except NgsiError as err:
            return _error(start_response, err)
        except Exception as err:
            log.exception("unexpected error on %s %s", method, path)
            return _error(start_response, NgsiError(
                500, "InternalServerError", f"internal error ({type(err).__name__}); see the "
                                            "context broker's log"))
        start_response(NO_CONTENT, list(NO_CONTENT_HEADERS))
        return [b""]

    return app


def _error(start_response: Callable[..., Any], err: NgsiError) -> list[bytes]:
    body = json.dumps(err.body(), ensure_ascii=False, separators=(",", ":")).encode()
    headers = [*err.headers.items(), ("Content-Type", "application/json"),
               ("Content-Length", str(len(body)))]
    start_response(_status(err.status), headers)
    return [body]


__all__ = ["fast_writes", "is_hot_write"]

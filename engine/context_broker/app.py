"""The context broker's Flask app: ``create_app(store, ...)``.

What every request goes through, before its view (in this order):

1. writes (POST, PUT, PATCH, DELETE; ``POST /v2/op/query`` is a read) need
   ``Authorization: Bearer <token>`` when the app has a token: 401 ``Unauthorized`` otherwise;
   on a closed broker (a ``gate``, :mod:`.access`) every request but ``/version`` needs a
   principal's token (401 without, 403 outside its rights, checked after step 2); the
   principal is left in the environ for the subscriptions blueprint (:mod:`.subscriptions.ownership`);
2. a body-carrying request without ``Content-Length`` (nor chunked encoding): 411
   ``ContentLengthRequired``; over 1 MB (Orion's limit): 413 ``RequestEntityTooLarge``;
3. tenancy headers are checked by the views (``Fiware-Service``, ``Fiware-ServicePath``).

Every :class:`NgsiError` (also from the subscriptions blueprint) is answered with Orion's body
``{"error", "description"}``; unknown URLs 404 ``NotFound``, a wrong method 405
``MethodNotAllowed`` with ``Allow`` (what Orion sends, HttpStatusCode.cpp; its manual's
"MethodNotAlowed" is a typo). Any other exception is a bug: logged with
its traceback and answered 500 ``InternalServerError``.

The hot writes (``/attrs`` and ``/attrs/{name}/value``) of a plain request are served before
Flask by :mod:`.fastpath`, with the same functions and the same answers.

Also served: ``GET /version`` (Orion-shaped, FiLiP reads ``orion.version``), ``GET /v2``,
``GET /plantkg/v1/graph`` (the whole context as N-Quads), ``GET /plantkg/v1/openapi.json``.
"""

from __future__ import annotations

import hmac
import logging
import time
from collections.abc import Callable, Iterable
from typing import Any

from flask import Blueprint, Flask, Response, request
from werkzeug.exceptions import HTTPException, MethodNotAllowed, NotFound, RequestEntityTooLarge

from engine.context_broker import batch, routes
from engine.context_broker.access import PUBLIC_PATHS, Gate, authorize, requester
from engine.context_broker.contract import ChangeListener, NgsiError
from engine.context_broker.fastpath import fast_writes
from engine.context_broker.openapi import openapi_document
from engine.context_broker.params import FREE_PARAMS, check_url_param
from engine.context_broker.routes import json_response
from engine.context_broker.store import ContextStore
from engine.context_broker.subscriptions.ownership import ENVIRON_KEY

log = logging.getLogger(__name__)
MAX_BODY = 1024 * 1024
DRAIN_LIMIT = 16 * MAX_BODY
ORION_VERSION = "3.10.1"
PLANTKG_VERSION = "0.1.0"
WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
READ_POSTS = ("/v2/op/query",)


def _error(err: NgsiError) -> Response:
    return json_response(err.body(), err.status, err.headers)


def create_app(store: ContextStore, *, token: str | None = None,
               listeners: Iterable[ChangeListener] = (),
               subscriptions_blueprint: Blueprint | None = None,
               clock: Callable[[], float] = time.time, fast: bool = True,
               gate: Gate | None = None) -> Flask:
    """The WSGI app over ``store``. ``token`` None: writes are open. ``gate``: the broker is
    closed (:mod:`.access`): every request but ``/version`` needs a principal's token (or
    ``token``, which ``gate`` holds as plantkg's own principal) and stays within its rights.
    ``listeners`` are told
    every change (see :class:`ChangeListener`); ``subscriptions_blueprint`` serves
    ``/v2/subscriptions`` under the same token check and error handling. ``fast`` False: every
    request goes through Flask (the fast path's tests compare the two)."""
    app = Flask(__name__)
    app.url_map.merge_slashes = False
    inner = fast_writes(app.wsgi_app, store, token, MAX_BODY, clock) if fast else app.wsgi_app
    app.wsgi_app = _without_trailing_slash(inner)  # type: ignore[method-assign]
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY
    started = clock()
    for listener in listeners:
        store.add_listener(listener)

    access = gate

    @app.before_request
    def check_request() -> Response | None:
        method = request.method
        who = access.principal(request.headers) if access is not None and request.path not in PUBLIC_PATHS else None
        if who is None and method in WRITE_METHODS and token is not None and not (
                method == "POST" and request.path.rstrip("/") in READ_POSTS):
            given = request.headers.get("Authorization", "")
            scheme, _, value = given.partition(" ")
            if scheme.lower() != "bearer" or not hmac.compare_digest(value.strip().encode(), token.encode()):
                what = "missing" if not given else "wrong"
                raise NgsiError(401, "Unauthorized", f"{what} token: writes need the header "
                                "Authorization: Bearer <token> (the broker's --token-file)",
                                {"WWW-Authenticate": 'Bearer realm="plantkg context broker"'})
        for name, value in request.args.items(multi=True):
            if name not in FREE_PARAMS:
                check_url_param(name, value)
        if method in ("POST", "PUT", "PATCH"):
            chunked = "chunked" in (request.headers.get("Transfer-Encoding") or "").lower()
            length = request.content_length
            if length is None and not chunked:
                raise NgsiError(411, "ContentLengthRequired",
                                "Zero/No Content-Length in PUT/POST/PATCH request: send Content-Length")
            if length is not None and length > MAX_BODY:
                _drain(request.environ, length)
                raise _too_large(length)
        if who is not None:
            body = request.get_json(silent=True) if method == "POST" else None
            authorize(who, method, request.path, request.args, body)
        request.environ[ENVIRON_KEY] = requester(who)
        return None

    app.register_error_handler(NgsiError, _error)

    @app.errorhandler(HTTPException)
    def http_error(err: HTTPException) -> Response:
        if isinstance(err, MethodNotAllowed):
            allowed = sorted(m for m in (err.valid_methods or []) if m not in ("HEAD", "OPTIONS"))
            return _error(NgsiError(405, "MethodNotAllowed",
                                    f"method {request.method} not allowed on {request.path}; "
                                    f"allowed: {', '.join(allowed)}", {"Allow": ", ".join(allowed)}))
        if isinstance(err, NotFound):
            return _error(NgsiError(404, "NotFound", f"no such resource: {request.path} (see "
                                                     "GET /v2 and /plantkg/v1/openapi.json)"))
        if isinstance(err, RequestEntityTooLarge):
            return _error(_too_large(request.content_length))
        return _error(NgsiError(err.code or 400, "BadRequest", err.description or str(err)))

    @app.errorhandler(Exception)
    def bug(err: Exception) -> Response:
        log.exception("unexpected error on %s %s", request.method, request.path)
        return _error(NgsiError(500, "InternalServerError", f"internal error ({type(err).__name__}); "
                                                            "see the context broker's log"))

    @app.get("/version")
    def version() -> Response:
        return json_response({
            "orion": {"version": ORION_VERSION, "uptime": f"{int(clock() - started)} s",
                      "git_hash": "plantkg", "compile_time": "", "compiled_by": "plantkg",
                      "compiled_in": "", "release_date": "", "doc": "/plantkg/v1/openapi.json"},
            "plantkg": {"version": PLANTKG_VERSION, "api": "NGSI-v2, Orion 3.x-compatible subset",
                        "store": "oxigraph", "entities": store.count()}})

    @app.get("/v2")
    def resources() -> Response:
        return json_response({"entities_url": "/v2/entities", "types_url": "/v2/types",
                              "subscriptions_url": "/v2/subscriptions",
                              "registrations_url": "/v2/registrations"})

    @app.get("/plantkg/v1/graph")
    def graph() -> Response:
        return Response(store.nquads(), mimetype="application/n-quads")

    @app.get("/plantkg/v1/openapi.json")
    def openapi() -> Response:
        return json_response(openapi_document(with_subscriptions=subscriptions_blueprint is not None))

    app.register_blueprint(routes.make_blueprint(store, clock))
    app.register_blueprint(batch.make_blueprint(store, clock))
    if subscriptions_blueprint is not None:
        app.register_blueprint(subscriptions_blueprint)
    return app


def _drain(environ: dict[str, Any], length: int) -> None:
    """Read (and drop) a refused body of up to DRAIN_LIMIT bytes, so the client, still
    sending, reads the 413 instead of a broken pipe; larger bodies are not read at all."""
    if length > DRAIN_LIMIT:
        return
    stream = environ["wsgi.input"]
    left = length
    while left > 0:
        chunk = stream.read(min(left, 65536))
        if not chunk:
            break
        left -= len(chunk)


def _without_trailing_slash(wsgi_app: Callable[..., Any]) -> Callable[..., Any]:
    """``/v2/entities/`` is ``/v2/entities`` (FiLiP calls the first): one rule per route, and a
    wrong method still finds its route (405 with ``Allow``, not 404)."""
    def app(environ: dict[str, Any], start_response: Callable[..., Any]) -> Any:
        path = environ.get("PATH_INFO", "")
        if len(path) > 1 and path.endswith("/"):
            environ["PATH_INFO"] = path.rstrip("/") or "/"
        return wsgi_app(environ, start_response)
    return app


def _too_large(length: Any) -> NgsiError:
    return NgsiError(413, "RequestEntityTooLarge",
                     f"payload size: {length} bytes, max size supported: {MAX_BODY} bytes")

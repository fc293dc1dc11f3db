"""The agent's HTTP API (Flask): ``create_app(state)`` with one blueprint, ``/v1``.

Routes and bodies are those of docs/engine-contracts.md; the OpenAPI document
(:mod:`engine.agent.openapi`) describes them. Every route but ``/v1/openapi.json`` needs
``Authorization: Bearer <token>`` (compared in constant time). Errors are JSON
``{"error", "hint", "retryable", "field"?}``:

=====  ==================================================================================
400    malformed JSON, unknown/missing field, invalid value (``field`` names it)
401    missing or wrong token
404    unknown broker or route
409    the broker cannot do it: fewer Kafka partitions, broker failed or stopped (a PUT that
       would start a broker the operator stopped, too); or the
       request names an ``owner`` and another plant owns the broker, topic or bridge
422    the agent cannot do it: no driver for the kind, a part missing, the broker exited
       while starting
503    try again: the broker is still starting, restarting, or did not answer (retryable)
500    a bug in the agent (retryable: it may be transient)
=====  ==================================================================================
"""

from __future__ import annotations

import hmac
import json
import logging
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from typing import Any

from flask import Blueprint, Flask, Response, current_app, jsonify, request
from werkzeug.exceptions import HTTPException
from werkzeug.routing import PathConverter

from engine.agent.batch import parse_batch, run_batch
from engine.agent.changes import REMOTE_TOKEN, Changes, check_remote_token, error_body, error_status
from engine.agent.manager import BrokerManager, BrokerNotFoundError
from engine.agent.openapi import openapi_document
from engine.agent.owners import OWNER_FIELD, check_owner
from engine.agent.wire import (
    BROKER_ID,
    WireError,
    bridge_spec_from_json,
    broker_spec_from_json,
    topic_spec_from_json,
)
from engine.agent.workers import WorkerManager
from engine.model import to_dict

log = logging.getLogger(__name__)

MAX_BODY_BYTES = 1 << 20
EXTENSION = "plantkg_agent"


@dataclass(frozen=True)
class AgentState:
    """What the app serves: the brokers, the token clients must present, the agent's name, and
    the bridge workers (None: this agent refuses worker bridges)."""

    brokers: BrokerManager
    token: str
    name: str = "plantkg-agent"
    workers: WorkerManager | None = None

    @property
    def changes(self) -> Changes:
        return Changes(self.brokers, self.workers)


class TopicName(PathConverter):
    """Any non-empty rest of the path: MQTT topic names hold slashes, even leading or doubled
    ones (a client percent-encodes the name; the server decodes %2F back to /). Any character at
    all, a newline too (``.`` would not match it: a name ending in %0A found no route, a 404 the
    document does not list, found by the fuzzer): the handler refuses a bad name with a 400."""

    regex = r"[\s\S]+"
    part_isolating = False


v1 = Blueprint("v1", __name__, url_prefix="/v1")


def create_app(state: AgentState) -> Flask:
    """A Flask app serving ``state``; start ``state.brokers`` (``open()``) before serving."""
    app = Flask("engine.agent")
    app.config["MAX_CONTENT_LENGTH"] = MAX_BODY_BYTES
    app.json.sort_keys = False  # type: ignore[attr-defined]
    app.extensions[EXTENSION] = state
    app.url_map.converters["topic"] = TopicName
    app.url_map.merge_slashes = False
    app.register_blueprint(v1)
    app.register_error_handler(HTTPException, _http_error)
    app.register_error_handler(Exception, _error)
    return app


def _state() -> AgentState:
    return current_app.extensions[EXTENSION]


# --- authentication ------------------------------------------------------------------------

@v1.before_request
def _authenticate() -> Response | None:
    if request.endpoint == "v1.openapi":
        return None
    header = request.headers.get("Authorization", "")
    scheme, _, token = header.partition(" ")
    expected = _state().token.encode("utf-8")
    if scheme.lower() == "bearer" and hmac.compare_digest(token.strip().encode("utf-8"), expected):
        return None
    response = _json_error(401, "missing or wrong bearer token",
                           "send 'Authorization: Bearer <token>' with the token from the agent's "
                           "token file", retryable=False)
    response.headers["WWW-Authenticate"] = 'Bearer realm="plantkg-agent"'
    return response


# --- routes --------------------------------------------------------------------------------

@v1.get("/health")
def health() -> Response:
    state = _state()
    return jsonify({
        "status": "ok",
        "agent": state.name,
        "version": _version(),
        "drivers": state.brokers.registry.kinds(),
        "driver_errors": state.brokers.registry.errors,
    })


@v1.get("/brokers")
def list_brokers() -> Response:
    return jsonify({"brokers": to_dict(_state().brokers.list())})


def _bridges(state: AgentState) -> list[Any]:
    found = state.brokers.native_bridges() + (state.workers.list() if state.workers else [])
    return to_dict(sorted(found, key=lambda b: b.spec.address))


@v1.get("/state")
def state() -> Response:
    """What GET /v1/brokers and GET /v1/bridges answer, in one request (the engine's observation)."""
    st = _state()
    return jsonify({"brokers": to_dict(st.brokers.list()), "bridges": _bridges(st)})


@v1.post("/batch")
def batch() -> Response:
    """Many changes in one request (engine.agent.batch): lanes in parallel, items of a lane in
    order, a result per item; with ``observe`` also the brokers and bridges afterwards."""
    lanes, observe = parse_batch(_body())
    state = _state()
    answer: dict[str, Any] = {"lanes": run_batch(state.changes, lanes)}
    if observe:
        answer["brokers"] = to_dict(state.brokers.list())
        answer["bridges"] = _bridges(state)
    return jsonify(answer)


@v1.get("/brokers/<broker_id>")
def get_broker(broker_id: str) -> Response:
    observed = _state().brokers.get(_broker_id(broker_id))
    if observed is None:
        raise BrokerNotFoundError(broker_id)
    return jsonify(to_dict(observed))


@v1.put("/brokers/<broker_id>")
def put_broker(broker_id: str) -> Response:
    """The body is the BrokerSpec, plus an optional ``owner`` (the plant that owns it)."""
    body = _body()
    owner = _owner_of(body)
    spec = broker_spec_from_json(body)
    if spec.id != _broker_id(broker_id):
        raise WireError("id", f"{spec.id!r} differs from the id in the URL ({broker_id!r})")
    return jsonify(to_dict(_state().changes.put_broker(spec, owner)))


@v1.put("/brokers/<broker_id>/owner")
def put_owner(broker_id: str) -> Response:
    """Import: ``{"owner": ...}`` becomes the owner of the broker and of every topic and bridge
    on it that nobody owns (409 if another plant owns the broker). Nothing is restarted."""
    body = _body()
    if not isinstance(body, dict) or set(body) != {OWNER_FIELD}:
        raise WireError("body", 'expected {"owner": "<plant>"}')
    owner = check_owner(body[OWNER_FIELD])
    if owner is None:
        raise WireError(OWNER_FIELD, "missing")
    state = _state()
    observed = state.brokers.set_owner(_broker_id(broker_id), owner)
    if state.workers is not None:
        state.workers.set_owner(broker_id, owner)
    return jsonify(to_dict(observed))


@v1.delete("/brokers/<broker_id>")
def delete_broker(broker_id: str) -> tuple[str, int]:
    """Stop the broker; the bridge workers it carries go with it. ``?owner=``: refused (409) if
    another plant owns it."""
    _state().changes.delete_broker(_broker_id(broker_id), _owner_arg())
    return "", 204


@v1.post("/brokers/<broker_id>/stop")
def stop_broker(broker_id: str) -> Response:
    """The operator's stop (no body): the broker stops and stays stopped — its spec, config and
    data kept — until ``start`` or ``restart``; idempotent. Answers the broker as GET does."""
    return _verb("stop", broker_id)


@v1.post("/brokers/<broker_id>/start")
def start_broker(broker_id: str) -> Response:
    """Start a broker the operator stopped, as it was; answers once healthy (a running one is
    left alone)."""
    return _verb("start", broker_id)


@v1.post("/brokers/<broker_id>/restart")
def restart_broker(broker_id: str) -> Response:
    """Stop the broker gracefully and start it again (a new pid, its data kept)."""
    return _verb("restart", broker_id)


def _verb(verb: str, broker_id: str) -> Response:
    if request.get_data(cache=False).strip():
        raise WireError("body", f"POST .../{verb} takes no body")
    brokers = _state().brokers
    action = {"stop": brokers.stop, "start": brokers.start, "restart": brokers.restart}[verb]
    return jsonify(to_dict(action(_broker_id(broker_id))))


@v1.get("/bridges")
def list_bridges() -> Response:
    return jsonify({"bridges": _bridges(_state())})


@v1.put("/brokers/<broker_id>/bridges/<remote_id>")
def put_bridge(broker_id: str, remote_id: str) -> Response:
    """Make the bridge run: in the broker's own config (Mosquitto) or as a worker. The body is the
    BridgeSpec, plus for mechanism mqtt-ngsi an optional transport field ``remote_token`` (the
    context broker's write token), which is kept in the worker's folder and never echoed."""
    body = _body()
    remote_token = body.pop(REMOTE_TOKEN, None) if isinstance(body, dict) else None
    owner = _owner_of(body)
    spec = bridge_spec_from_json(body)
    remote_token = check_remote_token(remote_token, spec.mechanism)
    if (spec.local.id, spec.remote.id) != (_broker_id(broker_id), _broker_id(remote_id)):
        raise WireError("local", f"the bridge {spec.local.id} -> {spec.remote.id} differs from the "
                        f"URL ({broker_id} -> {remote_id})")
    return jsonify(to_dict(_state().changes.put_bridge(spec, owner, remote_token)))


@v1.delete("/brokers/<broker_id>/bridges/<remote_id>")
def delete_bridge(broker_id: str, remote_id: str) -> tuple[str, int]:
    _state().changes.delete_bridge(_broker_id(broker_id), _broker_id(remote_id), _owner_arg())
    return "", 204


@v1.put("/brokers/<broker_id>/topics/<topic:name>")
def put_topic(broker_id: str, name: str) -> Response:
    body = _body()
    owner = _owner_of(body)
    topic = topic_spec_from_json(body)
    if topic.broker_id != _broker_id(broker_id):
        raise WireError("broker_id", f"{topic.broker_id!r} differs from the broker id in the URL "
                        f"({broker_id!r})")
    if topic.name != name:
        raise WireError("name", f"{topic.name!r} differs from the topic name in the URL ({name!r})")
    return jsonify(to_dict(_state().changes.put_topic(topic, owner)))


@v1.delete("/brokers/<broker_id>/topics/<topic:name>")
def delete_topic(broker_id: str, name: str) -> tuple[str, int]:
    _state().changes.delete_topic(_broker_id(broker_id), name, _owner_arg())
    return "", 204


@v1.get("/openapi.json")
def openapi() -> Response:
    return jsonify(openapi_document(_version()))


# --- helpers -------------------------------------------------------------------------------

def _broker_id(value: str) -> str:
    if not BROKER_ID.fullmatch(value):
        raise WireError("id", "a broker id is 1 to 128 characters of A-Z a-z 0-9 _ . - starting "
                        "with a letter, a digit or _")
    return value


def _owner_of(body: Any) -> str | None:
    """The body's optional ``owner`` transport field, removed from it (it is not a spec field)."""
    return check_owner(body.pop(OWNER_FIELD, None)) if isinstance(body, dict) else None


def _owner_arg() -> str | None:
    """The ``?owner=`` of a DELETE (None if not given)."""
    return check_owner(request.args.get(OWNER_FIELD))


def _body() -> Any:
    """The request's JSON, strictly: UTF-8, no duplicate keys, no NaN/Infinity."""
    raw = request.get_data(cache=False)
    if not raw:
        raise WireError("body", "empty; expected a JSON object")
    try:
        return json.loads(raw.decode("utf-8"), object_pairs_hook=_no_duplicates,
                          parse_constant=_no_constant)
    except UnicodeDecodeError as exc:
        raise WireError("body", f"not UTF-8 ({exc.reason})") from None
    except ValueError as exc:
        if isinstance(exc, WireError):
            raise
        raise WireError("body", f"not JSON: {exc}") from None


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    result: dict[str, Any] = {}
    for key, value in pairs:
        if key in result:
            raise WireError(key, "given twice")
        result[key] = value
    return result


def _no_constant(name: str) -> Any:
    raise WireError("body", f"{name} is not JSON")


def _version() -> str:
    try:
        return version("plantkg")
    except PackageNotFoundError:
        return "unknown"


def _json_error(status: int, message: str, hint: str | None, *, retryable: bool,
                field: str | None = None) -> Response:
    response = jsonify(error_body(message, hint, retryable=retryable, field=field))
    response.status_code = status
    return response


def _error(exc: Exception) -> Response:
    status, body = error_status(exc, f"{request.method} {request.path}")
    response = jsonify(body)
    response.status_code = status
    return response


def _http_error(exc: HTTPException) -> Response:
    hints = {404: "see GET /v1/openapi.json for the routes",
             405: "see GET /v1/openapi.json for the methods of this route",
             413: f"bodies are at most {MAX_BODY_BYTES} bytes"}
    return _json_error(exc.code or 500, exc.description or exc.name, hints.get(exc.code or 0),
                       retryable=(exc.code or 500) >= 500)

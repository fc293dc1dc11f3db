"""``/api``: the JSON the dashboard uses, documented in ``/api/openapi.json`` (engine.web.openapi).

Reads are open (the server binds loopback by default); writes (``apply``, ``refresh``, and the
operator's ``stop``/``start``/``restart`` of a broker) need a logged-in session with its CSRF
token, or ``Authorization: Bearer <token>``.
"""

from __future__ import annotations

from typing import Any

from flask import Blueprint, Response, current_app, jsonify, request

from engine.errors import DispatchError, TemporaryDispatchError
from engine.model import to_dict
from engine.render.plan import plan_dict, render_plan
from engine.web.auth import login_required
from engine.web.openapi import openapi_document
from engine.web.plant_state import ApplyRefused, PlantState
from engine.web.rates import disabled_document
from kg.errors import PlantKGError

bp = Blueprint("api", __name__, url_prefix="/api")


def _state() -> PlantState:
    return current_app.config["PLANTKG_STATE"]


@bp.get("/status")
def status() -> Any:
    """The status document; ``If-None-Match`` with the last ETag answers 304 when nothing changed."""
    snap = _state().snapshot
    etag = f'"{snap.version}"'
    if etag in request.headers.get("If-None-Match", ""):
        return Response(status=304, headers={"ETag": etag})
    return Response(snap.status_json, mimetype="application/json", headers={"ETag": etag,
                                                                               "Cache-Control": "no-cache"})


@bp.get("/rates")
def rates() -> Any:
    """Messages per second per (broker, topic) over the last minute (engine.web.rates); a read,
    open as ``/api/status`` is."""
    monitor = current_app.extensions.get("plantkg_rates")
    document = monitor.document() if monitor is not None else disabled_document()
    response = jsonify(document)
    response.headers["Cache-Control"] = "no-cache"
    return response


@bp.get("/plan")
def plan() -> Any:
    snap = _state().snapshot
    if snap.plan is None:
        return jsonify(plan=None, fingerprint=None, text=None, error=snap.error,
                       valid=snap.report.conforms if snap.report else None)
    return jsonify(plan=plan_dict(snap.plan), fingerprint=snap.fingerprint, text=render_plan(snap.plan),
                   error=snap.error, valid=True)


@bp.get("/validation")
def validation() -> Any:
    snap = _state().snapshot
    return jsonify(report=snap.report.to_dict() if snap.report else None, error=snap.error)


@bp.post("/apply")
@login_required
def apply() -> Any:
    """Start applying the plan named by ``fingerprint`` (JSON body or form field); 202 when started."""
    body = request.get_json(silent=True) if request.is_json else request.form
    fingerprint = (body or {}).get("fingerprint")
    if not isinstance(fingerprint, str) or not fingerprint:
        return jsonify(error="name the plan to apply: {\"fingerprint\": \"...\"} from /api/plan",
                       hint="the fingerprint makes sure the plan applied is the plan you saw"), 400
    try:
        job = _state().start_apply(fingerprint, by="dashboard")
    except ApplyRefused as exc:
        return jsonify(error=exc.message, hint=exc.hint), 409
    return jsonify(state=job.state, fingerprint=job.fingerprint, started_at=job.started_at), 202


@bp.post("/stop")
@login_required
def stop() -> Any:
    """Stop a broker and keep it stopped (data and config kept) until started."""
    return _broker_verb("stop")


@bp.post("/start")
@login_required
def start() -> Any:
    """Start a broker the operator stopped."""
    return _broker_verb("start")


@bp.post("/restart")
@login_required
def restart() -> Any:
    """Stop a broker gracefully and start it again (a new pid)."""
    return _broker_verb("restart")


def _broker_verb(verb: str) -> Any:
    """``{"broker_id": ...}`` (JSON body or form field) -> the broker as its agent answers."""
    body = request.get_json(silent=True) if request.is_json else request.form
    broker_id = (body or {}).get("broker_id")
    if not isinstance(broker_id, str) or not broker_id:
        return jsonify(error=f'name the broker to {verb}: {{"broker_id": "..."}}',
                       hint="the id as the brokers table shows it"), 400
    try:
        broker = _state().broker_verb(broker_id, verb)
    except ApplyRefused as exc:
        return jsonify(error=exc.message, hint=exc.hint), 404
    except TemporaryDispatchError as exc:
        return jsonify(error=exc.message, hint=exc.hint), 503
    except DispatchError as exc:
        return jsonify(error=exc.message, hint=exc.hint), 409
    return jsonify(broker=to_dict(broker))


@bp.post("/refresh")
@login_required
def refresh() -> Any:
    """Ask the agents again now (otherwise they are asked every few seconds)."""
    snap = _state().refresh()
    return jsonify(version=snap.version, observed_at=snap.observed_at, error=snap.error)


@bp.get("/explain")
def explain_address() -> Any:
    """Why ``address`` (a broker, topic or bridge of the plan) must exist, as ``plantkg explain``
    says it (engine.reasoning.explain, on the plant's files; no agent asked); ``format=text``: its text."""
    from engine.reasoning.explain import AddressError, explain  # noqa: PLC0415 - only when asked

    address = request.args.get("address", "")
    try:
        _, explanation = explain(_state().files, address)
    except AddressError as exc:
        return jsonify(error=exc.message, hint=exc.hint), 400
    except PlantKGError as exc:
        return jsonify(error=exc.message, hint=exc.hint), 422
    if explanation is None:
        return jsonify(error="the plant has violations: nothing can be explained",
                       hint="see /api/validation"), 409
    if request.args.get("format") == "text":
        return Response(explanation.text() + "\n", mimetype="text/plain")
    return jsonify(explanation.to_dict())


@bp.get("/openapi.json")
def openapi() -> Any:
    return jsonify(openapi_document())

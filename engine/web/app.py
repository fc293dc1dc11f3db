"""``create_app(config)``: the Flask app of ``plantkg serve`` (dashboard, SPARQL endpoint, API).

The app holds no global state: the plant comes in ``config.state`` (a :class:`PlantState`
someone else started), the SPARQL runner is an extension of this app, the session key is random
per process unless given (logins do not outlive the server).
"""

from __future__ import annotations

import secrets
from dataclasses import dataclass, field
from typing import Any

from flask import Flask, jsonify, request
from werkzeug.exceptions import HTTPException

from engine.web import api, auth, dashboard, sparql
from engine.web.plant_state import PlantState
from engine.web.rates import RateMonitor
from engine.web.sparql_protocol import Limits, QueryRunner


@dataclass(frozen=True)
class WebConfig:
    """What the app needs: the plant, the login token, the SPARQL limits."""

    state: PlantState
    token: str
    limits: Limits = Limits()
    secret_key: bytes = field(default_factory=lambda: secrets.token_bytes(32))
    secure_cookies: bool = False  # True behind https
    rates: RateMonitor | None = None  # live message rates (``plantkg serve`` with agents); None: off


def create_app(config: WebConfig) -> Flask:
    app = Flask(__name__)
    app.config.update(
        SECRET_KEY=config.secret_key,
        PLANTKG_STATE=config.state,
        PLANTKG_TOKEN=config.token,
        SESSION_COOKIE_HTTPONLY=True,
        SESSION_COOKIE_SAMESITE="Strict",
        SESSION_COOKIE_SECURE=config.secure_cookies,
        MAX_CONTENT_LENGTH=1 << 20,  # a query or a form is small
    )
    app.extensions["plantkg_sparql"] = QueryRunner(config.limits)
    app.extensions["plantkg_rates"] = config.rates
    auth.init_app(app)
    for blueprint in (dashboard.bp, sparql.bp, api.bp):
        app.register_blueprint(blueprint)
    app.register_error_handler(HTTPException, _http_error)
    app.after_request(_security_headers)
    return app


def _http_error(exc: HTTPException) -> Any:
    """JSON errors under /api, the usual page elsewhere."""
    if request.path.startswith("/api/"):
        response = jsonify(error=exc.description or exc.name)
        response.status_code = exc.code or 500
        return response
    return exc


def _security_headers(response: Any) -> Any:
    # Everything is served by the app itself: no script, style or image from elsewhere.
    response.headers.setdefault(
        "Content-Security-Policy",
        "default-src 'self'; img-src 'self' data:; style-src 'self' 'unsafe-inline'; frame-ancestors 'none'")
    response.headers.setdefault("X-Content-Type-Options", "nosniff")
    response.headers.setdefault("Referrer-Policy", "same-origin")
    return response

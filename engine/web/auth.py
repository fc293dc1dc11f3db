"""Who may change the plant from the web, and proof that a request was meant.

- One secret token, read from a token file (created 0600 on first start, as the agent's), logs a
  person in (``/login``: a signed, HttpOnly, SameSite=Strict session cookie) or authenticates a
  program (``Authorization: Bearer <token>``).
- Every state-changing request (POST, PUT, PATCH, DELETE) must carry the session's CSRF token
  (form field ``csrf_token`` or header ``X-CSRF-Token``), unless it is bearer-authenticated
  (a browser never adds that header by itself). Exempt endpoints are listed explicitly
  (:data:`CSRF_EXEMPT`): only the read-only SPARQL endpoint, whose POST is a query.
- :func:`login_required` guards every write: a page redirects to the login form, the API
  answers 401 JSON.
"""

from __future__ import annotations

import functools
import hmac
import secrets
from collections.abc import Callable
from typing import Any, TypeVar

from flask import Blueprint, Flask, abort, current_app, jsonify, redirect, render_template, request, session, url_for

F = TypeVar("F", bound=Callable[..., Any])
#: Endpoints that accept POST without a CSRF token: reads only (the SPARQL protocol's POST query).
CSRF_EXEMPT = frozenset({"sparql.endpoint"})
_WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})

bp = Blueprint("auth", __name__)


def token_matches(given: str | None) -> bool:
    expected = current_app.config["PLANTKG_TOKEN"]
    return bool(given) and hmac.compare_digest(given.encode(), expected.encode())  # type: ignore[union-attr]


def bearer_ok() -> bool:
    header = request.headers.get("Authorization", "")
    scheme, _, value = header.partition(" ")
    return scheme.lower() == "bearer" and token_matches(value.strip())


def authenticated() -> bool:
    return session.get("user") == "operator" or bearer_ok()


def csrf_token() -> str:
    """This session's CSRF token (made on first use)."""
    if "csrf" not in session:
        session["csrf"] = secrets.token_urlsafe(32)
    return session["csrf"]


def check_csrf() -> None:
    """``before_request`` hook: refuse a state-changing request that does not prove intent."""
    if request.method not in _WRITE_METHODS or request.endpoint in CSRF_EXEMPT or bearer_ok():
        return
    sent = request.headers.get("X-CSRF-Token") or request.form.get("csrf_token")
    expected = session.get("csrf")
    if not sent or not expected or not hmac.compare_digest(sent.encode(), expected.encode()):
        if request.path.startswith("/api/"):
            abort(_json_error(403, "missing or wrong CSRF token",
                              "reload the page, or authenticate with Authorization: Bearer <token>"))
        abort(403, description="The form was stale or not sent by this dashboard (CSRF check). "
                               "Reload the page and try again.")


def _json_error(status: int, message: str, hint: str) -> Any:
    response = jsonify(error=message, hint=hint)
    response.status_code = status
    return response


def login_required(view: F) -> F:
    """Only an authenticated session or bearer token gets through."""
    @functools.wraps(view)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        if authenticated():
            return view(*args, **kwargs)
        if request.path.startswith("/api/"):
            return _json_error(401, "authentication required",
                               "log in on the dashboard, or send Authorization: Bearer <token> "
                               "(the token file `plantkg serve` printed)")
        return redirect(url_for("auth.login", next=request.path))
    return wrapped  # type: ignore[return-value]


def _safe_next(target: str | None) -> str:
    return target if target and target.startswith("/") and not target.startswith("//") else url_for("dashboard.overview")


@bp.route("/login", methods=["GET", "POST"])
def login() -> Any:
    error = None
    if request.method == "POST":
        if token_matches(request.form.get("token", "").strip()):
            session.clear()
            session["user"] = "operator"
            session["csrf"] = secrets.token_urlsafe(32)
            return redirect(_safe_next(request.form.get("next")))
        error = "That is not the token of this server."
    status = 401 if error else 200
    return render_template("login.html", error=error, next=request.args.get("next", "")), status


@bp.route("/logout", methods=["POST"])
def logout() -> Any:
    session.clear()
    return redirect(url_for("dashboard.overview"))


def init_app(app: Flask) -> None:
    app.before_request(check_csrf)
    app.jinja_env.globals["csrf_token"] = csrf_token
    app.jinja_env.globals["authenticated"] = authenticated
    app.register_blueprint(bp)

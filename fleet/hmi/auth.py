"""Who may press the operators' buttons: the dashboard's scheme (engine/web/auth.py), for the HMI.

engine.web is the top layer of the engine and fleet is an application beside it, so this module
repeats the dashboard's small scheme instead of importing it:

- one secret token from a token file (created 0600 on first start; by default the dashboard's own
  ``$XDG_STATE_HOME/plantkg/web-token``, so the same token logs into both) logs a person in
  (``/login``: a signed, HttpOnly, SameSite=Strict session cookie);
- every POST carries the session's CSRF token (header ``X-CSRF-Token`` or form field
  ``csrf_token``), else 403;
- :func:`login_required` guards every page and endpoint: a page redirects to the login form,
  ``/api/`` answers 401 JSON.
"""

from __future__ import annotations

import functools
import hmac
import os
import secrets
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from flask import Blueprint, Flask, abort, current_app, jsonify, redirect, render_template, request, session, url_for

from fleet.hmi.errors import HmiError

F = TypeVar("F", bound=Callable[..., Any])
_WRITE_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
MIN_TOKEN = 16

bp = Blueprint("auth", __name__)


def default_token_file() -> Path:
    """The dashboard's token file: ``$XDG_STATE_HOME/plantkg/web-token`` (``~/.local/state/...``)."""
    base = os.environ.get("XDG_STATE_HOME") or str(Path("~/.local/state").expanduser())
    return Path(base) / "plantkg" / "web-token"


def load_or_create_token(path: Path) -> tuple[str, bool]:
    """The token of ``path`` (first line), made (0600, random) when the file does not exist."""
    created = False
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(secrets.token_urlsafe(32) + "\n", encoding="utf-8")
        tmp.chmod(0o600)
        tmp.replace(path)
        created = True
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise HmiError(f"{path}: cannot read the token file: {exc.strerror}",
                       hint="give --token-file a readable file") from None
    token = lines[0].strip() if lines else ""
    if len(token) < MIN_TOKEN:
        raise HmiError(f"{path}: the token is {len(token)} characters, at least {MIN_TOKEN} are needed",
                       hint="write a longer random token on its first line, or remove the file to get one")
    return token, created


def token_matches(given: str | None) -> bool:
    expected: str = current_app.config["HMI_TOKEN"]
    return bool(given) and hmac.compare_digest(given.encode(), expected.encode())  # type: ignore[union-attr]


def authenticated() -> bool:
    return session.get("user") == "operator"


def csrf_token() -> str:
    if "csrf" not in session:
        session["csrf"] = secrets.token_urlsafe(32)
    return session["csrf"]


def json_error(status: int, message: str, **extra: Any) -> Any:
    response = jsonify(error=message, **extra)
    response.status_code = status
    return response


def check_csrf() -> None:
    """``before_request``: refuse a POST that does not carry this session's CSRF token."""
    if request.method not in _WRITE_METHODS:
        return
    sent = request.headers.get("X-CSRF-Token") or request.form.get("csrf_token")
    expected = session.get("csrf")
    if not sent or not expected or not hmac.compare_digest(sent.encode(), expected.encode()):
        if request.path.startswith("/api/"):
            abort(json_error(403, "missing or wrong CSRF token", hint="reload the page and try again"))
        abort(403, description="The form was stale or not sent by this page (CSRF check). Reload and try again.")


def login_required(view: F) -> F:
    @functools.wraps(view)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        if authenticated():
            return view(*args, **kwargs)
        if request.path.startswith("/api/"):
            return json_error(401, "authentication required", hint="log in on /login with the token file's token")
        return redirect(url_for("auth.login", next=request.path))
    return wrapped  # type: ignore[return-value]


def _safe_next(target: str | None) -> str:
    return target if target and target.startswith("/") and not target.startswith("//") else url_for("pages.fleet")


@bp.route("/login", methods=["GET", "POST"])
def login() -> Any:
    error = None
    if request.method == "POST":
        if token_matches(request.form.get("token", "").strip()):
            session.clear()
            session["user"] = "operator"
            session["csrf"] = secrets.token_urlsafe(32)
            return redirect(_safe_next(request.form.get("next")))
        error = "That is not the token of this HMI."
    return render_template("login.html", error=error, next=request.args.get("next", "")), 401 if error else 200


@bp.route("/logout", methods=["POST"])
def logout() -> Any:
    session.clear()
    return redirect(url_for("auth.login"))


def init_app(app: Flask) -> None:
    app.before_request(check_csrf)
    app.jinja_env.globals["csrf_token"] = csrf_token
    app.jinja_env.globals["authenticated"] = authenticated
    app.register_blueprint(bp)

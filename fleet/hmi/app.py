"""``create_app(HmiConfig)``: the operators' Flask app (pages, JSON endpoints, the buttons).

| method | path | what |
|--------|------|------|
| GET | ``/`` | the fleet page: live map, vehicles, task list with filters |
| GET | ``/stations/<name>`` | a station's page: start a job, ready to load/unload, Loaded/Unloaded, jobs |
| GET | ``/api/site`` | the map, the stations with a page, the LoTLan tasks (routes) |
| GET | ``/api/fleet?state=&vehicle=`` | vehicles (position, battery, state, task) and the filtered tasks |
| GET | ``/api/stations/<name>`` | what the station's page shows |
| POST | ``/api/stations/<name>/jobs`` | form ``task``: start that LoTLan task as a job (planner ``POST /v1/jobs``) |
| POST | ``/api/stations/<name>/loaded`` | fire the FinishedBy events of the pick waiting there (``/unloaded``: the drop) |
| POST | ``/api/tasks/<id>/withdraw`` | withdraw a task (planner ``POST /v1/tasks/<id>/withdraw``; 409 if final) |

Every poll shares the planner's and the manager's answer of the last 0.25 s (``Recent``), so any
number of screens ask each of them at most four times a second; a button reads a fresh snapshot.
Every page and endpoint needs the login, every POST the CSRF token (fleet/hmi/auth.py). A planner
or manager that does not answer is part of the answer (``{"planner": {"ok": false, "error"}}``,
the page shows it), a POST that needs it answers 503; bad input 400 (404 unknown station, 409
nothing waits) with ``{"error", "field"}``; a refusal of the planner is passed on with its status
(502 for its 401/403: the HMI's planner token is wrong, not the operator's login).
"""

from __future__ import annotations

import json
import secrets
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from flask import Blueprint, Flask, abort, current_app, render_template, request
from werkzeug.exceptions import HTTPException

from fleet.hmi import auth, views
from fleet.hmi.auth import json_error, login_required
from fleet.hmi.errors import UpstreamDown, UpstreamRefused
from fleet.hmi.upstream import ManagerLink, PlannerLink, Recent
from fleet.lotlan.model import Program
from fleet.sim.map import SiteMap


@dataclass(frozen=True)
class HmiConfig:
    program: Program
    site: SiteMap
    planner: PlannerLink
    manager: ManagerLink
    token: str
    secret_key: bytes = field(default_factory=lambda: secrets.token_bytes(32))
    secure_cookies: bool = False
    share: float = 0.25  # s an answer of the planner / manager is shared by the polling screens


pages = Blueprint("pages", __name__)
api = Blueprint("api", __name__, url_prefix="/api")


def _config() -> HmiConfig:
    return current_app.extensions["fleet_hmi"]  # type: ignore[no-any-return]


def _station_or_404(name: str) -> str:
    config = _config()
    if name not in {s["name"] for s in views.stations(config.program, config.site)}:
        abort(json_error(404, f"station: no station {name[:80]!r} with jobs on map {config.site.map_id}",
                         field="station") if request.path.startswith("/api/") else 404)
    return name


def _recent(name: str) -> Recent:
    return current_app.extensions["fleet_hmi_recent"][name]  # type: ignore[no-any-return]


def _snapshot() -> tuple[dict[str, Any], dict[str, Any]]:
    """The planner's snapshot and how it answered (never raises: a page says what is down)."""
    try:
        return _recent("planner").get(), {"ok": True}
    except (UpstreamDown, UpstreamRefused) as exc:
        return {"tasks": [], "jobs": {}}, {"ok": False, "error": exc.message}


@pages.route("/")
@login_required
def fleet() -> Any:
    config = _config()
    return render_template("fleet.html", stations=views.stations(config.program, config.site),
                           states=["open", *views.PROGRESS, "FINISHED", "FAILED", "WITHDRAWN"])


@pages.route("/stations/<name>")
@login_required
def station(name: str) -> Any:
    config = _config()
    _station_or_404(name)
    return render_template("station.html", station=name, stations=views.stations(config.program, config.site),
                           routes=[r for r in views.routes(config.program, config.site) if name in (r.pickup, r.delivery)])


@api.route("/site")
@login_required
def site() -> Any:
    config = _config()
    return {**views.site_json(config.site, config.program),
            "routes": [r.to_json() for r in views.routes(config.program, config.site)]}


def _manager_status(data_dir: Path) -> Any:
    """The manager's ``status.json`` (written atomically by it), or {} while there is none."""
    try:
        return json.loads((data_dir / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


@api.route("/fleet")
@login_required
def fleet_json() -> Any:
    state, vehicle = views.check_filters(request.args.get("state"), request.args.get("vehicle"))
    snapshot, planner = _snapshot()
    try:
        rows, manager = _recent("manager").get(), {"ok": True}
    except (UpstreamDown, UpstreamRefused) as exc:
        rows, manager = [], {"ok": False, "error": exc.message}
    tasks = snapshot.get("tasks") or []
    return {"planner": planner, "manager": manager, "vehicles": views.vehicle_rows(rows, tasks),
            "refused": views.refused_rows(_manager_status(_config().manager.data_dir)),
            "tasks": views.filter_tasks(tasks, state, vehicle), "filters": {"state": state, "vehicle": vehicle}}


@api.route("/stations/<name>")
@login_required
def station_json(name: str) -> Any:
    config = _config()
    _station_or_404(name)
    snapshot, planner = _snapshot()
    return {"planner": planner, **views.station_view(config.program, config.site, name, snapshot)}


def _form() -> dict[str, Any]:
    if request.is_json:
        body = request.get_json(silent=True)
        if not isinstance(body, dict):
            raise views.InputError("body", "expected a JSON object or a form")
        return body
    return request.form.to_dict()


@api.route("/stations/<name>/jobs", methods=["POST"])
@login_required
def start_job(name: str) -> Any:
    config = _config()
    _station_or_404(name)
    task = views.check_start(config.program, config.site, name, _form().get("task"))
    job = config.planner.start_job([task])
    _recent("planner").forget()
    return job, 201


@api.route("/stations/<name>/<button>", methods=["POST"])
@login_required
def press(name: str, button: str) -> Any:
    config = _config()
    _station_or_404(name)
    tasks = config.planner.snapshot().get("tasks") or []
    events = views.button_events(config.program, name, button, tasks)
    fired = [config.planner.fire(event, True) for event in events]
    _recent("planner").forget()
    return {"button": button, "station": name, "fired": fired}, 201


@api.route("/tasks/<task_id>/withdraw", methods=["POST"])
@login_required
def withdraw(task_id: str) -> Any:
    task_id = views.check_task_id(task_id)
    task = _config().planner.withdraw(task_id)
    _recent("planner").forget()
    return task, 200


def _input_error(exc: views.InputError) -> Any:
    return json_error(exc.status, str(exc), field=exc.field)


def _upstream_down(exc: UpstreamDown) -> Any:
    return json_error(503, exc.message, upstream=exc.who)


def _upstream_refused(exc: UpstreamRefused) -> Any:
    # the planner's 401/403 is the HMI's configuration (its token file), not the operator's login
    status = exc.status if 400 <= exc.status < 500 and exc.status not in (401, 403) else 502
    return json_error(status, str(exc), upstream=exc.who)


def _http_error(exc: HTTPException) -> Any:
    if request.path.startswith("/api/"):
        return json_error(exc.code or 500, exc.description or exc.name)
    return exc


def _security_headers(response: Any) -> Any:
    response.headers.setdefault("Content-Security-Policy",
                                "default-src 'self'; img-src 'self' data:; style-src 'self'; frame-ancestors 'none'")
    response.headers.setdefault("X-Content-Type-Options", "nosniff")
    response.headers.setdefault("Referrer-Policy", "same-origin")
    response.headers.setdefault("Cache-Control", "no-store")
    return response


def create_app(config: HmiConfig) -> Flask:
    app = Flask(__name__)
    app.config.update(SECRET_KEY=config.secret_key, HMI_TOKEN=config.token, SESSION_COOKIE_HTTPONLY=True,
                      SESSION_COOKIE_SAMESITE="Strict", SESSION_COOKIE_SECURE=config.secure_cookies,
                      SESSION_COOKIE_NAME="plantkg_hmi", MAX_CONTENT_LENGTH=64 * 1024)
    app.extensions["fleet_hmi"] = config
    app.extensions["fleet_hmi_recent"] = {"planner": Recent(config.planner.snapshot, config.share),
                                          "manager": Recent(config.manager.vehicles, config.share)}
    auth.init_app(app)
    app.register_blueprint(pages)
    app.register_blueprint(api)
    app.register_error_handler(views.InputError, _input_error)
    app.register_error_handler(UpstreamDown, _upstream_down)
    app.register_error_handler(UpstreamRefused, _upstream_refused)
    app.register_error_handler(HTTPException, _http_error)
    app.after_request(_security_headers)
    return app

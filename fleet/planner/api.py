"""The planner's HTTP API, on loopback, with a bearer token (the fleet manager's scheme).

The token is ``<data-dir>/planner.token`` (created 0600 at the first start), the address is in
``<data-dir>/planner.json`` (``{"url", "pid"}``). Errors are JSON ``{"error", "description"}``
with a 4xx status naming the field; a bug answers 500 with its name and the planner goes on
(the plumbing is :mod:`fleet.loopback_api`, shared with the fleet manager).

| method | path | what |
|--------|------|------|
| GET | ``/v1/tasks`` | ``{"tasks": [...], "jobs": {...}, "events": N, "eventSources": {"mqtt"?, "ngsi"?}}`` |
| GET | ``/v1/tasks/<id>`` | one task (404 if unknown) |
| POST | ``/v1/jobs`` | ``{"tasks": [LoTLan task names]?}`` (default: the program's start tasks) -> 201 ``{"job", "tasks"}`` |
| POST | ``/v1/events`` | ``{"event": name or physical name, "value": true}`` -> 201 the journaled event |
| POST | ``/v1/tasks/<id>/withdraw`` | -> 200 the task, 409 if it is final already |

``eventSources`` are the counts of the event sources running (:mod:`events_mqtt`,
:mod:`events_ngsi`: received, fired, refused, the last refusals). The context broker's
notifications go to a second server, :class:`NotifyServer` (``planner-notify.json``,
``planner-notify.token``), with one route, ``POST /v1/ngsi/notify`` (Orion's notification body ->
200 ``{"fired", "refused"}``; 400 naming the field when the body is no notification): its token
sits in the context broker's subscription, so it may fire Events and nothing else.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from fleet.loopback_api import ApiError, LoopbackServer, token_for as _token_for
from fleet.planner.event_sources import EventMessageError
from fleet.planner.events_ngsi import NOTIFY_PATH
from fleet.planner.service import Planner, RequestError

MAX_BODY = 100_000
_NAMES = {400: "BadRequest", 404: "NotFound", 405: "MethodNotAllowed", 409: "Conflict", 413: "PayloadTooLarge"}


def token_for(data_dir: Path) -> str:
    return _token_for(data_dir, "planner")


def _object(body: Callable[[], Any]) -> dict[str, Any]:
    value = body()
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise RequestError(400, f"the body must be a JSON object, got {type(value).__name__}")
    return value


#: an event source's ``status()`` (counts for ``GET /v1/tasks``)
Status = Callable[[], dict[str, Any]]


def routes(planner: Planner, sources: Mapping[str, Status] | None = None
           ) -> Callable[[str, str, Callable[[], Any]], tuple[int, Any]]:
    def route(method: str, path: str, body: Callable[[], Any]) -> tuple[int, Any]:
        try:
            if method == "GET" and path == "/v1/tasks" and sources:
                return 200, {**planner.snapshot(), "eventSources": {k: status() for k, status in sources.items()}}
            return _route(planner, method, path, body)
        except RequestError as exc:
            raise ApiError(exc.status, _NAMES.get(exc.status, "Error"), exc.message) from None
    return route


def _route(planner: Planner, method: str, path: str, body: Callable[[], Any]) -> tuple[int, Any]:
    parts = path.split("/")
    if method == "GET" and path == "/v1/tasks":
        return 200, planner.snapshot()
    if method == "GET" and len(parts) == 4 and parts[:3] == ["", "v1", "tasks"]:
        return 200, planner.task_json(parts[3])
    if method == "POST" and path == "/v1/jobs":
        names = _object(body).get("tasks")
        if names is not None and (not isinstance(names, list) or not all(isinstance(n, str) for n in names)):
            raise RequestError(400, f"tasks: expected a list of LoTLan task names, got {names!r}"[:300])
        return 201, planner.start_job(names)
    if method == "POST" and path == "/v1/events":
        request = _object(body)
        if "value" not in request:
            raise RequestError(400, "value: missing (e.g. {\"event\": \"loaded\", \"value\": true})")
        return 201, planner.fire(request.get("event"), request["value"])
    if method == "POST" and len(parts) == 5 and parts[:3] == ["", "v1", "tasks"] and parts[4] == "withdraw":
        return 200, planner.withdraw(parts[3])
    raise RequestError(404 if method == "GET" else 405, f"{method} {path}: no such resource (see fleet/planner/api.py)")


class ApiServer(LoopbackServer):
    def __init__(self, planner: Planner, data_dir: Path, host: str = "127.0.0.1", port: int = 0,
                 sources: Mapping[str, Status] | None = None) -> None:
        super().__init__(routes(planner, sources), data_dir, "planner", host, port, max_body=MAX_BODY)


def notify_routes(notify: Callable[[Any], dict[str, Any]]) -> Callable[[str, str, Callable[[], Any]], tuple[int, Any]]:
    """``POST /v1/ngsi/notify`` only: ``notify(body)`` (:meth:`NgsiEvents.notify`)."""
    def route(method: str, path: str, body: Callable[[], Any]) -> tuple[int, Any]:
        if path != NOTIFY_PATH:
            raise ApiError(404, "NotFound", f"{method} {path}: this server only takes POST {NOTIFY_PATH}")
        if method != "POST":
            raise ApiError(405, "MethodNotAllowed", f"{method} {path}: only POST (the context broker's notifications)")
        try:
            return 200, notify(body())
        except EventMessageError as exc:
            raise ApiError(400, "BadRequest", str(exc)) from None
    return route


class NotifyServer(LoopbackServer):
    """The endpoint of the context broker's Event subscription, with a token of its own."""

    def __init__(self, notify: Callable[[Any], dict[str, Any]], data_dir: Path, host: str = "127.0.0.1",
                 port: int = 0) -> None:
        super().__init__(notify_routes(notify), data_dir, "planner-notify", host, port, max_body=MAX_BODY)

    @property
    def notify_url(self) -> str:
        return self.url + NOTIFY_PATH

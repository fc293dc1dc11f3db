"""The fleet manager's HTTP API, on loopback, with the agents' token scheme.

``Authorization: Bearer <token>`` on every request (compared in constant time); the token is
``<data-dir>/manager.token`` (created 0600 at the first start), the address is in
``<data-dir>/manager.json`` (``{"url", "pid"}``), which is how ``plantkg fleet order`` finds a
running manager. Errors are JSON ``{"error", "description"}`` with a 4xx status naming the field:

| method | path | what |
|--------|------|------|
| GET | ``/v1/vehicles`` | every vehicle: record, connection state, last state |
| GET | ``/v1/vehicles/<serial>`` | one vehicle (404 if unknown) |
| POST | ``/v1/orders`` | ``{"serial", "manufacturer"?, "orderId"?, "nodes": [{"nodeId", "x", "y", "mapId", "actions": [..]}]}`` → 201 ``{"orderId", "topic"}``; 409 if the vehicle is not ONLINE |
| POST | ``/v1/instantActions`` | ``{"serial", "manufacturer"?, "actionType", "actionParameters"?}`` → 201 ``{"actionId", "actionType", "vehicle", "topic"}``; ``actionType`` a VDA 5050 2.1 instant action (fleet/manager/instant.py); 409 if the vehicle is not ONLINE |
| POST | ``/v1/reconcile`` | reconcile now → 202 |

Until the manager has read its vehicle records after a (re)start, the vehicle resources answer
503 ``{"error": "NotReady", ...}``: a client waits and asks again (an empty list would read as
"every vehicle is gone").

A request body is at most 1 MB; a slow client holds one thread of its own, not the manager
(the plumbing is :mod:`fleet.loopback_api`, shared with the task planner).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from fleet.loopback_api import ApiError, LoopbackServer, token_for as _token_for

__all__ = ["ApiError", "ApiServer", "Manager", "token_for"]


class Manager(Protocol):
    def vehicles(self) -> list[dict[str, Any]]: ...
    def send_order(self, body: Any) -> dict[str, Any]: ...
    def send_instant_action(self, body: Any) -> dict[str, Any]: ...
    def request_reconcile(self) -> None: ...


def token_for(data_dir: Path) -> str:
    """The manager's token, created (0600) if there is none."""
    return _token_for(data_dir, "manager")


def routes(manager: Manager) -> Callable[[str, str, Callable[[], Any]], tuple[int, Any]]:
    def route(method: str, path: str, body: Callable[[], Any]) -> tuple[int, Any]:
        if method == "GET" and path == "/v1/vehicles":
            return 200, manager.vehicles()
        if method == "GET" and path.startswith("/v1/vehicles/"):
            name = path[len("/v1/vehicles/"):]
            found = [v for v in manager.vehicles() if name in (v["serial"], v["vehicle"])]
            if not found:
                raise ApiError(404, "NotFound", f"no vehicle {name!r}")
            return 200, found[0]
        if method == "POST" and path == "/v1/orders":
            return 201, manager.send_order(body())
        if method == "POST" and path == "/v1/instantActions":
            return 201, manager.send_instant_action(body())
        if method == "POST" and path == "/v1/reconcile":
            manager.request_reconcile()
            return 202, {"reconcile": "requested"}
        raise ApiError(404 if method == "GET" else 405, "NotFound",
                       f"{method} {path}: no such resource (see fleet/manager/api.py)")
    return route


class ApiServer(LoopbackServer):
    def __init__(self, manager: Manager, data_dir: Path, host: str = "127.0.0.1", port: int = 0) -> None:
        super().__init__(routes(manager), data_dir, "manager", host, port, max_body=1_000_000)

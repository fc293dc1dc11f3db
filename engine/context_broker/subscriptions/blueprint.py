"""``/v2/subscriptions``: Orion's subscription routes over a :class:`SubscriptionService`.

- ``GET /v2/subscriptions`` (and ``/v2/subscriptions/``, as FiLiP calls it): ``limit`` (default
  20, at most 1000), ``offset``, ``options=count`` (``Fiware-Total-Count``); the service's
  subscriptions, narrowed to those created with exactly the ``Fiware-ServicePath`` sent (none:
  all). A subscription's service path is the query of the entities it watches (none: ``/#``,
  every path; ``/a/#`` a subtree; a list), see :mod:`.scope`.
- ``POST``: 201, ``Location: /v2/subscriptions/<24 hex>``, empty body.
- ``GET``/``PATCH`` (204)/``DELETE`` (204) ``/v2/subscriptions/<id>``: 400 for an id that is
  not 24 hex digits, 404 for one the service does not have.

On a closed context broker the app leaves the request's principal in the WSGI environ
(:data:`.ownership.ENVIRON_KEY`): a principal creates only what it may hold and sees, changes,
deletes and lists only its own (:mod:`.ownership`); without it, plantkg's own rights.

Every refusal is an :class:`NgsiError`; this blueprint renders it as Orion does (the app's
handler does the same for the other routes).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from flask import Blueprint, Response, request

from engine.context_broker.contract import NgsiError, bad_request
from engine.context_broker.subscriptions.model import render
from engine.context_broker.subscriptions.ownership import ENVIRON_KEY, PLANTKG, Requester
from engine.context_broker.subscriptions.scope import subscription_tenant

if TYPE_CHECKING:
    from engine.context_broker.subscriptions.service import SubscriptionService

DEFAULT_LIMIT = 20
MAX_LIMIT = 1000


def _json_response(body: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    return Response(json.dumps(body, ensure_ascii=False), status=status,
                    mimetype="application/json", headers=headers or {})


def _error(err: NgsiError) -> Response:
    return _json_response(err.body(), err.status, err.headers)


def _count(name: str, default: int, low: int, high: int | None = None) -> int:
    raw = request.args.get(name)
    if raw is None:
        return default
    if not raw.isdigit() or int(raw) < low or (high is not None and int(raw) > high):
        limits = f"{low} to {high}" if high is not None else f"at least {low}"
        raise bad_request(f"Bad pagination {name}: /{raw}/ (an integer, {limits})")
    return int(raw)


def _options() -> set[str]:
    return {o for o in request.args.get("options", "").split(",") if o}


def _body() -> Any:
    mimetype = request.mimetype
    if mimetype != "application/json":
        raise NgsiError(415, "UnsupportedMediaType",
                        f"not supported content type: {mimetype or '(none)'}; send application/json")
    raw = request.get_data(cache=False)
    if not raw.strip():
        raise bad_request("empty payload: send the subscription as a JSON object")
    try:
        return json.loads(raw)
    except (ValueError, UnicodeDecodeError) as err:
        raise NgsiError(400, "ParseError", f"Errors found in incoming JSON buffer: {err}") from None


def _requester() -> Requester:
    return request.environ.get(ENVIRON_KEY, PLANTKG)


def make_blueprint(service: SubscriptionService) -> Blueprint:
    bp = Blueprint("ngsi_subscriptions", __name__)
    bp.register_error_handler(NgsiError, _error)

    @bp.get("/v2/subscriptions")
    @bp.get("/v2/subscriptions/")
    def list_subscriptions() -> Response:
        tenant = subscription_tenant(request.headers)
        limit = _count("limit", DEFAULT_LIMIT, 1, MAX_LIMIT)
        offset = _count("offset", 0, 0)
        options = _options()
        unknown = options - {"count"}
        if unknown:
            raise bad_request(f"Invalid value for URI param /options/: {', '.join(sorted(unknown))} "
                              "(subscriptions take only count)")
        path_given = bool((request.headers.get("Fiware-ServicePath") or "").strip())
        subs = service.listing(tenant, path_given, _requester())
        now = service.clock()
        page = [render(s, d, now) for s, d in subs[offset:offset + limit]]
        headers = {"Fiware-Total-Count": str(len(subs))} if "count" in options else {}
        return _json_response(page, headers=headers)

    @bp.post("/v2/subscriptions")
    @bp.post("/v2/subscriptions/")
    def create_subscription() -> Response:
        tenant = subscription_tenant(request.headers)
        sub = service.create(tenant, _body(), _requester())
        return Response(status=201, headers={"Location": f"/v2/subscriptions/{sub.id}"})

    @bp.get("/v2/subscriptions/<sub_id>")
    def get_subscription(sub_id: str) -> Response:
        tenant = subscription_tenant(request.headers)
        sub, status = service.get(sub_id, tenant, _requester())
        return _json_response(render(sub, status, service.clock()))

    @bp.patch("/v2/subscriptions/<sub_id>")
    def patch_subscription(sub_id: str) -> Response:
        tenant = subscription_tenant(request.headers)
        service.update(sub_id, tenant, _body(), _requester())
        return Response(status=204)

    @bp.delete("/v2/subscriptions/<sub_id>")
    def delete_subscription(sub_id: str) -> Response:
        tenant = subscription_tenant(request.headers)
        service.delete(sub_id, tenant, _requester())
        return Response(status=204)

    return bp

"""Reading one request: tenancy headers, URL parameters and bodies, each refusal an NgsiError.

- :func:`write_tenant`: the one ``Fiware-ServicePath`` a write names (no list, no ``#``).
- :func:`read_scope`: a read's ``Fiware-ServicePath`` list (up to 10, ``/a/#`` for a subtree;
  none means ``/#``), as Orion.
- :func:`count_param`, :func:`options`: pagination and ``options`` with Orion's 400s.
- :func:`json_body` / :func:`value_body`: the body by ``Content-Type`` (415 otherwise).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from flask import request

from engine.context_broker.contract import (
    DEFAULT_SERVICE_PATH, NgsiError, Tenant, bad_request, tenant_from_headers,
)
from engine.context_broker.entities import parse_json, parse_text_value
from engine.context_broker.names import check_identifier
from engine.context_broker.store import ReadScope

MAX_SERVICE_PATHS = 10
DEFAULT_LIMIT = 20
MAX_LIMIT = 1000


def write_tenant(headers: Mapping[str, str]) -> Tenant:
    raw = (headers.get("Fiware-ServicePath") or "").strip()
    if "," in raw:
        raise bad_request(f"a write names one Fiware-ServicePath, got a list: {raw!r}")
    if raw.endswith("/#") or raw == "#":
        raise bad_request(f"a write cannot use the recursive Fiware-ServicePath {raw!r}: name one path")
    return _normalized(tenant_from_headers(headers))


def _normalized(tenant: Tenant) -> Tenant:
    path = tenant.service_path.rstrip("/") or DEFAULT_SERVICE_PATH
    return Tenant(tenant.service, path)


def read_scope(headers: Mapping[str, str]) -> ReadScope:
    service = tenant_from_headers({"Fiware-Service": headers.get("Fiware-Service") or ""}).service
    raw = (headers.get("Fiware-ServicePath") or "").strip()
    if not raw:
        return ReadScope(service, ((DEFAULT_SERVICE_PATH, True),))
    items = [item.strip() for item in raw.split(",")]
    if len(items) > MAX_SERVICE_PATHS:
        raise bad_request(f"too many service paths in Fiware-ServicePath: {len(items)}, at most "
                          f"{MAX_SERVICE_PATHS}")
    paths = []
    for item in items:
        recursive = item.endswith("/#")
        path = item[:-2] or "/" if recursive else item
        if item == "/#":
            path = "/"
        tenant = _normalized(tenant_from_headers({"Fiware-ServicePath": path}))
        paths.append((tenant.service_path, recursive))
    return ReadScope(service, tuple(paths))


def count_param(name: str, default: int, low: int, high: int | None = None) -> int:
    raw = request.args.get(name)
    if raw is None:
        return default
    if not raw.isdigit() or int(raw) < low or (high is not None and int(raw) > high):
        limits = f"from {low} to {high}" if high is not None else f"at least {low}"
        raise bad_request(f"Bad pagination {name}: /{raw}/ must be an integer {limits}")
    return int(raw)


def limit_offset() -> tuple[int, int]:
    return count_param("limit", DEFAULT_LIMIT, 1, MAX_LIMIT), count_param("offset", 0, 0)


def options(allowed: frozenset[str]) -> set[str]:
    raw = request.args.get("options")
    if raw is None:
        return set()
    given = {o.strip() for o in raw.split(",")}
    unknown = sorted(o for o in given if o not in allowed)
    if unknown or "" in given:
        bad = ", ".join(unknown) or "(empty)"
        raise bad_request(f"Invalid value for URL parameter options: {bad} (allowed here: "
                          f"{', '.join(sorted(allowed))})")
    return given


def render_mode(opts: set[str]) -> str:
    modes = [m for m in ("keyValues", "values", "unique") if m in opts]
    if len(modes) > 1 and set(modes) != {"values", "unique"}:
        raise bad_request(f"options {' and '.join(modes)} exclude each other: choose one rendering")
    if "normalized" in opts and modes:
        raise bad_request(f"options normalized and {modes[0]} exclude each other")
    if "unique" in modes:
        return "unique"
    return modes[0] if modes else "normalized"


def entity_type_param() -> str | None:
    raw = request.args.get("type")
    if raw is None:
        return None
    return check_identifier(raw, "entity type (URL parameter type)")


def _mimetype() -> str:
    return (request.mimetype or "").lower()


def json_body() -> Any:
    mimetype = _mimetype()
    if mimetype != "application/json":
        raise NgsiError(415, "UnsupportedMediaType",
                        f"not supported content type: {mimetype or 'no Content-Type header'}; "
                        "send Content-Type: application/json")
    raw = request.get_data(cache=False)
    if not raw.strip():
        raise NgsiError(400, "BadRequest", "empty payload: a JSON body is required")
    return parse_json(raw)


def value_body() -> Any:
    """The body of ``PUT .../attrs/{name}/value``: JSON, or text/plain read as Orion does."""
    mimetype = _mimetype()
    if mimetype not in ("application/json", "text/plain"):
        raise NgsiError(415, "UnsupportedMediaType",
                        f"not supported content type: {mimetype or 'no Content-Type header'}; "
                        "send application/json or text/plain")
    raw = request.get_data(cache=False)
    if not raw.strip():
        raise NgsiError(400, "BadRequest", "empty payload: send the new value")
    if mimetype == "text/plain":
        return parse_text_value(raw)
    return parse_json(raw)

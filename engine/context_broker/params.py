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
from engine.context_broker.names import FORBIDDEN, check_identifier
from engine.context_broker.store import ReadScope

MAX_SERVICE_PATHS = 10
#: URL parameters that may hold Orion's forbidden characters (orion-api.md, "General syntax
#: restrictions": the query languages, patterns and geo parameters).
FREE_PARAMS = frozenset({"q", "mq", "idPattern", "typePattern", "georel", "geometry", "coords"})
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
    return parse_options(request.args.get("options"), allowed)


def parse_options(raw: str | None, allowed: frozenset[str]) -> set[str]:
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
    return parse_entity_type(request.args.get("type"))


def parse_entity_type(raw: str | None) -> str | None:
    if raw is None:
        return None
    return check_identifier(raw, "entity type (URL parameter type)")


def _mimetype() -> str:
    return (request.mimetype or "").lower()


def json_body() -> Any:
    return json_from(_mimetype(), request.get_data(cache=False))


def json_from(mimetype: str, raw: bytes) -> Any:
    """A JSON body of content type ``mimetype`` (lower-cased, without parameters)."""
    if mimetype != "application/json":
        raise NgsiError(415, "UnsupportedMediaType",
                        f"not supported content type: {mimetype or 'no Content-Type header'}; "
                        "send Content-Type: application/json")
    if not raw.strip():
        raise NgsiError(400, "BadRequest", "empty payload: a JSON body is required")
    return parse_json(raw)


def value_body() -> Any:
    """The body of ``PUT .../attrs/{name}/value``: JSON, or text/plain read as Orion does."""
    return value_from(_mimetype(), request.get_data(cache=False))


def value_from(mimetype: str, raw: bytes) -> Any:
    if mimetype not in ("application/json", "text/plain"):
        raise NgsiError(415, "UnsupportedMediaType",
                        f"not supported content type: {mimetype or 'no Content-Type header'}; "
                        "send application/json or text/plain")
    if not raw.strip():
        raise NgsiError(400, "BadRequest", "empty payload: send the new value")
    if mimetype == "text/plain":
        return parse_text_value(raw)
    return parse_json(raw)


def check_url_param(name: str, value: str) -> None:
    for position, char in enumerate(value):
        if char in FORBIDDEN or ord(char) < 32:
            raise NgsiError(400, "BadRequest", f"Invalid characters in URL parameter {name}: "
                                               f"{char!r} at position {position} (< > \" ' = ; ( ) "
                                               "are allowed only in q, mq, idPattern and typePattern)")

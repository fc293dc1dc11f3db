"""What the context broker's parts share: tenants, change events, the error body.

The HTTP layer (entities, attributes, types, batch operations) and the subscription engine are
separate parts. They meet here:

- :class:`Tenant`: the ``Fiware-Service`` / ``Fiware-ServicePath`` of a request (Orion's
  multi-tenancy), parsed and checked once by :func:`tenant_from_headers`.
- :class:`EntityChange`: what a successful write did to one entity, handed to every
  :class:`ChangeListener` *after* the write is durable and before the response is sent. Entities
  travel as Orion's normalized JSON (``{"id", "type", "<attr>": {"type", "value", "metadata"}}``),
  the form notifications are rendered from.
- :class:`NgsiError`: an error answered with Orion's status and body
  ``{"error": ..., "description": ...}``; every refusal of a request is one of these.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Protocol

#: Orion's default service path, and the bounds it enforces on the two tenancy headers.
DEFAULT_SERVICE_PATH = "/"
MAX_SERVICE_LENGTH = 50
MAX_SERVICE_PATH_LEVELS = 10
MAX_SERVICE_PATH_LEVEL_LENGTH = 50


class NgsiError(Exception):
    """A request refused with an NGSI-v2 error: HTTP ``status``, Orion's ``error`` name and a
    ``description`` that says what is wrong and where (field, character, position)."""

    def __init__(self, status: int, error: str, description: str,
                 headers: Mapping[str, str] | None = None) -> None:
        super().__init__(f"{status} {error}: {description}")
        self.status = status
        self.error = error
        self.description = description
        self.headers = dict(headers or {})

    def body(self) -> dict[str, str]:
        return {"error": self.error, "description": self.description}


def bad_request(description: str) -> NgsiError:
    return NgsiError(400, "BadRequest", description)


def not_found(description: str = "The requested entity has not been found. Check type and id") -> NgsiError:
    return NgsiError(404, "NotFound", description)


def unprocessable(description: str) -> NgsiError:
    return NgsiError(422, "Unprocessable", description)


@dataclass(frozen=True)
class Tenant:
    """A request's tenant. ``service`` "" is Orion's default tenant (no ``Fiware-Service``)."""

    service: str = ""
    service_path: str = DEFAULT_SERVICE_PATH


def tenant_from_headers(headers: Mapping[str, str]) -> Tenant:
    """The tenant named by ``Fiware-Service`` (lower-cased, as Orion does; letters, digits and
    ``_`` only, at most 50) and ``Fiware-ServicePath`` (``/`` or ``/a/b``: absolute, at most 10
    levels of at most 50 letters, digits or ``_``; a write names one path). Raises
    :class:`NgsiError` 400 naming the header, the character and its position."""
    service = (headers.get("Fiware-Service") or "").strip().lower()
    if len(service) > MAX_SERVICE_LENGTH:
        raise bad_request(f"bad length for Fiware-Service: {len(service)} characters, at most "
                          f"{MAX_SERVICE_LENGTH}")
    for i, char in enumerate(service):
        if not (char.isascii() and (char.isalnum() or char == "_")):
            raise bad_request(f"bad character for Fiware-Service: {char!r} at position {i} "
                              "(letters, digits and '_' only)")
    path = (headers.get("Fiware-ServicePath") or "").strip() or DEFAULT_SERVICE_PATH
    if not path.startswith("/"):
        raise bad_request("Only /absolute/ Service Paths allowed [a service path must begin "
                          f"with /]: Fiware-ServicePath {path!r}")
    if path != "/":
        levels = path[1:].split("/")
        if len(levels) > MAX_SERVICE_PATH_LEVELS:
            raise bad_request(f"too many components in Fiware-ServicePath: {len(levels)}, at most "
                              f"{MAX_SERVICE_PATH_LEVELS}")
        offset = 1
        for level in levels:
            if not level or len(level) > MAX_SERVICE_PATH_LEVEL_LENGTH:
                raise bad_request(f"component {level!r} of Fiware-ServicePath at position {offset}: "
                                  f"1 to {MAX_SERVICE_PATH_LEVEL_LENGTH} characters")
            for i, char in enumerate(level):
                if not (char.isascii() and (char.isalnum() or char == "_")):
                    raise bad_request(f"bad character in Fiware-ServicePath: {char!r} at position "
                                      f"{offset + i} (letters, digits and '_' per component)")
            offset += len(level) + 1
    return Tenant(service, path)


@dataclass(frozen=True)
class EntityChange:
    """One entity after a successful write (``entity`` in normalized JSON; for a delete, the
    entity as it was). ``changed``: the attribute names added, updated (new value or metadata) or
    removed; for a create, all of them. Orion notifies on a value update even when the value is
    unchanged unless the attribute's metadata says otherwise; plantkg lists every attribute the
    request wrote in ``changed`` (``forced`` is Orion's ``options=forcedUpdate``)."""

    tenant: Tenant
    entity: Mapping[str, Any]
    changed: frozenset[str]
    created: bool = False
    deleted: bool = False
    forced: bool = False

    @property
    def entity_id(self) -> str:
        return str(self.entity["id"])

    @property
    def entity_type(self) -> str:
        return str(self.entity["type"])


class ChangeListener(Protocol):
    """Receives every change after it is durable. Must return quickly (queue, never block on a
    receiver): it runs on the request's thread, before the response."""

    def entity_changed(self, change: EntityChange) -> None: ...

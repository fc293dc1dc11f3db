"""Who may do what on a closed context broker: its principals and their entities (docs/security.md).

A context broker started with ``--principals FILE`` is *closed*: every request but ``GET
/version`` (the health check, public on Orion too) needs a token, reads included. The file
(rendered 0600 by the driver on the broker's machine) holds, per principal, its name, the
SHA-256 digest of its token (never the token) and the entity ids it may write and read — the
entities of the topics the rules gave it (``pk:mayWrite``/``pk:mayRead``). The agent's own
token (``--token-file``) is plantkg's internal principal, with every right.

A token comes as ``Authorization: Bearer <token>`` (what FiLiP's ``FiwareHeaderSecure`` sends)
or ``X-Auth-Token: <token>`` (what a Wilma PEP proxy in front of Orion takes). Missing or
unknown: 401; a known principal outside its rights: 403; both with Orion's error body.

What a principal may do (:func:`authorize`):

- write (POST/PUT/PATCH/DELETE) ``/v2/entities/{id}...`` and create (``POST /v2/entities``) an
  entity it may write; ``POST /v2/op/update`` when it may write every entity of the batch;
- read ``/v2/entities/{id}...`` of an entity it may read or write; list ``/v2/entities`` or
  ``POST /v2/op/query`` only when the request names its ids (``id=a,b`` or the query's
  ``entities[].id``), all of them readable;
- ``/v2/subscriptions`` (create, list) and ``/v2/subscriptions/{id}`` (get, change, delete):
  let through with the principal as the request's :class:`Requester` (:func:`requester`); the
  subscriptions' own rules need the parsed subscription and its stored owner, so
  :mod:`.subscriptions.ownership` checks them: subjects only by ``id`` of entities it may read,
  HTTP notifications only, its own subscriptions only;
- nothing else: types and the whole graph are plantkg's (the agent's token).
"""

from __future__ import annotations

import hmac
from collections.abc import Mapping
from typing import Any

from engine.context_broker.contract import NgsiError
from engine.context_broker.subscriptions.ownership import PLANTKG, Requester
from engine.security.ngsi_principals import Principal, token_digest

PUBLIC_PATHS = frozenset({"/version"})
REALM = {"WWW-Authenticate": 'Bearer realm="plantkg context broker"'}
ENTITY_PREFIX = "/v2/entities/"
SUBSCRIPTIONS = "/v2/subscriptions"


class Gate:
    """The token check of a closed context broker: ``internal`` (the agent's token) and the
    principals (by token digest)."""

    def __init__(self, internal: str, principals: tuple[Principal, ...]) -> None:
        self._internal = token_digest(internal)
        self._by_digest = {p.digest: p for p in principals}

    def principal(self, headers: Mapping[str, str]) -> Principal:
        """The principal the request's token belongs to; 401 without a token or with an unknown one."""
        given = headers.get("Authorization") or ""
        scheme, _, value = given.partition(" ")
        token = value.strip() if scheme.lower() == "bearer" else ""
        token = token or (headers.get("X-Auth-Token") or "").strip()
        if not token:
            raise NgsiError(401, "Unauthorized", "missing token: this context broker is closed; send "
                            "Authorization: Bearer <token> (or X-Auth-Token: <token>)", REALM)
        digest = token_digest(token)
        if hmac.compare_digest(digest, self._internal):
            return Principal("plantkg.agent", digest, internal=True)
        found = self._by_digest.get(digest)
        if found is None:
            raise NgsiError(401, "Unauthorized", "wrong token: no principal of this context broker "
                            "has it", REALM)
        return found

    def owners(self) -> dict[str, Requester]:
        """The principals as owners of subscriptions (:mod:`.subscriptions.ownership`), by name."""
        return {p.name: requester(p) for p in self._by_digest.values()}


def authorize(who: Principal, method: str, path: str, args: Mapping[str, str], body: Any) -> None:
    """Nothing if ``who`` may make the request, else 403 naming the principal and the entity
    (the rules in the module docstring). ``body``: the parsed JSON body, or None."""
    if who.internal or path in PUBLIC_PATHS:
        return
    if path == SUBSCRIPTIONS or path.startswith(SUBSCRIPTIONS + "/"):
        return  # the subscriptions' rules: .subscriptions.ownership, with requester(who)
    read = method in ("GET", "HEAD") or (method == "POST" and path == "/v2/op/query")
    allowed = (who.read | who.write) if read else who.write
    wanted: list[str] | None
    if path.startswith(ENTITY_PREFIX):
        wanted = [path[len(ENTITY_PREFIX):].split("/", 1)[0]]
    elif path == "/v2/entities" and method == "POST":
        wanted = [body["id"]] if isinstance(body, dict) and isinstance(body.get("id"), str) else None
    elif path == "/v2/entities" and read:
        ids = args.get("id")
        wanted = [i for i in ids.split(",")] if ids and "idPattern" not in args else None
    elif path in ("/v2/op/update", "/v2/op/query"):
        wanted = _batch_ids(body)
    else:
        raise NgsiError(403, "Forbidden", f"principal {who.name!r} may not use {method} {path}: "
                        "only plantkg's own token may")
    if not wanted:
        raise NgsiError(403, "Forbidden", f"principal {who.name!r} may {'read' if read else 'write'} "
                        "only entities it names by id (id=..., or each entity's id)")
    for eid in wanted:
        if eid not in allowed:
            raise NgsiError(403, "Forbidden", f"principal {who.name!r} may not "
                            f"{'read' if read else 'write'} entity {eid!r}")


def requester(who: Principal | None) -> Requester:
    """Who the subscriptions blueprint serves: plantkg's rights for the agent's token (and on a
    broker without a gate, ``who`` None), else the principal and the entities it may read."""
    if who is None or who.internal:
        return PLANTKG
    return Requester(who.name, who.read | who.write)


def _batch_ids(body: Any) -> list[str] | None:
    entities = body.get("entities") if isinstance(body, dict) else None
    if not isinstance(entities, list) or not entities:
        return None
    ids = [e.get("id") for e in entities if isinstance(e, dict)]
    if len(ids) != len(entities) or not all(isinstance(i, str) for i in ids):
        return None
    return ids

"""Orion's batch operations: ``POST /v2/op/update`` and ``POST /v2/op/query``.

``op/update`` parses the WHOLE batch before writing anything (one bad entity: 400, nothing
written), then applies each entity as its single operation (orion-api.md, "Update operation"):
``append`` = create or POST attrs, ``appendStrict`` = create or POST attrs?options=append,
``update`` = PATCH attrs, ``delete`` = DELETE the listed attributes (or the entity when none),
``replace`` = PUT attrs. All of it is one store transaction. Entities that fail (missing,
missing attribute) are reported: 404 ``NotFound`` when none succeeded for update/delete/replace,
422 ``PartialUpdate`` when some did, 422 ``Unprocessable`` otherwise.

``op/query`` is a read (no token needed): ``entities`` selectors, ``attrs``, ``expression``
(``q``, ``mq``), ``metadata``; pagination, ``orderBy`` and renderings as ``GET /v2/entities``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from flask import Blueprint, Response, request

from engine.context_broker import entities as ent
from engine.context_broker import listing
from engine.context_broker.contract import NgsiError, bad_request
from engine.context_broker.names import check_identifier
from engine.context_broker.params import json_body, limit_offset, options, read_scope, render_mode, write_tenant
from engine.context_broker.q import parse_q
from engine.context_broker.routes import json_response, no_content, page
from engine.context_broker.store import ContextStore, Transaction

ACTIONS = ("append", "appendStrict", "update", "delete", "replace")
UPDATE_OPTIONS = frozenset({"keyValues", "overrideMetadata", "forcedUpdate", "flowControl"})
QUERY_OPTIONS = frozenset({"count", "keyValues", "values", "unique", "normalized", "skipForwarding"})


@dataclass(frozen=True)
class BatchEntity:
    id: str
    type: str | None  # None: not given (update/delete/replace then take any type)
    attrs: Mapping[str, ent.AttrInput]


def parse_update(body: Any, key_values: bool) -> tuple[str, list[BatchEntity]]:
    if not isinstance(body, Mapping):
        raise NgsiError(400, "ParseError", "Errors found in incoming JSON buffer: the batch must be "
                                           "a JSON object with actionType and entities")
    unknown = set(body) - {"actionType", "entities"}
    if unknown:
        raise bad_request(f"unrecognized field(s) in batch: {', '.join(sorted(unknown))} "
                          "(actionType and entities only)")
    action = body.get("actionType")
    if action not in ACTIONS:
        raise bad_request(f"invalid actionType {action!r}: one of {', '.join(ACTIONS)}"
                          if "actionType" in body else "actionType is missing: one of " + ", ".join(ACTIONS))
    items = body.get("entities")
    if not isinstance(items, list):
        raise bad_request("entities must be a JSON array of entities")
    if not items:
        raise bad_request("empty entities vector: give at least one entity")
    out = []
    for index, item in enumerate(items):
        try:
            if action == "delete" and isinstance(item, Mapping):
                # the values of the listed attributes are not relevant: names only
                item = {k: (v if k in ("id", "type") else {}) for k, v in item.items()}
            entity_id, entity_type, attrs = ent.parse_entity(item, key_values=key_values and action != "delete")
        except NgsiError as err:
            raise NgsiError(err.status, err.error, f"entities[{index}]: {err.description}") from None
        given_type = entity_type if isinstance(item, Mapping) and "type" in item else None
        out.append(BatchEntity(entity_id, given_type, attrs))
    return action, out


def _label(item: BatchEntity) -> str:
    return f"{item.id}/{item.type or ''}"


@dataclass
class Outcome:
    """What a batch did: the failures' descriptions, whether anything was written, and whether
    every failure is an entity that does not exist."""

    failures: list[str]
    applied: bool = False
    only_missing_entities: bool = True


def apply(txn: Transaction, action: str, items: list[BatchEntity], opts: set[str]) -> Outcome:
    """Apply every entity as its single operation would; collect what failed."""
    out = Outcome([])
    forced = "forcedUpdate" in opts
    override = "overrideMetadata" in opts

    def fail(item: BatchEntity, why: str, missing_entity: bool = False) -> None:
        out.failures.append(f"{_label(item)} - {why}")
        out.only_missing_entities &= missing_entity

    for item in items:
        try:
            if action in ("append", "appendStrict"):
                old = txn.find(item.id, item.type or ent.DEFAULT_ENTITY_TYPE)
                if old is None:
                    txn.put(None, ent.create_entity(item.id, item.type or ent.DEFAULT_ENTITY_TYPE,
                                                    txn.tenant.service_path, item.attrs, txn.now),
                            item.attrs, forced=forced)
                    out.applied = True
                    continue
            else:
                old = txn.find(item.id, item.type)
                if old is None:
                    fail(item, "[entity itself]", missing_entity=True)
                    continue
            if action in ("append", "appendStrict", "update"):
                split = ent.split_attrs(old, item.attrs, strict=action == "appendStrict",
                                        existing_only=action == "update")
                if split.applicable:
                    txn.put(old, ent.merge_attrs(old, split.applicable, txn.now, override_metadata=override),
                            split.applicable, forced=forced)
                    out.applied = True
                if split.skipped:
                    fail(item, f"[{', '.join(split.skipped)}]")
            elif action == "replace":
                txn.put(old, ent.replace_attrs(old, item.attrs, txn.now), item.attrs, forced=forced)
                out.applied = True
            elif item.attrs:
                present = [n for n in item.attrs if n in old.attrs]
                if present:
                    txn.put(old, ent.delete_attrs(old, present, txn.now), present)
                    out.applied = True
                if len(present) < len(item.attrs):
                    fail(item, f"[{', '.join(n for n in item.attrs if n not in old.attrs)}]")
            else:
                txn.put(old, None, old.attrs)
                out.applied = True
        except NgsiError as err:
            if err.status >= 500:
                raise
            fail(item, err.description)
    return out


def _parse_query_body(body: Any) -> tuple[list[listing.Selector], list[str] | None, Any, Any, list[str] | None]:
    if not isinstance(body, Mapping):
        raise NgsiError(400, "ParseError", "Errors found in incoming JSON buffer: the query must be "
                                           "a JSON object")
    unknown = set(body) - {"entities", "attrs", "expression", "metadata"}
    if unknown:
        raise bad_request(f"unrecognized field(s) in query: {', '.join(sorted(unknown))}")
    selectors = []
    for index, item in enumerate(body.get("entities", [])):
        where = f"entities[{index}]"
        if not isinstance(item, Mapping):
            raise bad_request(f"{where} must be a JSON object")
        if ("id" in item) == ("idPattern" in item):
            raise bad_request(f"{where}: give exactly one of id and idPattern")
        if "type" in item and "typePattern" in item:
            raise bad_request(f"{where}: type and typePattern exclude each other")
        selectors.append(listing.Selector(
            frozenset([check_identifier(item["id"], f"{where}.id")]) if "id" in item else None,
            listing.pattern(_str(item["idPattern"], f"{where}.idPattern"), f"{where}.idPattern")
            if "idPattern" in item else None,
            frozenset([check_identifier(item["type"], f"{where}.type")]) if "type" in item else None,
            listing.pattern(_str(item["typePattern"], f"{where}.typePattern"), f"{where}.typePattern")
            if "typePattern" in item else None))
    attrs = _names(body.get("attrs"), "attrs")
    metadata = _names(body.get("metadata"), "metadata")
    expression = body.get("expression", {})
    if not isinstance(expression, Mapping):
        raise bad_request("expression must be a JSON object with q and/or mq")
    if set(expression) - {"q", "mq"}:
        raise bad_request("expression: only q and mq are supported (no geographical queries)")
    q = parse_q(_str(expression["q"], "expression.q")) if "q" in expression else None
    mq = parse_q(_str(expression["mq"], "expression.mq"), metadata=True) if "mq" in expression else None
    return selectors, attrs, q, mq, metadata


def _str(value: Any, field: str) -> str:
    if not isinstance(value, str):
        raise bad_request(f"{field} must be a string")
    return value


def _names(value: Any, field: str) -> list[str] | None:
    if value is None:
        return None
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise bad_request(f"{field} must be an array of names")
    return value


def make_blueprint(store: ContextStore, clock: Callable[[], float] = time.time) -> Blueprint:
    bp = Blueprint("ngsi_batch", __name__)

    @bp.post("/v2/op/update")
    def op_update() -> Response:
        opts = options(UPDATE_OPTIONS)
        action, items = parse_update(json_body(), "keyValues" in opts)
        outcome = store.write(write_tenant(request.headers), clock(),
                              lambda txn: apply(txn, action, items, opts))
        if not outcome.failures:
            return no_content()
        verb = "already exist" if action == "appendStrict" else "do not exist"
        described = f"{verb}: " + "; ".join(outcome.failures)
        if outcome.applied:
            raise NgsiError(422, "PartialUpdate", described)
        if outcome.only_missing_entities and action in ("update", "delete", "replace"):
            raise NgsiError(404, "NotFound", described)
        raise NgsiError(422, "Unprocessable", described)

    @bp.post("/v2/op/query")
    def op_query() -> Response:
        opts = options(QUERY_OPTIONS)
        mode = render_mode(opts)
        limit, offset = limit_offset()
        order_by = listing.parse_order_by(request.args.get("orderBy"))
        selectors, attrs, q, mq, metadata = _parse_query_body(json_body())
        found = listing.select(store.entities(read_scope(request.headers)), selectors, q, mq)
        found = listing.order(found, order_by)
        body = [ent.render(e, mode, attrs, metadata) for e in found[offset:offset + limit]]
        return json_response(body, headers=page(found, opts, limit, offset))

    return bp

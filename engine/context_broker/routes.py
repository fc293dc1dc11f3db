"""Orion's entity routes over a :class:`ContextStore`: entities, attributes, values, types.

Each view reads its request (:mod:`.params`), parses the body (:mod:`.entities`), and runs one
:meth:`ContextStore.write` (or a lock-free read). The app strips a trailing slash before routing,
so ``/v2/entities/`` (as FiLiP calls it) is ``/v2/entities``. Status codes and error names follow orion-api.md; batch operations live in :mod:`.batch`.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from typing import Any

from flask import Blueprint, Response, request

from engine.context_broker import entities as ent
from engine.context_broker import listing
from engine.context_broker.contract import NgsiError, Tenant, bad_request, not_found, unprocessable
from engine.context_broker.names import check_attribute_name, check_identifier
from engine.context_broker.params import (
    count_param, entity_type_param, json_body, limit_offset, options, read_scope, render_mode,
    value_body, write_tenant,
)
from engine.context_broker.q import parse_q
from engine.context_broker.store import ContextStore, Transaction

LIST_OPTIONS = frozenset({"count", "keyValues", "values", "unique", "normalized", "skipForwarding"})
GET_OPTIONS = frozenset({"keyValues", "values", "unique", "normalized", "skipForwarding"})
WRITE_OPTIONS = frozenset({"keyValues", "forcedUpdate", "overrideMetadata", "flowControl"})
VALUE_OPTIONS = frozenset({"forcedUpdate", "flowControl"})
CREATE_OPTIONS = WRITE_OPTIONS | {"upsert"}
#: The options of each /attrs write method, and its mode (see :func:`write_attrs`).
ATTRS_WRITES = {"POST": (WRITE_OPTIONS | {"append"}, "append"), "PATCH": (WRITE_OPTIONS, "update"),
                "PUT": (WRITE_OPTIONS, "replace")}
NO_ATTR = "The entity does not have such an attribute"


def json_response(body: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    return Response(json.dumps(body, ensure_ascii=False, separators=(",", ":")), status=status,
                    mimetype="application/json", headers=headers or {})


def no_content() -> Response:
    return Response(status=204)


def _list_param(name: str, check: Callable[[str], Any] | None = None) -> list[str] | None:
    raw = request.args.get(name)
    if raw is None:
        return None
    items = [item for item in raw.split(",")]
    if not all(items):
        raise bad_request(f"URL parameter {name}: empty item in {raw!r}")
    if check is not None:
        for item in items:
            check(item)
    return items


def _attrs_param() -> list[str] | None:
    return _list_param("attrs", lambda n: n == "*" or check_identifier(n, "attribute name in attrs"))


def _metadata_param() -> list[str] | None:
    return _list_param("metadata", lambda n: n == "*" or check_identifier(n, "metadata name in metadata"))


def _selectors() -> list[listing.Selector]:
    args = request.args
    if "id" in args and "idPattern" in args:
        raise bad_request("id and idPattern exclude each other: use one")
    if "type" in args and "typePattern" in args:
        raise bad_request("type and typePattern exclude each other: use one")
    ids = _list_param("id", lambda v: check_identifier(v, "entity id (URL parameter id)"))
    types = _list_param("type", lambda v: check_identifier(v, "entity type (URL parameter type)"))
    id_pattern = args.get("idPattern")
    type_pattern = args.get("typePattern")
    selector = listing.Selector(
        frozenset(ids) if ids is not None else None,
        listing.pattern(id_pattern, "idPattern") if id_pattern is not None else None,
        frozenset(types) if types is not None else None,
        listing.pattern(type_pattern, "typePattern") if type_pattern is not None else None)
    return [selector]


def _queries() -> tuple[Any, Any]:
    for geo in ("georel", "geometry", "coords"):
        if geo in request.args:
            raise bad_request(f"URL parameter {geo}: geographical queries are not supported by plantkg")
    q = request.args.get("q")
    mq = request.args.get("mq")
    return (parse_q(q) if q is not None else None,
            parse_q(mq, metadata=True) if mq is not None else None)


def page(found: list[Any], opts: set[str], limit: int, offset: int) -> dict[str, str]:
    return {"Fiware-Total-Count": str(len(found))} if "count" in opts else {}


def write_attrs(store: ContextStore, tenant: Tenant, now: float, eid: str, etype: str | None,
                attrs: dict[str, Any], opts: set[str], mode: str) -> None:
    """The write of ``/attrs``: ``mode`` append (strict with options=append), update or replace.
    Orion applies what it can: skipped attributes make a 422 (PartialUpdate when others were
    written). Shared by the Flask view and the fast path (:mod:`.fastpath`)."""
    override = "overrideMetadata" in opts

    def work(txn: Transaction) -> NgsiError | None:
        old = txn.get(eid, etype)
        if mode == "replace":
            txn.put(old, ent.replace_attrs(old, attrs, txn.now), attrs, forced="forcedUpdate" in opts)
            return None
        split = ent.split_attrs(old, attrs, strict=mode == "append" and "append" in opts,
                                existing_only=mode == "update")
        if split.applicable:
            new = ent.merge_attrs(old, split.applicable, txn.now, override_metadata=override)
            txn.put(old, new, split.applicable, forced="forcedUpdate" in opts)
        return split.refusal(old)

    refusal = store.write(tenant, now, work)
    if refusal is not None:
        raise refusal


def create(store: ContextStore, tenant: Tenant, now: float, parsed: tuple[str, str, dict[str, Any]],
           opts: set[str]) -> tuple[str, str] | None:
    """``POST /v2/entities``: create, or with options=upsert update an existing entity (422
    otherwise). The new entity's id and type, None for an upsert; shared with the fast path."""
    entity_id_, entity_type, attrs = parsed
    upsert = "upsert" in opts

    def work(txn: Transaction) -> None:
        old = txn.find(entity_id_, entity_type)
        if old is None:
            txn.put(None, ent.create_entity(entity_id_, entity_type, txn.tenant.service_path,
                                            attrs, txn.now), attrs, forced="forcedUpdate" in opts)
            return
        if not upsert:
            raise unprocessable(f"Already Exists: entity {entity_id_!r} of type "
                                f"{entity_type!r} (use options=upsert to update it)")
        new = ent.merge_attrs(old, attrs, txn.now, override_metadata="overrideMetadata" in opts)
        txn.put(old, new, attrs, forced="forcedUpdate" in opts)

    store.write(tenant, now, work)
    return None if upsert else (entity_id_, entity_type)


def created_location(entity_id: str, entity_type: str) -> str:
    return f"/v2/entities/{entity_id}?type={entity_type}"


def created_response(made: tuple[str, str] | None) -> Response:
    if made is None:
        return no_content()
    return Response(status=201, headers={"Location": created_location(*made)})


def write_value(store: ContextStore, tenant: Tenant, now: float, eid: str, etype: str | None,
                name: str, value: Any, opts: set[str]) -> None:
    """``PUT .../attrs/{name}/value``; shared by the Flask view and the fast path."""
    def work(txn: Transaction) -> None:
        old = txn.get(eid, etype)
        txn.put(old, ent.set_value(old, name, value, txn.now), {name}, forced="forcedUpdate" in opts)

    store.write(tenant, now, work)


def make_blueprint(store: ContextStore, clock: Callable[[], float] = time.time) -> Blueprint:
    bp = Blueprint("ngsi_entities", __name__)

    def write(work: Callable[[Transaction], Any]) -> Any:
        return store.write(write_tenant(request.headers), clock(), work)

    def entity_id(raw: str) -> str:
        return check_identifier(raw, "entity id")

    def attr_name(raw: str) -> str:
        return check_attribute_name(raw)

    # --- /v2/entities --------------------------------------------------------------------
    @bp.get("/v2/entities")
    def list_entities() -> Response:
        opts = options(LIST_OPTIONS)
        mode = render_mode(opts)
        limit, offset = limit_offset()
        selectors = _selectors()
        q, mq = _queries()
        order_by = listing.parse_order_by(request.args.get("orderBy"))
        attrs, metadata = _attrs_param(), _metadata_param()
        found = listing.select(store.entities(read_scope(request.headers)), selectors, q, mq)
        found = listing.order(found, order_by)
        body = [ent.render(e, mode, attrs, metadata) for e in found[offset:offset + limit]]
        return json_response(body, headers=page(found, opts, limit, offset))

    @bp.post("/v2/entities")
    def create_entity() -> Response:
        opts = options(CREATE_OPTIONS)
        parsed = ent.parse_entity(json_body(), key_values="keyValues" in opts)
        return created_response(create(store, write_tenant(request.headers), clock(), parsed, opts))

    # --- /v2/entities/{id} ---------------------------------------------------------------
    @bp.get("/v2/entities/<raw_id>")
    def get_entity(raw_id: str) -> Response:
        opts = options(GET_OPTIONS)
        entity = store.get(read_scope(request.headers), entity_id(raw_id), entity_type_param())
        return json_response(ent.render(entity, render_mode(opts), _attrs_param(), _metadata_param()))

    @bp.delete("/v2/entities/<raw_id>")
    def delete_entity(raw_id: str) -> Response:
        eid, etype = entity_id(raw_id), entity_type_param()

        def work(txn: Transaction) -> None:
            old = txn.get(eid, etype)
            txn.put(old, None, old.attrs)

        write(work)
        return no_content()

    # --- /v2/entities/{id}/attrs ---------------------------------------------------------
    @bp.get("/v2/entities/<raw_id>/attrs")
    def get_attrs(raw_id: str) -> Response:
        opts = options(GET_OPTIONS)
        entity = store.get(read_scope(request.headers), entity_id(raw_id), entity_type_param())
        return json_response(ent.render_attrs(entity, render_mode(opts), _attrs_param(), _metadata_param()))

    def _attrs_write(raw_id: str, allowed: frozenset[str], mode: str) -> Response:
        """POST (``mode`` append, or strict with options=append), PATCH (update) or PUT
        (replace) of /attrs (see :func:`write_attrs`)."""
        opts = options(allowed)
        eid, etype = entity_id(raw_id), entity_type_param()
        attrs = ent.parse_attrs(json_body(), key_values="keyValues" in opts)
        write_attrs(store, write_tenant(request.headers), clock(), eid, etype, attrs, opts, mode)
        return no_content()

    @bp.post("/v2/entities/<raw_id>/attrs")
    def append_attrs(raw_id: str) -> Response:
        return _attrs_write(raw_id, *ATTRS_WRITES["POST"])

    @bp.patch("/v2/entities/<raw_id>/attrs")
    def update_attrs(raw_id: str) -> Response:
        return _attrs_write(raw_id, *ATTRS_WRITES["PATCH"])

    @bp.put("/v2/entities/<raw_id>/attrs")
    def replace_attrs(raw_id: str) -> Response:
        return _attrs_write(raw_id, *ATTRS_WRITES["PUT"])

    # --- /v2/entities/{id}/attrs/{name} --------------------------------------------------
    @bp.get("/v2/entities/<raw_id>/attrs/<raw_name>")
    def get_attr(raw_id: str, raw_name: str) -> Response:
        name = attr_name(raw_name)
        entity = store.get(read_scope(request.headers), entity_id(raw_id), entity_type_param())
        data = ent.attribute_json(entity, name, _metadata_param())
        if data is None:
            raise not_found(NO_ATTR)
        return json_response(data)

    @bp.put("/v2/entities/<raw_id>/attrs/<raw_name>")
    def put_attr(raw_id: str, raw_name: str) -> Response:
        opts = options(frozenset({"forcedUpdate", "overrideMetadata", "flowControl"}))
        eid, etype, name = entity_id(raw_id), entity_type_param(), attr_name(raw_name)
        given = ent.parse_attr(name, json_body())

        def work(txn: Transaction) -> None:
            old = txn.get(eid, etype)
            if name not in old.attrs:
                raise not_found(NO_ATTR)
            new = ent.merge_attrs(old, {name: given}, txn.now, override_metadata="overrideMetadata" in opts)
            txn.put(old, new, {name}, forced="forcedUpdate" in opts)

        write(work)
        return no_content()

    @bp.delete("/v2/entities/<raw_id>/attrs/<raw_name>")
    def delete_attr(raw_id: str, raw_name: str) -> Response:
        eid, etype, name = entity_id(raw_id), entity_type_param(), attr_name(raw_name)

        def work(txn: Transaction) -> None:
            old = txn.get(eid, etype)
            if name not in old.attrs:
                raise not_found(NO_ATTR)
            txn.put(old, ent.delete_attrs(old, [name], txn.now), {name})

        write(work)
        return no_content()

    # --- /v2/entities/{id}/attrs/{name}/value --------------------------------------------
    @bp.get("/v2/entities/<raw_id>/attrs/<raw_name>/value")
    def get_value(raw_id: str, raw_name: str) -> Response:
        name = attr_name(raw_name)
        entity = store.get(read_scope(request.headers), entity_id(raw_id), entity_type_param())
        data = ent.attribute_json(entity, name)
        if data is None:
            raise not_found(NO_ATTR)
        text = json.dumps(data["value"], ensure_ascii=False)
        wants_text = request.accept_mimetypes.best_match(["application/json", "text/plain"]) == "text/plain"
        return Response(text, mimetype="text/plain" if wants_text else "application/json")

    @bp.put("/v2/entities/<raw_id>/attrs/<raw_name>/value")
    def put_value(raw_id: str, raw_name: str) -> Response:
        opts = options(VALUE_OPTIONS)
        eid, etype, name = entity_id(raw_id), entity_type_param(), attr_name(raw_name)
        value = value_body()
        write_value(store, write_tenant(request.headers), clock(), eid, etype, name, value, opts)
        return no_content()

    # --- /v2/types -----------------------------------------------------------------------
    @bp.get("/v2/types")
    def list_types() -> Response:
        opts = options(frozenset({"count", "values", "noAttrDetail"}))
        limit, offset = limit_offset()
        summaries = listing.type_summaries(store.entities(read_scope(request.headers)),
                                           detail="noAttrDetail" not in opts)
        names = list(summaries)
        chosen = names[offset:offset + limit]
        body: list[Any] = chosen if "values" in opts else [{"type": t, **summaries[t]} for t in chosen]
        return json_response(body, headers=page(names, opts, limit, offset))

    @bp.get("/v2/types/<raw_type>")
    def get_type(raw_type: str) -> Response:
        options(frozenset({"noAttrDetail"}))
        entity_type = check_identifier(raw_type, "entity type")
        summaries = listing.type_summaries(
            (e for e in store.entities(read_scope(request.headers)) if e.type == entity_type),
            detail="noAttrDetail" not in request.args.get("options", ""))
        if entity_type not in summaries:
            raise not_found(f"Entity type not found: {entity_type!r}")
        return json_response(summaries[entity_type])

    return bp


__all__ = ["NgsiError", "count_param", "json_response", "make_blueprint", "no_content"]

"""The OpenAPI 3 document of every route the context broker serves (``/plantkg/v1/openapi.json``).

Built from data, so a route, its parameters, bodies and answers are written once. Complete enough
for a fuzzer (schemathesis) to generate requests: every path and method, path/query/header
parameters with their types, request bodies, and the status codes each operation can answer
(Orion's error body for all errors).

403 is documented where a closed broker (``--principals``, engine.context_broker.access) can refuse
a principal its token is known for: every operation but the public ones (``GET /version``) and
those of a subscription that only ever answer 404 for another's (:data:`NEVER_FORBIDDEN`: reading,
listing, deleting; ``.subscriptions.ownership``). tests/unit/context_broker/test_openapi_forbidden.py
provokes the 403 of each operation through the app and checks the two agree.
"""

from __future__ import annotations

from typing import Any

from engine.context_broker.access import PUBLIC_PATHS

ERROR = {"$ref": "#/components/schemas/Error"}
JSON_ANY: dict[str, Any] = {}
ID_SCHEMA = {"type": "string", "minLength": 1, "maxLength": 256}


def _param(name: str, where: str = "query", schema: dict[str, Any] | None = None,
           required: bool = False, description: str = "") -> dict[str, Any]:
    out = {"name": name, "in": where, "required": required or where == "path",
           "schema": schema or {"type": "string"}}
    if description:
        out["description"] = description
    return out


TENANCY = [_param("Fiware-Service", "header", {"type": "string", "maxLength": 50}),
           _param("Fiware-ServicePath", "header")]
PAGING = [_param("limit", schema={"type": "integer", "minimum": 1, "maximum": 1000}),
          _param("offset", schema={"type": "integer", "minimum": 0})]
ENTITY_ID = _param("entityId", "path", ID_SCHEMA)
ATTR_NAME = _param("attrName", "path", ID_SCHEMA)
TYPE = _param("type", description="entity type, when the id names several entities")
OPTIONS = _param("options", description="comma-separated options")
SELECT = [_param("attrs"), _param("metadata")]
QUERY = [_param("id"), _param("type"), _param("idPattern"), _param("typePattern"), _param("q"),
         _param("mq"), _param("orderBy")]


#: Subscription operations a principal is never refused with 403: another's subscription is 404
#: to it (as if absent), and it lists only its own (.subscriptions.ownership).
NEVER_FORBIDDEN = frozenset({("get", "/v2/subscriptions"), ("get", "/v2/subscriptions/{subscriptionId}"),
                             ("delete", "/v2/subscriptions/{subscriptionId}")})
FORBIDDEN = {"description": "a closed context broker (--principals) refuses the principal the token "
                            "belongs to: outside its rights (Orion error body, error \"Forbidden\")",
             "content": {"application/json": {"schema": ERROR}}}


def _errors(*codes: int) -> dict[str, Any]:
    base = {400, 401, 404, 405, 409, 411, 413, 415, 422}
    return {str(c): {"description": "Orion error body", "content": {"application/json": {"schema": ERROR}}}
            for c in sorted(base | set(codes))}


def may_be_forbidden(method: str, path: str) -> bool:
    """Whether a closed broker can answer ``method`` ``path`` (a path of this document) with 403."""
    return path not in PUBLIC_PATHS and (method, path) not in NEVER_FORBIDDEN


def _with_forbidden(paths: dict[str, Any]) -> dict[str, Any]:
    """``paths`` with the 403 answer on every operation :func:`may_be_forbidden` says can give it."""
    for path, operations in paths.items():
        for method, operation in operations.items():
            if may_be_forbidden(method, path):
                operation["responses"] = dict(sorted({**operation["responses"], "403": FORBIDDEN}.items()))
    return paths


def _ok(code: int, schema: dict[str, Any] | None = None, mimetype: str = "application/json",
        headers: dict[str, Any] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {"description": "success"}
    if schema is not None:
        out["content"] = {mimetype: {"schema": schema}}
    if headers:
        out["headers"] = headers
    return {str(code): out}


def _body(schema: dict[str, Any], *extra: str) -> dict[str, Any]:
    content = {"application/json": {"schema": schema}}
    for mimetype in extra:
        content[mimetype] = {"schema": {"type": "string"}}
    return {"required": True, "content": content}


def _op(summary: str, params: list[dict[str, Any]], responses: dict[str, Any],
        body: dict[str, Any] | None = None, write: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {"summary": summary, "parameters": params + TENANCY,
                           "responses": {**responses, **_errors()}}
    if body is not None:
        out["requestBody"] = body
    if write:
        out["security"] = [{"bearer": []}]
    return out


COUNT = {"Fiware-Total-Count": {"schema": {"type": "integer"}}}
ENTITY = {"$ref": "#/components/schemas/Entity"}
ATTRIBUTE = {"$ref": "#/components/schemas/Attribute"}
ATTRS = {"type": "object", "additionalProperties": ATTRIBUTE}


def openapi_document(with_subscriptions: bool = False) -> dict[str, Any]:
    paths: dict[str, Any] = {
        "/version": {"get": _op("Orion-shaped version (FiLiP reads orion.version)", [],
                                _ok(200, {"type": "object"}))},
        "/v2": {"get": _op("API resources", [], _ok(200, {"type": "object"}))},
        "/v2/entities": {
            "get": _op("List entities", QUERY + SELECT + PAGING + [OPTIONS],
                       _ok(200, {"type": "array"}, headers=COUNT)),
            "post": _op("Create an entity (options=upsert: update if it exists, 204)",
                        [OPTIONS], {**_ok(201), **_ok(204)}, _body(ENTITY), True)},
        "/v2/entities/{entityId}": {
            "get": _op("Retrieve an entity", [ENTITY_ID, TYPE, OPTIONS] + SELECT, _ok(200, JSON_ANY)),
            "delete": _op("Remove an entity", [ENTITY_ID, TYPE], _ok(204), write=True)},
        "/v2/entities/{entityId}/attrs": {
            "get": _op("Retrieve the attributes of an entity", [ENTITY_ID, TYPE, OPTIONS] + SELECT,
                       _ok(200, JSON_ANY)),
            "post": _op("Update or append attributes (options=append: append only)",
                        [ENTITY_ID, TYPE, OPTIONS], _ok(204), _body(ATTRS), True),
            "patch": _op("Update existing attributes", [ENTITY_ID, TYPE, OPTIONS], _ok(204),
                         _body(ATTRS), True),
            "put": _op("Replace all attributes", [ENTITY_ID, TYPE, OPTIONS], _ok(204), _body(ATTRS), True)},
        "/v2/entities/{entityId}/attrs/{attrName}": {
            "get": _op("Get attribute data", [ENTITY_ID, ATTR_NAME, TYPE, _param("metadata")],
                       _ok(200, ATTRIBUTE)),
            "put": _op("Update attribute data", [ENTITY_ID, ATTR_NAME, TYPE, OPTIONS], _ok(204),
                       _body(ATTRIBUTE), True),
            "delete": _op("Remove an attribute", [ENTITY_ID, ATTR_NAME, TYPE], _ok(204), write=True)},
        "/v2/entities/{entityId}/attrs/{attrName}/value": {
            "get": _op("Get an attribute value", [ENTITY_ID, ATTR_NAME, TYPE], _ok(200, JSON_ANY)),
            "put": _op("Update an attribute value (JSON, or text/plain: \"text\", number, true, "
                       "false, null)", [ENTITY_ID, ATTR_NAME, TYPE, OPTIONS], _ok(204),
                       _body(JSON_ANY, "text/plain"), True)},
        "/v2/types": {"get": _op("List entity types", PAGING + [OPTIONS],
                                 _ok(200, {"type": "array"}, headers=COUNT))},
        "/v2/types/{entityType}": {"get": _op("Entity type information",
                                              [_param("entityType", "path", ID_SCHEMA), OPTIONS],
                                              _ok(200, {"type": "object"}))},
        "/v2/op/update": {"post": _op("Batch update", [OPTIONS], _ok(204), _body({
            "type": "object", "required": ["actionType", "entities"],
            "properties": {"actionType": {"type": "string", "enum": ["append", "appendStrict", "update",
                                                                     "delete", "replace"]},
                           "entities": {"type": "array", "items": ENTITY}}}), True)},
        "/v2/op/query": {"post": _op("Batch query (a read: no token needed)",
                                     PAGING + [_param("orderBy"), OPTIONS],
                                     _ok(200, {"type": "array"}, headers=COUNT), _body({
                                         "type": "object", "properties": {
                                             "entities": {"type": "array", "items": {"type": "object"}},
                                             "attrs": {"type": "array", "items": {"type": "string"}},
                                             "metadata": {"type": "array", "items": {"type": "string"}},
                                             "expression": {"type": "object", "properties": {
                                                 "q": {"type": "string"}, "mq": {"type": "string"}}}}}))},
        "/plantkg/v1/graph": {"get": _op("The whole context as N-Quads (one named graph per tenant)",
                                         [], _ok(200, {"type": "string"}, "application/n-quads"))},
        "/plantkg/v1/openapi.json": {"get": _op("This document", [], _ok(200, {"type": "object"}))},
    }
    if with_subscriptions:
        sub_id = _param("subscriptionId", "path", {"type": "string", "pattern": "^[0-9a-f]{24}$"})
        paths["/v2/subscriptions"] = {
            "get": _op("List subscriptions", PAGING + [OPTIONS], _ok(200, {"type": "array"}, headers=COUNT)),
            "post": _op("Create a subscription", [], _ok(201), _body({"type": "object"}), True)}
        paths["/v2/subscriptions/{subscriptionId}"] = {
            "get": _op("Retrieve a subscription", [sub_id], _ok(200, {"type": "object"})),
            "patch": _op("Update a subscription", [sub_id], _ok(204), _body({"type": "object"}), True),
            "delete": _op("Delete a subscription", [sub_id], _ok(204), write=True)}
    return {
        "openapi": "3.0.3",
        "info": {"title": "plantkg NGSI-v2 context broker", "version": "0.1.0",
                 "description": "FIWARE Orion's NGSI-v2 API (a subset, see docs/context-broker.md); "
                                "the context is kept as RDF."},
        "paths": _with_forbidden(paths),
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": {
                "Error": {"type": "object", "required": ["error"], "properties": {
                    "error": {"type": "string"}, "description": {"type": "string"}}},
                "Attribute": {"type": "object", "properties": {
                    "type": {"type": "string"}, "value": {}, "metadata": {"type": "object"}}},
                "Entity": {"type": "object", "required": ["id"], "properties": {
                    "id": ID_SCHEMA, "type": ID_SCHEMA}, "additionalProperties": ATTRIBUTE},
            }},
    }

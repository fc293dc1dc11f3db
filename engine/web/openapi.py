"""The dashboard's JSON API and the SPARQL endpoint as an OpenAPI 3.1 document, written by hand
(served at ``/api/openapi.json``). A unit test checks that every route of the app is described
here and nothing more, as for the agent (engine/agent/openapi.py)."""

from __future__ import annotations

from typing import Any

_ERROR = {"type": "object", "required": ["error"],
          "properties": {"error": {"type": "string"}, "hint": {"type": ["string", "null"]}}}
_NULLABLE_NUMBER = {"type": ["number", "null"]}


def _json(schema: dict[str, Any], description: str) -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": schema}}}


def _error(description: str) -> dict[str, Any]:
    return _json({"$ref": "#/components/schemas/Error"}, description)


_SCHEMAS: dict[str, Any] = {
    "Error": _ERROR,
    "Broker": {"type": "object", "required": ["id", "kind", "host", "port", "status"], "properties": {
        "id": {"type": "string"}, "name": {"type": "string"}, "kind": {"type": "string"},
        "host": {"type": "string"}, "port": {"type": "integer"}, "address": {"type": "string"},
        "status": {"type": "string", "description": "running, starting, stopped, crashed, failed; "
                                                    "absent (no agent runs it), unknown (agent unreachable)"},
        "in_plant": {"type": "boolean"}, "pid": {"type": ["integer", "null"]},
        "started_at": _NULLABLE_NUMBER, "restarts": {"type": ["integer", "null"]},
        "last_error": {"type": ["string", "null"]}, "topics_wanted": {"type": "integer"},
        "topics_present": {"type": "integer"}, "topics_extra": {"type": "integer"}}},
    "Bridge": {"type": "object", "required": ["address", "local", "remote", "status"], "properties": {
        "address": {"type": "string"}, "local": {"type": "string"}, "remote": {"type": "string"},
        "mechanism": {"type": ["string", "null"]}, "asserted": {"type": "boolean"},
        "routes": {"type": "array", "items": {"type": "object"}}, "status": {"type": "string"},
        "forwarded": {"type": ["integer", "null"]}, "retried": {"type": ["integer", "null"]},
        "refused": {"type": ["integer", "null"], "description": "messages the remote refused for their content"},
        "restarts": {"type": ["integer", "null"]}, "started_at": _NULLABLE_NUMBER,
        "last_error": {"type": ["string", "null"]}, "in_plant": {"type": "boolean"}}},
    "Status": {"type": "object", "required": ["version", "brokers", "bridges", "plan", "apply"], "properties": {
        "version": {"type": "integer", "description": "Grows with every change; also the ETag"},
        "files": {"type": "array", "items": {"type": "string"}},
        "loaded_at": _NULLABLE_NUMBER, "observed_at": _NULLABLE_NUMBER,
        "error": {"type": ["string", "null"]},
        "validation": {"type": "object"},
        "machines": {"type": "array", "items": {"type": "object"}},
        "brokers": {"type": "array", "items": {"$ref": "#/components/schemas/Broker"}},
        "topics": {"type": "array", "items": {"type": "object"}},
        "topics_total": {"type": "integer"},
        "bridges": {"type": "array", "items": {"$ref": "#/components/schemas/Bridge"}},
        "graph": {"type": "object", "description": "nodes and edges for the picture"},
        "context": {"type": ["object", "null"], "description": "the live context read from the plant's "
                    "context brokers: quads, brokers, unavailable (broker, why)"},
        "plan": {"type": ["object", "null"], "description": "summary and fingerprint of the pending plan"},
        "apply": {"type": "object", "description": "the last apply: state, progress, summary"}}},
    "Rates": {"type": "object", "required": ["window_s", "enabled", "topics"], "properties": {
        "window_s": {"type": "integer", "description": "seconds in per_s"},
        "enabled": {"type": "boolean", "description": "false: this server watches no topic (no live state)"},
        "topics": {"type": "array", "items": {
            "type": "object", "required": ["broker", "topic", "per_s", "total", "watching"], "properties": {
                "broker": {"type": "string"}, "topic": {"type": "string"},
                "per_s": {"type": "array", "items": {"type": "integer"},
                          "description": "messages in each of the last window_s complete seconds, oldest first"},
                "total": {"type": "integer", "description": "messages counted since the topic was first watched"},
                "watching": {"type": "boolean", "description": "subscribed at the broker now"},
                "error": {"type": ["string", "null"], "description": "why the broker cannot be watched (retried)"}}}}}},
}

_WRITE = {"security": [{"session": [], "csrf": []}, {"bearer": []}]}


def _sparql_operation(method: str) -> dict[str, Any]:
    op: dict[str, Any] = {
        "operationId": f"sparql{method.capitalize()}",
        "summary": "SPARQL 1.1 Protocol query (read-only)",
        "responses": {
            "200": {"description": "SELECT/ASK: SPARQL JSON, XML, CSV, TSV; CONSTRUCT/DESCRIBE: Turtle, "
                                   "JSON-LD, N-Triples, RDF/XML (by Accept)"},
            **{str(c): {"description": d, "content": {"text/plain": {}}} for c, d in (
                (400, "No or malformed query"), (403, "An update: the endpoint is read-only"),
                (406, "No acceptable result format"), (413, "More results than the limit"),
                (415, "POST of another content type"), (503, "Timeout, or too many queries at once"))},
        },
    }
    if method == "get":
        op["parameters"] = [{"name": n, "in": "query", "required": n == "query", "schema": {"type": "string"}}
                            for n in ("query", "default-graph-uri", "named-graph-uri")]
    else:
        op["requestBody"] = {"content": {"application/x-www-form-urlencoded": {"schema": {
            "type": "object", "properties": {"query": {"type": "string"}}}},
            "application/sparql-query": {"schema": {"type": "string"}}}}
    return op


def openapi_document() -> dict[str, Any]:
    """The document (see docs/web.md for the pages around it)."""
    return {
        "openapi": "3.1.0",
        "info": {"title": "plantkg serve", "version": "1",
                 "description": "The dashboard's JSON API and the SPARQL endpoint. Reads are open; "
                                "writes need a login session with its CSRF token (X-CSRF-Token) or a "
                                "bearer token. See docs/web.md."},
        "servers": [{"url": "/"}],
        "components": {
            "securitySchemes": {
                "bearer": {"type": "http", "scheme": "bearer"},
                "session": {"type": "apiKey", "in": "cookie", "name": "session"},
                "csrf": {"type": "apiKey", "in": "header", "name": "X-CSRF-Token"},
            },
            "schemas": _SCHEMAS,
        },
        "paths": {
            "/api/status": {"get": {"operationId": "status", "summary": "Brokers, bridges, topics, plan, apply",
                                    "responses": {"200": _json({"$ref": "#/components/schemas/Status"}, "Status"),
                                                  "304": {"description": "Unchanged (If-None-Match)"}}}},
            "/api/rates": {"get": {
                "operationId": "rates", "summary": "Messages per second per (broker, topic), the last minute",
                "responses": {"200": _json({"$ref": "#/components/schemas/Rates"}, "The rates")}}},
            "/api/plan": {"get": {"operationId": "plan", "summary": "The pending plan with before/after",
                                  "responses": {"200": _json({"type": "object", "properties": {
                                      "plan": {"type": ["object", "null"]}, "fingerprint": {"type": ["string", "null"]},
                                      "text": {"type": ["string", "null"]}}}, "The plan (null: none)")}}},
            "/api/validation": {"get": {"operationId": "validation", "summary": "The validation report",
                                        "responses": {"200": _json({"type": "object"}, "The report")}}},
            "/api/explain": {"get": {
                "operationId": "explain", "summary": "Why a broker, topic or bridge of the plan must exist",
                "parameters": [
                    {"name": "address", "in": "query", "required": True, "schema": {"type": "string"},
                     "description": "broker.ID, topic.BROKER_ID.TOPIC_NAME or bridge.ID.ID"},
                    {"name": "format", "in": "query", "schema": {"type": "string", "enum": ["json", "text"]}}],
                "responses": {"200": _json({"type": "object", "properties": {
                                  "address": {"type": "string"}, "required": {"type": "boolean"},
                                  "reasons": {"type": "array"}, "note": {"type": "string"}}},
                                  "The reasons (required false: why not)"),
                              "400": _error("Not a plan address"), "409": _error("The plant has violations"),
                              "422": _error("The plant cannot be explained (a bad file, or only HermiT reasons over it)")}}},
            "/api/apply": {"post": {
                "operationId": "apply", "summary": "Start applying the plan named by its fingerprint", **_WRITE,
                "requestBody": {"required": True, "content": {"application/json": {"schema": {
                    "type": "object", "required": ["fingerprint"],
                    "properties": {"fingerprint": {"type": "string"}}}}}},
                "responses": {"202": _json({"type": "object"}, "Started; follow it in /api/status"),
                              "400": _error("No fingerprint"), "401": _error("Not authenticated"),
                              "403": _error("Missing or wrong CSRF token"),
                              "409": _error("Another plan is current, an apply runs, or the plan cannot be applied")}}},
            **{f"/api/{verb}": {"post": {
                "operationId": f"{verb}Broker", "summary": summary, **_WRITE,
                "requestBody": {"required": True, "content": {"application/json": {"schema": {
                    "type": "object", "required": ["broker_id"],
                    "properties": {"broker_id": {"type": "string"}}}}}},
                "responses": {"200": _json({"type": "object", "properties": {
                                  "broker": {"type": "object"}}}, "The broker as its agent answers"),
                              "400": _error("No broker_id"), "401": _error("Not authenticated"),
                              "403": _error("Missing or wrong CSRF token"),
                              "404": _error("No agent reports this broker"),
                              "409": _error("The agent refused (e.g. unknown broker there)"),
                              "503": _error("The agent did not answer")}}}
              for verb, summary in (
                  ("stop", "Stop a broker and keep it stopped, its data and config kept, until started"),
                  ("start", "Start a broker the operator stopped"),
                  ("restart", "Stop a broker gracefully and start it again (a new pid)"))},
            "/api/refresh": {"post": {
                "operationId": "refresh", "summary": "Ask the agents again now", **_WRITE,
                "responses": {"200": _json({"type": "object"}, "Observed again"),
                              "401": _error("Not authenticated"), "403": _error("Missing or wrong CSRF token")}}},
            "/api/openapi.json": {"get": {"operationId": "openapi", "summary": "This document",
                                          "responses": {"200": {"description": "OpenAPI 3.1"}}}},
            "/sparql": {"get": _sparql_operation("get"), "post": _sparql_operation("post")},
        },
    }

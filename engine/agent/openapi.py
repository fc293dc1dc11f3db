"""The agent API as an OpenAPI 3.1 document, written by hand (served at ``/v1/openapi.json``).

Schemas mirror engine.model's dataclasses as :func:`engine.model.to_dict` writes them; a unit test
checks that every route of the app is described here and nothing more.
"""

from __future__ import annotations

from typing import Any

_NULLABLE_INT = {"type": ["integer", "null"]}


def _ref(name: str) -> dict[str, str]:
    return {"$ref": f"#/components/schemas/{name}"}


def _error_responses(*codes: int) -> dict[str, Any]:
    text = {
        400: "Invalid JSON, unknown or missing field, or invalid value (`field` names it)",
        401: "Missing or wrong bearer token",
        404: "Unknown broker",
        409: "The broker cannot do this (fewer Kafka partitions, broker failed or stopped), or "
             "the request names an owner and another plant owns the broker, topic or bridge",
        422: "The agent cannot do this (no driver for the kind, a part missing, the broker "
             "exited while starting)",
        503: "Try again: the broker is starting, restarting, or did not answer",
        500: "Internal error",
    }
    return {str(c): {"description": text[c], "content": {
        "application/json": {"schema": _ref("Error")}}} for c in codes}


def _json(schema: dict[str, Any], description: str) -> dict[str, Any]:
    return {"description": description, "content": {"application/json": {"schema": schema}}}


_BROKER_ID = {"name": "broker_id", "in": "path", "required": True,
              "schema": {"type": "string", "pattern": "^[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}$"}}
#: Ownership (docs/operating.md): the plant that owns a broker, topic or bridge on this agent.
_OWNER = {"type": "string", "minLength": 1, "maxLength": 512, "pattern": "^[^\\s]+$",
          "description": "The owning plant (its owner name or ontology IRI); stored with the thing "
                         "in the agent's state dir (survives restarts). A request naming an owner "
                         "is refused (409) on a thing another plant owns; without one the "
                         "recorded owner is kept"}
_NULLABLE_OWNER = {"type": ["string", "null"],
                   "description": "The plant that owns it on this agent; null: nobody"}
_OWNER_QUERY = {"name": "owner", "in": "query", "required": False, "schema": _OWNER,
                "description": "Refuse (409) if another plant owns it"}
_TOPIC_NAME = {"name": "name", "in": "path", "required": True,
               "description": "The topic name, percent-encoded (MQTT names hold slashes: %2F)",
               "schema": {"type": "string"}}

_SCHEMAS: dict[str, Any] = {
    "Error": {
        "type": "object", "required": ["error", "retryable"],
        "properties": {
            "error": {"type": "string"},
            "hint": {"type": ["string", "null"]},
            "retryable": {"type": "boolean"},
            "field": {"type": "string", "description": "The field of the body at fault"},
        },
    },
    "BrokerSpec": {
        "type": "object", "additionalProperties": False,
        "required": ["id", "iri", "name", "kind", "host", "port"],
        "properties": {
            "id": _BROKER_ID["schema"],
            "iri": {"type": "string"},
            "name": {"type": "string", "minLength": 1},
            "kind": {"type": "string", "description": "A driver name: mosquitto, kafka, ..."},
            "host": {"type": "string", "description": "IPv4 or IPv6 address the broker binds"},
            "port": {"type": "integer", "minimum": 1, "maximum": 65535},
            "persist_every": {"type": ["integer", "null"], "minimum": 1, "maximum": 1000000,
                              "description": "mosquitto: save after this many changes"},
            "allow_anonymous": {"type": ["boolean", "null"],
                                "description": "ngsi-v2: writes need no token (restarts the broker)"},
            "mqtt_port": {"type": ["integer", "null"], "minimum": 1, "maximum": 65535,
                          "description": "the MQTT listener of a broker type whose port speaks "
                                         "another protocol (pk:mqttPort); bridges connect to it"},
            "users": {"type": "array", "items": {"$ref": "#/components/schemas/BrokerUser"},
                      "description": "the clients the broker admits and their ACLs (pk:secretRef, "
                                     "pk:clientCertificate); "
                                     "with users, a broker is closed to anonymous clients unless "
                                     "allow_anonymous is true"},
            "tls": {"type": "boolean", "description": "the listener speaks TLS only (pk:tls)"},
            "certificate_port": {"type": ["integer", "null"], "minimum": 1, "maximum": 65535,
                                 "description": "mosquitto with tls: a second TLS listener that admits "
                                                "only clients with a plant-CA client certificate, its "
                                                "common name their user name (pk:certificatePort)"},
            "kafka": {"oneOf": [{"type": "null"}, {"$ref": "#/components/schemas/KafkaNode"}],
                      "description": "kafka: the broker is one node of a multi-node cluster"},
            "closed_kafkas": {"type": "array", "items": {"type": "string"},
                              "description": "ngsi-v2: the plant's closed Kafka brokers ('host:port'), "
                                             "where its kafka:// notifications log in as plantkg"},
            "tls_kafkas": {"type": "array", "items": {"type": "string"},
                           "description": "ngsi-v2: the plant's Kafka brokers that speak TLS ('host:port'), "
                                          "where its kafka:// notifications use TLS, trusting the plant CA"},
        },
    },
    "KafkaNode": {
        "type": "object", "additionalProperties": False,
        "required": ["cluster", "cluster_id", "node_id", "roles", "voters"],
        "properties": {
            "cluster": {"type": "string", "description": "the cluster's pk:id"},
            "cluster_id": {"type": "string", "pattern": "^[A-Za-z0-9_][A-Za-z0-9_-]{21}$",
                           "description": "the KRaft cluster id every node is formatted with"},
            "node_id": {"type": "integer", "minimum": 0, "maximum": 2147483647},
            "roles": {"type": "array", "minItems": 1, "items": {"enum": ["broker", "controller"]}},
            "voters": {"type": "array", "minItems": 1, "items": {
                "type": "object", "additionalProperties": False, "required": ["node_id", "host", "port"],
                "properties": {"node_id": {"type": "integer", "minimum": 0},
                               "host": {"type": "string"},
                               "port": {"type": "integer", "minimum": 1, "maximum": 65535}}}},
            "controller_port": {"type": ["integer", "null"], "minimum": 1, "maximum": 65535},
            "replication": {"type": "integer", "minimum": 1, "maximum": 32767},
            "min_insync": {"type": ["integer", "null"], "minimum": 1, "maximum": 32767},
            "bootstrap": {"type": "array", "items": {"type": "string"},
                          "description": "host:port of every broker node of the cluster"},
            "lead": {"type": "boolean", "description": "this node's agent manages the cluster's topics"},
        },
    },
    "BrokerUser": {
        "type": "object", "additionalProperties": False,
        "required": ["name"],
        "properties": {
            "name": {"type": "string", "pattern": "^[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}$"},
            "secret_ref": {"type": ["string", "null"],
                           "pattern": "^(env:[A-Za-z_][A-Za-z0-9_]{0,127}|file:/\\S{1,4095})$",
                           "description": "where the password is on the agent's machine: env:NAME "
                                          "or file:/absolute/path (never the password); null or "
                                          "absent only for a certificate user without a password"},
            "certificate": {"type": "boolean",
                            "description": "the user may log in with a plant-CA client certificate "
                                           "(common name its name) on the broker's certificate_port"},
            "write": {"type": "array", "items": {"type": "string", "minLength": 1},
                      "description": "topic names the user may publish"},
            "read": {"type": "array", "items": {"type": "string", "minLength": 1},
                     "description": "topic names the user may subscribe to"},
        },
    },
    "TopicSpec": {
        "type": "object", "additionalProperties": False,
        "required": ["broker_id", "name", "iri"],
        "properties": {
            "broker_id": {"type": "string"},
            "name": {"type": "string", "minLength": 1},
            "iri": {"type": "string"},
            "partitions": {"type": ["integer", "null"], "minimum": 1, "maximum": 10000},
            "replication_factor": {"type": ["integer", "null"], "minimum": 1, "maximum": 32767},
            "retention_ms": {"type": ["integer", "null"], "minimum": -1},
            "qos": {"type": ["integer", "null"], "minimum": 0, "maximum": 2},
            "retain": {"type": ["boolean", "null"]},
            "entity_id": {"type": ["string", "null"], "maxLength": 256,
                          "description": "ngsi-v2: the topic's entity (Orion's identifier rules)"},
            "entity_type": {"type": ["string", "null"], "maxLength": 256},
            "min_insync_replicas": {"type": ["integer", "null"], "minimum": 1, "maximum": 32767},
        },
    },
    "ObservedTopic": {
        "type": "object", "required": ["name"],
        "properties": {
            "name": {"type": "string"},
            "partitions": _NULLABLE_INT,
            "replication_factor": _NULLABLE_INT,
            "retention_ms": _NULLABLE_INT,
            "qos": _NULLABLE_INT,
            "retain": {"type": ["boolean", "null"]},
            "entity_id": {"type": ["string", "null"]},
            "entity_type": {"type": ["string", "null"]},
            "owner": _NULLABLE_OWNER,
            "min_insync_replicas": _NULLABLE_INT,
        },
    },
    "ObservedBroker": {
        "type": "object", "required": ["spec", "status", "topics", "restarts"],
        "properties": {
            "spec": _ref("BrokerSpec"),
            "status": {"type": "string",
                       "enum": ["running", "starting", "stopped", "stopped-by-operator",
                                "crashed", "failed"]},
            "topics": {"type": "array", "items": _ref("ObservedTopic")},
            "pid": _NULLABLE_INT,
            "started_at": {"type": ["number", "null"], "description": "Seconds since the epoch"},
            "restarts": {"type": "integer", "description": "Restarts after crashes"},
            "config_hash": {"type": ["string", "null"]},
            "last_error": {"type": ["string", "null"]},
            "owner": _NULLABLE_OWNER,
        },
    },
    "BridgeEnd": {
        "type": "object", "required": ["id", "kind", "host", "port"],
        "properties": {"id": {"type": "string"}, "kind": {"type": "string"},
                       "host": {"type": "string"}, "port": {"type": "integer"},
                       "bootstrap": {"type": "array", "items": {"type": "string"},
                                     "description": "a Kafka cluster: host:port of each broker node"},
                       "tls": {"type": "boolean",
                               "description": "the broker speaks TLS: connect with it, verify with the plant CA"},
                       "closed": {"type": "boolean",
                                  "description": "a Kafka that authenticates every client: the worker "
                                                 "or MirrorMaker 2 logs in as plantkg's principal"}},
    },
    "BridgeSpec": {
        "type": "object", "additionalProperties": False,
        "required": ["local", "remote", "mechanism", "routes"],
        "properties": {
            "local": _ref("BridgeEnd"),
            "remote": _ref("BridgeEnd"),
            "mechanism": {"type": "string", "enum": ["mosquitto", "mqtt-kafka", "mqtt-ngsi", "kafka-mirror"]},
            "routes": {"type": "array", "minItems": 1, "items": {
                "type": "object", "required": ["topic", "direction"],
                "properties": {"topic": {"type": "string"},
                               "direction": {"type": "string", "enum": ["out", "in", "both"]},
                               "qos": {"type": "integer", "minimum": 0, "maximum": 2},
                               "key": {"type": "string", "enum": ["mqtt-topic", "none"]},
                               "entity_id": {"type": ["string", "null"],
                                             "description": "mqtt-ngsi: the topic's NGSI entity"},
                               "entity_type": {"type": ["string", "null"]}}}},
            "asserted": {"type": "boolean"},
        },
    },

    "ObservedBridge": {
        "type": "object", "required": ["spec", "status"],
        "properties": {
            "spec": _ref("BridgeSpec"),
            "status": {"type": "string",
                       "enum": ["running", "connecting", "stopped", "crashed", "failed"]},
            "pid": _NULLABLE_INT,
            "started_at": {"type": ["number", "null"]},
            "restarts": {"type": "integer"},
            "forwarded": _NULLABLE_INT,
            "retried": _NULLABLE_INT,
            "refused": {"type": ["integer", "null"],
                        "description": "mqtt-ngsi: messages the context broker refused (4xx), "
                                       "acknowledged and not retried"},
            "last_error": {"type": ["string", "null"]},
            "owner": _NULLABLE_OWNER,
            "forwarded_per_s": {"type": ["number", "null"], "minimum": 0,
                                "description": "Messages forwarded per second over the worker's "
                                               "last ~10 s (null: the mechanism does not count)"},
            "lag": {"type": ["integer", "null"], "minimum": 0,
                    "description": "kafka-mirror: records on the source cluster not yet on the target"},
        },
    },
    "Health": {
        "type": "object", "required": ["status", "agent", "version"],
        "properties": {
            "status": {"const": "ok"},
            "agent": {"type": "string"},
            "version": {"type": "string"},
            "drivers": {"type": "array", "items": {"type": "string"}},
            "driver_errors": {"type": "object", "additionalProperties": {"type": "string"}},
        },
    },
}

#: The bridge PUT's body: a BridgeSpec plus (mqtt-ngsi only) the transport field remote_token, the
#: context broker's write token, kept by the agent in the worker's folder (mode 0600), never returned.
_SCHEMAS["BridgePut"] = {
    **_SCHEMAS["BridgeSpec"],
    "properties": {**_SCHEMAS["BridgeSpec"]["properties"],
                   "remote_token": {"type": "string", "writeOnly": True,
                                    "description": "mqtt-ngsi: the context broker's write token"},
                   "owner": _OWNER},
}
#: PUT bodies of brokers and topics: the spec plus the optional transport field owner.
_SCHEMAS["BrokerPut"] = {**_SCHEMAS["BrokerSpec"],
                         "properties": {**_SCHEMAS["BrokerSpec"]["properties"], "owner": _OWNER}}
_SCHEMAS["TopicPut"] = {**_SCHEMAS["TopicSpec"],
                        "properties": {**_SCHEMAS["TopicSpec"]["properties"], "owner": _OWNER}}
_SCHEMAS["OwnerPut"] = {"type": "object", "additionalProperties": False, "required": ["owner"],
                        "properties": {"owner": _OWNER}}

#: POST /v1/batch (engine.agent.batch): each item is one change, as its single request.
_ITEM_ID = {"type": "string", "pattern": _BROKER_ID["schema"]["pattern"]}


def _item(op: str, fields: dict[str, Any], required: tuple[str, ...], what: str) -> dict[str, Any]:
    return {"type": "object", "additionalProperties": False, "description": what,
            "required": ["op", *required],
            "properties": {"op": {"const": op}, **fields, "owner": _OWNER}}


_SCHEMAS["BatchItem"] = {"oneOf": [
    _item("put_broker", {"spec": _ref("BrokerSpec")}, ("spec",), "as PUT /v1/brokers/{spec.id}"),
    _item("delete_broker", {"broker_id": _ITEM_ID}, ("broker_id",), "as DELETE /v1/brokers/{broker_id}"),
    _item("put_topic", {"spec": _ref("TopicSpec")}, ("spec",),
          "as PUT /v1/brokers/{spec.broker_id}/topics/{spec.name}"),
    _item("delete_topic", {"broker_id": _ITEM_ID, "name": {"type": "string", "minLength": 1}},
          ("broker_id", "name"), "as DELETE /v1/brokers/{broker_id}/topics/{name}"),
    _item("put_bridge", {"spec": _ref("BridgeSpec"),
                         "remote_token": {"type": "string", "writeOnly": True,
                                          "description": "mqtt-ngsi: the context broker's write token"}},
          ("spec",), "as PUT /v1/brokers/{spec.local.id}/bridges/{spec.remote.id}"),
    _item("delete_bridge", {"broker_id": _ITEM_ID, "remote_id": _ITEM_ID}, ("broker_id", "remote_id"),
          "as DELETE /v1/brokers/{broker_id}/bridges/{remote_id}"),
]}
_SCHEMAS["Batch"] = {
    "type": "object", "additionalProperties": False, "required": ["lanes"],
    "properties": {
        "lanes": {"type": "array", "maxItems": 512, "description":
                  "Lanes run at the same time; the items of a lane in order, and after a failed "
                  "item the rest of its lane is skipped. At most 4096 items in all.",
                  "items": {"type": "array", "minItems": 1, "items": _ref("BatchItem")}},
        "observe": {"type": "boolean", "description": "Answer also the brokers and bridges as "
                    "GET /v1/brokers and GET /v1/bridges would, once every lane finished"},
    },
}
_SCHEMAS["BatchResult"] = {
    "type": "object", "required": ["outcome"],
    "properties": {
        "outcome": {"type": "string", "enum": ["done", "failed", "skipped"],
                    "description": "skipped: an earlier item of the lane failed; not attempted"},
        "status": {"type": "integer", "description": "The status the single request would have "
                   "answered (200, 204, 400, 404, 409, 422, 503, 500)"},
        "answer": {"description": "What the single request would have answered (null for 204)"},
        "error": _ref("Error"),
    },
}
_SCHEMAS["BatchAnswer"] = {
    "type": "object", "required": ["lanes"],
    "properties": {
        "lanes": {"type": "array", "items": {"type": "array", "items": _ref("BatchResult")},
                  "description": "One result per item, in the request's shape"},
        "brokers": {"type": "array", "items": _ref("ObservedBroker")},
        "bridges": {"type": "array", "items": _ref("ObservedBridge")},
    },
}


#: The operator's verbs (docs/operating.md): no request body; each answers the broker.
_VERBS: tuple[tuple[str, str, str, str, tuple[int, ...]], ...] = (
    ("stop", "Stop the broker and keep it stopped until started (idempotent)",
     "The broker's spec, config and data stay in its folder; it reports status "
     "stopped-by-operator (with the topics it had), and nothing starts it — the supervisor, an "
     "agent restart, a PUT (409) — until start or restart.",
     "Stopped by the operator", (400, 401, 404, 422, 500)),
    ("start", "Start a broker the operator stopped, as it was",
     "Answers once the driver's health check passes (503 after its start deadline); a running "
     "broker is left alone.", "Running and healthy", (400, 401, 404, 409, 422, 503, 500)),
    ("restart", "Stop the broker gracefully and start it again (a new pid, data kept)",
     "Also starts a broker the operator stopped. Answers once healthy.",
     "Running and healthy, a new process", (400, 401, 404, 409, 422, 503, 500)),
)


def openapi_document(version: str) -> dict[str, Any]:
    """The document for agent ``version``."""
    secured = [{"bearer": []}]
    return {
        "openapi": "3.1.0",
        "info": {
            "title": "plantkg agent",
            "version": version,
            "description": "Declarative, idempotent management of the message brokers of one "
                           "machine. See docs/agent.md.",
        },
        "servers": [{"url": "/"}],
        "security": secured,
        "components": {
            "securitySchemes": {"bearer": {"type": "http", "scheme": "bearer"}},
            "schemas": _SCHEMAS,
        },
        "paths": {
            "/v1/health": {"get": {
                "operationId": "health", "summary": "The agent answers",
                "responses": {"200": _json(_ref("Health"), "Alive"), **_error_responses(401)},
            }},
            "/v1/brokers": {"get": {
                "operationId": "listBrokers", "summary": "Every broker of this agent",
                "responses": {
                    "200": _json({"type": "object", "required": ["brokers"], "properties": {
                        "brokers": {"type": "array", "items": _ref("ObservedBroker")}}},
                        "The brokers, sorted by id"),
                    **_error_responses(401),
                },
            }},
            "/v1/brokers/{broker_id}": {
                "parameters": [_BROKER_ID],
                "get": {
                    "operationId": "getBroker", "summary": "One broker as observed",
                    "responses": {"200": _json(_ref("ObservedBroker"), "The broker"),
                                  **_error_responses(400, 401, 404)},
                },
                "put": {
                    "operationId": "putBroker",
                    "summary": "Make the broker run as specified (idempotent)",
                    "description": "Same essence already running and healthy: returned unchanged. "
                                   "Otherwise stopped, re-rendered, started; answers once the "
                                   "driver's health check passes (503 after its start deadline).",
                    "requestBody": {"required": True, "content": {
                        "application/json": {"schema": _ref("BrokerPut")}}},
                    "responses": {"200": _json(_ref("ObservedBroker"), "Running and healthy"),
                                  **_error_responses(400, 401, 409, 422, 503, 500)},
                },
                "delete": {
                    "operationId": "deleteBroker",
                    "summary": "Stop the broker and retire its folder (idempotent)",
                    "parameters": [_OWNER_QUERY],
                    "responses": {"204": {"description": "Gone"},
                                  **_error_responses(400, 401, 409)},
                },
            },
            "/v1/brokers/{broker_id}/owner": {
                "parameters": [_BROKER_ID],
                "put": {
                    "operationId": "putOwner",
                    "summary": "Import: record the owner of the broker and of its unowned topics "
                               "and bridges",
                    "description": "Nothing is restarted or changed but the recorded owner. 409 if "
                                   "another plant owns the broker.",
                    "requestBody": {"required": True, "content": {
                        "application/json": {"schema": _ref("OwnerPut")}}},
                    "responses": {"200": _json(_ref("ObservedBroker"), "The broker, owned"),
                                  **_error_responses(400, 401, 404, 409)},
                },
            },
            **{f"/v1/brokers/{{broker_id}}/{verb}": {
                "parameters": [_BROKER_ID],
                "post": {
                    "operationId": f"{verb}Broker", "summary": summary, "description": text,
                    "responses": {"200": _json(_ref("ObservedBroker"), answer),
                                  **_error_responses(*codes)},
                },
            } for verb, summary, text, answer, codes in _VERBS},
            "/v1/brokers/{broker_id}/topics/{name}": {
                "parameters": [_BROKER_ID, _TOPIC_NAME],
                "put": {
                    "operationId": "putTopic", "summary": "Create or alter a topic",
                    "requestBody": {"required": True, "content": {
                        "application/json": {"schema": _ref("TopicPut")}}},
                    "responses": {"200": _json(_ref("ObservedTopic"), "The topic as observed"),
                                  **_error_responses(400, 401, 404, 409, 422, 503)},
                },
                "delete": {
                    "operationId": "deleteTopic", "summary": "Delete a topic (idempotent)",
                    "parameters": [_OWNER_QUERY],
                    "responses": {"204": {"description": "Gone"},
                                  **_error_responses(400, 401, 409, 503)},
                },
            },
            "/v1/bridges": {"get": {
                "operationId": "listBridges", "summary": "Every bridge this agent's brokers carry",
                "responses": {
                    "200": _json({"type": "object", "required": ["bridges"], "properties": {
                        "bridges": {"type": "array", "items": _ref("ObservedBridge")}}},
                        "The bridges, sorted by address"),
                    **_error_responses(401),
                },
            }},
            "/v1/brokers/{broker_id}/bridges/{remote_id}": {
                "parameters": [_BROKER_ID, {**_BROKER_ID, "name": "remote_id"}],
                "put": {
                    "operationId": "putBridge",
                    "summary": "Make the bridge from this broker to the remote one run (idempotent)",
                    "description": "mechanism mosquitto: rendered into the broker's config, which "
                                   "restarts only if its config changed; mqtt-kafka and mqtt-ngsi: "
                                   "a supervised worker process. A remote that is down is not an "
                                   "error: the bridge connects when it comes up (status connecting).",
                    "requestBody": {"required": True, "content": {
                        "application/json": {"schema": _ref("BridgePut")}}},
                    "responses": {"200": _json(_ref("ObservedBridge"), "The bridge as observed"),
                                  **_error_responses(400, 401, 404, 409, 422, 503)},
                },
                "delete": {
                    "operationId": "deleteBridge", "summary": "Stop the bridge (idempotent)",
                    "parameters": [_OWNER_QUERY],
                    "responses": {"204": {"description": "Gone"},
                                  **_error_responses(400, 401, 409, 503)},
                },
            },
            "/v1/state": {"get": {
                "operationId": "state",
                "summary": "Every broker and every bridge of this agent, in one answer",
                "description": "What GET /v1/brokers and GET /v1/bridges answer, together: the "
                               "engine observes an agent with one request.",
                "responses": {
                    "200": _json({"type": "object", "required": ["brokers", "bridges"], "properties": {
                        "brokers": {"type": "array", "items": _ref("ObservedBroker")},
                        "bridges": {"type": "array", "items": _ref("ObservedBridge")}}},
                        "The brokers sorted by id, the bridges by address"),
                    **_error_responses(401),
                },
            }},
            "/v1/batch": {"post": {
                "operationId": "batch",
                "summary": "Make many changes in one request, in lanes, with a result per item",
                "description": "Each item is exactly the single request it names (same checks, "
                               "owner rule and status). Lanes run at the same time, so brokers "
                               "start and stop together; a failed item skips the rest of its "
                               "lane only. A malformed request is refused whole (400 naming the "
                               "field, e.g. lanes[1][0].spec.port): nothing is done.",
                "requestBody": {"required": True, "content": {
                    "application/json": {"schema": _ref("Batch")}}},
                "responses": {"200": _json(_ref("BatchAnswer"), "Every item's result"),
                              **_error_responses(400, 401, 500)},
            }},
            "/v1/openapi.json": {"get": {
                "operationId": "openapi", "summary": "This document", "security": [],
                "responses": {"200": {"description": "OpenAPI 3.1",
                                      "content": {"application/json": {}}}},
            }},
        },
    }

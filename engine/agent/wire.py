"""JSON <-> engine.model dataclasses for the agent API, strictly.

The agent reads BrokerSpec, TopicSpec and BridgeSpec bodies with :func:`broker_spec_from_json`,
:func:`topic_spec_from_json` and :func:`bridge_spec_from_json`: an unknown field, a missing one, a value of the wrong JSON type or an
unsafe value (control character, port out of range, a host name where an address belongs) raises
:class:`WireError` naming the field, which the agent answers with 400. The client reads the agent's
answers with :func:`observed_broker_from_json` / :func:`observed_topic_from_json`. Writing is
:func:`engine.model.to_dict`.
"""

from __future__ import annotations

import re
from dataclasses import MISSING, fields
from typing import Any

from engine.drivers.base import check_text
from engine.errors import ConfigValueError, EngineError
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BridgeStatus,
    BrokerSpec,
    BrokerStatus,
    BrokerUser,
    KafkaNode,
    KafkaVoter,
    ObservedBridge,
    ObservedBroker,
    ObservedTopic,
    TopicSpec,
)
from engine.values import check_broker_user, check_host, check_ngsi_id, check_port, check_secret_ref

#: pk:id as the shapes allow it (pks:PlantElement-idValue); ids name folders on the agent.
BROKER_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}")
#: A KRaft cluster id: 16 bytes in base64url without padding, not starting with "-".
KRAFT_CLUSTER_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{21}")
#: A broker kind is an entry-point name.
KIND = re.compile(r"[a-z][a-z0-9_-]{0,63}")


class WireError(EngineError):
    """A request or answer body that does not fit the API; ``field`` names the culprit."""

    def __init__(self, field: str, problem: str) -> None:
        super().__init__(f"{field}: {problem}", hint=f"correct the field {field!r} of the JSON body")
        self.field = field
        self.problem = problem


def _fields(data: Any, cls: type, where: str, *, strict: bool = True) -> dict[str, Any]:
    """``data`` as keyword arguments of dataclass ``cls``: no missing key, and no unknown one
    if ``strict`` (requests); answers are read leniently so a newer agent can add fields."""
    if not isinstance(data, dict):
        raise WireError(where or "body", f"expected a JSON object, got {_json_type(data)}")
    known = {f.name: f for f in fields(cls)}
    for key in data:
        if key not in known and strict:
            raise WireError(_join(where, str(key)), f"unknown field (known: {', '.join(known)})")
    for name, f in known.items():
        if name not in data and f.default is MISSING and f.default_factory is MISSING:
            raise WireError(_join(where, name), "missing")
    return {k: v for k, v in data.items() if k in known}


def _join(where: str, name: str) -> str:
    return f"{where}.{name}" if where else name


def _typed(data: dict[str, Any], name: str, types: tuple[type, ...], where: str,
           optional: bool = False) -> Any:
    value = data.get(name)
    if value is None and optional:
        return None
    if isinstance(value, bool) and bool not in types:
        raise WireError(_join(where, name), f"expected {_names(types)}, got a boolean")
    if not isinstance(value, types):
        raise WireError(_join(where, name), f"expected {_names(types)}, got {_json_type(value)}")
    return value


def _names(types: tuple[type, ...]) -> str:
    return " or ".join({str: "a string", int: "an integer", bool: "a boolean",
                        float: "a number", list: "an array"}[t] for t in types)


def _json_type(value: Any) -> str:
    return "null" if value is None else {dict: "an object", list: "an array", str: "a string",
                                         int: "an integer", float: "a number"}.get(type(value), "?")


def _matching(data: dict[str, Any], name: str, pattern: re.Pattern[str], where: str, problem: str) -> str:
    """A string field that must match ``pattern`` whole; else ``problem`` names what it must be."""
    value = _typed(data, name, (str,), where)
    if not pattern.fullmatch(value):
        raise WireError(_join(where, name), problem)
    return value


def _checked(where: str, check: Any, *args: Any) -> Any:
    try:
        return check(*args)
    except ConfigValueError as exc:
        raise WireError(_join(where, exc.field), exc.problem) from None


def broker_spec_from_json(data: Any, where: str = "", *, strict: bool = True) -> BrokerSpec:
    """A validated BrokerSpec. The host is kept as written (an IPv6 address is not compressed),
    so the spec an agent reports equals the one it was given."""
    data = _fields(data, BrokerSpec, where, strict=strict)
    broker_id = _matching(data, "id", BROKER_ID, where, "must be 1 to 128 characters of A-Z a-z 0-9 _ . - "
                          "starting with a letter, a digit or _")
    iri = _checked(where, check_text, "iri", _typed(data, "iri", (str,), where))
    if any(c.isspace() for c in iri):
        raise WireError(_join(where, "iri"), "an IRI must not contain whitespace")
    name = _checked(where, check_text, "name", _typed(data, "name", (str,), where))
    kind = _matching(data, "kind", KIND, where, "must be a lower-case driver name such as mosquitto")
    host = _typed(data, "host", (str,), where)
    _checked(where, check_host, "host", host)
    port = _checked(where, check_port, "port", _typed(data, "port", (int,), where))
    persist = _typed(data, "persist_every", (int,), where, optional=True)
    if persist is not None and not 1 <= persist <= 1_000_000:
        raise WireError(_join(where, "persist_every"), "must be in 1..1000000")
    anonymous = _typed(data, "allow_anonymous", (bool,), where, optional=True)
    mqtt_port = _typed(data, "mqtt_port", (int,), where, optional=True)
    if mqtt_port is not None:
        _checked(where, check_port, "mqtt_port", mqtt_port)
    users = _typed(data, "users", (list,), where, optional=True) or []
    tls = _typed(data, "tls", (bool,), where, optional=True) or False
    cert_port = _certificate_port(data, where, kind, port, tls)
    kafka = data.get("kafka")
    closed_kafkas = _typed(data, "closed_kafkas", (list,), where, optional=True) or []
    tls_kafkas = _typed(data, "tls_kafkas", (list,), where, optional=True) or []
    users_at = _join(where, "users")
    checked = _users(users, users_at)
    for i, user in enumerate(checked):
        if user.certificate and cert_port is None:
            raise WireError(f"{users_at}[{i}].certificate", "a certificate user needs the broker's "
                            "certificate_port (the listener that checks client certificates)")
    return BrokerSpec(id=broker_id, iri=iri, name=name, kind=kind, host=host, port=port,
                      persist_every=persist, allow_anonymous=anonymous, mqtt_port=mqtt_port,
                      users=checked, tls=tls, certificate_port=cert_port,
                      kafka=None if kafka is None else _kafka_node(kafka, _join(where, "kafka"), strict),
                      closed_kafkas=_bootstrap(closed_kafkas, _join(where, "closed_kafkas")),
                      tls_kafkas=_bootstrap(tls_kafkas, _join(where, "tls_kafkas")))


def _certificate_port(data: dict[str, Any], where: str, kind: str, port: int, tls: bool) -> int | None:
    """A Mosquitto's certificate listener (docs/security.md, Client certificates): a port of its
    own, on a broker whose listener speaks TLS (it uses the broker's TLS files)."""
    value = _typed(data, "certificate_port", (int,), where, optional=True)
    if value is None:
        return None
    _checked(where, check_port, "certificate_port", value)
    if kind != "mosquitto" or not tls:
        raise WireError(_join(where, "certificate_port"), "only a Mosquitto with tls true has a certificate listener")
    if value == port:
        raise WireError(_join(where, "certificate_port"), "must differ from port (a listener that requires "
                        "client certificates refuses password clients)")
    return value


def _kafka_node(data: Any, where: str, strict: bool) -> KafkaNode:
    """A cluster node's place (engine.model.KafkaNode); the driver checks what it renders."""
    data = _fields(data, KafkaNode, where, strict=strict)
    cluster = _matching(data, "cluster", BROKER_ID, where, "not a broker id")
    cluster_id = _matching(data, "cluster_id", KRAFT_CLUSTER_ID, where, "expected 22 base64url characters, not starting with -")
    roles = _typed(data, "roles", (list,), where)
    if not roles or any(r not in ("broker", "controller") for r in roles) or len(set(roles)) != len(roles):
        raise WireError(_join(where, "roles"), "expected 'broker', 'controller' or both")
    voters = []
    for i, item in enumerate(_typed(data, "voters", (list,), where)):
        at = _join(where, f"voters[{i}]")
        v = _fields(item, KafkaVoter, at, strict=strict)
        host = _typed(v, "host", (str,), at)
        _checked(at, check_host, "host", host)
        voters.append(KafkaVoter(_node_id(v, "node_id", at), host,
                                 _checked(at, check_port, "port", _typed(v, "port", (int,), at))))
    if not voters:
        raise WireError(_join(where, "voters"), "a cluster needs at least one voter")
    cport = _typed(data, "controller_port", (int,), where, optional=True)
    if cport is not None:
        _checked(where, check_port, "controller_port", cport)
    replication = _typed(data, "replication", (int,), where) if "replication" in data else 1
    mis = _typed(data, "min_insync", (int,), where, optional=True)
    for name, value in (("replication", replication), ("min_insync", mis)):
        if value is not None and not 1 <= value <= 32_767:
            raise WireError(_join(where, name), "must be in 1..32767")
    bootstrap = _typed(data, "bootstrap", (list,), where) if "bootstrap" in data else []
    return KafkaNode(cluster=cluster, cluster_id=cluster_id, node_id=_node_id(data, "node_id", where),
                     roles=tuple(sorted(roles)), voters=tuple(voters), controller_port=cport,
                     replication=replication, min_insync=mis,
                     bootstrap=_bootstrap(bootstrap, _join(where, "bootstrap")),
                     lead=_typed(data, "lead", (bool,), where) if "lead" in data else False)


def _node_id(data: dict[str, Any], name: str, where: str) -> int:
    value = _typed(data, name, (int,), where)
    if not 0 <= value <= 2**31 - 1:
        raise WireError(_join(where, name), "must be in 0..2147483647")
    return value


def _bootstrap(items: list[Any], where: str) -> tuple[str, ...]:
    """``host:port`` addresses (an IPv6 host in brackets), each checked."""
    out = []
    for i, item in enumerate(items):
        at = f"{where}[{i}]"
        if not isinstance(item, str) or ":" not in item:
            raise WireError(at, "expected 'host:port'")
        host, _, port = item.rpartition(":")
        bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
        _checked(at, check_host, "host", bare)
        if not port.isdigit():
            raise WireError(at, "expected 'host:port'")
        _checked(at, check_port, "port", int(port))
        out.append(item)
    return tuple(out)


def _users(items: list[Any], where: str) -> tuple[BrokerUser, ...]:
    """A broker's users: names unique, secret references (never secrets; none for a
    certificate user without a password), topic-name lists."""
    out = []
    for i, item in enumerate(items):
        at = f"{where}[{i}]"
        data = _fields(item, BrokerUser, at)
        name = _checked(at, check_broker_user, "name", _typed(data, "name", (str,), at))
        certificate = _typed(data, "certificate", (bool,), at, optional=True) or False
        ref = _typed(data, "secret_ref", (str,), at, optional=True)
        if ref is None and not certificate:
            raise WireError(_join(at, "secret_ref"), "missing: a user logs in with a password (secret_ref), "
                            "a client certificate (certificate true), or both")
        ref = None if ref is None else _checked(at, check_secret_ref, "secret_ref", ref)
        lists = {}
        for field in ("write", "read"):
            topics = _typed(data, field, (list,), at, optional=True) or []
            for j, topic in enumerate(topics):
                if not isinstance(topic, str):
                    raise WireError(_join(at, f"{field}[{j}]"), "must be a topic name (a string)")
                _checked(at, check_text, f"{field}[{j}]", topic)
            lists[field] = tuple(topics)
        out.append(BrokerUser(name=name, secret_ref=ref, certificate=certificate, **lists))
    names = [u.name for u in out]
    if len(set(names)) != len(names):
        raise WireError(where, "two users with the same name")
    return tuple(out)


def topic_spec_from_json(data: Any, where: str = "") -> TopicSpec:
    """A TopicSpec with JSON types checked; names and ranges are the driver's to check."""
    data = _fields(data, TopicSpec, where)
    broker_id = _typed(data, "broker_id", (str,), where)
    name = _checked(where, check_text, "name", _typed(data, "name", (str,), where))
    iri = _checked(where, check_text, "iri", _typed(data, "iri", (str,), where))
    ints = {k: _typed(data, k, (int,), where, optional=True)
            for k in ("partitions", "replication_factor", "retention_ms", "qos", "min_insync_replicas")}
    retain = _typed(data, "retain", (bool,), where, optional=True)
    return TopicSpec(broker_id=broker_id, name=name, iri=iri, retain=retain, **ints,
                     **_entity(data, where))


def observed_topic_from_json(data: Any, where: str = "") -> ObservedTopic:
    data = _fields(data, ObservedTopic, where, strict=False)
    name = _typed(data, "name", (str,), where)
    ints = {k: _typed(data, k, (int,), where, optional=True)
            for k in ("partitions", "replication_factor", "retention_ms", "qos", "min_insync_replicas")}
    retain = _typed(data, "retain", (bool,), where, optional=True)
    return ObservedTopic(name=name, retain=retain, **ints, **_entity(data, where),
                         owner=_typed(data, "owner", (str,), where, optional=True))


def _entity(data: dict[str, Any], where: str) -> dict[str, str | None]:
    """``entity_id`` / ``entity_type`` of a topic or route (NGSI), each absent or an Orion id."""
    out: dict[str, str | None] = {}
    for name in ("entity_id", "entity_type"):
        value = _typed(data, name, (str,), where, optional=True)
        out[name] = None if value is None else _checked(where, check_ngsi_id, name, value)
    return out


def observed_broker_from_json(data: Any, where: str = "") -> ObservedBroker:
    data = _fields(data, ObservedBroker, where, strict=False)
    spec = broker_spec_from_json(data["spec"], _join(where, "spec"), strict=False)
    try:
        status = BrokerStatus(_typed(data, "status", (str,), where))
    except ValueError:
        raise WireError(_join(where, "status"), f"not one of {[s.value for s in BrokerStatus]}") \
            from None
    topics_data = data.get("topics", [])
    if not isinstance(topics_data, list):
        raise WireError(_join(where, "topics"), "expected an array")
    topics = tuple(observed_topic_from_json(t, _join(where, f"topics[{i}]"))
                   for i, t in enumerate(topics_data))
    started = _typed(data, "started_at", (int, float), where, optional=True)
    return ObservedBroker(
        spec=spec,
        status=status,
        topics=topics,
        pid=_typed(data, "pid", (int,), where, optional=True),
        started_at=float(started) if started is not None else None,
        restarts=_typed(data, "restarts", (int,), where) if "restarts" in data else 0,
        config_hash=_typed(data, "config_hash", (str,), where, optional=True),
        last_error=_typed(data, "last_error", (str,), where, optional=True),
        owner=_typed(data, "owner", (str,), where, optional=True),
        tls_renew=_typed(data, "tls_renew", (str,), where, optional=True),
    )


def _enum(data: dict[str, Any], name: str, cls: type, where: str) -> Any:
    value = _typed(data, name, (str,), where)
    try:
        return cls(value)
    except ValueError:
        raise WireError(_join(where, name), f"not one of {[e.value for e in cls]}") from None


def _bridge_end(data: Any, where: str, strict: bool) -> BridgeEnd:
    data = _fields(data, BridgeEnd, where, strict=strict)
    end_id = _matching(data, "id", BROKER_ID, where, "not a broker id")
    kind = _matching(data, "kind", KIND, where, "must be a lower-case driver name such as mosquitto")
    host = _typed(data, "host", (str,), where)
    _checked(where, check_host, "host", host)
    port = _checked(where, check_port, "port", _typed(data, "port", (int,), where))
    tls = _typed(data, "tls", (bool,), where, optional=True) or False
    closed = _typed(data, "closed", (bool,), where, optional=True) or False
    if closed and kind != "kafka":
        raise WireError(_join(where, "closed"), f"only a Kafka end is closed (a login of plantkg's), not a {kind} one")
    bootstrap = _typed(data, "bootstrap", (list,), where) if "bootstrap" in data else []
    return BridgeEnd(id=end_id, kind=kind, host=host, port=port, tls=tls, closed=closed,
                     bootstrap=_bootstrap(bootstrap, _join(where, "bootstrap")))


def _bridge_route(data: Any, where: str, strict: bool) -> BridgeRoute:
    data = _fields(data, BridgeRoute, where, strict=strict)
    topic = _checked(where, check_text, "topic", _typed(data, "topic", (str,), where))
    qos = _typed(data, "qos", (int,), where) if "qos" in data else 1
    if qos not in (0, 1, 2):
        raise WireError(_join(where, "qos"), "must be 0, 1 or 2")
    key = _typed(data, "key", (str,), where) if "key" in data else "mqtt-topic"
    if key not in ("mqtt-topic", "none"):
        raise WireError(_join(where, "key"), "must be 'mqtt-topic' or 'none'")
    return BridgeRoute(topic=topic, direction=_enum(data, "direction", BridgeDirection, where),
                       qos=qos, key=key, **_entity(data, where))


def bridge_spec_from_json(data: Any, where: str = "", *, strict: bool = True) -> BridgeSpec:
    """A BridgeSpec with types, ids, addresses and routes checked (the driver or the worker
    checks what it renders)."""
    data = _fields(data, BridgeSpec, where, strict=strict)
    routes = data.get("routes")
    if not isinstance(routes, list) or not routes:
        raise WireError(_join(where, "routes"), "expected a non-empty array")
    parsed = tuple(_bridge_route(r, _join(where, f"routes[{i}]"), strict) for i, r in enumerate(routes))
    if len({r.topic for r in parsed}) != len(parsed):
        raise WireError(_join(where, "routes"), "a topic is routed twice")
    local = _bridge_end(data["local"], _join(where, "local"), strict)
    remote = _bridge_end(data["remote"], _join(where, "remote"), strict)
    if local.id == remote.id:
        raise WireError(_join(where, "remote"), "a broker cannot bridge to itself")
    asserted = _typed(data, "asserted", (bool,), where) if "asserted" in data else True
    return BridgeSpec(local=local, remote=remote,
                      mechanism=_enum(data, "mechanism", BridgeMechanism, where),
                      routes=parsed, asserted=asserted)


def observed_bridge_from_json(data: Any, where: str = "") -> ObservedBridge:
    data = _fields(data, ObservedBridge, where, strict=False)
    started = _typed(data, "started_at", (int, float), where, optional=True)
    rate = _typed(data, "forwarded_per_s", (int, float), where, optional=True)
    return ObservedBridge(
        spec=bridge_spec_from_json(data["spec"], _join(where, "spec"), strict=False),
        status=_enum(data, "status", BridgeStatus, where),
        pid=_typed(data, "pid", (int,), where, optional=True),
        started_at=float(started) if started is not None else None,
        restarts=_typed(data, "restarts", (int,), where) if "restarts" in data else 0,
        forwarded=_typed(data, "forwarded", (int,), where, optional=True),
        retried=_typed(data, "retried", (int,), where, optional=True),
        refused=_typed(data, "refused", (int,), where, optional=True),
        last_error=_typed(data, "last_error", (str,), where, optional=True),
        owner=_typed(data, "owner", (str,), where, optional=True),
        forwarded_per_s=float(rate) if rate is not None else None,
        lag=_typed(data, "lag", (int,), where, optional=True),
    )

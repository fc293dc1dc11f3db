"""What one bridge worker does: its brokers, its routes, its state folder (``worker.json``).

The carrying agent builds a :class:`WorkerConfig` from a bridge spec and writes it with
:meth:`WorkerConfig.to_json`; the worker process reads it back with :meth:`WorkerConfig.from_json`.
Reading is strict: an unknown or missing field, a wrong type or a value that cannot work (a Kafka
topic name Kafka refuses, an MQTT filter where a topic name belongs) raises
:class:`engine.errors.ConfigValueError` naming the field, so a bad file stops the worker at once
instead of half-running it.
"""

from __future__ import annotations

import enum
import json
import re
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any

from engine.errors import ConfigValueError
from engine.security import kafka_client
from engine.values import check_host, check_path, check_port


class Direction(str, enum.Enum):
    """Which way a route forwards."""

    MQTT_TO_KAFKA = "mqtt-to-kafka"
    KAFKA_TO_MQTT = "kafka-to-mqtt"


class KeyMode(str, enum.Enum):
    """The Kafka record key of MQTT -> Kafka records."""

    MQTT_TOPIC = "mqtt-topic"   # the MQTT topic: one partition per MQTT topic, order kept
    NONE = "none"               # no key: spread over partitions, no order across them


#: Kafka's own rule for topic names (kafka.common.internals.Topic): legal characters, 1..249.
_KAFKA_TOPIC = re.compile(r"[a-zA-Z0-9._-]{1,249}")
#: A bridge id becomes part of an MQTT client id and a Kafka group id.
_BRIDGE_ID = re.compile(r"[A-Za-z0-9_.-]{1,200}")


@dataclass(frozen=True)
class Route:
    """One topic forwarded one way between ``mqtt_topic`` and ``kafka_topic``."""

    mqtt_topic: str
    kafka_topic: str
    direction: Direction
    qos: int = 1
    key: KeyMode = KeyMode.MQTT_TOPIC

    def __post_init__(self) -> None:
        _check_mqtt_topic("mqtt_topic", self.mqtt_topic)
        _check_kafka_topic("kafka_topic", self.kafka_topic)
        object.__setattr__(self, "direction", _enum("direction", Direction, self.direction))
        object.__setattr__(self, "key", _enum("key", KeyMode, self.key))
        if isinstance(self.qos, bool) or self.qos not in (0, 1):
            # QoS 0 may be lost by definition; QoS 2 adds a round trip and buys nothing here:
            # the Kafka side is at-least-once anyway.
            raise ConfigValueError("qos", self.qos, "must be 1 (at least once) or 0 (at most once)")

    def to_dict(self) -> dict[str, object]:
        return {"mqtt_topic": self.mqtt_topic, "kafka_topic": self.kafka_topic,
                "direction": self.direction.value, "qos": self.qos, "key": self.key.value}

    @classmethod
    def from_dict(cls, data: object, where: str = "routes[]") -> Route:
        values = _fields_of(cls, data, where)
        return cls(**values)


@dataclass(frozen=True)
class WorkerConfig:
    """One bridge worker: the MQTT broker it is attached to, the Kafka cluster, its routes."""

    bridge_id: str
    mqtt_host: str
    mqtt_port: int
    kafka_bootstrap: str
    routes: tuple[Route, ...]
    state_dir: Path
    stats_interval: float = 0.5
    #: The worker's user on its MQTT broker (a plantkg principal, engine.security.principals): the
    #: worker derives its password from the principal key; None: anonymous.
    mqtt_username: str | None = None
    #: The plant CA's certificate: the MQTT broker speaks TLS, verified against it; None: plain.
    mqtt_ca_file: Path | None = None
    #: A closed Kafka (issue 13): the file holding plantkg's own password there (SASL/PLAIN as
    #: user "plantkg"; the agent writes it 0600); None: Kafka is open.
    kafka_password_file: Path | None = None
    #: The plant CA's certificate: Kafka speaks TLS (``pk:tls``), verified against it only,
    #: address included; None: plain.
    kafka_ca_file: Path | None = None

    def __post_init__(self) -> None:
        check_mqtt_username(self.mqtt_username)
        if self.mqtt_ca_file is not None:
            object.__setattr__(self, "mqtt_ca_file", check_path("mqtt_ca_file", self.mqtt_ca_file))
        if not isinstance(self.bridge_id, str) or not _BRIDGE_ID.fullmatch(self.bridge_id):
            raise ConfigValueError("bridge_id", self.bridge_id, "must be 1 to 200 of A-Z a-z 0-9 _ . -")
        for name in ("kafka_password_file", "kafka_ca_file"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, check_path(name, getattr(self, name)))
        object.__setattr__(self, "mqtt_host", check_host("mqtt_host", self.mqtt_host))
        check_port("mqtt_port", self.mqtt_port)
        _check_bootstrap("kafka_bootstrap", self.kafka_bootstrap)
        if not isinstance(self.routes, tuple) or not self.routes:
            raise ConfigValueError("routes", self.routes, "a worker needs a non-empty tuple of routes")
        if not all(isinstance(r, Route) for r in self.routes):
            raise ConfigValueError("routes", self.routes, "every route must be a Route")
        _check_unique_routes(self.routes)
        object.__setattr__(self, "state_dir", check_path("state_dir", self.state_dir))
        interval = self.stats_interval
        if isinstance(interval, bool) or not isinstance(interval, (int, float)) or not 0.01 <= interval <= 60:
            raise ConfigValueError("stats_interval", interval, "must be a number of seconds in 0.01..60")
        object.__setattr__(self, "stats_interval", float(interval))

    @property
    def client_id(self) -> str:
        """The MQTT client id, stable across restarts (the broker keeps the session under it)."""
        return f"plantkg-bridge-{self.bridge_id}"

    @property
    def group_id(self) -> str:
        """The Kafka consumer group of the Kafka -> MQTT routes."""
        return f"plantkg-bridge-{self.bridge_id}"

    def routes_of(self, direction: Direction) -> tuple[Route, ...]:
        return tuple(r for r in self.routes if r.direction is direction)

    def kafka_auth(self) -> dict[str, str]:
        """librdkafka settings that authenticate the worker's Kafka clients (SASL at a closed
        Kafka) and, at a TLS Kafka, make them speak TLS trusting the plant CA only (none: an open,
        plain Kafka)."""
        auth = self._kafka_sasl()
        if self.kafka_ca_file is not None:
            auth.update({"security.protocol": "SASL_SSL" if auth else "SSL",
                         "ssl.ca.location": str(self.kafka_ca_file),
                         "ssl.endpoint.identification.algorithm": "https"})
        return auth

    def _kafka_sasl(self) -> dict[str, str]:
        if self.kafka_password_file is None:
            return {}
        try:
            password = self.kafka_password_file.read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigValueError("kafka_password_file", str(self.kafka_password_file),
                                   f"cannot be read ({exc.strerror})") from None
        return {"security.protocol": "SASL_PLAINTEXT", "sasl.mechanism": "PLAIN",
                "sasl.username": kafka_client.USER, "sasl.password": password}

    def to_json(self) -> str:
        return json.dumps({
            "bridge_id": self.bridge_id, "mqtt_host": self.mqtt_host, "mqtt_port": self.mqtt_port,
            "kafka_bootstrap": self.kafka_bootstrap, "routes": [r.to_dict() for r in self.routes],
            "state_dir": str(self.state_dir), "stats_interval": self.stats_interval,
            "mqtt_username": self.mqtt_username,
            "mqtt_ca_file": None if self.mqtt_ca_file is None else str(self.mqtt_ca_file),
            **({"kafka_password_file": str(self.kafka_password_file)} if self.kafka_password_file else {}),
            **({"kafka_ca_file": str(self.kafka_ca_file)} if self.kafka_ca_file else {}),
        }, indent=2)

    @classmethod
    def from_json(cls, text: str) -> WorkerConfig:
        values = worker_json_fields(cls, text, Route.from_dict)
        if not isinstance(values["state_dir"], str):
            raise ConfigValueError("state_dir", values["state_dir"], "must be a path string")
        values["state_dir"] = Path(values["state_dir"])
        return cls(**values)


def check_mqtt_username(value: object, field: str = "mqtt_username") -> None:
    """None, or a plantkg principal's name (the worker derives its password; nothing else)."""
    if value is not None and (not isinstance(value, str) or not value.startswith("plantkg.")
                              or not _BRIDGE_ID.fullmatch(value)):
        raise ConfigValueError(field, value, "must be null or a plantkg principal "
                               "(plantkg.<letters, digits, _ . ->)")


def worker_json_fields(cls: type, text: str, route: Any) -> dict[str, Any]:
    """A worker.json's fields for ``cls`` (unknown or missing ones refused), its ``routes`` parsed
    with ``route(dict, where)``; shared by the Kafka and the NGSI worker configs."""
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, TypeError) as exc:
        raise ConfigValueError("worker.json", str(text)[:80], f"not JSON: {exc}") from None
    values = _fields_of(cls, data, "worker.json")
    routes = values["routes"]
    if not isinstance(routes, list):
        raise ConfigValueError("routes", routes, "must be a list of routes")
    values["routes"] = tuple(route(r, f"routes[{i}]") for i, r in enumerate(routes))
    return values


def _fields_of(cls: type, data: object, where: str) -> dict[str, Any]:
    """The fields of dataclass ``cls`` from the JSON object ``data``; unknown or missing: refused."""
    if not isinstance(data, dict):
        raise ConfigValueError(where, data, "must be a JSON object")
    known = {f.name for f in fields(cls)}
    required = {f.name for f in fields(cls) if f.default is MISSING and f.default_factory is MISSING}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigValueError(unknown[0], data[unknown[0]], f"unknown field in {where}")
    missing = sorted(required - set(data))
    if missing:
        raise ConfigValueError(missing[0], None, f"missing in {where}")
    return dict(data)


def _enum(field: str, kind: type[enum.Enum], value: object) -> Any:
    try:
        return kind(value)
    except ValueError:
        allowed = ", ".join(repr(m.value) for m in kind)  # type: ignore[var-annotated]
        raise ConfigValueError(field, value, f"must be one of {allowed}") from None


def _check_mqtt_topic(field: str, value: object) -> None:
    """An MQTT topic name (not a filter): 1..65535 UTF-8 bytes, no wildcard, no NUL, not $-topic."""
    if not isinstance(value, str) or not value:
        raise ConfigValueError(field, value, "must be a non-empty string")
    if "+" in value or "#" in value:
        raise ConfigValueError(field, value, "a bridged topic is a name, not a filter (no + or #)")
    if "\0" in value or len(value.encode("utf-8")) > 65535:
        raise ConfigValueError(field, value, "not a valid MQTT topic name")
    if value.startswith("$"):
        raise ConfigValueError(field, value, "topics starting with $ belong to the broker")


def _check_kafka_topic(field: str, value: object) -> None:
    if not isinstance(value, str) or not _KAFKA_TOPIC.fullmatch(value) or value in (".", ".."):
        raise ConfigValueError(field, value, "a Kafka topic is 1 to 249 of a-z A-Z 0-9 . _ - "
                                             "(not '.' or '..')")


def _check_bootstrap(field: str, value: object) -> None:
    """``host:port[,host:port...]`` with IP addresses (IPv6 in brackets)."""
    if not isinstance(value, str) or not value:
        raise ConfigValueError(field, value, "must be host:port[,host:port...]")
    for part in value.split(","):
        host, sep, port = part.rpartition(":")
        if not sep or not port.isdigit():
            raise ConfigValueError(field, value, f"{part!r} is not host:port")
        check_host(field, host[1:-1] if host.startswith("[") and host.endswith("]") else host)
        check_port(field, int(port))


def _check_unique_routes(routes: tuple[Route, ...]) -> None:
    seen: set[tuple[str, str, Direction]] = set()
    for route in routes:
        ident = (route.mqtt_topic, route.kafka_topic, route.direction)
        if ident in seen:
            raise ConfigValueError("routes", route.to_dict(), "the same route appears twice")
        seen.add(ident)
    # One source, one target per direction: a message is acknowledged (MQTT) or committed (Kafka)
    # once, after its one forward.
    for direction, source in ((Direction.MQTT_TO_KAFKA, "mqtt_topic"), (Direction.KAFKA_TO_MQTT, "kafka_topic")):
        sources = [getattr(r, source) for r in routes if r.direction is direction]
        if len(set(sources)) != len(sources):
            raise ConfigValueError("routes", sources, f"each {source} is forwarded {direction.value} at most once")

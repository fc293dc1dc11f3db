"""What one MQTT <-> NGSI-v2 bridge worker does (``worker.json`` with ``"mechanism": "mqtt-ngsi"``).

The carrying agent builds an :class:`NgsiWorkerConfig` from a bridge spec and writes it with
:meth:`NgsiWorkerConfig.to_json`; the worker reads it back with :meth:`NgsiWorkerConfig.from_json`
(``python -m engine.bridge_worker`` picks this class when the file says ``mechanism: mqtt-ngsi``,
the Kafka :class:`engine.bridge_worker.config.WorkerConfig` otherwise). Reading is as strict as for
the Kafka worker: an unknown or missing field or a value that cannot work raises
:class:`engine.errors.ConfigValueError` naming the field.

Each route is one MQTT topic and one NGSI entity (``entity_id``, ``entity_type``), one way:
``mqtt-to-ngsi`` (messages become upserts of the entity) or ``ngsi-to-mqtt`` (a subscription on
the context broker whose notifications it publishes on the MQTT broker itself). The context
broker's write token, if any, is in ``token_file`` (mode 0600, written by the agent), never in
this file.
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from engine.bridge_worker.config import (
    _BRIDGE_ID,
    _check_mqtt_topic,
    _enum,
    _fields_of,
    check_mqtt_username,
    worker_json_fields,
)
from engine.bridge_worker.ngsi_mapping import Refused, check_name
from engine.errors import ConfigValueError
from engine.security import https
from engine.values import check_host, check_path, check_port

MECHANISM = "mqtt-ngsi"


class NgsiDirection(str, enum.Enum):
    """Which way a route forwards."""

    MQTT_TO_NGSI = "mqtt-to-ngsi"
    NGSI_TO_MQTT = "ngsi-to-mqtt"


@dataclass(frozen=True)
class NgsiRoute:
    """One MQTT topic <-> one NGSI entity, one way."""

    mqtt_topic: str
    entity_id: str
    entity_type: str
    direction: NgsiDirection
    qos: int = 1

    def __post_init__(self) -> None:
        _check_mqtt_topic("mqtt_topic", self.mqtt_topic)
        for name in ("entity_id", "entity_type"):
            value = getattr(self, name)
            if not isinstance(value, str):
                raise ConfigValueError(name, value, "must be a string")
            try:
                check_name(name, value)
            except Refused as exc:
                raise ConfigValueError(name, value, exc.reason) from None
        object.__setattr__(self, "direction", _enum("direction", NgsiDirection, self.direction))
        if isinstance(self.qos, bool) or self.qos not in (0, 1):
            raise ConfigValueError("qos", self.qos, "must be 1 (at least once) or 0 (at most once)")

    def to_dict(self) -> dict[str, object]:
        return {"mqtt_topic": self.mqtt_topic, "entity_id": self.entity_id,
                "entity_type": self.entity_type, "direction": self.direction.value, "qos": self.qos}

    @classmethod
    def from_dict(cls, data: object, where: str = "routes[]") -> NgsiRoute:
        return cls(**_fields_of(cls, data, where))


@dataclass(frozen=True)
class NgsiWorkerConfig:
    """One MQTT <-> NGSI bridge worker: the MQTT broker it is attached to, the context broker
    (``ngsi_url``: ``http://host:port``, or ``https://`` with ``ngsi_ca_file``, the plant CA's
    certificate it is verified against), its routes, the token file, its state folder."""

    bridge_id: str
    mqtt_host: str
    mqtt_port: int
    ngsi_url: str
    routes: tuple[NgsiRoute, ...]
    state_dir: Path
    token_file: Path | None = None
    stats_interval: float = 0.5
    check_every: float = 30.0      # seconds between checks that the subscriptions are still right
    mqtt_username: str | None = None  # as WorkerConfig.mqtt_username
    mqtt_ca_file: Path | None = None  # as WorkerConfig.mqtt_ca_file
    ngsi_ca_file: Path | None = None  # an https:// context broker (pk:tls): the plant CA's certificate
    #: The principal the context broker publishes the notifications as (a closed MQTT broker).
    notify_username: str | None = None
    mechanism: str = MECHANISM

    def __post_init__(self) -> None:
        if self.mechanism != MECHANISM:
            raise ConfigValueError("mechanism", self.mechanism, f"must be {MECHANISM!r}")
        check_mqtt_username(self.mqtt_username)
        check_mqtt_username(self.notify_username, "notify_username")
        if self.mqtt_ca_file is not None:
            object.__setattr__(self, "mqtt_ca_file", check_path("mqtt_ca_file", self.mqtt_ca_file))
        if not isinstance(self.bridge_id, str) or not _BRIDGE_ID.fullmatch(self.bridge_id):
            raise ConfigValueError("bridge_id", self.bridge_id, "must be 1 to 200 of A-Z a-z 0-9 _ . -")
        object.__setattr__(self, "mqtt_host", check_host("mqtt_host", self.mqtt_host))
        check_port("mqtt_port", self.mqtt_port)
        _check_url("ngsi_url", self.ngsi_url)
        object.__setattr__(self, "ngsi_ca_file",
                           https.check_ca_file("ngsi_ca_file", self.ngsi_url, self.ngsi_ca_file, required=True))
        if not isinstance(self.routes, tuple) or not self.routes:
            raise ConfigValueError("routes", self.routes, "a worker needs a non-empty tuple of routes")
        if not all(isinstance(r, NgsiRoute) for r in self.routes):
            raise ConfigValueError("routes", self.routes, "every route must be an NgsiRoute")
        for direction in NgsiDirection:
            topics = [r.mqtt_topic for r in self.routes if r.direction is direction]
            if len(set(topics)) != len(topics):
                raise ConfigValueError("routes", topics, f"a topic is routed {direction.value} twice")
        object.__setattr__(self, "state_dir", check_path("state_dir", self.state_dir))
        if self.token_file is not None:
            object.__setattr__(self, "token_file", check_path("token_file", self.token_file))
        interval = self.stats_interval
        if isinstance(interval, bool) or not isinstance(interval, (int, float)) or not 0.01 <= interval <= 60:
            raise ConfigValueError("stats_interval", interval, "must be a number of seconds in 0.01..60")
        object.__setattr__(self, "stats_interval", float(interval))
        every = self.check_every
        if isinstance(every, bool) or not isinstance(every, (int, float)) or not 0.1 <= every <= 3600:
            raise ConfigValueError("check_every", every, "must be a number of seconds in 0.1..3600")
        object.__setattr__(self, "check_every", float(every))

    @property
    def client_id(self) -> str:
        """The MQTT client id, stable across restarts (the broker keeps the session under it)."""
        return f"plantkg-bridge-{self.bridge_id}"

    @property
    def mqtt_url(self) -> str:
        """Where the context broker publishes notifications (the worker's own MQTT broker):
        ``mqtts://`` when it speaks TLS (the context broker verifies it against the plant CA)."""
        host = f"[{self.mqtt_host}]" if ":" in self.mqtt_host else self.mqtt_host
        return f"{'mqtt' if self.mqtt_ca_file is None else 'mqtts'}://{host}:{self.mqtt_port}"

    def routes_of(self, direction: NgsiDirection) -> tuple[NgsiRoute, ...]:
        return tuple(r for r in self.routes if r.direction is direction)

    def to_json(self) -> str:
        return json.dumps({
            "mechanism": self.mechanism, "bridge_id": self.bridge_id, "mqtt_host": self.mqtt_host,
            "mqtt_port": self.mqtt_port, "ngsi_url": self.ngsi_url,
            "routes": [r.to_dict() for r in self.routes], "state_dir": str(self.state_dir),
            "token_file": str(self.token_file) if self.token_file is not None else None,
            "stats_interval": self.stats_interval, "check_every": self.check_every,
            "mqtt_username": self.mqtt_username,
            "mqtt_ca_file": None if self.mqtt_ca_file is None else str(self.mqtt_ca_file),
            **({"ngsi_ca_file": str(self.ngsi_ca_file)} if self.ngsi_ca_file is not None else {}),
            **({"notify_username": self.notify_username} if self.notify_username else {}),
        }, indent=2)

    @classmethod
    def from_json(cls, text: str) -> NgsiWorkerConfig:
        values = worker_json_fields(cls, text, NgsiRoute.from_dict)
        for name in ("state_dir", "token_file"):
            value = values.get(name)
            if value is None and name == "token_file":
                continue
            if not isinstance(value, str):
                raise ConfigValueError(name, value, "must be a path string")
            values[name] = Path(value)
        return cls(**values)


def is_ngsi_config(text: str) -> bool:
    """Does this ``worker.json`` text describe an NGSI worker (``"mechanism": "mqtt-ngsi"``)?"""
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, TypeError):
        return False
    return isinstance(data, dict) and data.get("mechanism") == MECHANISM


def _check_url(field: str, value: object) -> None:
    """``http://<IP>:<port>`` (or ``https://``) with nothing after it (the worker adds the NGSI paths)."""
    if not isinstance(value, str):
        raise ConfigValueError(field, value, "must be http://<ip>:<port>")
    parts = urlsplit(value)
    if parts.scheme not in ("http", "https") or parts.path not in ("", "/") or parts.query or parts.fragment \
            or parts.username or parts.password or parts.hostname is None:
        raise ConfigValueError(field, value, "must be http://<ip>:<port>")
    check_host(field, parts.hostname)
    try:
        port = parts.port
    except ValueError:
        port = None
    if port is None:
        raise ConfigValueError(field, value, "must name a port: http://<ip>:<port>")

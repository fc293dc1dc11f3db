"""The driver Protocol: what the agent asks of a broker type, and the helpers every driver shares.

A driver turns a :class:`~engine.model.BrokerSpec` into files and a command line, says when the
running broker answers its own protocol, and manages topics. It holds no per-broker state: the
agent owns the broker folder (``<state-dir>/brokers/<id>/``) and passes it in. The verbs map onto
the paper's client tool: *start* = ``prepare`` + ``render_config`` + ``command`` (the agent spawns
it), *config* = ``ensure_topic``/``delete_topic``, *stop*/*restart* are the agent's process
handling, *connect* = the ``bridges`` a driver renders into its broker's config (a driver that
carries bridges natively, Mosquitto, also implements :class:`BridgeCarrier`; other bridges run as
workers, see :mod:`engine.bridge_worker`).

Drivers are found through the entry-point group ``plantkg.drivers`` (see
:mod:`engine.drivers.registry` and docs/drivers.md).
"""

from __future__ import annotations

import hashlib
import signal
import unicodedata
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from engine.errors import ConfigValueError
from engine.model import BridgeSpec, BrokerSpec, BrokerUser, ObservedTopic, TopicSpec
from engine.security import principal_key, principals
from engine.security.secrets import read_secret

#: Folder of a broker's logs inside its broker folder; the agent spawns the process with its
#: stdout/stderr appended to ``logs/<kind>.log`` (see :func:`log_file`).
LOGS_DIR = "logs"
#: Folder of a broker's persistent data inside its broker folder.
DATA_DIR = "data"
#: Set by ``plantkg agent`` to its token file, for drivers whose broker checks the agent's token
#: (the context broker); unset, such a driver looks for ``<state dir>/token``.
AGENT_TOKEN_FILE_ENV = "PLANTKG_AGENT_TOKEN_FILE"

#: Topic fields that only Kafka uses, and those that only MQTT uses.
KAFKA_TOPIC_FIELDS = ("partitions", "replication_factor", "retention_ms", "min_insync_replicas")
MQTT_TOPIC_FIELDS = ("qos", "retain")
#: Topic fields that only an NGSI-v2 context broker uses (the topic's entity).
NGSI_TOPIC_FIELDS = ("entity_id", "entity_type")


@runtime_checkable
class Driver(Protocol):
    """One broker type. Implementations are small classes built with no arguments."""

    #: The ontology's pk:brokerType and the entry-point name ("mosquitto", "kafka").
    kind: str
    #: True when the broker has no topic list of its own (MQTT): the agent records the topics
    #: it was asked for and reports that record; otherwise it reports :meth:`observe_topics`.
    implicit_topics: bool
    #: Seconds a start may take until :meth:`health` passes.
    start_deadline: float
    #: Seconds between SIGTERM and SIGKILL when stopping.
    stop_grace: float

    def validate(self, spec: BrokerSpec) -> None:
        """Refuse a spec this driver cannot run (ConfigValueError naming the field) before the
        agent stops anything. Pure."""

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        """File name (relative to ``broker_dir``) -> text, with the native ``bridges`` the broker
        carries (a driver without native bridges refuses any). Pure; refuses bad values with
        :class:`~engine.errors.ConfigValueError` naming the field."""

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        """argv that runs the broker in the foreground with the rendered files."""

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """One-time folder setup before rendering and starting (idempotent)."""

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        """True if the broker answers its own protocol within ``timeout`` s; never raises."""

    def ensure_topic(self, spec: BrokerSpec, topic: TopicSpec) -> ObservedTopic:
        """Create or alter ``topic`` so it matches; return it as observed. Raises
        :class:`~engine.errors.DriverRefusedError` for changes the broker cannot make."""

    def delete_topic(self, spec: BrokerSpec, name: str) -> None:
        """Delete topic ``name`` (absent already: nothing to do)."""

    def observe_topics(self, spec: BrokerSpec) -> list[ObservedTopic]:
        """The topics the broker reports (an implicit-topics driver returns [])."""

    def essence(self, spec: BrokerSpec) -> dict[str, Any]:
        """The fields of ``spec`` whose change needs a restart of the broker."""


@dataclass(frozen=True)
class SaveSignal:
    """A signal that makes a running broker save its state, and how often the agent sends it."""

    signal: signal.Signals
    every: float


@runtime_checkable
class PeriodicSave(Protocol):
    """A driver whose broker saves its state when signalled (Mosquitto: SIGUSR1), more often
    than it can by itself; the agent sends it (:mod:`engine.agent.save_tick`)."""

    def save_signal(self, spec: BrokerSpec) -> SaveSignal | None:
        """The signal and its period for ``spec``, or None if the agent should not send it."""


@runtime_checkable
class Waking(Protocol):
    """A driver whose broker acts on SIGTERM only once something wakes its event loop (Mosquitto
    2.0 masks its signals while it waits in epoll): the agent opens a connection to each address,
    for all brokers it stops at once (:func:`engine.netutil.touch_all`), right after the signals."""

    def wake_address(self, spec: BrokerSpec) -> tuple[str, int]:
        """Where a TCP connection wakes ``spec``'s broker."""


@runtime_checkable
class Settling(Protocol):
    """A driver whose healthy broker may still have to wait for others to take in what it set:
    a closed Kafka cluster's lead sets the users and ACLs, and the other nodes apply them from
    the cluster's metadata log a moment later. The agent calls :meth:`settle` after every PUT of
    such a broker that ended healthy (restarted or not), before it answers."""

    def settle(self, spec: BrokerSpec) -> None:
        """Return once what ``spec``'s broker set is in force wherever clients reach it (at once
        when there is nothing to wait for); after the driver's own deadline a retryable
        :class:`~engine.errors.BrokerUnavailableError` naming what lags."""


@runtime_checkable
class BridgeCarrier(Protocol):
    """A driver whose broker runs bridges itself (Mosquitto's ``connection`` sections)."""

    def bridge_states(self, spec: BrokerSpec, bridges: tuple[BridgeSpec, ...],
                      timeout: float) -> dict[str, bool]:
        """Bridge address -> connected, as the running broker reports it; a bridge the broker
        says nothing of is left out. Never raises."""


def refuse_bridges(kind: str, bridges: tuple[BridgeSpec, ...]) -> None:
    """For drivers without native bridges."""
    if bridges:
        raise ConfigValueError("bridges", [b.address for b in bridges],
                               f"a {kind} broker carries no native bridge")


def spec_essence(spec: BrokerSpec) -> dict[str, Any]:
    """What both built-in drivers restart for: kind, address and port (not id, iri or name)."""
    return {"kind": spec.kind, "host": spec.host, "port": spec.port}


def log_file(broker_dir: Path, kind: str) -> Path:
    """Where the broker's stdout/stderr (and, for Mosquitto, its own log) go."""
    return broker_dir / LOGS_DIR / f"{kind}.log"


def config_hash(files: Mapping[str, str]) -> str:
    """A sha256 over rendered files (names and texts), so a changed rendering is visible."""
    digest = hashlib.sha256()
    for name in sorted(files):
        digest.update(name.encode("utf-8") + b"\0" + files[name].encode("utf-8") + b"\0")
    return digest.hexdigest()


def check_text(field: str, value: object, *, max_length: int | None = None) -> str:
    """A non-empty string without control characters (C0, C1, DEL, U+2028/U+2029)."""
    if not isinstance(value, str):
        raise ConfigValueError(field, value, "must be a string")
    if not value:
        raise ConfigValueError(field, value, "must not be empty")
    bad = next((c for c in value if _is_control(c)), None)
    if bad is not None:
        raise ConfigValueError(field, value, f"must not contain the control character {bad!r}")
    if max_length is not None and len(value) > max_length:
        raise ConfigValueError(field, value, f"must be at most {max_length} characters")
    return value


def _is_control(char: str) -> bool:
    return unicodedata.category(char) == "Cc" or char in "\u2028\u2029"


def check_topic_fields(topic: TopicSpec, kind: str, applicable: tuple[str, ...]) -> None:
    """Refuse a TopicSpec field set for another broker kind, and out-of-range values."""
    for field in (*KAFKA_TOPIC_FIELDS, *MQTT_TOPIC_FIELDS, *NGSI_TOPIC_FIELDS):
        value = getattr(topic, field)
        if value is not None and field not in applicable:
            raise ConfigValueError(field, value, f"does not apply to a {kind} broker")
    _check_int(topic, "partitions", 1, 10_000)
    _check_int(topic, "replication_factor", 1, 32_767)
    _check_int(topic, "retention_ms", -1, 2**63 - 1)
    _check_int(topic, "min_insync_replicas", 1, 32_767)
    _check_int(topic, "qos", 0, 2)
    if topic.retain is not None and not isinstance(topic.retain, bool):
        raise ConfigValueError("retain", topic.retain, "must be true or false")


def _check_int(topic: TopicSpec, field: str, low: int, high: int) -> None:
    value = getattr(topic, field)
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigValueError(field, value, "must be an integer")
    if not low <= value <= high:
        raise ConfigValueError(field, value, f"must be in {low}..{high}")


def resolve_secret(user: BrokerUser, environ: Mapping[str, str] | None = None) -> str:
    """The password of ``user`` on this machine: derived from the principal key for plantkg's
    principals (``plantkg:principal-key``), else what ``user.secret_ref`` points to (an
    environment variable of this process, or a file's text without one trailing newline;
    engine.security.secrets). A missing, empty or unreadable secret is a ConfigValueError naming
    the user and the reference, never the secret. Shared by the Mosquitto and Kafka drivers."""
    if user.secret_ref == principals.PRINCIPAL_REF:
        return principal_key.password_for(user.name)
    return read_secret(f"users[{user.name}].secret_ref", user.secret_ref, environ)

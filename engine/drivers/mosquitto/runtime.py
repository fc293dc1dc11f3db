"""Mosquitto: render ``mosquitto.conf`` from validated values, and its command line.

Pure functions over frozen dataclasses, reused by the Mosquitto driver. The broker listens on one
address and port and logs to a file. Anonymous clients are allowed unless the config closes the
broker (``allow_anonymous false``, with a password file and an ACL file: see "Users and ACLs"
below). Settings that make bridges lose nothing:

- persistence on (with a ``data_dir``): queued messages and sessions survive a clean restart;
  the state is saved every :data:`DEFAULT_SAVE_SECONDS` s and, told by its agent, every
  :data:`SAVE_TICK_SECONDS` s while clients send it anything; or after every ``persist_every``
  changes when the plant sets ``pk:persistEvery``. A broker killed with SIGKILL keeps what it
  acknowledged but what changed since its last save (Mosquitto has no write-ahead log to close
  that window; docs/bridges.md measures it);
- ``max_queued_messages`` raised from Mosquitto's 1000, past which it silently drops QoS 1
  messages queued for a disconnected persistent session (a bridge, a bridge worker);
- ``max_inflight_messages`` raised from 20, so a consumer that acknowledges late (a worker waiting
  for Kafka's confirmation) is not throttled to 20 messages per round trip;
- ``set_tcp_nodelay``: without it a PUBACK can wait ~40 ms for the client's delayed ACK (Nagle).
  A trade-off (benchmarks/results/nodelay-10-repeats): 100-message bursts, PUBACK p99 42.1 ms
  without, 13.1 ms with; 500-message bursts, 62.2 ms without, 93.1 ms with.

Each :class:`MosquittoBridge` is one ``connection`` section: Mosquitto's own bridge with a
persistent session (``cleansession false``), notifications of its state on the local broker
(retained ``$SYS/broker/connection/<client id>/state``: 1 up, 0 down) and a restart backoff.

Users and ACLs: the broker loads Mosquitto's dynamic security plugin with a file rendered by
:mod:`engine.drivers.mosquitto.dynsec` (why the plugin and not an ACL file: see there). Here are
the users' names and topics (:class:`MosquittoUser`), checked so they cannot break a file, and the
password hash parameters (Mosquitto 2.x's: PBKDF2-HMAC-SHA512, 101 iterations, 12-byte salt).
"""

from __future__ import annotations

import getpass
import ipaddress
import re
import unicodedata
from dataclasses import dataclass, field
from pathlib import Path

from engine.errors import ConfigValueError
from engine.values import check_host, check_path, check_port, check_user


#: QoS 1/2 messages Mosquitto queues per client beyond those in flight (its default: 1000).
MAX_QUEUED_MESSAGES = 1_000_000
#: QoS 1/2 messages in flight to one client at once (its default: 20).
MAX_INFLIGHT_MESSAGES = 1000
#: ``autosave_interval`` when the plant sets no ``pk:persistEvery``: a save by time (Mosquitto counts
#: whole seconds and saves once the current one is more than this past the last save's, so every
#: 1-2 s; also on a clean stop). Mosquitto's own default, 1800 s (plantkg had 60 s), lost thousands
#: of acknowledged messages through a SIGKILL; saving after every 10 changes (plantkg's default
#: before issue 16) lost fewer, but every save writes the whole database and syncs it, and with a
#: backlog every queued message is a change: the broker did little but save (a bridge at full
#: speed: 0.06x the unsafe setting's throughput, benchmarks/bench_durability). A save by time costs
#: the same whatever the backlog.
DEFAULT_SAVE_SECONDS = 1
#: Seconds between the save signals (SIGUSR1) the agent sends a Mosquitto that sets no
#: ``pk:persistEvery`` and read anything since its last save (engine/agent/save_tick.py): the time
#: save alone lost 5,042 of 15,000 acknowledged messages queued for an offline subscriber through a
#: SIGKILL, with this tick none, at the same throughput (benchmarks/bench_durability).
SAVE_TICK_SECONDS = 0.25
#: Bridge reconnection backoff: first delay and cap, in seconds.
BRIDGE_RESTART_TIMEOUT = (1, 10)
BRIDGE_DIRECTIONS = ("out", "in", "both")
#: Mosquitto 2.x's password hash: type 7 (PBKDF2-HMAC-SHA512), its default iteration count and
#: salt length (mosquitto_passwd's output_new_password; password_mosq.h).
PW_HASH_TYPE = 7
PW_ITERATIONS = 101
PW_SALT_BYTES = 12
#: MQTT 3.1.1 section 3.1.3.5: a password is at most 65535 bytes.
MAX_PASSWORD_BYTES = 65_535


@dataclass(frozen=True)
class MosquittoBridgeTopic:
    """One ``topic`` line of a bridge: a topic (no wildcard), its direction, its QoS."""

    pattern: str
    direction: str   # "out" (local -> remote), "in" (remote -> local) or "both"
    qos: int = 1

    def __post_init__(self) -> None:
        _check_token("pattern", self.pattern)
        if "+" in self.pattern or "#" in self.pattern:
            raise ConfigValueError("pattern", self.pattern, "a bridged topic is a name, not a filter")
        if self.direction not in BRIDGE_DIRECTIONS:
            raise ConfigValueError("direction", self.direction, f"must be one of {BRIDGE_DIRECTIONS}")
        if isinstance(self.qos, bool) or self.qos not in (0, 1, 2):
            raise ConfigValueError("qos", self.qos, "must be 0, 1 or 2")


@dataclass(frozen=True)
class MosquittoBridge:
    """A bridge this broker carries: a connection to ``remote_host:remote_port``."""

    name: str                   # connection name, also the bridge's client id on the remote
    remote_host: str
    remote_port: int
    topics: tuple[MosquittoBridgeTopic, ...]
    #: Mark the bridge as one (MQTT protocol level | 0x80) so a Mosquitto remote does not send back
    #: what came from us; a remote that is not Mosquitto may refuse the flag as a corrupt header.
    try_private: bool = True
    #: The bridge's user on the remote broker (``remote_username``/``remote_password``); None:
    #: anonymous. The password ends up in ``mosquitto.conf`` (mode 0600): Mosquitto reads it there.
    remote_username: str | None = None
    remote_password: str | None = field(default=None, repr=False)
    #: The CA certificate to verify a TLS remote with (``bridge_cafile``); None: plain MQTT.
    cafile: Path | None = None

    def __post_init__(self) -> None:
        if self.cafile is not None:
            object.__setattr__(self, "cafile", check_path("cafile", self.cafile, forbid="\t "))
        if (self.remote_username is None) != (self.remote_password is None):
            raise ConfigValueError("remote_username", self.remote_username,
                                   "a bridge's remote user name and password go together")
        if self.remote_username is not None:
            check_user_name(self.remote_username)
            check_password(self.remote_username, self.remote_password)
            if any(c.isspace() or c == '"' for c in self.remote_password or ""):
                raise ConfigValueError(f"users[{self.remote_username}].password", "(not shown)",
                                       "a bridge's password is one word of mosquitto.conf")
        if not isinstance(self.try_private, bool):
            raise ConfigValueError("try_private", self.try_private, "must be true or false")
        if not _NAME.fullmatch(self.name):
            raise ConfigValueError("name", self.name, "must be 1 to 300 of A-Z a-z 0-9 _ . -")
        host = check_host("remote_host", self.remote_host)
        if ipaddress.ip_address(host).version == 6:
            raise ConfigValueError("remote_host", self.remote_host,
                                   "Mosquitto's bridge 'address' takes no IPv6 literal; give the "
                                   "remote broker an IPv4 address")
        object.__setattr__(self, "remote_host", host)
        check_port("remote_port", self.remote_port)
        if not self.topics:
            raise ConfigValueError("topics", self.topics, "a bridge needs at least one topic")


@dataclass(frozen=True)
class MosquittoTls:
    """The listener's TLS files: the CA certificate, the server certificate and its key (PEM)."""

    cafile: Path
    certfile: Path
    keyfile: Path

    def __post_init__(self) -> None:
        for name in ("cafile", "certfile", "keyfile"):
            object.__setattr__(self, name, check_path(name, getattr(self, name), forbid="\t "))


@dataclass(frozen=True)
class MosquittoConfig:
    """One Mosquitto broker. ``run_as`` matters only when started as root: Mosquitto then
    switches to this user (default: its own ``mosquitto`` user, which cannot write our files)."""

    host: str
    port: int
    log_file: Path
    run_as: str | None = None
    data_dir: Path | None = None          # persistence on, in this folder; None: off
    persist_every: int | None = None      # save after this many changes; None: every DEFAULT_SAVE_SECONDS
    bridges: tuple[MosquittoBridge, ...] = ()
    allow_anonymous: bool = True          # False: only clients of the password file connect
    dynsec_plugin: Path | None = None     # Mosquitto's dynamic security plugin (users and ACLs)
    dynsec_file: Path | None = None       # its file (engine.drivers.mosquitto.dynsec)
    tls: MosquittoTls | None = None       # the listener speaks TLS only (TLS 1.2 or newer)
    #: A second TLS listener (same host) that admits only clients with a certificate of ``tls``'s
    #: CA and takes its common name as the user name (docs/security.md, Client certificates);
    #: a listener that requires certificates refuses password clients, so it cannot be ``port``.
    cert_port: int | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "host", check_host("host", self.host))
        if self.tls is not None and not isinstance(self.tls, MosquittoTls):
            raise ConfigValueError("tls", self.tls, "must be a MosquittoTls or None")
        check_port("port", self.port)
        if self.cert_port is not None:
            check_port("cert_port", self.cert_port)
            if self.tls is None or self.cert_port == self.port:
                raise ConfigValueError("cert_port", self.cert_port,
                                       "needs tls, and a port of its own (not the password listener's)")
        object.__setattr__(self, "log_file", check_path("log_file", self.log_file, forbid="\t"))
        if self.data_dir is not None:
            object.__setattr__(self, "data_dir", check_path("data_dir", self.data_dir, forbid="\t "))
        if self.run_as is not None:
            check_user("run_as", self.run_as)
        if self.persist_every is not None and (isinstance(self.persist_every, bool)
                                               or not isinstance(self.persist_every, int)
                                               or not 1 <= self.persist_every <= 1_000_000):
            raise ConfigValueError("persist_every", self.persist_every, "must be an integer in 1..1000000")
        if self.persist_every is not None and self.data_dir is None:
            raise ConfigValueError("persist_every", self.persist_every, "needs a data_dir (persistence)")
        names = [b.name for b in self.bridges]
        if len(set(names)) != len(names):
            raise ConfigValueError("bridges", names, "two bridges with the same name")
        if not isinstance(self.allow_anonymous, bool):
            raise ConfigValueError("allow_anonymous", self.allow_anonymous, "must be true or false")
        if (self.dynsec_plugin is None) != (self.dynsec_file is None):
            raise ConfigValueError("dynsec_file", self.dynsec_file, "the plugin and its file go together")
        for name in ("dynsec_plugin", "dynsec_file"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, check_path(name, value, forbid="\t "))


def render_mosquitto_conf(cfg: MosquittoConfig) -> str:
    """The ``mosquitto.conf`` text for ``cfg`` (a pure function)."""
    lines = [
        "# Rendered by plantkg; edits are overwritten.",
        "per_listener_settings false",
        f"listener {cfg.port} {cfg.host}",
        *([] if cfg.tls is None else _tls_lines(cfg.tls)),
        f"allow_anonymous {'true' if cfg.allow_anonymous else 'false'}",
        *([] if cfg.dynsec_plugin is None else [f"plugin {cfg.dynsec_plugin}",
                                                f"plugin_opt_config_file {cfg.dynsec_file}"]),
        f"max_queued_messages {MAX_QUEUED_MESSAGES}",
        f"max_inflight_messages {MAX_INFLIGHT_MESSAGES}",
        "set_tcp_nodelay true",
        *_persistence_lines(cfg.data_dir, cfg.persist_every),
        f"log_dest file {cfg.log_file}",
        "log_type error",
        "log_type warning",
        "log_type notice",
        "log_type information",
        "log_timestamp true",
        "connection_messages true",
    ]
    if cfg.cert_port is not None and cfg.tls is not None:
        lines += ["", f"listener {cfg.cert_port} {cfg.host}", *_tls_lines(cfg.tls),
                  "require_certificate true", "use_identity_as_username true"]
    if cfg.run_as is not None:
        lines.append(f"user {cfg.run_as}")
    for bridge in cfg.bridges:
        lines += ["", *_bridge_lines(bridge)]
    return "\n".join(lines) + "\n"


def _tls_lines(tls: MosquittoTls) -> list[str]:
    return [f"cafile {tls.cafile}", f"certfile {tls.certfile}", f"keyfile {tls.keyfile}", "tls_version tlsv1.2"]


def _persistence_lines(data_dir: Path | None, every: int | None) -> list[str]:
    if data_dir is None:
        return ["persistence false"]
    if every is None:  # saved by time: autosave_on_changes is false by default
        return ["persistence true", f"persistence_location {data_dir}/", f"autosave_interval {DEFAULT_SAVE_SECONDS}"]
    # autosave_on_changes: autosave_interval counts changes (queued messages, subscriptions).
    return ["persistence true", f"persistence_location {data_dir}/", "autosave_on_changes true",
            f"autosave_interval {every}"]


def _bridge_lines(bridge: MosquittoBridge) -> list[str]:
    """One ``connection`` section (see mosquitto.conf(5), "Configuring Bridges")."""
    base, cap = BRIDGE_RESTART_TIMEOUT
    return [
        f"connection {bridge.name}",
        f"address {bridge.remote_host}:{bridge.remote_port}",
        "bridge_protocol_version mqttv311",
        f"remote_clientid {bridge.name}",
        f"local_clientid {bridge.name}.local",
        "cleansession false",
        f"try_private {'true' if bridge.try_private else 'false'}",
        "start_type automatic",
        f"restart_timeout {base} {cap}",
        "keepalive_interval 10",
        "notifications true",
        "notifications_local_only true",
        *([] if bridge.remote_username is None else
          [f"remote_username {bridge.remote_username}", f"remote_password {bridge.remote_password}"]),
        *([] if bridge.cafile is None else [f"bridge_cafile {bridge.cafile}", "bridge_insecure false"]),
        *(f"topic {t.pattern} {t.direction} {t.qos}" for t in bridge.topics),
    ]


def bridge_state_topic(bridge_name: str) -> str:
    """Where Mosquitto publishes (retained, on the local broker) the bridge's state: 1 up, 0 down."""
    return f"$SYS/broker/connection/{bridge_name}/state"


_NAME = re.compile(r"[A-Za-z0-9_.-]{1,300}")


def _check_token(field: str, value: object) -> str:
    """One word of a config line: text without whitespace, quotes or control characters."""
    if not isinstance(value, str) or not value:
        raise ConfigValueError(field, value, "must be a non-empty string")
    if any(c.isspace() or c == '"' or unicodedata.category(c) == "Cc" for c in value):
        raise ConfigValueError(field, value, "must not contain whitespace, quotes or control "
                                             "characters (it is one word of mosquitto.conf)")
    return value


@dataclass(frozen=True)
class MosquittoUser:
    """A user of the ACL file: the topic names it may publish (``write``) and subscribe to
    (``read``). Names only, no filter: a plant grants topics, not patterns. ``filters``:
    (access, filter) pairs with wildcards, for plantkg's own principals only (the driver sets
    them: ``read $SYS/#`` for the agent, ``read #`` for the observer); never from a spec."""

    name: str
    write: tuple[str, ...] = ()
    read: tuple[str, ...] = ()
    filters: tuple[tuple[str, str], ...] = ()
    #: may log in with a plant-CA client certificate naming it; such a user may have no password
    certificate: bool = False

    def __post_init__(self) -> None:
        check_user_name(self.name)
        for field in ("write", "read"):
            topics = getattr(self, field)
            if not isinstance(topics, tuple):
                raise ConfigValueError(f"users[{self.name}].{field}", topics, "must be a tuple of topic names")
            for topic in topics:
                _check_token(f"users[{self.name}].{field}", topic)
                if "+" in topic or "#" in topic:
                    raise ConfigValueError(f"users[{self.name}].{field}", topic,
                                           "an ACL grants topic names, not filters: no + or #")
        for access, pattern in self.filters:
            if access not in ("read", "write", "readwrite"):
                raise ConfigValueError(f"users[{self.name}].filters", access, "must be read, write or readwrite")
            _check_token(f"users[{self.name}].filters", pattern)


def check_user_name(name: object) -> str:
    """One word of the password and ACL files: no whitespace, quote, control character or ':'."""
    _check_token("users.name", name)
    assert isinstance(name, str)
    if ":" in name:
        raise ConfigValueError("users.name", name, "must not contain ':' (the password file's separator)")
    return name


def check_password(name: str, password: object) -> None:
    field = f"users[{name}].password"
    if not isinstance(password, str) or not password:
        raise ConfigValueError(field, "(not shown)", "must be a non-empty string")
    if "\0" in password:
        raise ConfigValueError(field, "(not shown)", "must not contain a NUL character")
    try:
        size = len(password.encode("utf-8"))
    except UnicodeEncodeError:
        raise ConfigValueError(field, "(not shown)", "must be UTF-8 text") from None
    if size > MAX_PASSWORD_BYTES:
        raise ConfigValueError(field, "(not shown)", f"is at most {MAX_PASSWORD_BYTES} bytes in MQTT")


def default_run_as() -> str:
    """The user this process runs as: a root-started broker stays able to write our files."""
    return getpass.getuser()


def mosquitto_command(mosquitto: Path, conf_file: Path) -> list[str]:
    """argv that runs Mosquitto in the foreground with ``conf_file``."""
    check_path("conf_file", conf_file)
    return [str(mosquitto), "-c", str(conf_file)]

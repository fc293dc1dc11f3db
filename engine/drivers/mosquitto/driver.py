"""The Mosquitto (MQTT) driver: ``mosquitto -c <broker dir>/mosquitto.conf``.

Config and command line come from :mod:`engine.drivers.mosquitto.runtime`; persistence is on, in
``<broker dir>/data/``. Bridges to other MQTT brokers are Mosquitto's own (``connection`` sections
of the config, one per :class:`~engine.model.BridgeSpec` this broker carries); their state is read
from the retained notifications Mosquitto publishes on the broker. MQTT has no topic list: a topic
exists as soon as someone publishes to it, so :meth:`MosquittoDriver.ensure_topic` only validates
the name and settings and the agent records them (``implicit_topics``). Health is a real MQTT
CONNECT/CONNACK with paho, not just an open port.

Users (``BrokerSpec.users``): each user's ``secret_ref`` is resolved here, on the broker's machine
(``env:NAME``, the agent's environment; ``file:/path``, the file's text without one trailing
newline), and only hashes reach the broker folder: ``dynamic-security.json``, the file of
Mosquitto's dynamic security plugin (hashed passwords and what each user may publish and
receive; :mod:`engine.drivers.mosquitto.dynsec` says why not an ACL file), mode 0600 like every
rendered file. A broker
with users is closed (``allow_anonymous false``) unless the spec says ``allow_anonymous`` true; a
spec with ``allow_anonymous`` false is closed even without users. A closed broker answers the
agent's anonymous health check with a refusing CONNACK, which still proves it speaks MQTT.

plantkg's own principals (engine.security.principals): a broker with a password file also admits
``plantkg.agent`` (read ``$SYS/#``: the health check and the bridge states log in as it),
``plantkg.observer`` (read ``#``) and ``plantkg.check`` (write ``#``), and the bridge principals
the spec lists as users (``secret_ref`` ``plantkg:principal-key``); their passwords derive from
the plant's principal key on this machine. A bridge to a Mosquitto logs in there as its
principal (``remote_username``/``remote_password`` in ``mosquitto.conf``, mode 0600).
"""

from __future__ import annotations

import getpass
import os
import secrets
import signal
import time
from pathlib import Path
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, parts
from engine.drivers.mosquitto import dynsec
from engine.drivers.mosquitto import runtime as mosquitto_runtime
from engine.drivers.base import (  # resolve_secret: shared with the Kafka driver
    resolve_secret,
    DATA_DIR,
    MQTT_TOPIC_FIELDS,
    SaveSignal,
    check_text,
    check_topic_fields,
    log_file,
    spec_essence,
)
from engine.errors import ConfigValueError
from engine.model import BridgeMechanism, BridgeSpec, BrokerSpec, ObservedTopic, TopicSpec
from engine.security import ca, principal_key, principals
from engine.security.mqtt_client import MqttLogin, apply_login, apply_tls, principal_login

CONF_FILE = "mosquitto.conf"
#: The users file of a broker with users (in its broker folder): the dynamic security plugin's,
#: hashed passwords and ACLs (engine.drivers.mosquitto.dynsec).
USERS_FILE = dynsec.DYNSEC_FILE
#: Files of an earlier plantkg (password_file + acl_file), removed when the broker is prepared.
OLD_FILES = ("passwords", "acl")
#: The TLS files of a broker with ``tls`` (its listener) or with a bridge to a TLS broker (the CA
#: certificate only): the plant CA's certificate, the broker's certificate and key.
TLS_CA_FILE = "tls-ca.pem"
TLS_CERT_FILE = "tls-cert.pem"
TLS_KEY_FILE = "tls-key.pem"
#: CONNACKs that prove the broker answers MQTT: accepted, and the refusals of a closed broker to
#: the agent's anonymous health check (MQTT 3.1.1 return codes 4 and 5, paho's names).
ANSWERING_CONNACKS = ("Success", "Bad user name or password", "Not authorized")
#: MQTT 3.1.1 section 1.5.3: a topic name is at most 65535 bytes of UTF-8.
MAX_TOPIC_BYTES = 65_535

_AUTO = object()


class MosquittoDriver:
    """Mosquitto, one listener on the spec's address and port, persistence on."""

    kind = "mosquitto"
    implicit_topics = True
    start_deadline = 10.0
    stop_grace = 5.0

    def __init__(self, *, run_as: Any = _AUTO, binary: Path | None = None,
                 dynsec_plugin: Path | None = None) -> None:
        """``run_as``: the ``user`` line (only used by a root-started Mosquitto); by default the
        current user when running as root, else none. ``binary``, ``dynsec_plugin``: by default
        found when needed (engine.parts)."""
        if run_as is _AUTO:
            run_as = getpass.getuser() if os.geteuid() == 0 else None
        self.run_as: str | None = run_as
        self._binary = binary
        self._dynsec_plugin = dynsec_plugin

    def validate(self, spec: BrokerSpec) -> None:
        self.render_config(spec, Path("/nonexistent/plantkg/broker"))

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        """``mosquitto.conf``; for a broker with users (or closed) its users file (reading each
        user's secret, and the previous file so unchanged passwords keep their hash: the same
        inputs render the same files); for TLS its certificate and key, kept while current."""
        closed = is_closed(spec)
        files: dict[str, str] = {}
        if has_users(spec):
            acl_users = (*(mosquitto_runtime.MosquittoUser(u.name, u.write, u.read, certificate=u.certificate)
                           for u in spec.users),
                         *FIXED_PRINCIPALS)  # names and topics checked before any secret
            # a certificate user without a secret_ref gets no password: it logs in only on the
            # certificate listener, whose certificate names it (use_identity_as_username)
            passwords = {u.name: resolve_secret(u) for u in spec.users if u.secret_ref is not None}
            passwords.update((p.name, principal_key.password_for(p.name)) for p in FIXED_PRINCIPALS)
            files[USERS_FILE] = dynsec.render_dynsec(acl_users, passwords, _previous(broker_dir / USERS_FILE),
                                                     anonymous=not closed)
        files.update(_tls_files(spec, broker_dir, bridges))
        tls = (mosquitto_runtime.MosquittoTls(broker_dir / TLS_CA_FILE, broker_dir / TLS_CERT_FILE,
                                              broker_dir / TLS_KEY_FILE) if spec.tls else None)
        cafile = broker_dir / TLS_CA_FILE if TLS_CA_FILE in files else None
        cfg = mosquitto_runtime.MosquittoConfig(
            host=spec.host,
            port=spec.port,
            log_file=log_file(broker_dir, self.kind),
            run_as=self.run_as,
            data_dir=broker_dir / DATA_DIR,
            persist_every=spec.persist_every,
            bridges=tuple(native_bridge(spec, b, cafile) for b in bridges),
            allow_anonymous=not closed,
            dynsec_plugin=self._plugin() if has_users(spec) else None,
            dynsec_file=broker_dir / USERS_FILE if has_users(spec) else None,
            tls=tls,
            cert_port=spec.certificate_port,
        )
        return {CONF_FILE: mosquitto_runtime.render_mosquitto_conf(cfg), **files}

    def _plugin(self) -> Path:
        return self._dynsec_plugin or parts.mosquitto_dynsec_plugin()

    def save_signal(self, spec: BrokerSpec) -> SaveSignal | None:
        """SIGUSR1 every :data:`~engine.drivers.mosquitto.runtime.SAVE_TICK_SECONDS` s, unless the
        plant chose a save policy of its own (``pk:persistEvery``)."""
        if spec.persist_every is not None:
            return None
        return SaveSignal(signal.SIGUSR1, mosquitto_runtime.SAVE_TICK_SECONDS)

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        binary = self._binary or parts.mosquitto_binary()
        return mosquitto_runtime.mosquitto_command(binary, broker_dir / CONF_FILE)

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """The persistence folder (Mosquitto does not create it); the users file of a broker that
        no longer has users, the TLS key of one that no longer speaks TLS, and an earlier
        plantkg's password and ACL files are removed (no stale hashes or keys left behind)."""
        (broker_dir / DATA_DIR).mkdir(parents=True, exist_ok=True)
        for name in OLD_FILES:
            (broker_dir / name).unlink(missing_ok=True)
        if not has_users(spec):
            (broker_dir / USERS_FILE).unlink(missing_ok=True)
        if not spec.tls:
            for name in (TLS_CERT_FILE, TLS_KEY_FILE):
                (broker_dir / name).unlink(missing_ok=True)

    def wake_address(self, spec: BrokerSpec) -> tuple[str, int]:
        """Where to wake a Mosquitto just sent SIGTERM, so it exits now. Mosquitto 2.0 blocks its
        signals while it waits in epoll (``rt_sigprocmask`` around ``epoll_wait(..., 100)``, seen
        with strace): an idle broker acts on SIGTERM only when that wait times out, up to 100 ms
        later (a destroy of one broker took ~0.1 s against ~1 ms by hand). A TCP connection to its
        listener ends the wait at once; the agent opens one to each broker it stops and closes it
        unused (:func:`engine.netutil.touch_all`, all brokers of a batch at once)."""
        return (spec.host, spec.port)

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        """An MQTT CONNECT answered by a CONNACK within ``timeout`` s: accepted, or refused as a
        closed broker refuses the agent, which has no credentials (:data:`ANSWERING_CONNACKS`).
        A closed port answers False at once, before an MQTT client is built: a start polls this
        every 2 ms, and 100 brokers starting together would otherwise spend the CPU building
        clients."""
        if not netutil.port_open(spec.host, spec.port, timeout=min(timeout, 0.5)):
            return False
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=f"plantkg-health-{secrets.token_hex(4)}"
        )
        apply_tls(client, spec.tls)
        apply_login(client, agent_login(spec))
        answers: list[str] = []
        client.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
        client.connect_timeout = max(timeout, 0.05)
        end = time.monotonic() + timeout
        try:
            client.connect(spec.host, spec.port, keepalive=max(5, int(timeout) + 1))
            while not answers:
                remaining = end - time.monotonic()
                if remaining <= 0:
                    return False
                if client.loop(timeout=min(remaining, 0.05)) != mqtt.MQTT_ERR_SUCCESS:
                    break
            return connack_answers(answers[0]) if answers else False
        except OSError:
            return False
        finally:
            _close(client)

    def ensure_topic(self, spec: BrokerSpec, topic: TopicSpec) -> ObservedTopic:
        """Validate; MQTT topics need no creation. The agent records the result."""
        check_mqtt_topic_name(topic.name)
        check_topic_fields(topic, self.kind, MQTT_TOPIC_FIELDS)
        return ObservedTopic(name=topic.name, qos=topic.qos, retain=topic.retain)

    def delete_topic(self, spec: BrokerSpec, name: str) -> None:
        """Nothing on the broker (retained messages stay until overwritten)."""
        check_mqtt_topic_name(name)

    def observe_topics(self, spec: BrokerSpec) -> list[ObservedTopic]:
        return []

    def essence(self, spec: BrokerSpec) -> dict[str, Any]:
        """Address, persistence, whether the broker is closed, its users and its certificate
        listener (JSON values: the
        essence is kept in pid.json). A password's new content is not here: it shows in the
        rendered password file, whose change restarts the broker at the next PUT."""
        out = {**spec_essence(spec), "persist_every": spec.persist_every,
               "closed": is_closed(spec), "tls": spec.tls,
               "users": [{"name": u.name, "secret_ref": u.secret_ref, "write": sorted(u.write),
                          "read": sorted(u.read), **({"certificate": True} if u.certificate else {})}
                         for u in sorted(spec.users, key=lambda u: u.name)]}
        if spec.certificate_port is not None:  # absent otherwise: essences kept by agents read as before
            out["certificate_port"] = spec.certificate_port
        return out

    def tls_renewal(self, spec: BrokerSpec, broker_dir: Path) -> str | None:
        """Why the broker's TLS certificate must be issued again (engine.security.ca: none,
        expiring within 30 days, for another address, another CA); None if current. The agent
        reports it, the plan turns it into an update, and the PUT renders a new one."""
        if not spec.tls:
            return None
        return ca.renewal_reason(_previous_bytes(broker_dir / TLS_CERT_FILE), (spec.host,))

    def bridge_states(self, spec: BrokerSpec, bridges: tuple[BridgeSpec, ...],
                      timeout: float) -> dict[str, bool]:
        """Read the retained ``$SYS/broker/connection/<name>/state`` of each bridge."""
        wanted = {mosquitto_runtime.bridge_state_topic(bridge_name(b)): b.address for b in bridges}
        if not wanted:
            return {}
        found: dict[str, bool] = {}
        client = mqtt.Client(CallbackAPIVersion.VERSION2,
                             client_id=f"plantkg-bridge-state-{secrets.token_hex(4)}")
        apply_tls(client, spec.tls)
        apply_login(client, agent_login(spec))
        client.on_message = lambda _c, _u, msg: found.__setitem__(
            wanted[msg.topic], msg.payload == b"1") if msg.topic in wanted else None
        subscribed: list[float] = []
        client.on_subscribe = lambda *_args: subscribed.append(time.monotonic())
        end = time.monotonic() + timeout
        try:
            client.connect(spec.host, spec.port, keepalive=max(5, int(timeout) + 1))
            client.subscribe([(topic, 0) for topic in wanted])
            # Retained messages follow the SUBACK at once: after it, drain briefly, then stop.
            while len(found) < len(wanted) and time.monotonic() < end:
                if subscribed and time.monotonic() - subscribed[0] > 0.1:
                    break
                if client.loop(timeout=0.02) != mqtt.MQTT_ERR_SUCCESS:
                    break
        except OSError:
            return found
        finally:
            _close(client)
        return found


def is_closed(spec: BrokerSpec) -> bool:
    """Closed to anonymous clients: users and no ``allow_anonymous`` true, or ``allow_anonymous``
    false."""
    return spec.allow_anonymous is False or (bool(spec.users) and spec.allow_anonymous is not True)


def has_users(spec: BrokerSpec) -> bool:
    """The broker gets a password and an ACL file: it has users, or it is closed."""
    return bool(spec.users) or is_closed(spec)


#: plantkg's principals every broker with a password file admits, with what they may do.
FIXED_PRINCIPALS = (
    mosquitto_runtime.MosquittoUser(principals.AGENT, filters=(("read", "$SYS/#"),)),
    mosquitto_runtime.MosquittoUser(principals.OBSERVER, filters=(("read", "#"),)),
    mosquitto_runtime.MosquittoUser(principals.CHECK, filters=(("write", "#"),)),
)


def agent_login(spec: BrokerSpec) -> MqttLogin | None:
    """How the agent logs in to ``spec``'s broker: as ``plantkg.agent`` where there is a
    password file, else anonymously (no key needed)."""
    return principal_login(MosquittoDriver.kind, principals.AGENT) if has_users(spec) else None


def connack_answers(reason: str) -> bool:
    """True if a CONNACK with this reason (paho's name) shows a broker answering MQTT."""
    return reason in ANSWERING_CONNACKS


def _previous(path: Path) -> str:
    """The password file rendered last time ('' if absent or unreadable: new salts)."""
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return ""


def bridge_name(bridge: BridgeSpec) -> str:
    """The Mosquitto connection name (and client id) of a bridge."""
    return f"plantkg.{bridge.local.id}.{bridge.remote.id}"


def _tls_files(spec: BrokerSpec, broker_dir: Path, bridges: tuple[BridgeSpec, ...]) -> dict[str, str]:
    """The CA certificate (for a TLS listener or a bridge to a TLS broker) and, for a TLS
    listener, the broker's certificate and key for its address: the previous ones while current
    (so re-rendering gives the same files), else new ones (engine.security.ca)."""
    if not spec.tls and not any(b.remote.tls for b in bridges):
        return {}
    authority = ca.load_or_create_ca(ca.ca_dir())
    files = {TLS_CA_FILE: ca.ca_pem(authority).decode("ascii")}
    if spec.tls:
        cert, key = ca.current_server_cert(_previous_bytes(broker_dir / TLS_CERT_FILE),
                                           _previous_bytes(broker_dir / TLS_KEY_FILE), authority,
                                           (spec.host,), name=f"plantkg broker {spec.id}")
        files[TLS_CERT_FILE], files[TLS_KEY_FILE] = cert.decode("ascii"), key.decode("ascii")
    return files


def _previous_bytes(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except OSError:
        return None


def native_bridge(spec: BrokerSpec, bridge: BridgeSpec,
                  cafile: Path | None = None) -> mosquitto_runtime.MosquittoBridge:
    """The ``connection`` section of ``bridge``, which ``spec`` must carry (``cafile``: the CA
    certificate, for a remote that speaks TLS)."""
    if bridge.mechanism is not BridgeMechanism.MOSQUITTO or bridge.local.id != spec.id:
        raise ConfigValueError("bridges", bridge.address,
                               f"not a Mosquitto bridge carried by broker {spec.id!r}")
    return mosquitto_runtime.MosquittoBridge(
        name=bridge_name(bridge),
        remote_host=bridge.remote.host,
        remote_port=bridge.remote.port,
        topics=tuple(mosquitto_runtime.MosquittoBridgeTopic(r.topic, r.direction.value, r.qos)
                     for r in bridge.routes),
        # the bridge flag is Mosquitto's own: another MQTT broker (RabbitMQ's plugin, say) may
        # refuse it as a corrupt header (engine.derived.bridge_pairs keeps such bridges one-way)
        try_private=bridge.remote.kind == MosquittoDriver.kind,
        **_remote_login(bridge),
        cafile=cafile if bridge.remote.tls else None,
    )


def _remote_login(bridge: BridgeSpec) -> dict[str, str]:
    """The bridge's principal at a Mosquitto remote (derived users there: engine.derived.access)."""
    login = principal_login(bridge.remote.kind,
                            principals.bridge_principal(bridge.local.id, bridge.remote.id))
    return {} if login is None else {"remote_username": login.username,
                                     "remote_password": login.password}


def _close(client: mqtt.Client) -> None:
    """Send DISCONNECT if connected and close the socket (no file descriptor left to the GC)."""
    try:
        if client.is_connected():
            client.disconnect()
            client.loop(timeout=0.01)
    except OSError:
        pass
    sock = client.socket()
    if sock is not None:
        sock.close()


def check_mqtt_topic_name(name: object) -> str:
    """A topic name one can publish to: no wildcard, no control character, at most 64 KiB."""
    text = check_text("name", name)
    if "+" in text or "#" in text:
        raise ConfigValueError("name", name, "an MQTT topic name must not contain + or #")
    if len(text.encode("utf-8")) > MAX_TOPIC_BYTES:
        raise ConfigValueError("name", name, f"an MQTT topic name is at most {MAX_TOPIC_BYTES} bytes")
    return text

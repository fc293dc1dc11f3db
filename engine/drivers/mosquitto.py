"""The Mosquitto (MQTT) driver: ``mosquitto -c <broker dir>/mosquitto.conf``.

Config and command line come from :mod:`engine.mosquitto_runtime`; persistence is on, in
``<broker dir>/data/``. Bridges to other MQTT brokers are Mosquitto's own (``connection`` sections
of the config, one per :class:`~engine.model.BridgeSpec` this broker carries); their state is read
from the retained notifications Mosquitto publishes on the broker. MQTT has no topic list: a topic
exists as soon as someone publishes to it, so :meth:`MosquittoDriver.ensure_topic` only validates
the name and settings and the agent records them (``implicit_topics``). Health is a real MQTT
CONNECT/CONNACK with paho, not just an open port.

Users (``BrokerSpec.users``): each user's ``secret_ref`` is resolved here, on the broker's machine
(``env:NAME``, the agent's environment; ``file:/path``, the file's text without one trailing
newline), and only hashes reach the broker folder: ``passwords`` (Mosquitto's hashed format) and
``acl`` (what each user may publish and subscribe to), mode 0600 like every rendered file. A broker
with users is closed (``allow_anonymous false``) unless the spec says ``allow_anonymous`` true; a
spec with ``allow_anonymous`` false is closed even without users. A closed broker answers the
agent's anonymous health check with a refusing CONNACK, which still proves it speaks MQTT; it
carries no bridge (they connect, and their states are read, anonymously).
"""

from __future__ import annotations

import getpass
import os
import secrets
import time
from pathlib import Path
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import mosquitto_runtime, netutil, parts
from engine.drivers.base import (  # resolve_secret: shared with the Kafka driver
    resolve_secret,
    DATA_DIR,
    MQTT_TOPIC_FIELDS,
    check_text,
    check_topic_fields,
    log_file,
    spec_essence,
)
from engine.errors import ConfigValueError
from engine.model import BridgeMechanism, BridgeSpec, BrokerSpec, ObservedTopic, TopicSpec

CONF_FILE = "mosquitto.conf"
#: The hashed password file and the ACL file of a broker with users (in its broker folder).
PASSWORD_FILE = "passwords"
ACL_FILE = "acl"
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

    def __init__(self, *, run_as: Any = _AUTO, binary: Path | None = None) -> None:
        """``run_as``: the ``user`` line (only used by a root-started Mosquitto); by default the
        current user when running as root, else none. ``binary``: default found at start."""
        if run_as is _AUTO:
            run_as = getpass.getuser() if os.geteuid() == 0 else None
        self.run_as: str | None = run_as
        self._binary = binary

    def validate(self, spec: BrokerSpec) -> None:
        self.render_config(spec, Path("/nonexistent/plantkg/broker"))

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        """``mosquitto.conf``, and for a broker with users its password and ACL files (reading
        each user's secret, and the previous password file so unchanged passwords keep their
        hash: the same inputs render the same files)."""
        closed = is_closed(spec)
        if closed and bridges:
            raise ConfigValueError("bridges", [b.address for b in bridges],
                                   f"broker {spec.id!r} is closed to anonymous clients: bridges "
                                   "with closed brokers are not supported yet")
        files: dict[str, str] = {}
        if spec.users:
            acl_users = tuple(mosquitto_runtime.MosquittoUser(u.name, u.write, u.read)
                              for u in spec.users)  # names and topics checked before any secret
            passwords = [(u.name, resolve_secret(u)) for u in spec.users]
            files[PASSWORD_FILE] = mosquitto_runtime.render_password_file(
                passwords, _previous(broker_dir / PASSWORD_FILE))
            files[ACL_FILE] = mosquitto_runtime.render_acl_file(acl_users, anonymous=not closed)
        cfg = mosquitto_runtime.MosquittoConfig(
            host=spec.host,
            port=spec.port,
            log_file=log_file(broker_dir, self.kind),
            run_as=self.run_as,
            data_dir=broker_dir / DATA_DIR,
            persist_every=spec.persist_every,
            bridges=tuple(native_bridge(spec, b) for b in bridges),
            allow_anonymous=not closed,
            password_file=broker_dir / PASSWORD_FILE if spec.users else None,
            acl_file=broker_dir / ACL_FILE if spec.users else None,
        )
        return {CONF_FILE: mosquitto_runtime.render_mosquitto_conf(cfg), **files}

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        binary = self._binary or parts.mosquitto_binary()
        return mosquitto_runtime.mosquitto_command(binary, broker_dir / CONF_FILE)

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """The persistence folder (Mosquitto does not create it); the password and ACL files of
        a broker that no longer has users are removed (no stale hashes left in the folder)."""
        (broker_dir / DATA_DIR).mkdir(parents=True, exist_ok=True)
        if not spec.users:
            for name in (PASSWORD_FILE, ACL_FILE):
                (broker_dir / name).unlink(missing_ok=True)

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
        """Address, persistence, whether the broker is closed and its users (JSON values: the
        essence is kept in pid.json). A password's new content is not here: it shows in the
        rendered password file, whose change restarts the broker at the next PUT."""
        return {**spec_essence(spec), "persist_every": spec.persist_every,
                "closed": is_closed(spec),
                "users": [{"name": u.name, "secret_ref": u.secret_ref, "write": sorted(u.write),
                           "read": sorted(u.read)} for u in sorted(spec.users, key=lambda u: u.name)]}

    def bridge_states(self, spec: BrokerSpec, bridges: tuple[BridgeSpec, ...],
                      timeout: float) -> dict[str, bool]:
        """Read the retained ``$SYS/broker/connection/<name>/state`` of each bridge."""
        wanted = {mosquitto_runtime.bridge_state_topic(bridge_name(b)): b.address for b in bridges}
        if not wanted:
            return {}
        found: dict[str, bool] = {}
        client = mqtt.Client(CallbackAPIVersion.VERSION2,
                             client_id=f"plantkg-bridge-state-{secrets.token_hex(4)}")
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


def native_bridge(spec: BrokerSpec, bridge: BridgeSpec) -> mosquitto_runtime.MosquittoBridge:
    """The ``connection`` section of ``bridge``, which ``spec`` must carry."""
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
        # refuse it as a corrupt header (engine.bridge_pairs keeps such bridges one-way)
        try_private=bridge.remote.kind == MosquittoDriver.kind,
    )


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

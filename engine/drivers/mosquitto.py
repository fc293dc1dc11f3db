"""The Mosquitto (MQTT) driver: ``mosquitto -c <broker dir>/mosquitto.conf``.

Config and command line come from :mod:`engine.mosquitto_runtime`; persistence is on, in
``<broker dir>/data/``. Bridges to other MQTT brokers are Mosquitto's own (``connection`` sections
of the config, one per :class:`~engine.model.BridgeSpec` this broker carries); their state is read
from the retained notifications Mosquitto publishes on the broker. MQTT has no topic list: a topic
exists as soon as someone publishes to it, so :meth:`MosquittoDriver.ensure_topic` only validates
the name and settings and the agent records them (``implicit_topics``). Health is a real MQTT
CONNECT/CONNACK with paho, not just an open port.
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
from engine.drivers.base import (
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
        cfg = mosquitto_runtime.MosquittoConfig(
            host=spec.host,
            port=spec.port,
            log_file=log_file(broker_dir, self.kind),
            run_as=self.run_as,
            data_dir=broker_dir / DATA_DIR,
            persist_every=spec.persist_every,
            bridges=tuple(native_bridge(spec, b) for b in bridges),
        )
        return {CONF_FILE: mosquitto_runtime.render_mosquitto_conf(cfg)}

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        binary = self._binary or parts.mosquitto_binary()
        return mosquitto_runtime.mosquitto_command(binary, broker_dir / CONF_FILE)

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """The persistence folder (Mosquitto does not create it)."""
        (broker_dir / DATA_DIR).mkdir(parents=True, exist_ok=True)

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        """An MQTT CONNECT answered by a successful CONNACK within ``timeout`` s. A closed port
        answers False at once, before an MQTT client is built: a start polls this every 2 ms, and
        100 brokers starting together would otherwise spend the CPU building clients."""
        if not netutil.port_open(spec.host, spec.port, timeout=min(timeout, 0.5)):
            return False
        client = mqtt.Client(
            CallbackAPIVersion.VERSION2, client_id=f"plantkg-health-{secrets.token_hex(4)}"
        )
        client.connect_timeout = max(timeout, 0.05)
        end = time.monotonic() + timeout
        try:
            client.connect(spec.host, spec.port, keepalive=max(5, int(timeout) + 1))
            while not client.is_connected():
                remaining = end - time.monotonic()
                if remaining <= 0:
                    return False
                if client.loop(timeout=min(remaining, 0.05)) != mqtt.MQTT_ERR_SUCCESS:
                    return False
            return True
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
        return {**spec_essence(spec), "persist_every": spec.persist_every}

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

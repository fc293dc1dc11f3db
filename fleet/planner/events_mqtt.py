"""LoTLan Events from MQTT: operator buttons and sensors publish on ``<prefix>/<event>``.

The planner subscribes ``<prefix>/+`` at QoS 1 (``python -m fleet.planner --events-mqtt
HOST:PORT [--events-topic PREFIX]``, prefix ``plantkg/events`` by default). The last topic level
is the Event's LoTLan name or its physical ``name`` (``plantkg/events/Loaded``); the payload is
a JSON value (``true``, ``3.5``, ``"text"``) or ``{"value": ...}``. Each message is fired through
``Planner.fire`` (:mod:`event_sources`), so it is typed and journaled as ``POST /v1/events``.

Delivery: a persistent session (``clean_session`` off, a client id derived from the planner's
data directory), so QoS 1 messages published while the planner is down or reconnecting are kept
by the broker and delivered when it is back; paho acknowledges a message only after its
callback returned, i.e. after the event was journaled, so a kill -9 before that gets it again.
Retained messages are refused: they are a stored state that every (re)subscribe would fire again,
not a new press. paho's loop reconnects by itself (0.1 to 2 s back-off) and subscribes again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import threading
from pathlib import Path
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from fleet.planner.event_sources import EventMessageError, Fire, Tally

log = logging.getLogger("fleet.planner.events")
DEFAULT_PREFIX = "plantkg/events"
QOS = 1


def check_prefix(prefix: str) -> str:
    """The topic prefix without a trailing ``/``; MQTT wildcards and empty levels are refused."""
    text = prefix.strip().rstrip("/")
    if not text or "+" in text or "#" in text or "" in text.split("/") or "\x00" in text:
        raise EventMessageError("--events-topic", f"{prefix!r}: expected topic levels such as plantkg/events "
                                                  "(no wildcards, no empty level)")
    return text


def event_of(topic: str, payload: bytes, prefix: str) -> tuple[str, Any]:
    """``(event name, value)`` of one message on ``<prefix>/<name>``; :class:`EventMessageError` names the field."""
    head, sep, name = topic.rpartition("/")
    if not sep or head != prefix or not name:
        raise EventMessageError("topic", f"{topic!r} is not {prefix}/<event name>")
    try:
        value = json.loads(payload.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        shown = payload[:60].decode("utf-8", "replace")
        raise EventMessageError("payload", f"not JSON: {shown!r} (send e.g. true, 3.5, \"text\" or "
                                           "{\"value\": true})") from None
    if isinstance(value, dict):
        extra = sorted(set(value) - {"value"})
        if "value" not in value or extra:
            raise EventMessageError("payload", f"an object must be {{\"value\": ...}}, got the keys "
                                               f"{sorted(value)}")
        value = value["value"]
    if value is None or isinstance(value, (dict, list)):
        raise EventMessageError("payload", f"an event's value is a boolean, number or string, got {value!r}"[:200])
    return name, value


def client_id(data_dir: Path) -> str:
    """Stable per data directory: the broker keeps this planner's session (and its QoS 1 queue)."""
    return "plantkg-planner-events-" + hashlib.sha256(str(data_dir).encode("utf-8")).hexdigest()[:16]


class MqttEvents:
    """Subscribes ``<prefix>/+`` and fires what arrives; :meth:`status` for the planner's API."""

    def __init__(self, host: str, port: int, prefix: str, fire: Fire, data_dir: Path) -> None:
        self.host, self.port, self.prefix = host, port, check_prefix(prefix)
        self.tally = Tally("mqtt", fire)
        self.connected = threading.Event()
        self.connects = 0  # successful connections: more than one means paho reconnected
        self._stopping = False
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id(data_dir), clean_session=False)
        self.client.reconnect_delay_set(0.1, 2)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_subscribe = self._on_subscribe
        self.client.on_message = self._on_message

    @property
    def topic(self) -> str:
        return f"{self.prefix}/+"

    def start(self) -> None:
        self.client.connect_async(self.host, self.port, keepalive=15)
        self.client.loop_start()

    def stop(self) -> None:
        self._stopping = True
        self.client.disconnect()
        self.client.loop_stop()

    def status(self) -> dict[str, Any]:
        return {"broker": f"{self.host}:{self.port}", "topic": self.topic, "subscribed": self.connected.is_set(),
                "connects": self.connects, **self.tally.status()}

    def _on_connect(self, client: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any = None) -> None:
        if getattr(reason, "is_failure", False):
            log.warning("events: MQTT %s:%d refused the connection: %s", self.host, self.port, reason)
            return
        client.subscribe(self.topic, qos=QOS)  # on every connect: a restarted broker may have lost the session

    def _on_subscribe(self, _c: Any, _u: Any, _mid: int, reasons: list[Any], _p: Any = None) -> None:
        if any(getattr(r, "is_failure", False) for r in reasons):
            log.warning("events: MQTT %s:%d refused the subscription to %s: %s", self.host, self.port, self.topic,
                        ", ".join(map(str, reasons)))
            return
        self.connects += 1
        self.connected.set()  # subscribed (SUBACK): from now on every event published reaches the planner
        log.info("events: connected to MQTT %s:%d, subscribed to %s", self.host, self.port, self.topic)

    def _on_disconnect(self, *_: Any) -> None:
        if self.connected.is_set() and not self._stopping:
            log.warning("events: MQTT %s:%d connection lost; reconnecting", self.host, self.port)
        self.connected.clear()

    def _on_message(self, _c: Any, _u: Any, message: mqtt.MQTTMessage) -> None:
        if message.retain:
            self.tally.refuse(message.topic, "retain: a retained message is a stored state, not a new event "
                                             "(publish events without the retain flag)")
            return
        try:
            name, value = event_of(message.topic, bytes(message.payload), self.prefix)
        except EventMessageError as exc:
            self.tally.refuse(message.topic, str(exc))
            return
        try:
            self.tally.deliver(message.topic, name, value)
        except Exception as exc:  # a bug must not end paho's loop (it would stop every later event)
            log.exception("events: MQTT message on %s failed", message.topic)
            self.tally.refuse(message.topic, f"internal error {type(exc).__name__}: {exc}", counted=True)

"""The fleet manager's MQTT connection: subscriptions in, instant actions and orders out.

paho runs its network thread (``loop_start``); received messages go, untouched, into a bounded
queue the manager's main loop reads (a flood cannot grow memory without bound: when the queue is
full the oldest ``state`` messages are the ones that suffer, counted in ``dropped``). It
reconnects by itself (paho's back-off, 0.1 to 2 s) and subscribes again on every connect, so the
broker's retained ``connection`` messages are read again after a broker restart.

It logs in as plantkg's principal ``plantkg.fleet`` (the ``pk:principalName`` of
``fleet:fleet-manager`` in ontology/plantkg-fleet.ttl): on a closed Mosquitto the engine gave that
user exactly what the rules let the fleet manager read and write (docs/security.md); its password
is derived from the plant's principal key on this machine, as for plantkg's other principals. An
open broker without a users file does not check the login.

Outgoing messages get their VDA 5050 header from one ``HeaderCounter`` per vehicle (headerId
counted per topic), under a lock: the HTTP API and the main loop both send.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine.security import mqtt_client
from fleet.discovery.inbox import SUBSCRIPTIONS
from fleet.vda5050 import schemas, topics
from fleet.vda5050.headers import HeaderCounter
from fleet.vda5050.messages import Action, ActionParameter, BlockingType, InstantActions

log = logging.getLogger("fleet.manager")

#: The principal the fleet manager logs in as (fleet:fleet-manager's pk:principalName).
PRINCIPAL = "plantkg.fleet"


@dataclass(frozen=True)
class Received:
    topic: str
    payload: bytes
    retained: bool
    at: float  # time.monotonic() when it arrived


class MqttLink:
    def __init__(self, host: str, port: int, *, client_id: str | None = None, queue_size: int = 100_000,
                 login: mqtt_client.MqttLogin | None = None) -> None:
        self.host, self.port = host, port
        self.inbox: queue.Queue[Received] = queue.Queue(maxsize=queue_size)
        self.dropped = 0
        self.connected = threading.Event()
        self._headers: dict[tuple[str, str], HeaderCounter] = {}
        self._lock = threading.Lock()
        self._seq = 0
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2,
                                  client_id=client_id or f"plantkg-fleet-manager-{os.getpid()}")
        self.client.reconnect_delay_set(0.1, 2)
        mqtt_client.apply_login(self.client, login or mqtt_client.principal_login("mosquitto", PRINCIPAL))
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message

    def start(self) -> None:
        self.client.connect_async(self.host, self.port, keepalive=15)
        self.client.loop_start()

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def _on_connect(self, client: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any = None) -> None:
        if getattr(reason, "is_failure", False):
            log.warning("MQTT %s:%d refused the connection as %s: %s (on a closed broker the plant's "
                        "fleet manager resource must send to it, and this machine hold the plant's principal key)",
                        self.host, self.port, PRINCIPAL, reason)
            return
        client.subscribe([(t, 1) for t in SUBSCRIPTIONS])
        self.connected.set()
        log.info("connected to MQTT %s:%d, subscribed to %s", self.host, self.port, ", ".join(SUBSCRIPTIONS))

    def _on_disconnect(self, *_: Any) -> None:
        if self.connected.is_set():
            log.warning("MQTT %s:%d connection lost; reconnecting", self.host, self.port)
        self.connected.clear()

    def _on_message(self, _c: Any, _u: Any, message: mqtt.MQTTMessage) -> None:
        item = Received(message.topic, bytes(message.payload), bool(message.retain), time.monotonic())
        try:
            self.inbox.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    # ------------------------------------------------------------------ sending
    def header(self, manufacturer: str, serial: str, subtopic: str) -> dict[str, object]:
        with self._lock:
            counter = self._headers.get((manufacturer, serial))
            if counter is None:
                counter = self._headers.setdefault((manufacturer, serial), HeaderCounter(manufacturer, serial))
            return counter.next(subtopic)

    def next_id(self, prefix: str) -> str:
        with self._lock:
            self._seq += 1
            return f"{prefix}-{os.getpid()}-{int(time.time())}-{self._seq}"

    def instant_action(self, manufacturer: str, serial: str, action_type: str,
                       parameters: tuple[ActionParameter, ...] = ()) -> str:
        """Send one instant action (``factsheetRequest``, ``stateRequest``, ...); returns its id.
        The message is checked against the official schema first (raises SchemaError)."""
        action_id = self.next_id(action_type)
        message = InstantActions((Action(action_type, action_id, BlockingType.NONE, parameters),))
        wire = message.to_json(self.header(manufacturer, serial, "instantActions"))
        schemas.check("instantActions", wire)
        self.publish(topics.topic(manufacturer, serial, "instantActions"), wire, "instantActions")
        return action_id

    def publish(self, topic: str, message: dict[str, Any], subtopic: str) -> None:
        rule = topics.rule(subtopic)
        self.client.publish(topic, json.dumps(message, separators=(",", ":")), qos=rule.qos, retain=rule.retain)

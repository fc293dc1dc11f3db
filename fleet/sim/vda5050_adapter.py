"""VDA 5050 2.1 over MQTT for one simulated vehicle (paho-mqtt, one client per vehicle).

One MQTT client per vehicle because the last will is per connection (all of them driven by one
:class:`~fleet.sim.mqtt_pump.MqttPump` on the runner's thread): each vehicle's will is its
own ``connection`` = ``CONNECTIONBROKEN`` (QoS 1, retained), which the broker publishes when the
process dies without saying goodbye (kill -9, network loss). On connect the link subscribes to its
own ``order`` and ``instantActions`` (exact topics, never wildcards) and publishes ``ONLINE``
(QoS 1, retained); ``goodbye`` publishes ``OFFLINE`` (the runner pumps until the broker's PUBACK),
``close`` disconnects.

Received messages are checked against the official JSON schema first; a refused one becomes a
``validationError`` in the vehicle's ``errors`` (and a log line naming the path and reason) and
changes nothing else. ``state`` goes out on every event the vehicle reports and at least every
``state_interval`` seconds, ``visualization`` every ``visualization_interval`` seconds.
"""

from __future__ import annotations

import json
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from fleet.sim.mqtt_pump import MqttPump
from fleet.sim.vehicle import Outbox, SimVehicle
from fleet.vda5050 import schemas, topics
from fleet.vda5050.errors import SchemaError
from fleet.vda5050.headers import HeaderCounter
from fleet.vda5050.messages import Connection, ConnectionState, InstantActions, Order, visualization_json
from fleet.vda5050.topics import Subtopic

log = logging.getLogger("fleet.sim.vda5050")

MAX_STATE_INTERVAL = 30.0  # s: the standard's upper bound for the periodic state


@dataclass(frozen=True)
class LinkConfig:
    host: str = "127.0.0.1"
    port: int = 1883
    state_interval: float = MAX_STATE_INTERVAL
    visualization_interval: float | None = 1.0  # None: no visualization
    keepalive: int = 15
    username: str | None = None
    password: str | None = None

    def __post_init__(self) -> None:
        if not 0 < self.state_interval <= MAX_STATE_INTERVAL:
            raise ValueError(f"state_interval must be > 0 and at most {MAX_STATE_INTERVAL} s (VDA 5050), got {self.state_interval}")
        if self.visualization_interval is not None and self.visualization_interval <= 0:
            raise ValueError(f"visualization_interval must be > 0 s, got {self.visualization_interval}")


def _next_due(due: float, now: float, interval: float, restart: bool) -> float:
    """The next periodic send: on the grid ``due + interval`` (so tick jitter does not stretch the
    period), restarted from ``now`` after an event-driven send or when far behind (no bursts)."""
    following = due + interval
    return now + interval if restart or following <= now else following


def _dumps(message: dict[str, Any]) -> bytes:
    return json.dumps(message, separators=(",", ":")).encode("utf-8")


class Vda5050Link:
    def __init__(self, vehicle: SimVehicle, config: LinkConfig, pump: MqttPump) -> None:
        self.vehicle = vehicle
        self.pump = pump
        self.config = config
        spec = vehicle.spec
        self.headers = HeaderCounter(spec.manufacturer, spec.serial)
        self._topic = {s: topics.topic(spec.manufacturer, spec.serial, s) for s in Subtopic}
        self._inbox: deque[tuple[Subtopic, bytes]] = deque(maxlen=1000)  # a flood drops the oldest
        self._state_due = float("-inf")  # monotonic time the next periodic state is due
        self._visualization_due = float("-inf")
        self.refused = 0
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"plantkg-sim-{spec.serial}",
                                  clean_session=True)
        if config.username is not None:
            self.client.username_pw_set(config.username, config.password)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        broken = Connection(ConnectionState.CONNECTIONBROKEN).to_json(self.headers.next(Subtopic.CONNECTION))
        rule = topics.rule(Subtopic.CONNECTION)
        self.client.will_set(self._topic[Subtopic.CONNECTION], _dumps(broken), qos=rule.qos, retain=rule.retain)

    # ------------------------------------------------------------- lifecycle
    def start(self) -> None:
        """Non-blocking: the pump makes the connection (and every later reconnection)."""
        self.pump.add(self.client)  # first: it sets connect_timeout, which paho allows only before connecting
        self.client.connect_async(self.config.host, self.config.port, keepalive=self.config.keepalive)

    def connected(self) -> bool:
        return self.client.is_connected()

    def goodbye(self) -> Callable[[], bool]:
        """Publish OFFLINE; the returned check is true once the broker acknowledged it."""
        if not self.client.is_connected():
            return lambda: False
        info = self._send(Subtopic.CONNECTION, Connection(ConnectionState.OFFLINE).to_json(self.headers.next(Subtopic.CONNECTION)))
        return info.is_published

    def close(self) -> None:
        self.client.disconnect()
        self.pump.remove(self.client)

    # ------------------------------------------------------------- paho callbacks (runner thread, via the pump)
    def _on_connect(self, client: mqtt.Client, _userdata: Any, _flags: Any, reason: Any, _props: Any) -> None:
        if reason.is_failure:
            log.warning("%s: broker refused the connection: %s", self.vehicle.spec.serial, reason)
            return
        for sub in (Subtopic.ORDER, Subtopic.INSTANT_ACTIONS):
            client.subscribe(self._topic[sub], qos=topics.rule(sub).qos)
        self._send(Subtopic.CONNECTION, Connection(ConnectionState.ONLINE).to_json(self.headers.next(Subtopic.CONNECTION)))
        self._state_due = float("-inf")  # a fresh state right after (re)connecting

    def _on_message(self, _client: mqtt.Client, _userdata: Any, message: mqtt.MQTTMessage) -> None:
        kind = Subtopic.ORDER if message.topic == self._topic[Subtopic.ORDER] else Subtopic.INSTANT_ACTIONS
        self._inbox.append((kind, bytes(message.payload)))

    # ------------------------------------------------------------- runner
    def poll(self) -> None:
        while self._inbox:
            kind, payload = self._inbox.popleft()
            try:
                data = schemas.parse(kind, payload)
            except SchemaError as exc:
                self.refused += 1
                log.warning("%s: refused %s: %s", self.vehicle.spec.serial, kind.value, exc.message)
                self.vehicle.refuse_message(kind.value, f"{exc.path or '(message)'}: {exc.reason}")
                continue
            if kind is Subtopic.ORDER:
                order = Order.from_json(data)
                if not self.vehicle.receive_order(order):
                    log.info("%s: order %s/%s refused: %s", self.vehicle.spec.serial, order.order_id,
                             order.order_update_id, self.vehicle.errors[-1].description)
            else:
                self.vehicle.receive_instant_actions(InstantActions.from_json(data))

    def publish(self, outbox: Outbox, now: float) -> None:
        if not self.client.is_connected():
            return
        if outbox.state or now >= self._state_due:
            self._send(Subtopic.STATE, self.vehicle.state().to_json(self.headers.next(Subtopic.STATE)))
            self._state_due = _next_due(self._state_due, now, self.config.state_interval, outbox.state)
        if outbox.factsheet:
            self._send(Subtopic.FACTSHEET, self.vehicle.factsheet().to_json(self.headers.next(Subtopic.FACTSHEET)))
        interval = self.config.visualization_interval
        if interval is not None and now >= self._visualization_due:
            v = self.vehicle
            self._send(Subtopic.VISUALIZATION, visualization_json(self.headers.next(Subtopic.VISUALIZATION), v.position(), (v.motion.v, v.motion.omega)))
            self._visualization_due = _next_due(self._visualization_due, now, interval, False)

    def _send(self, subtopic: Subtopic, message: dict[str, Any]) -> mqtt.MQTTMessageInfo:
        rule = topics.rule(subtopic)
        return self.client.publish(self._topic[subtopic], _dumps(message), qos=rule.qos, retain=rule.retain)

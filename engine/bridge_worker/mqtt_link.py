"""The worker's one MQTT connection: MQTT v5, a persistent session, manual acknowledgements.

One client both subscribes (MQTT -> Kafka routes) and publishes (Kafka -> MQTT routes), and its
subscriptions carry ``no_local``: a topic bridged both ways never comes back to the worker that
published it. The session outlives the worker (``clean_start`` false, a week of session expiry), so
Mosquitto queues the subscribed topics while the worker is down or restarting. paho's own thread
reconnects forever with a capped backoff; a broker down at start is simply reached later.

Publishing is tied to a connection: each (dis)connect starts a new ``generation``, and
:meth:`MqttLink.publish` refuses a message meant for an older one. On connect, the messages paho
still holds from the previous connection are dropped instead of being sent again: they are newer
than what the broker may have lost in a crash, and the Kafka -> MQTT half publishes everything
again from its last commit, in order (paho 2 has no public call for this; see ``_drop_unsent``).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from engine.bridge_worker.config import Direction, WorkerConfig
from engine.bridge_worker.health import Health
from engine.bridge_worker.ngsi_config import NgsiWorkerConfig
from engine.security import principal_key

log = logging.getLogger("plantkg.bridge.mqtt")

SESSION_EXPIRY = 7 * 24 * 3600      # seconds Mosquitto keeps the session of a worker that is gone
RECEIVE_MAXIMUM = 1000              # unacknowledged messages Mosquitto may send us at once
RECONNECT_DELAY = (1, 5)            # paho's reconnect backoff: first delay, cap (seconds)
KEEPALIVE = 10


class MqttLink:
    """Owns the paho client. ``on_message``, ``on_puback`` and ``on_connection`` are set by the
    forwarding halves and called from paho's thread."""

    def __init__(self, cfg: WorkerConfig | NgsiWorkerConfig, health: Health,
                 topics: list[tuple[str, int]] | None = None) -> None:
        """``topics``: (topic, QoS) to subscribe; default: the MQTT -> Kafka routes of ``cfg``."""
        self.cfg = cfg
        self.health = health
        self.on_message: Callable[[mqtt.MQTTMessage], None] = lambda msg: None
        self.on_puback: Callable[[int], None] = lambda mid: None
        self.on_connection: list[Callable[[bool, int], None]] = []
        self.generation = 0
        self._publish_lock = threading.Lock()
        if topics is None:
            assert isinstance(cfg, WorkerConfig)
            topics = [(r.mqtt_topic, r.qos) for r in cfg.routes_of(Direction.MQTT_TO_KAFKA)]
        self._subscriptions = [(topic, SubscribeOptions(qos=qos, noLocal=True)) for topic, qos in topics]
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=cfg.client_id,
                             protocol=mqtt.MQTTv5, manual_ack=True)
        if cfg.mqtt_username is not None:  # a plantkg principal: its password derives from the key
            client.username_pw_set(cfg.mqtt_username, principal_key.password_for(cfg.mqtt_username))
        if cfg.mqtt_ca_file is not None:   # the broker speaks TLS: verify it against the plant CA
            client.tls_set(ca_certs=str(cfg.mqtt_ca_file))
        client.reconnect_delay_set(*RECONNECT_DELAY)
        client.max_inflight_messages_set(RECEIVE_MAXIMUM)
        client.max_queued_messages_set(0)
        client.on_connect = self._connected
        client.on_connect_fail = self._connect_failed
        client.on_disconnect = self._disconnected
        client.on_subscribe = self._subscribed
        client.on_message = lambda _c, _u, msg: self.on_message(msg)
        client.on_publish = lambda _c, _u, mid, _rc, _p: self.on_puback(mid)
        self.client = client
        if not all(hasattr(client, a) for a in ("_out_messages", "_out_message_mutex", "_inflight_messages")):
            raise RuntimeError("this paho-mqtt has no _out_messages: pin paho-mqtt 2.x (see _drop_unsent)")

    def start(self) -> None:
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = SESSION_EXPIRY
        props.ReceiveMaximum = RECEIVE_MAXIMUM
        self.client.connect_async(self.cfg.mqtt_host, self.cfg.mqtt_port, KEEPALIVE,
                                  clean_start=False, properties=props)
        self.client.loop_start()

    def stop(self) -> None:
        """Disconnect (the session stays on the broker) and end paho's thread."""
        self.client.disconnect()
        self.client.loop_stop()
        self.health.set(mqtt_connected=False, subscribed=False)

    def ack(self, mid: int, qos: int) -> None:
        self.client.ack(mid, qos)

    def publish(self, generation: int, topic: str, payload: bytes, qos: int) -> mqtt.MQTTMessageInfo | None:
        """Publish on connection ``generation``; None (nothing sent) if it is not the current one."""
        with self._publish_lock:
            if generation != self.generation or not self.health.mqtt_connected:
                return None
            return self.client.publish(topic, payload, qos=qos)

    def _drop_unsent(self) -> None:
        """Forget the QoS>0 messages paho would send again on this new connection."""
        with self.client._out_message_mutex:
            dropped = len(self.client._out_messages)
            self.client._out_messages.clear()
            self.client._inflight_messages = 0
        if dropped:
            log.info("dropped %d messages unacknowledged by the previous connection", dropped)

    # paho callbacks (paho's thread)
    def _connected(self, client: mqtt.Client, _u: Any, flags: Any, reason: Any, props: Any) -> None:
        if reason.is_failure:
            self.health.error(f"MQTT {self.cfg.mqtt_host}:{self.cfg.mqtt_port} refused the connection: {reason}")
            return
        server_max = getattr(props, "ReceiveMaximum", RECEIVE_MAXIMUM)
        if server_max < RECEIVE_MAXIMUM:  # paho cannot lower its window on an open connection
            log.warning("the broker takes %d unacknowledged QoS>0 messages at once, the worker "
                        "sends up to %d: raise its max_inflight_messages", server_max, RECEIVE_MAXIMUM)
        log.info("connected to %s:%s (session present: %s)", self.cfg.mqtt_host, self.cfg.mqtt_port,
                 flags.session_present)
        if self._subscriptions:
            client.subscribe(self._subscriptions)
        with self._publish_lock:  # paho sends its leftovers right after this callback returns
            self._drop_unsent()
            self.generation += 1
            self.health.set(mqtt_connected=True)
            for hook in self.on_connection:
                hook(True, self.generation)

    def _connect_failed(self, _c: mqtt.Client, _u: Any) -> None:
        self.health.error(f"MQTT {self.cfg.mqtt_host}:{self.cfg.mqtt_port} unreachable; retrying")

    def _disconnected(self, _c: mqtt.Client, _u: Any, _f: Any, reason: Any, _p: Any) -> None:
        with self._publish_lock:
            was_up = self.health.mqtt_connected
            self.generation += 1
            self.health.set(mqtt_connected=False, subscribed=False)
        if was_up and reason.value != 0:  # 0: our own disconnect at stop
            self.health.error(f"MQTT {self.cfg.mqtt_host}:{self.cfg.mqtt_port} connection lost: {reason}")
        if was_up:
            for hook in self.on_connection:
                hook(False, self.generation)

    def _subscribed(self, _c: mqtt.Client, _u: Any, _mid: int, reasons: list[Any], _p: Any) -> None:
        refused = [str(r) for r in reasons if r.is_failure]
        if refused:
            self.health.error(f"MQTT subscription refused: {', '.join(refused)}")
        else:
            self.health.set(subscribed=True)

"""The worker's one MQTT connection: MQTT v5, a persistent session, manual acknowledgements.

One client both subscribes (MQTT -> Kafka routes) and publishes (Kafka -> MQTT routes), and its
subscriptions carry ``no_local``: a topic bridged both ways never comes back to the worker that
published it. The session outlives the worker (``clean_start`` false, a week of session expiry), so
Mosquitto queues the subscribed topics while the worker is down or restarting. The client
(:mod:`engine.bridge_worker.mqtt_client`, the worker's own, for speed) reconnects forever with a
capped backoff; a broker down at start is simply reached later.

Publishing is tied to a connection: each (dis)connect starts a new ``generation``, and
:meth:`MqttLink.publish` refuses a message meant for an older one. What was in flight or waiting
when a connection dropped is never sent again by the client: the Kafka -> MQTT half publishes
everything again from its last commit, in order.

Acknowledgements: :meth:`ack` sends a PUBACK at once; :meth:`ack_later` only queues it: the
client's I/O thread writes what is queued on its next pass, and another thread that queued a
batch wakes it with :meth:`flush`. The MQTT -> Kafka half serves Kafka's delivery reports on the
I/O thread itself (:meth:`pump_on_io_thread`), so its PUBACKs leave on that thread's next write.
"""

from __future__ import annotations

import logging
import ssl
import threading
from collections.abc import Callable, Iterable

from engine.bridge_worker import mqtt_wire as wire
from engine.bridge_worker.config import Direction, WorkerConfig
from engine.bridge_worker.health import Health
from engine.bridge_worker.mqtt_client import MqttClient
from engine.bridge_worker.ngsi_config import NgsiWorkerConfig
from engine.security import principal_key

log = logging.getLogger("plantkg.bridge.mqtt")

SESSION_EXPIRY = 7 * 24 * 3600      # seconds Mosquitto keeps the session of a worker that is gone
RECEIVE_MAXIMUM = 1000              # unacknowledged messages Mosquitto may send us at once (default)
RECONNECT_DELAY = (1, 5)            # reconnect backoff: first delay, cap (seconds)
KEEPALIVE = 10


class MqttLink:
    """Owns the MQTT client. ``on_message``, ``on_pubacks`` and ``on_connection`` are set by the
    forwarding halves and called from the client's I/O thread."""

    def __init__(self, cfg: WorkerConfig | NgsiWorkerConfig, health: Health,
                 topics: list[tuple[str, int]] | None = None, receive_maximum: int = RECEIVE_MAXIMUM) -> None:
        """``topics``: (topic, QoS) to subscribe; default: the MQTT -> Kafka routes of ``cfg``.
        ``receive_maximum``: the unacknowledged messages the worker asks Mosquitto to send at
        most (:attr:`receive_maximum`; the halves hold reading there, see :meth:`hold_reading_while`)."""
        self.cfg = cfg
        self.receive_maximum = receive_maximum
        self.health = health
        self.on_message: Callable[[wire.Publish], None] = lambda msg: None
        self.on_pubacks: Callable[[list[int]], None] = lambda mids: None
        self.on_connection: list[Callable[[bool, int], None]] = []
        self.generation = 0
        self._publish_lock = threading.Lock()
        if topics is None:
            assert isinstance(cfg, WorkerConfig)
            topics = [(r.mqtt_topic, r.qos) for r in cfg.routes_of(Direction.MQTT_TO_KAFKA)]
        # a plantkg principal logs in with the password it derives from the key; a TLS broker is
        # verified against the plant CA
        username = cfg.mqtt_username
        password = principal_key.password_for(username).encode("utf-8") if username is not None else None
        context = ssl.create_default_context(cafile=str(cfg.mqtt_ca_file)) if cfg.mqtt_ca_file is not None else None
        client = MqttClient(cfg.mqtt_host, cfg.mqtt_port, cfg.client_id, keepalive=KEEPALIVE,
                            session_expiry=SESSION_EXPIRY, receive_maximum=receive_maximum,
                            reconnect_delay=RECONNECT_DELAY, username=username, password=password,
                            ssl_context=context)
        client.subscriptions = [(topic, qos, True) for topic, qos in topics]
        client.on_connect = self._connected
        client.on_connect_failed = self._connect_failed
        client.on_disconnect = self._disconnected
        client.on_suback = self._subscribed
        client.on_message = lambda msg: self.on_message(msg)
        client.on_pubacks = lambda mids: self.on_pubacks(mids)
        self.client = client

    def start(self) -> None:
        self.client.start()

    def stop(self) -> None:
        """Disconnect (the session stays on the broker) and end the client's thread."""
        self.client.stop()
        self.health.set(mqtt_connected=False, subscribed=False)

    def ack(self, mid: int, qos: int) -> None:
        """Send the PUBACK of message ``mid`` now (nothing for QoS 0)."""
        if qos:
            self.client.send(wire.puback(mid))

    def ack_later(self, mid: int, qos: int) -> None:
        """Queue the PUBACK of message ``mid`` for the next :meth:`flush`."""
        if qos:
            self.client.queue(wire.puback(mid))

    def flush(self) -> None:
        self.client.flush()

    def hold_reading_while(self, full: Callable[[], bool]) -> None:
        """Read no more messages while ``full()``: the half has as many unacknowledged messages
        as it takes (the broker may send more than the Receive Maximum asked for)."""
        self.client.can_read = lambda: not full()

    def pump_on_io_thread(self, pump: Callable[[], float]) -> None:
        """Call ``pump()`` on every pass of the client's I/O thread while connected; it returns
        the longest the thread may then wait for the socket (s)."""
        self.client.pump = pump

    def unsubscribe(self, topic: str) -> None:
        self.client.unsubscribe([topic])

    def publish_many(self, generation: int, messages: Iterable[tuple[str, bytes, int]]) -> list[int] | None:
        """Queue messages (topic, payload, QoS), in order, on connection ``generation``; their
        packet ids (0 for QoS 0), or None (none sent) if that connection is not the current one.
        Sent at the next :meth:`flush`."""
        with self._publish_lock:
            if generation != self.generation or not self.health.mqtt_connected:
                return None
            return self.client.publish_many(messages)

    # client callbacks (its I/O thread)
    def _connected(self, connack: wire.Connack) -> None:
        if connack.receive_maximum < RECEIVE_MAXIMUM:
            log.info("the broker takes %d unacknowledged QoS>0 messages at once (its "
                     "max_inflight_messages); more wait in the worker", connack.receive_maximum)
        log.info("connected to %s:%s (session present: %s)", self.cfg.mqtt_host, self.cfg.mqtt_port,
                 connack.session_present)
        with self._publish_lock:
            self.generation += 1
            self.health.set(mqtt_connected=True)
            for hook in self.on_connection:
                hook(True, self.generation)

    def _connect_failed(self, why: str) -> None:
        self.health.error(f"MQTT {self.cfg.mqtt_host}:{self.cfg.mqtt_port} unreachable ({why}); retrying")

    def _disconnected(self, why: str | None) -> None:
        with self._publish_lock:
            was_up = self.health.mqtt_connected
            self.generation += 1
            self.health.set(mqtt_connected=False, subscribed=False)
        if was_up and why is not None:  # None: our own disconnect at stop
            self.health.error(f"MQTT {self.cfg.mqtt_host}:{self.cfg.mqtt_port} connection lost: {why}")
        if was_up:
            for hook in self.on_connection:
                hook(False, self.generation)

    def _subscribed(self, reasons: list[int]) -> None:
        refused = [f"0x{r:02x}" for r in reasons if r >= 0x80]
        if refused:
            self.health.error(f"MQTT subscription refused: reason codes {', '.join(refused)}")
        else:
            self.health.set(subscribed=True)

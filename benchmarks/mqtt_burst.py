"""A burst of QoS-1 MQTT messages sent to many brokers at once, each message timed twice:
publish → PUBACK (the broker has it) and publish → delivery (a subscriber on that broker has it).

All clients (publishers and one subscriber per broker) are driven by one thread through paho's
external-loop API and a selector, so a hundred brokers need no hundred threads. The burst is sent
as simultaneously as one thread can: every message is handed to its socket in one loop (its
publish time taken just before), and only then are answers read; the time the loop took is
reported as ``send_s`` — the spread of "simultaneous" — and is part of early messages' latency,
as it would be on a real network interface.

Distribution of the messages over the brokers:

- ``spread``: one publisher per broker, message *i* goes to broker *i mod N*;
- ``one-to-one``: one publisher (its own connection) per message, message *i* to broker *i mod N* —
  many devices sending one reading each at the same time.

Every payload starts with its 8-byte index, so a delivery is matched to its publish.
"""

from __future__ import annotations

import selectors
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import paho.mqtt.client as mqtt

MODES = ("spread", "one-to-one")
TOPIC = "bench/load"
MISC_S = 0.5


@dataclass(frozen=True)
class BurstResult:
    """Per-message latencies in seconds (lost messages are absent) and the burst's send time."""

    messages: int
    brokers: int
    size: int
    mode: str
    send_s: float
    ack_s: tuple[float, ...]
    delivery_s: tuple[float, ...]

    @property
    def lost(self) -> int:
        return self.messages - min(len(self.ack_s), len(self.delivery_s))


@dataclass
class _Clients:
    """Clients of one burst, their sockets registered with one selector."""

    selector: selectors.DefaultSelector = field(default_factory=selectors.DefaultSelector)
    clients: list[mqtt.Client] = field(default_factory=list)
    _misc_due: float = 0.0

    def add(self, host: str, port: int, client_id: str) -> mqtt.Client:
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id)
        client.max_inflight_messages_set(0)  # 0 = unlimited: the burst is not held back client-side
        client.max_queued_messages_set(0)
        client.connect(host, port, keepalive=60)
        self.selector.register(client.socket(), selectors.EVENT_READ, client)
        self.clients.append(client)
        return client

    def pump(self, timeout: float) -> None:
        """Write what is pending, read what arrived (within ``timeout`` s), run keep-alives (at
        most every MISC_S: with hundreds of clients, doing it on every read would cost more than
        the reads)."""
        for client in self.clients:
            if client.want_write():
                client.loop_write()
        for key, _ in self.selector.select(timeout):
            key.data.loop_read()
        if time.monotonic() >= self._misc_due:
            for client in self.clients:
                client.loop_misc()
            self._misc_due = time.monotonic() + MISC_S

    def until(self, done: Callable[[], bool], deadline: float, what: str) -> bool:
        """Pump until ``done()``; False when ``deadline`` s pass first (``what`` is for errors)."""
        end = time.monotonic() + deadline
        while not done():
            if time.monotonic() > end:
                return False
            self.pump(0.001)
        return True

    def close(self) -> None:
        for client in self.clients:
            try:
                self.selector.unregister(client.socket())
            except (KeyError, ValueError, TypeError):
                pass
            client.disconnect()
            client.loop_write()
        self.selector.close()


class BurstRig:
    """Connected publishers and subscribers for bursts against ``brokers`` (host, port) pairs;
    ``max_messages`` publishers are kept for the one-to-one mode. Use as a context manager."""

    def __init__(self, brokers: Sequence[tuple[str, int]], max_messages: int, connect_deadline: float = 60.0):
        self.brokers = list(brokers)
        self._c = _Clients()
        self._sent: dict[int, float] = {}
        self._acked: dict[int, float] = {}
        self._delivered: dict[int, float] = {}
        self._mid: dict[tuple[int, int], int] = {}
        self._subscribed = 0
        try:
            self.subscribers = [self._subscriber(i, h, p) for i, (h, p) in enumerate(self.brokers)]
            self.per_broker = [self._publisher(f"pub-b{i}", h, p) for i, (h, p) in enumerate(self.brokers)]
            self.per_message = [self._publisher(f"pub-m{i}", *self.brokers[i % len(self.brokers)])
                                for i in range(max_messages)]
            everyone = self._c.clients
            if not self._c.until(lambda: all(c.is_connected() for c in everyone), connect_deadline, "connect"):
                raise TimeoutError(f"not all of {len(everyone)} MQTT clients connected in {connect_deadline} s")
            for s in self.subscribers:
                s.subscribe(TOPIC, qos=1)
            if not self._c.until(lambda: self._subscribed == len(self.subscribers), connect_deadline, "subscribe"):
                raise TimeoutError("not every subscriber got its SUBACK")
        except BaseException:
            self._c.close()
            raise

    def __enter__(self) -> BurstRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self._c.close()

    def _subscriber(self, i: int, host: str, port: int) -> mqtt.Client:
        client = self._c.add(host, port, f"sub-{i}")
        client.on_subscribe = lambda *a: setattr(self, "_subscribed", self._subscribed + 1)
        client.on_message = self._on_message
        return client

    def _publisher(self, name: str, host: str, port: int) -> mqtt.Client:
        client = self._c.add(host, port, name)
        client.on_publish = self._on_publish
        return client

    def _on_publish(self, client: mqtt.Client, userdata: object, mid: int, *rest: object) -> None:
        index = self._mid.pop((id(client), mid), None)
        if index is not None:
            self._acked[index] = time.perf_counter()

    def _on_message(self, client: mqtt.Client, userdata: object, msg: mqtt.MQTTMessage) -> None:
        self._delivered.setdefault(int.from_bytes(msg.payload[:8], "big"), time.perf_counter())

    def burst(self, messages: int, size: int, mode: str, deadline: float = 60.0) -> BurstResult:
        """Send ``messages`` payloads of ``size`` bytes (>= 8) at once; wait for their acks and
        deliveries (at most ``deadline`` s); return the latencies."""
        if mode not in MODES:
            raise ValueError(f"mode {mode!r}: expected one of {MODES}")
        if mode == "one-to-one" and messages > len(self.per_message):
            raise ValueError(f"{messages} messages but only {len(self.per_message)} one-to-one publishers")
        filler = b"x" * max(0, size - 8)
        payloads = [i.to_bytes(8, "big") + filler for i in range(messages)]
        senders = self.per_message if mode == "one-to-one" else self.per_broker
        self._sent, self._acked, self._delivered, self._mid = {}, {}, {}, {}
        began = time.perf_counter()
        for i, payload in enumerate(payloads):
            client = senders[i % len(senders)] if mode == "spread" else senders[i]
            self._sent[i] = time.perf_counter()
            info = client.publish(TOPIC, payload, qos=1)
            self._mid[(id(client), info.mid)] = i
        send_s = time.perf_counter() - began
        self._c.until(lambda: len(self._acked) == messages and len(self._delivered) == messages, deadline, "burst")
        return BurstResult(messages, len(self.brokers), size, mode, send_s,
                           tuple(self._acked[i] - self._sent[i] for i in sorted(self._acked)),
                           tuple(self._delivered[i] - self._sent[i] for i in sorted(self._delivered)))

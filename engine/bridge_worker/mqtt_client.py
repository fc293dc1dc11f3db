"""The bridge worker's MQTT 5 client: one connection, kept up by one I/O thread.

The I/O thread owns the socket: it connects (retrying forever with a capped backoff), sends
CONNECT and the subscriptions, reads everything the broker sends in large pieces and cuts it into
packets (:class:`engine.bridge_worker.mqtt_wire.Decoder`), and writes what other threads queued.
Other threads never touch the socket (a TLS socket must not be read and written from two threads
at once): they append packets to the outgoing buffer and :meth:`MqttClient.flush` wakes the I/O
thread once per batch, so a thousand PUBACKs leave in one write instead of a thousand.

QoS-1 publishing keeps to the broker's Receive Maximum: past it, messages wait in order in this
client and leave as PUBACKs free the window. A connection lost forgets what was in flight or
waiting (the owner knows: ``on_disconnect``); nothing is sent again by this client.

Callbacks run on the I/O thread and must not block: ``on_connect(connack)``, ``on_disconnect(why)``
(None when :meth:`stop` ended it), ``on_message(publish)``, ``on_pubacks(mids)`` (the PUBACKs of
one read, in order), ``on_suback(reason codes)``, ``on_connect_failed(why)``; and ``pump()``, called
on every pass of a connection's loop, which returns how long the thread may wait for the socket
before the next.

Receiving keeps to a window too: Mosquitto 2.0.11 does not hold to the client's Receive Maximum
(it had 9,991 QoS-1 messages unacknowledged towards a worker that asked for at most 1,000), so
the client handles no further PUBLISH while ``can_read()`` says no (what it already read waits in
order) and stops reading, so TCP holds the broker back; PINGREQs still leave meanwhile, so the
broker keeps the connection.
"""

from __future__ import annotations

import logging
import select
import socket
import ssl
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from engine.bridge_worker import mqtt_wire as wire

log = logging.getLogger("plantkg.bridge.mqtt")

READ_SIZE = 1 << 16          # bytes asked of the socket per read
TICK = 0.5                   # seconds between keep-alive checks when nothing happens
WRITE_EVERY = 64             # packets handled between writes of what other threads queued
CONNECT_TIMEOUT = 10.0       # seconds for TCP connect + CONNACK


class ConnectionLost(Exception):
    """The connection cannot go on; the text says why."""


class MqttClient:
    def __init__(self, host: str, port: int, client_id: str, *, keepalive: int, session_expiry: int,
                 receive_maximum: int, reconnect_delay: tuple[float, float] = (1.0, 5.0),
                 clean_start: bool = False, username: str | None = None, password: bytes | None = None,
                 ssl_context: ssl.SSLContext | None = None) -> None:
        self.host, self.port, self.client_id = host, port, client_id
        self.keepalive, self.session_expiry, self.receive_maximum = keepalive, session_expiry, receive_maximum
        self.reconnect_delay, self.clean_start = reconnect_delay, clean_start
        self.username, self.password, self.ssl_context = username, password, ssl_context
        self.subscriptions: list[tuple[str, int, bool]] = []   # (topic, QoS, no_local), sent on connect
        self.on_connect: Callable[[wire.Connack], None] = lambda c: None
        self.on_disconnect: Callable[[str | None], None] = lambda why: None
        self.on_message: Callable[[wire.Publish], None] = lambda p: None
        self.on_pubacks: Callable[[list[int]], None] = lambda mids: None
        self.on_suback: Callable[[list[int]], None] = lambda reasons: None
        self.on_connect_failed: Callable[[str], None] = lambda why: None
        #: Asked before each read: False holds back reading (TCP then holds the broker back)
        #: while the owner has as many messages unacknowledged as it takes.
        self.can_read: Callable[[], bool] = lambda: True
        #: Called on every pass of the I/O thread while connected, before it writes what is
        #: queued and waits: work the owner wants done on this thread (the MQTT -> Kafka half
        #: serves Kafka's delivery reports here). Returns the longest the thread may then wait
        #: for the socket, in seconds (at most TICK is used).
        self.pump: Callable[[], float] = lambda: TICK
        self._lock = threading.Lock()            # guards everything below
        self._out = bytearray()
        self._connected = False
        self._quota = 0                          # the broker's Receive Maximum of this connection
        self._inflight: set[int] = set()         # QoS-1 packet ids sent, not yet PUBACKed
        self._waiting: deque[tuple[int, bytes]] = deque()   # QoS-1 packets past the window
        self._next_mid = 0
        self._stopping = threading.Event()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._thread = threading.Thread(target=self._run, name=f"mqtt-{client_id}", daemon=True)

    # --- other threads -------------------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Send what is queued and a normal DISCONNECT (the session stays), end the thread."""
        self._stopping.set()
        self._wake()
        self._thread.join(timeout)

    @property
    def connected(self) -> bool:
        return self._connected

    def queue(self, packet: bytes) -> bool:
        """Append a packet for the next flush; False (dropped) while not connected."""
        with self._lock:
            if not self._connected:
                return False
            self._out += packet
            return True

    def flush(self) -> None:
        """Have the I/O thread write what is queued."""
        if self._out:
            self._wake()

    def send(self, packet: bytes) -> bool:
        ok = self.queue(packet)
        if ok:
            self._wake()
        return ok

    def publish_many(self, messages: Iterable[tuple[str, bytes, int]]) -> list[int] | None:
        """Queue PUBLISHes of (topic, payload, QoS), in order; their packet ids (0 for QoS 0), or
        None (nothing queued) when not connected. A QoS-1 message past the broker's window waits
        here, in order. One hold of the lock for all: taking it per message, the main thread
        kept waiting on the I/O thread, which takes it for each read of PUBACKs (py-spy profiles
        of benchmarks.bench_bridge's kafka-mqtt path at full speed)."""
        mids: list[int] = []
        with self._lock:
            if not self._connected:
                return None
            for topic, payload, qos in messages:
                if qos == 0:
                    self._out += wire.publish(topic, payload, 0)
                    mids.append(0)
                    continue
                mid = self._allocate_mid()
                packet = wire.publish(topic, payload, 1, mid)
                if len(self._inflight) < self._quota and not self._waiting:
                    self._inflight.add(mid)
                    self._out += packet
                else:
                    self._waiting.append((mid, packet))
                mids.append(mid)
        return mids

    def subscribe(self, topics: list[tuple[str, int, bool]]) -> None:
        with self._lock:
            mid = self._allocate_mid()
        self.send(wire.subscribe(mid, topics))

    def unsubscribe(self, topics: list[str]) -> None:
        with self._lock:
            mid = self._allocate_mid()
        self.send(wire.unsubscribe(mid, topics))

    def _allocate_mid(self) -> int:
        """A packet id not in flight (the caller holds the lock)."""
        while True:
            self._next_mid = self._next_mid % 65535 + 1
            if self._next_mid not in self._inflight:
                return self._next_mid

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, OSError):
            pass  # already awake (the pair's buffer is full) or closed at stop

    # --- the I/O thread ------------------------------------------------------------------------

    def _run(self) -> None:
        delay = self.reconnect_delay[0]
        while not self._stopping.is_set():
            try:
                sock, connack = self._connect()
            except (OSError, ConnectionLost, wire.MalformedPacket) as exc:
                self.on_connect_failed(str(exc) or type(exc).__name__)
                self._stopping.wait(delay)
                delay = min(delay * 2, self.reconnect_delay[1])
                continue
            delay = self.reconnect_delay[0]
            why: str | None = None
            try:
                self._session(sock, connack)
            except (OSError, ConnectionLost, wire.MalformedPacket) as exc:
                why = str(exc) or type(exc).__name__
            except Exception as exc:  # a fault of a callback: log it; unacknowledged messages come again
                log.exception("MQTT connection to %s:%s dropped after an internal error", self.host, self.port)
                why = f"internal error: {exc!r}"
            finally:
                with self._lock:
                    self._connected = False
                    self._out.clear()
                    self._inflight.clear()
                    self._waiting.clear()
                try:
                    sock.close()
                except OSError:
                    pass
            self.on_disconnect(why)
            if why is not None:
                self._stopping.wait(delay)
        self._wake_r.close()
        self._wake_w.close()

    def _connect(self) -> tuple[socket.socket, wire.Connack]:
        sock = socket.create_connection((self.host, self.port), timeout=CONNECT_TIMEOUT)
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            if self.ssl_context is not None:
                sock = self.ssl_context.wrap_socket(sock, server_hostname=self.host)
            sock.sendall(wire.connect(self.client_id, self.keepalive, clean_start=self.clean_start,
                                      session_expiry=self.session_expiry,
                                      receive_maximum=self.receive_maximum,
                                      username=self.username, password=self.password))
            decoder = wire.Decoder()
            deadline = time.monotonic() + CONNECT_TIMEOUT
            while True:
                data = sock.recv(4096)
                if not data:
                    raise ConnectionLost("closed by the broker before CONNACK")
                packets = decoder.feed(data)
                if packets:
                    break
                if time.monotonic() > deadline:
                    raise ConnectionLost("no CONNACK")
            if packets[0].kind != wire.CONNACK:
                raise ConnectionLost(f"expected CONNACK, got packet type {packets[0].kind}")
            connack = wire.parse_connack(packets[0].body)
            if connack.reason >= 0x80:
                raise ConnectionLost(f"connection refused: reason code 0x{connack.reason:02x}")
            self._decoder = decoder
            self._early = packets[1:]
            return sock, connack
        except BaseException:
            sock.close()
            raise

    def _session(self, sock: socket.socket, connack: wire.Connack) -> None:
        sock.settimeout(None)
        sock.setblocking(False)
        with self._lock:
            self._quota = max(1, connack.receive_maximum)
            self._connected = True
        self.on_connect(connack)
        if self.subscriptions:
            self.subscribe(self.subscriptions)
        keepalive = max(1, self.keepalive)
        ping_sent: float | None = None
        self._backlog = deque(self._early)
        self._sock = sock
        self._last_sent = time.monotonic()
        while True:
            if self._stopping.is_set():
                self._write_out(wire.DISCONNECT_PACKET)
                return
            wait = min(TICK, self.pump())
            self._write_out()
            self._handle_backlog()
            reading = not self._backlog and self.can_read()
            if not reading:
                ping_sent = None   # no answer can be read now: time it from the next PINGREQ
            if reading and isinstance(sock, ssl.SSLSocket) and sock.pending():
                readable, woke = True, False   # TLS bytes already decrypted: no select needed
            else:
                ready = select.select([sock, self._wake_r] if reading else [self._wake_r], [], [], wait)[0]
                readable, woke = sock in ready, self._wake_r in ready
            if woke:
                try:
                    self._wake_r.recv(65536)
                except BlockingIOError:
                    pass
            if readable:
                try:
                    data: bytes | None = sock.recv(READ_SIZE)
                except (BlockingIOError, ssl.SSLWantReadError):
                    data = None
                if data == b"":
                    raise ConnectionLost("connection closed by the broker")
                if data:
                    ping_sent = None
                    self._backlog.extend(self._decoder.feed(data))
                    self._handle_backlog()
            now = time.monotonic()
            if reading and ping_sent is not None and now - ping_sent > keepalive:
                raise ConnectionLost(f"no answer from the broker for {keepalive} s (keep-alive)")
            if now - self._last_sent >= keepalive / 2:  # the broker hears from us, reading or not
                with self._lock:
                    self._out += wire.PINGREQ_PACKET
                if ping_sent is None and reading:
                    ping_sent = now

    def _write_out(self, extra: bytes = b"") -> None:
        """Write what other threads queued (and ``extra``) now."""
        with self._lock:
            out = bytes(self._out) + extra
            self._out.clear()
        if out:
            _send_all(self._sock, out)
            self._last_sent = time.monotonic()

    def _handle_backlog(self) -> None:
        """Handle the packets read, in order, up to a PUBLISH that would take more than the
        owner's window (``can_read``): it and those after it wait for the window to open.
        What other threads queued meanwhile (PUBACKs) leaves every WRITE_EVERY packets, so the
        messages the broker counts as unacknowledged stay close to the owner's window."""
        backlog = self._backlog
        handled = 0
        acked: list[int] = []   # PUBACKs in a row are applied together: one hold of the lock
        try:
            while backlog:
                kind = backlog[0].kind
                if kind == wire.PUBLISH and not self.can_read():
                    return
                packet = backlog.popleft()
                if kind == wire.PUBACK:
                    acked.append(_puback_mid(packet))
                else:
                    self._acked(acked)
                    self._handle(packet)
                handled += 1
                if handled % WRITE_EVERY == 0:
                    self._acked(acked)
                    if self._out:
                        self._write_out()
        finally:
            self._acked(acked)

    def _acked(self, mids: list[int]) -> None:
        """Free the window of the PUBACKed ``mids`` (messages waiting take their places), tell
        the owner, empty ``mids``."""
        if not mids:
            return
        with self._lock:
            inflight, waiting = self._inflight, self._waiting
            inflight.difference_update(mids)
            while waiting and len(inflight) < self._quota:
                next_mid, data = waiting.popleft()
                inflight.add(next_mid)
                self._out += data
        done = mids.copy()
        mids.clear()
        self.on_pubacks(done)

    def _handle(self, packet: wire.Packet) -> None:
        kind = packet.kind
        if kind == wire.PUBLISH:
            self.on_message(wire.parse_publish(packet.flags, packet.body))
        elif kind == wire.PUBACK:
            self._acked([_puback_mid(packet)])
        elif kind == wire.SUBACK:
            self.on_suback(wire.parse_suback(packet.body)[1])
        elif kind == wire.DISCONNECT:
            reason, text = wire.parse_disconnect(packet.body)
            raise ConnectionLost(f"the broker disconnected: reason code 0x{reason:02x}"
                                 + (f" ({text})" if text else ""))
        elif kind in (wire.PINGRESP, wire.UNSUBACK):
            pass
        else:
            raise ConnectionLost(f"unexpected packet type {kind} from the broker")


def _puback_mid(packet: wire.Packet) -> int:
    """The packet id of a PUBACK; a refusal ends the connection (the owner publishes again)."""
    mid, reason = wire.parse_ack(packet.body)
    if reason >= 0x80:
        raise ConnectionLost(f"the broker refused message {mid}: reason code 0x{reason:02x}")
    return mid


def _send_all(sock: Any, data: bytes) -> None:
    """Write all of ``data`` on a non-blocking socket, waiting for room as needed."""
    view = memoryview(data)
    while view:
        try:
            sent = sock.send(view)
        except (BlockingIOError, ssl.SSLWantWriteError):
            select.select([], [sock], [], TICK)
            continue
        view = view[sent:]

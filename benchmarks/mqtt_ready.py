"""The fastest way by hand to know that many Mosquitto brokers answer: all polled at once.

The load study's baseline starts N brokers by hand and waits until each answers an MQTT CONNECT
with a CONNACK, the same criterion as the agent's health check. Polling them one after another
with a client library costs a client per attempt and a pass over all pending brokers per round;
here every pending broker gets a non-blocking TCP connect in the same round, those that accept
get a raw MQTT 3.1.1 CONNECT, and one ``select`` waits for all answers; a broker that refused is
tried again ``interval`` (sub-ms) later, until all answered or the deadline passes.
"""

from __future__ import annotations

import errno
import selectors
import socket
import time

from engine.errors import WaitTimeoutError

CONNACK = 0x20


def connect_packet(client_id: bytes = b"bench-ready") -> bytes:
    """An MQTT 3.1.1 CONNECT with a clean session, keep-alive 60 s."""
    variable = b"\x00\x04MQTT\x04\x02\x00\x3c"
    payload = len(client_id).to_bytes(2, "big") + client_id
    body = variable + payload
    assert len(body) < 128  # one byte of remaining length
    return bytes([0x10, len(body)]) + body


def wait_all_ready(brokers: list[tuple[str, int]], deadline: float = 60.0, interval: float = 0.00025) -> None:
    """Return once every (host, port) answered a CONNECT with a CONNACK; WaitTimeoutError after
    ``deadline`` s naming the brokers still silent. A broker not listening yet is tried again
    ``interval`` s after its refusal; one that accepted keeps its connection until it answers."""
    end = time.monotonic() + deadline
    packet = connect_packet()
    retry_at = {broker: 0.0 for broker in brokers}   # brokers without a connection in progress
    selector = selectors.DefaultSelector()
    answered = 0
    try:
        while answered < len(brokers):
            now = time.monotonic()
            if now > end:
                silent = sorted(set(retry_at) | {k.data for k in selector.get_map().values()})
                raise WaitTimeoutError(f"{len(brokers) - answered} mosquitto to answer a CONNECT",
                                       deadline, f"still silent: {silent[:5]}")
            for broker, when in list(retry_at.items()):
                if when <= now:
                    del retry_at[broker]
                    _connect(selector, broker, retry_at, interval)
            wait = min([interval, *(max(0.0, t - time.monotonic()) for t in retry_at.values())])
            for key, events in selector.select(wait):
                sock, broker = key.fileobj, key.data
                assert isinstance(sock, socket.socket)
                if events & selectors.EVENT_WRITE:  # the connect finished
                    if sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) != 0:
                        _drop(selector, sock, broker, retry_at, interval)
                        continue
                    try:
                        sock.send(packet)
                    except OSError:
                        _drop(selector, sock, broker, retry_at, interval)
                        continue
                    selector.modify(sock, selectors.EVENT_READ, broker)
                    continue
                try:
                    first = sock.recv(4)
                except OSError:
                    first = b""
                if first[:1] == bytes([CONNACK]):
                    selector.unregister(sock)
                    sock.close()
                    answered += 1
                else:
                    _drop(selector, sock, broker, retry_at, interval)
    finally:
        for key in list(selector.get_map().values()):
            key.fileobj.close()  # type: ignore[union-attr]
        selector.close()


def _connect(selector: selectors.BaseSelector, broker: tuple[str, int], retry_at: dict[tuple[str, int], float],
             interval: float) -> None:
    sock = socket.socket(socket.AF_INET6 if ":" in broker[0] else socket.AF_INET, socket.SOCK_STREAM)
    sock.setblocking(False)
    if sock.connect_ex(broker) in (0, errno.EINPROGRESS):
        selector.register(sock, selectors.EVENT_WRITE, broker)
    else:  # refused at once: not listening yet
        sock.close()
        retry_at[broker] = time.monotonic() + interval


def _drop(selector: selectors.BaseSelector, sock: socket.socket, broker: tuple[str, int],
          retry_at: dict[tuple[str, int], float], interval: float) -> None:
    selector.unregister(sock)
    sock.close()
    retry_at[broker] = time.monotonic() + interval

"""Loopback networking helpers: pick free ports at run time, test whether a port accepts.

Ports are never hard-coded (tests and agents run side by side); a port picked here is free when
picked, so bind it soon. :func:`free_ports` holds all sockets open until every port is chosen, so
the ports it returns are distinct.
"""

from __future__ import annotations

import errno
import ipaddress
import random
import selectors
import socket
import time
from collections.abc import Sequence
from pathlib import Path


def _family(host: str) -> socket.AddressFamily:
    return socket.AF_INET6 if ipaddress.ip_address(host).version == 6 else socket.AF_INET


#: Where picked ports come from when the kernel's ephemeral range is known: below it. A port the
#: kernel hands out itself (bind to port 0) is in that range, so any outgoing connection of any
#: process may take it between the pick and the broker's bind (a RabbitMQ listener lost its port
#: that way once in CI); the kernel never hands out a port below the range on its own.
PICK_LOW = 10_000
_PICK_TRIES = 200


def _ephemeral_low() -> int | None:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def free_ports(count: int, host: str = "127.0.0.1") -> list[int]:
    """``count`` distinct TCP ports that are free on ``host`` (an IP address) right now, picked at
    random below the kernel's ephemeral range where there is room (else by the kernel)."""
    sockets: list[socket.socket] = []
    low = _ephemeral_low()
    try:
        tries = 0
        while len(sockets) < count:
            sock = socket.socket(_family(host), socket.SOCK_STREAM)
            sockets.append(sock)
            if low is not None and low - PICK_LOW > 1000 and tries < _PICK_TRIES:
                tries += 1
                try:
                    sock.bind((host, random.randrange(PICK_LOW, low)))
                    continue
                except OSError:  # in use: try another
                    sockets.pop().close()
                    continue
            sock.bind((host, 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for sock in sockets:
            sock.close()


def free_port(host: str = "127.0.0.1") -> int:
    """One TCP port that is free on ``host`` right now."""
    return free_ports(1, host)[0]


def port_open(host: str, port: int, timeout: float = 0.2) -> bool:
    """True if something accepts TCP connections on ``host:port``."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def touch_all(addresses: Sequence[tuple[str, int]], timeout: float = 0.05) -> int:
    """Open a TCP connection to each ``(host, port)`` at once and close it unused; returns how many
    connected within ``timeout`` s (nothing listening is no error).

    All connects are started non-blocking before any is awaited, so touching N listeners takes
    about one round trip, not N (waking many brokers after their SIGTERM: the Mosquitto driver's
    ``wake_address``)."""
    pending: dict[socket.socket, tuple[str, int]] = {}
    connected = 0
    with selectors.DefaultSelector() as selector:
        try:
            for host, port in addresses:
                sock = socket.socket(_family(host), socket.SOCK_STREAM)
                sock.setblocking(False)
                code = sock.connect_ex((host, port))
                if code == 0:
                    connected += 1
                    sock.close()
                elif code in (errno.EINPROGRESS, errno.EAGAIN):
                    pending[sock] = (host, port)
                    selector.register(sock, selectors.EVENT_WRITE)
                else:
                    sock.close()
            end = time.monotonic() + timeout
            while pending and (left := end - time.monotonic()) > 0:
                for key, _events in selector.select(left):
                    sock = key.fileobj
                    assert isinstance(sock, socket.socket)
                    selector.unregister(sock)
                    del pending[sock]
                    if sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR) == 0:
                        connected += 1
                    sock.close()
        finally:
            for sock in pending:
                sock.close()
    return connected

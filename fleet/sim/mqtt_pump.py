"""Drives the MQTT clients of every simulated vehicle from ONE thread (the runner's).

paho's threaded mode (``loop_start``) gives each client a network thread and wakes it through a
socket pair for every publish: with 50 vehicles at 10 Hz that is ~1000 thread wake-ups a second,
and most of the simulator's CPU. Here no client has a thread: a publish from the runner writes to
the socket at once (paho does that when no loop thread exists), and between ticks :meth:`wait`
polls all sockets for what the broker sends (CONNACK, PUBACK, orders, pings) and does each
client's keep-alive work. Everything a vehicle does therefore happens on one thread: no locks.

Reconnecting: a client without a socket is reconnected here; a refused attempt means the broker
is down for everyone, so all attempts back off together (1 s doubling to 5 s). ``connect_timeout``
bounds one blocking connect (a remote broker that drops packets stalls the tick for that long).
"""

from __future__ import annotations

import logging
import select
import threading
import time
from collections.abc import Callable

from paho.mqtt import client as mqtt

log = logging.getLogger("fleet.sim.mqtt")


class MqttPump:
    def __init__(self, backoff_min: float = 1.0, backoff_max: float = 5.0, connect_timeout: float = 2.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self._clients: list[mqtt.Client] = []
        self._clock = clock
        self._backoff_min, self._backoff_max = backoff_min, backoff_max
        self._delay = backoff_min
        self._retry_at = 0.0
        self._connect_timeout = connect_timeout
        self._idle = threading.Event()  # never set: a wait with nothing to poll

    def add(self, client: mqtt.Client) -> None:
        client.connect_timeout = self._connect_timeout
        self._clients.append(client)

    def remove(self, client: mqtt.Client) -> None:
        if client in self._clients:
            self._clients.remove(client)

    def _reconnect(self) -> None:
        now = self._clock()
        if now < self._retry_at:
            return
        for client in self._clients:
            if client.socket() is not None:
                continue
            try:
                client.reconnect()
            except OSError as exc:
                log.warning("broker not reachable (%s); next attempt in %.0f s", exc, self._delay)
                self._retry_at = now + self._delay
                self._delay = min(self._backoff_max, self._delay * 2)
                return
        self._delay = self._backoff_min

    def wait(self, timeout: float) -> None:
        """Network I/O for ``timeout`` seconds (at least one pass; pending writes are flushed)."""
        end = self._clock() + timeout
        while True:
            self._reconnect()
            by_fd: dict[int, mqtt.Client] = {}
            poller = select.poll()
            for client in self._clients:
                sock = client.socket()
                if sock is None:
                    continue
                fd = sock.fileno()
                by_fd[fd] = client
                poller.register(fd, select.POLLIN | (select.POLLOUT if client.want_write() else 0))
            remaining = end - self._clock()
            if not by_fd:
                if remaining > 0:
                    self._idle.wait(remaining)
                return
            for fd, events in poller.poll(max(0.0, remaining) * 1000):
                client = by_fd[fd]
                if events & (select.POLLIN | select.POLLERR | select.POLLHUP):
                    client.loop_read()
                if events & select.POLLOUT and client.socket() is not None:
                    client.loop_write()
            for client in by_fd.values():
                client.loop_misc()
            if self._clock() >= end:
                return

    def run_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Pump until ``done()`` or ``timeout`` s; return ``done()``."""
        end = self._clock() + timeout
        while not done():
            remaining = end - self._clock()
            if remaining <= 0:
                break
            self.wait(min(0.05, remaining))
        return done()

"""Runs N simulated vehicles at a fixed tick, each behind its protocol link, until told to stop.

One thread does everything: it steps every vehicle (the physics tick, default 50 ms), lets each
link publish what is due, and spends the rest of the tick in the network's I/O. Ticks are
scheduled against the monotonic clock (a late tick is not made up by a burst: the next one starts
a full tick later). ``stop`` (SIGTERM/SIGINT in the CLI) ends the loop; ``shutdown`` then says
goodbye (OFFLINE) for every vehicle and waits for the confirmations.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence

from fleet.sim.adapter import Network, VehicleLink

log = logging.getLogger("fleet.sim")


class FleetRunner:
    def __init__(self, links: Sequence[VehicleLink], network: Network, tick: float = 0.05,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not 0.001 <= tick <= 1.0:
            raise ValueError(f"tick must be between 0.001 and 1 s, got {tick}")
        self.links = list(links)
        self.network = network
        self.tick = tick
        self._clock = clock
        self._stop = threading.Event()
        self.ticks = 0
        self.late_ticks = 0

    def stop(self) -> None:
        self._stop.set()

    def step(self, now: float) -> None:
        """One tick of every vehicle (also what tests call directly with their own ``now``)."""
        for link in self.links:
            link.poll()
            link.vehicle.tick(self.tick)
            link.publish(link.vehicle.take_outbox(), now)
        self.ticks += 1

    def run(self, on_all_connected: Callable[[], None] | None = None) -> None:
        for link in self.links:
            link.start()
        announced = False
        next_tick = self._clock()
        while not self._stop.is_set():
            now = self._clock()
            if not announced and all(link.connected() for link in self.links):
                announced = True
                if on_all_connected is not None:
                    on_all_connected()
            self.step(now)
            next_tick += self.tick
            wait = next_tick - self._clock()
            if wait < 0:
                self.late_ticks += 1
                next_tick = self._clock()
                wait = 0.0
            self.network.wait(wait)

    def shutdown(self, timeout: float = 5.0) -> int:
        """OFFLINE for every vehicle, then disconnect; returns how many the broker confirmed."""
        checks = [link.goodbye() for link in self.links]
        self.network.run_until(lambda: all(check() for check in checks), timeout)
        confirmed = sum(bool(check()) for check in checks)
        for link in self.links:
            link.close()
        self.network.wait(0.0)  # flush the DISCONNECTs
        return confirmed

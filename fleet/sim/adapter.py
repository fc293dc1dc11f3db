"""The seam between simulated vehicles and a protocol: a ``VehicleLink`` per vehicle, a ``Network`` for all.

The runner owns the vehicles and the clock; a link only translates, and the network does the I/O
between ticks on the runner's thread. VDA 5050 over MQTT is
:class:`fleet.sim.vda5050_adapter.Vda5050Link` with :class:`fleet.sim.mqtt_pump.MqttPump`; the
paper's channels (action/motion/movement/status/description over the context broker) will be
another pair implementing the same protocols, chosen on the command line, with no change to the
vehicle or the runner.

Threading contract: every method is called from the runner's thread; the vehicle is
single-threaded. What a link receives during ``Network.wait`` it queues until ``poll``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

from fleet.sim.vehicle import Outbox, SimVehicle


class VehicleLink(Protocol):
    vehicle: SimVehicle

    def start(self) -> None:
        """Begin connecting (non-blocking; the network connects and reconnects)."""

    def connected(self) -> bool:
        """True once the link can publish."""

    def poll(self) -> None:
        """Hand every command received since the last call to the vehicle."""

    def publish(self, outbox: Outbox, now: float) -> None:
        """Publish what the vehicle asked for (``outbox``) and whatever is due at monotonic ``now``."""

    def goodbye(self) -> Callable[[], bool]:
        """Say goodbye (VDA 5050: connection OFFLINE); the check is true once it is confirmed."""

    def close(self) -> None:
        """Disconnect."""


class Network(Protocol):
    def wait(self, timeout: float) -> None:
        """Do network I/O for ``timeout`` seconds."""

    def run_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Do network I/O until ``done()`` or ``timeout``; return ``done()``."""

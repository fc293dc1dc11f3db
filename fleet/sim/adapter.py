"""The seam between a simulated vehicle and a protocol: one ``VehicleLink`` per vehicle.

The runner owns the vehicles and the clock; a link only translates. VDA 5050 over MQTT is
:class:`fleet.sim.vda5050_adapter.Vda5050Link`; the paper's channels (action/motion/movement/status/
description over the context broker) will be another implementation of the same protocol, chosen
on the command line, with no change to the vehicle or the runner.

Threading contract: ``poll`` and ``publish`` are called from the runner's thread only (the vehicle
is single-threaded); whatever a link receives on its own network thread it queues until ``poll``.
"""

from __future__ import annotations

from typing import Protocol

from fleet.sim.vehicle import Outbox, SimVehicle


class VehicleLink(Protocol):
    vehicle: SimVehicle

    def start(self) -> None:
        """Connect and announce the vehicle (non-blocking; reconnects on its own)."""

    def connected(self) -> bool:
        """True once the link can publish."""

    def poll(self) -> None:
        """Hand every command received since the last call to the vehicle."""

    def publish(self, outbox: Outbox, now: float) -> None:
        """Publish what the vehicle asked for (``outbox``) and whatever is due at monotonic ``now``."""

    def stop(self, timeout: float) -> bool:
        """Say goodbye cleanly (for VDA 5050: connection OFFLINE) and disconnect; True if confirmed."""

"""The runner with recording fakes of the link and network protocols (no broker, no sleeps)."""

from __future__ import annotations

from fleet.sim.map import default_map
from fleet.sim.runner import FleetRunner
from fleet.sim.vehicle import Outbox, SimVehicle, VehicleSpec


class FakeLink:
    def __init__(self, vehicle: SimVehicle, log: list) -> None:
        self.vehicle, self.log = vehicle, log
        self.acked = False

    def start(self) -> None:
        self.log.append(("start", self.vehicle.spec.serial))

    def connected(self) -> bool:
        return True

    def poll(self) -> None:
        self.log.append(("poll", self.vehicle.spec.serial))

    def publish(self, outbox: Outbox, now: float) -> None:
        self.log.append(("publish", self.vehicle.spec.serial, outbox.state, now))

    def goodbye(self):
        self.log.append(("goodbye", self.vehicle.spec.serial))
        return lambda: self.acked

    def close(self) -> None:
        self.log.append(("close", self.vehicle.spec.serial))


class FakeNetwork:
    def __init__(self, links: list[FakeLink], log: list) -> None:
        self.links, self.log = links, log

    def wait(self, timeout: float) -> None:
        self.log.append(("wait",))

    def run_until(self, done, timeout: float) -> bool:
        self.links[0].acked = True  # the broker confirms only the first vehicle's OFFLINE
        return done()


def make(count: int = 2):
    site, log = default_map(), []
    links = [FakeLink(SimVehicle(VehicleSpec("M", f"s{i}", site, site.parking()[i])), log) for i in range(count)]
    return FleetRunner(links, FakeNetwork(links, log), tick=0.1), links, log


def test_step_polls_ticks_and_publishes_each_vehicle_in_turn() -> None:
    runner, _, log = make()
    runner.step(now=5.0)
    assert log == [("poll", "s0"), ("publish", "s0", True, 5.0), ("poll", "s1"), ("publish", "s1", True, 5.0)]
    log.clear()
    runner.step(now=5.1)
    assert [entry[2] for entry in log if entry[0] == "publish"] == [False, False]  # idle: no event


def test_shutdown_counts_confirmed_goodbyes_and_closes_everyone() -> None:
    runner, _, log = make()
    assert runner.shutdown() == 1
    assert [e for e in log if e[0] in ("goodbye", "close")] == [("goodbye", "s0"), ("goodbye", "s1"), ("close", "s0"), ("close", "s1")]


def test_run_stops_when_told() -> None:
    runner, links, log = make(1)
    calls = []
    runner.run(on_all_connected=lambda: (calls.append(1), runner.stop()))
    assert calls == [1] and runner.ticks == 1 and ("start", "s0") in log

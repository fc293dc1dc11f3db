"""The fleet manager's plant for a module of integration tests, set up and torn down in one place.

test_fleet_planner, test_fleet_plug_and_play and test_fleet_closed each apply a copy of
agv-fleet.ttl through local agents and run ``python -m fleet.manager`` on it for the whole module.
Their fixtures ended alike: the manager (a test may have replaced it) must have exited 0,
``plantkg destroy`` must remove the plant and every vehicle discovered, and whatever happened, a
manager still running and the agents are stopped (the agents check that no broker survived).
A fixture now says only how its rig is made: ``with managed_fleet(...) as rig: yield rig``.

test_fleet_paper and test_fleet_paper_scenario write a plant of their own for two agents (one
for Mosquitto, one for the context broker) per test: :func:`agents_with_plant`.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Protocol, TypeVar

from engine import netutil, process
from engine.cli import main
from tests.integration.agents import AgentFleet, start_agents


ROOT = Path(__file__).resolve().parents[2]


def spawn_manager(plant: Path, data: Path, agents_file: Path, logs: Path, name: str) -> process.Child:
    """``python -m fleet.manager`` on ``plant`` (reconciling every 5 s), its log ``logs/<name>.log``."""
    return process.spawn([sys.executable, "-m", "fleet.manager", plant, "--data-dir", data,
                          "--agents", agents_file, "--resync", "5"], log_dir=logs, name=name, cwd=ROOT)


class FleetRig(Protocol):
    """What the teardown needs of a module's rig."""

    manager: process.Child

    def files(self) -> list[str]: ...
    def wait_started(self) -> None: ...


R = TypeVar("R", bound=FleetRig)


@contextmanager
def managed_fleet(plant: Path, hosts: list[str], agents_dir: Path,
                  start: Callable[[AgentFleet], R]) -> Iterator[R]:
    """Start agents on ``hosts``, apply ``plant``, ``start`` the rig (it spawns the fleet manager)
    and wait until the manager started; the rig for the module's tests, then all of it torn down
    as the module docstring says."""
    agents = start_agents(hosts, agents_dir)
    rig: R | None = None
    try:
        assert main(["apply", str(plant), "--agents", str(agents.agents_file), "--yes"]) == 0
        rig = start(agents)
        rig.wait_started()
        yield rig
        manager = rig.manager  # a test may have restarted it (and stopped its own)
        if manager.running():
            # A stop finishes the reconcile in flight first (no half-done apply): one a test's last
            # change started may still restart a broker and wait for its health. 15 s was too short
            # once on CI's loaded machine (test_fleet_closed at 1da9870: SIGKILLed mid-reconcile).
            process.stop(manager, grace=60.0)
        assert manager.popen.returncode == 0, (manager.popen.returncode, manager.log_tail())
        assert main(["destroy", *rig.files(), "--agents", str(agents.agents_file), "--yes"]) == 0
    finally:
        if rig is not None and rig.manager.running():
            process.stop(rig.manager, grace=5.0)
        agents.stop()


@contextmanager
def agents_with_plant(folder: Path, plant_text: Callable[[int, int], str], mqtt_ip: str,
                      cb_ip: str) -> Iterator[tuple[AgentFleet, Path]]:
    """Agents on ``mqtt_ip`` and ``cb_ip``, and ``folder/plant.ttl`` written by ``plant_text(MQTT
    port, context broker port)`` with a free port of each; the agents stopped at the end (they
    check that no broker survived)."""
    agents = start_agents([mqtt_ip, cb_ip], folder / "agents")
    try:
        path = folder / "plant.ttl"
        path.write_text(plant_text(netutil.free_port(mqtt_ip), netutil.free_port(cb_ip)), encoding="utf-8")
        yield agents, path
    finally:
        agents.stop()

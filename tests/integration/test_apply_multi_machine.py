"""The multi-machine example with three real agents (127.0.0.2, 127.0.0.3, 127.0.0.4).

apply deploys two Mosquitto brokers and one Kafka broker in parallel, each on its own agent;
messages pass through each; the plan is then empty; status lists all three as running;
destroy removes them; no broker process is left.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from engine import netutil, process
from engine.model import BridgeStatus
from engine.cli import main
from tests.integration.agents import plant_copy, start_agents
from tests.integration.test_apply_robot_cell import as_prober, kafka_partitions, kafka_roundtrip, mqtt_roundtrip

pytestmark = pytest.mark.integration

HOSTS = {"mosquitto-a": "127.0.0.2", "mosquitto-b": "127.0.0.3", "kafka": "127.0.0.4"}


def test_multi_machine_plant_on_three_agents(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    fleet = start_agents(sorted(set(HOSTS.values())), tmp_path)
    try:
        plant, ports = plant_copy("multi-machine.ttl", tmp_path)

        def run(*args: object) -> tuple[int, str]:
            code = main([str(a) for a in args])
            out = capsys.readouterr()
            return code, out.out + out.err

        code, out = run("apply", plant, "--agents", fleet.agents_file, "--yes")
        assert code == 0, out
        # 3 brokers, 19 topics, 2 bridges (each Mosquitto cell to Kafka, run as workers)
        assert "Plan: 24 to create, 0 to update, 0 to replace, 0 to destroy." in out, out
        brokers = fleet.brokers()
        assert {b: brokers[b].spec.host for b in HOSTS} == HOSTS  # type: ignore[attr-defined]
        # closed brokers: plantkg's own principals publish (check) and read (observer)
        mqtt_roundtrip(HOSTS["mosquitto-a"], ports["mosquitto-a"], "cell-a/plc-a/robot-command", as_prober)
        mqtt_roundtrip(HOSTS["mosquitto-b"], ports["mosquitto-b"], "fleet/agv/command", as_prober)
        bootstrap = f"{HOSTS['kafka']}:{ports['kafka']}"
        assert kafka_partitions(bootstrap, "plant.kpi") >= 1
        kafka_roundtrip(bootstrap, "plant.kpi")

        code, out = run("plan", plant, "--agents", fleet.agents_file, "--detailed-exitcode")
        assert code == 0 and "No changes." in out, out
        def bridges_running() -> bool:
            found = [b for host in sorted(set(HOSTS.values()))
                     for b in fleet.client(host).list_bridges()]
            return len(found) == 2 and all(b.status is BridgeStatus.RUNNING for b in found)

        process.wait_until(bridges_running, 60, 0.2, what="both bridge workers to be ready")
        code, out = run("status", plant, "--agents", fleet.agents_file)
        brokers_table, bridges_table = out.split("\n\n")
        assert code == 0 and brokers_table.count("running") == 3, out
        assert bridges_table.count("running") == 2, out

        code, out = run("destroy", plant, "--agents", fleet.agents_file, "--yes")
        assert code == 0 and "Destroy complete" in out, out
        assert fleet.brokers() == {}
        assert not any(netutil.port_open(HOSTS[b], ports[b]) for b in HOSTS)
    finally:
        fleet.stop()

"""``plantkg demo`` on the AGV middleware: Mosquitto, the context broker and the NGSI bridge, end to end.

The AGV interface publishes its channels on Mosquitto; the task planner writes its commands as
entities on the context broker (with the agent's token); the bridge carries both ways; the taps
show the entity attribute values read back from the context broker. Everything is gone afterwards.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.agents import ROOT, plant_copy

pytestmark = pytest.mark.integration


def test_agv_demo_runs_end_to_end_and_leaves_nothing(tmp_path: Path) -> None:
    plant, ports = plant_copy("agv-middleware.ttl", tmp_path)
    assert set(ports) == {"fleet-mqtt", "fleet-context"}
    work = tmp_path / "work"
    proc = subprocess.run(
        [sys.executable, "-m", "engine.cli", "demo", str(plant), "--duration", "6", "--work-dir", str(work)],
        capture_output=True, text=True, cwd=ROOT, timeout=300,
    )
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    assert "Apply complete: 13 changed, 0 failed" in out
    assert "Destroy complete: 13 changed, 0 failed" in out
    assert "the context broker answered" not in out  # every write of the planner was accepted
    rows = {(broker, topic): (via, int(count), last) for broker, topic, via, count, last in re.findall(
        r"^(fleet-context|fleet-mqtt)\s+(\S+)\s+(published|bridge from \S+)\s+(\d+)\s+\S+\s+(.*)$", out, re.M)}
    # the planner's commands are entities written on the context broker...
    via, count, last = rows[("fleet-context", "agv-1/motion_channel")]
    assert via == "published" and count >= 3 and "'task_id': 'task-" in last
    # ... and reach the AGV side on MQTT through the bridge (as the context broker's notifications)
    via, count, last = rows[("fleet-mqtt", "agv-1/action_channel")]
    assert via == "bridge from fleet-context" and count >= 2 and "subscriptionId" in last
    # the AGV's status published on MQTT is an entity on the context broker, its values readable
    via, count, last = rows[("fleet-context", "agv-1/status_channel")]
    assert via == "bridge from fleet-mqtt" and count >= 3 and "'state': " in last
    assert rows[("fleet-mqtt", "agv-1/status_channel")][1] >= 30  # 10 Hz on MQTT
    leftovers = subprocess.run(["pgrep", "-f", str(work)], capture_output=True, text=True).stdout.split()
    assert leftovers == []

"""``plantkg demo``: the robot cell comes up, data flows through both real brokers, all goes away."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.integration.agents import ROOT, plant_copy

pytestmark = pytest.mark.integration


def test_demo_runs_end_to_end_and_leaves_nothing(tmp_path: Path) -> None:
    plant, ports = plant_copy("robot-cell.ttl", tmp_path)
    work = tmp_path / "work"
    # As a user runs it: none of the plant's `env:` passwords set (the suite sets them for every
    # other test, tests/conftest.py); the demo makes its own, for every user the plant logs in as.
    secret_vars = set(re.findall(r'pk:secretRef\s+"env:([A-Za-z_][A-Za-z0-9_]*)"', plant.read_text(encoding="utf-8")))
    assert secret_vars, "the robot cell logs in with no env: password: this test would check nothing"
    env = {k: v for k, v in os.environ.items() if k not in secret_vars}
    proc = subprocess.run(
        [sys.executable, "-m", "engine.cli", "demo", str(plant), "--duration", "3", "--work-dir", str(work)],
        capture_output=True, text=True, cwd=ROOT, timeout=240, env=env,
    )
    out = proc.stdout
    assert proc.returncode == 0, out[-3000:] + proc.stderr[-3000:]
    assert "Apply complete: 6 changed, 0 failed" in out
    assert "Destroy complete: 6 changed, 0 failed" in out
    rows = {(broker, topic): int(count) for broker, topic, count in re.findall(
        r"^(kafka|mosquitto)\s+(\S+)\s+(?:published|bridge from \S+)\s+(\d+)\s", out, re.M)}
    assert rows[("mosquitto", "robot.abb-irb120.position")] >= 10   # 10 Hz over MQTT for ~3 s
    assert rows[("kafka", "robot.abb-irb120.energy")] >= 1          # 1 Hz into Kafka
    # the merged stream on Kafka: the pose arrived there through the bridge
    assert "bridge from mosquitto" in out
    assert rows[("kafka", "robot.abb-irb120.position")] >= 5
    # every process the demo started is gone: agents (pid files' owners) and brokers
    leftovers = subprocess.run(["pgrep", "-f", str(work)], capture_output=True, text=True).stdout.split()
    assert leftovers == []
    assert ports  # the copy really moved the brokers to free ports

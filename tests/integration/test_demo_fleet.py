"""``plantkg fleet demo``: the AGV fleet end to end — its Mosquitto closed and the vehicles
admitted, plug and play, SPARQL, the task planner, Task entities — with real agents, brokers, fleet
manager, planner and simulated vehicles, and nothing left running afterwards."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from engine.demo.local_plant import processes_under
from tests.integration.agents import ROOT

pytestmark = pytest.mark.integration


def test_fleet_demo_runs_end_to_end_and_leaves_nothing(tmp_path: Path) -> None:
    work = tmp_path / "work"
    proc = subprocess.run(
        # --speed 4: the vehicles' drives and turns (most of the run at the default speed) take a quarter of the time
        [sys.executable, "-m", "engine.cli", "fleet", "demo", "--vehicles", "2", "--speed", "4", "--work-dir", str(work)],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )
    out = proc.stdout
    assert proc.returncode == 0, out[-4000:] + proc.stderr[-4000:]
    assert "Apply complete:" in out and "0 failed" in out
    joined = re.findall(r"^\s+(\S+/\S+)\s+(vda5050|paper-channels)\s+ready\s+(\d+) ms after ONLINE", out, re.M)
    assert sorted(i for _v, i, _ms in joined) == ["paper-channels", "vda5050", "vda5050"], out
    # the SPARQL answer lists the three discovered vehicles with their skills from the graph
    assert len(re.findall(r"^\s+agv-(demo|paper)-\d+ \| (vda5050|paper-channels) \| .*\bmove\b", out, re.M)) == 3, out
    assert "operator at pick-1: Loaded" in out
    assert re.search(r"operator screens \(HMI\): http://127\.0\.0\.1:\d+/ ", out), out
    finished = re.findall(r"^\s+urn:ngsi-ld:Task:\S+: FINISHED \S*(demo|paper)-\d+$", out, re.M)
    assert len(finished) == 2, out  # both jobs, as the context broker has them
    assert "nothing left running" in out
    assert processes_under(work) == []
    # closed by default: the vehicles were admitted (a 0600 password each, never printed) and the
    # fleet's Mosquitto admitted nobody else
    passwords = sorted((work / "secrets").glob("*.pw"))
    assert [p.name for p in passwords] == ["demo-0001.pw", "demo-0002.pw", "paper-0001.pw"]
    assert all(p.stat().st_mode & 0o077 == 0 for p in passwords)
    assert not [p for p in passwords if p.read_text().strip() in out + proc.stderr]
    [conf] = (work / "plant").glob("agent-*/removed/fleet-mqtt.*/mosquitto.conf")
    assert "allow_anonymous false" in conf.read_text().splitlines()

"""The Table 1 benchmark runs one run of each path against a real agent, Mosquitto and Kafka; the
emulated remote machine (network namespace + netem) is measured where this process may build one,
and otherwise skipped with the reason; the user-space delay proxy row is measured everywhere."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import bench_deploy

pytestmark = pytest.mark.integration


def test_deploy_benchmark_runs(tmp_path: Path) -> None:
    assert bench_deploy.main(["--runs", "1", "--cli-runs", "1", "--kafka-runs", "1", "--delay-ms", "1",
                              "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "deploy.json").read_text())
    rows = set(data["ms"])
    assert rows >= {"bare", "plantkg", "plantkg-dispatch", "plantkg-warm", "plantkg-cli", "plantkg-proxy-1ms",
                    "kafka-bare", "kafka-plantkg"}
    # the warm row's pipeline started once, then followed each run's one-line edit (the port)
    assert data["warm_calls"] == {"cold": 1, "warm": 1}
    assert "load" not in data["plantkg_warm_stages_ms"] and "apply" in data["plantkg_warm_stages_ms"]
    # every row one run; bare once more, interleaved with the command line's run
    assert {name: row["n"] for name, row in data["ms"].items() if row["n"] != 1} == {"bare": 2}
    # `plantkg apply` as a process starts an interpreter and imports: slower than in-process
    assert data["ms"]["plantkg-cli"]["min"] > data["ms"]["bare"]["min"]
    if "plantkg-remote-1ms" in rows:
        assert data["remote_note"] == ""
    else:  # not root, no iproute2 or no sch_netem: the row is skipped and says why
        assert data["remote_note"].startswith("not measured: the delayed link is not available here")
        assert "not measured" in (tmp_path / "deploy.md").read_text()
    # the proxy delays orders and publish by 1 ms each way: the deploy cannot be faster than that
    assert data["ms"]["plantkg-proxy-1ms"]["min"] > 2.0


def test_netns_link_without_delay_reaches_an_agent(tmp_path: Path) -> None:
    from benchmarks import netns
    from engine.agents_config import AgentDirectory

    try:
        with netns.delayed_link(0) as link, netns.remote_agent(link, tmp_path) as agent:
            directory = AgentDirectory.load(agent.agents_file)
            assert bench_deploy.through_plantkg(tmp_path, directory, False, host=link.remote_ip) > 0
    except netns.LinkUnavailable as exc:
        pytest.skip(f"no network namespace here: {exc}")

"""The load benchmark (the paper's Fig. 12) runs tiny against real Mosquitto brokers brought up by
one apply, and every message of every burst is acknowledged and delivered."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from benchmarks import bench_load
from benchmarks.mqtt_burst import BurstRig

pytestmark = pytest.mark.integration


def test_load_benchmark_runs(tmp_path: Path) -> None:
    args = ["--brokers", "1", "2", "--messages", "4", "6", "--repeat", "1", "--deploy-repeat", "1",
            "--sizes", "100", "20000", "--size-brokers", "2", "--size-messages", "3", "--nagle-brokers", "1", "--nagle-messages", "2",
            "--kafka-messages", "--bridge-messages", "--out", str(tmp_path)]
    assert bench_load.main(args) == 0
    data = json.loads((tmp_path / "load.json").read_text())
    assert [r["brokers"] for r in data["rows"]] == [1, 2]
    two = data["rows"][1]
    assert two["memory"]["brokers"] == 2 and two["memory"]["broker_rss_mb_mean"] > 0
    assert two["bringup"]["up_ratio"] > 0 and two["bringup"]["down_ratio"] > 0
    cells = [c for r in data["rows"] for c in r["cells"]]
    assert {(c["study"], c["mode"]) for c in cells} == {("matrix", "spread"), ("matrix", "one-to-one"),
                                                        ("size", "spread"), ("tcp-default", "spread"),
                                                        ("tcp-nodelay", "spread")}
    assert all(c["lost"] == 0 and c["ack"]["n"] == c["delivery"]["n"] == c["messages"] for c in cells)
    assert {c["size"] for c in cells if c["study"] == "size"} == {100, 20000}
    with (tmp_path / "load.csv").open() as fh:
        assert len(list(csv.DictReader(fh))) == len(cells)  # one row per burst (repeat 1)
    for png in ("load.png", "load-sizes.png", "load-bringup.png", "load-nodelay.png"):
        assert 0 < (tmp_path / png).stat().st_size < 200_000


def test_load_benchmark_kafka_arm(tmp_path: Path) -> None:
    args = ["--brokers", "1", "--messages", "3", "--repeat", "1", "--deploy-repeat", "1", "--sizes", "100", "5000",
            "--size-brokers", "--size-messages", "2", "--nagle-brokers", "--kafka-messages", "4",
            "--bridge-messages", "--out", str(tmp_path)]
    assert bench_load.main(args) == 0
    kafka = json.loads((tmp_path / "load.json").read_text())["kafka"]
    assert kafka["up_s"] > 0 and kafka["memory"]["brokers"] == 1  # the JVM is the agent's one child
    assert {(c["study"], c["size"], c["messages"]) for c in kafka["cells"]} == {
        ("kafka", 100, 4), ("kafka-size", 100, 2), ("kafka-size", 5000, 2)}
    assert all(c["lost"] == 0 and c["ack"]["n"] == c["delivery"]["n"] == c["messages"] for c in kafka["cells"])
    assert "## Kafka" in (tmp_path / "load.md").read_text()


def test_load_benchmark_bridge_arm(tmp_path: Path) -> None:
    """The MQTT -> Kafka bridge path of the matrix: one apply of Mosquitto + Kafka + their
    bridge, bursts published on Mosquitto and consumed from Kafka, nothing lost."""
    args = ["--brokers", "1", "--messages", "3", "--repeat", "1", "--deploy-repeat", "1", "--sizes", "100",
            "--size-brokers", "--nagle-brokers", "--kafka-messages", "--bridge-messages", "5", "20",
            "--out", str(tmp_path)]
    assert bench_load.main(args) == 0
    data = json.loads((tmp_path / "load.json").read_text())
    cells = data["bridge"]["cells"]
    assert [c["messages"] for c in cells] == [5, 20] and all(c["lost"] == 0 for c in cells)
    assert all(c["ack"]["n"] == c["delivery"]["n"] == c["messages"] for c in cells)
    assert "| MQTT → bridge → Kafka | 1 | 20 |" in (tmp_path / "load.md").read_text()


def test_burst_refuses_more_one_to_one_messages_than_publishers(tmp_path: Path) -> None:
    from engine import netutil, process
    from engine.drivers.mosquitto.runtime import MosquittoConfig, default_run_as, mosquitto_command, render_mosquitto_conf
    from engine.parts import mosquitto_binary

    port = netutil.free_port()
    conf = tmp_path / "m.conf"
    conf.write_text(render_mosquitto_conf(MosquittoConfig("127.0.0.1", port, tmp_path / "m.log", default_run_as())))
    child = process.spawn(mosquitto_command(mosquitto_binary(), conf), log_dir=tmp_path, name="m")
    try:
        bench_load.wait_all_ready([("127.0.0.1", port)], 10)
        with BurstRig([("127.0.0.1", port)], 2) as rig:
            assert rig.burst(5, 64, "spread").lost == 0
            with pytest.raises(ValueError, match="one-to-one publishers"):
                rig.burst(3, 64, "one-to-one")
    finally:
        process.stop(child)


def test_the_hand_baseline_waits_for_every_broker_at_once(tmp_path: Path) -> None:
    """benchmarks.mqtt_ready: three brokers spawned by hand all answer a raw CONNECT; a port where
    nothing listens is named when the deadline passes."""
    from benchmarks import mqtt_ready
    from engine import netutil, process
    from engine.errors import WaitTimeoutError

    ports, confs = bench_load._hand_confs(3, tmp_path)
    children: list = []
    try:
        bench_load._spawn_all(confs, tmp_path, children)
        mqtt_ready.wait_all_ready([(bench_load.HOST, p) for p in ports], 30)
        with BurstRig([(bench_load.HOST, p) for p in ports], 0) as rig:  # they really answer MQTT
            assert rig.burst(3, 64, "spread").lost == 0
        silent = netutil.free_port(bench_load.HOST)
        with pytest.raises(WaitTimeoutError, match=str(silent)):
            mqtt_ready.wait_all_ready([(bench_load.HOST, ports[0]), (bench_load.HOST, silent)], 0.3)
    finally:
        assert process.stop_all(children) and not any(c.group_alive() for c in children)

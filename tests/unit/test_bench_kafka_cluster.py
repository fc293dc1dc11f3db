"""benchmarks/bench_kafka_cluster.py, the parts without JVMs: its plant is valid and derives what
it measures (3 nodes, a topic of RF 3, a mirror with the site), and its table and goal."""

from __future__ import annotations

from pathlib import Path

from benchmarks import bench_kafka_cluster as bench
from benchmarks import report
from engine.model import BridgeMechanism
from engine.pipeline import run_pipeline

PORTS = {"n1": 9001, "c1": 9002, "n2": 9003, "c2": 9004, "n3": 9005, "c3": 9006, "s1": 9007, "sc1": 9008}


def test_the_bench_plant_is_valid_and_mirrors_with_the_site(tmp_path: Path) -> None:
    for site in (False, True):
        path = tmp_path / f"plant-{site}.ttl"
        path.write_text(bench.plant(PORTS, site=site), encoding="utf-8")
        result = run_pipeline([str(path)], None, observe=False)
        assert result.report.conforms, result.report.results
        desired = result.desired
        assert desired is not None
        assert [b.id for b in desired.brokers] == (["n1", "n2", "n3", "s1"] if site else ["n1", "n2", "n3"])
        assert [b.mechanism for b in desired.bridges] == ([BridgeMechanism.MIRROR] if site else [])
        assert bench.bootstrap(PORTS) == "127.0.0.2:9001,127.0.0.3:9003,127.0.0.4:9005"


def test_the_table_and_the_goal(tmp_path: Path) -> None:
    data = {"machine": {"cpus": 2, "load_average": (1.0, 1.0, 1.0)}, "load_average_end": (2.0, 2.0, 2.0),
            "command": "python -m benchmarks.bench_kafka_cluster",
            "bringup": {"seconds": {"plantkg": [30.0, 32.0], "hand": [29.0, 27.0]},
                        "median_s": {"plantkg": 31.0, "hand": 28.0}, "ratio": 31.0 / 28.0},
            "throughput": {"messages": 10, "size": 100, "median_msg_per_s": {"rf1": 2000.0, "rf3": 1000.0},
                           "rf3_over_rf1": 0.5},
            "mirror": {"messages": 10, "size": 100, "produce_s": 1.0, "mirror_s": 4.0, "mirror_msg_per_s": 2.5,
                       "max_lag": 7, "lag_zero_after_last_s": 0.5}}
    data["goals"] = bench.goals(data)
    assert data["goals"][0]["met"] and "31.0 / 28.0 s = 1.11x" in data["goals"][0]["measured"]
    text = bench.to_markdown(data)
    assert "| 31.0 s | 28.0 s | 1.11x |" in text and "max 7 records" in text and "(2.0, 2.0, 2.0)" in text
    (tmp_path / "kafka_cluster.json").write_text(__import__("json").dumps(data))
    [row] = [r for r in report.goals(tmp_path) if r[0].startswith("3-node cluster bring-up")]
    assert row[1:] == ("31.0 / 28.0 s = 1.11x", "≤ 1.2x", "met")

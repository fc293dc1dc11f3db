"""``plantkg-bench``: one entry point for every benchmark study, then ``benchmarks/RESULTS.md``.

Each study is a module with a ``main(argv)`` writing its raw results, table and plots into the
results folder; this runner only chooses which to run, with which arguments, and rebuilds the
report afterwards. ``--tiny`` runs each study at a size that takes seconds (what the test suite
does); the defaults are the full sizes of the issue (about ten minutes on two cores for the default studies).

Usage: ``plantkg-bench [STUDY ...] [--tiny] [--out DIR]`` — studies: deploy, load, scale,
validate, reason, bridge, web, durability, context_broker, bridge_ngsi, fleet_join, fleet_tasks, cli, security, kafka_cluster; default ``deploy load scale``; ``plantkg-bench report`` only rebuilds RESULTS.md.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

from benchmarks import (bench_bridge, bench_bridge_ngsi, bench_cli, bench_context_broker, bench_deploy, bench_durability,
                        bench_fleet_join, bench_fleet_tasks, bench_kafka_cluster, bench_load, bench_reason, bench_replan, bench_security, bench_validate,
                        bench_web, report)
from benchmarks.common import RESULTS

STUDIES: dict[str, Callable[[list[str]], int]] = {
    "deploy": bench_deploy.main, "load": bench_load.main, "scale": bench_replan.main,
    "validate": bench_validate.main, "reason": bench_reason.main, "bridge": bench_bridge.main,
    "web": bench_web.main, "durability": bench_durability.main, "context_broker": bench_context_broker.main,
    "bridge_ngsi": bench_bridge_ngsi.main, "fleet_join": bench_fleet_join.main,
    "fleet_tasks": bench_fleet_tasks.main, "cli": bench_cli.main, "security": bench_security.main,
    "kafka_cluster": bench_kafka_cluster.main,
}
DEFAULT = ["deploy", "load", "scale"]
TINY: dict[str, list[str]] = {
    "deploy": ["--runs", "2", "--kafka-runs", "0", "--delay-ms", "-1"],
    "load": ["--brokers", "1", "2", "--messages", "5", "10", "--repeat", "1", "--deploy-repeat", "1",
             "--sizes", "100", "10000", "--size-brokers", "2", "--size-messages", "5", "--nagle-brokers", "2", "--nagle-messages", "1", "5",
             "--kafka-messages", "--bridge-messages"],
    "scale": ["--sizes", "30", "60", "--repeat", "1"],
    "validate": ["--sizes", "40", "--repeat", "1", "--reference-max", "40"],
    "reason": ["--sizes", "20", "--repeat", "1", "--hermit-max", "0"],
    "bridge": ["--messages", "200"],
    "durability": ["--messages", "300", "--policies", "default", "1"],
    "web": ["--sizes", "100", "--threads", "1", "--requests", "5"],
    "context_broker": ["--tiny"],
    "bridge_ngsi": ["--messages", "200", "--topics", "1"],
    "fleet_join": ["--counts", "1", "2", "--floor-runs", "1", "--settle", "2"],
    "fleet_tasks": ["--tiny"],
    "cli": ["--runs", "2", "--no-agents"],
    "security": ["--tiny"],
    "kafka_cluster": ["--tiny"],
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="plantkg-bench", description="Run benchmark studies, then rebuild benchmarks/RESULTS.md.")
    parser.add_argument("studies", nargs="*", metavar="STUDY",
                        help=f"{', '.join(STUDIES)} or report (default: {' '.join(DEFAULT)})")
    parser.add_argument("--tiny", action="store_true", help="each study at a size that takes seconds")
    parser.add_argument("--out", type=Path, default=None,
                        help="results folder (default benchmarks/results; RESULTS.md goes next to it)")
    args = parser.parse_args(argv)
    chosen = args.studies or DEFAULT
    unknown = [s for s in chosen if s not in STUDIES and s != "report"]
    if unknown:
        parser.error(f"unknown study {', '.join(unknown)}: choose from {', '.join(STUDIES)}, report")
    for name in (s for s in chosen if s != "report"):
        print(f"== {name}", flush=True)
        study_args = [*(TINY[name] if args.tiny else []), *(["--out", str(args.out)] if args.out else [])]
        if STUDIES[name](study_args) != 0:
            return 1
    out = args.out or RESULTS
    path = report.write(out, out.parent / "RESULTS.md")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

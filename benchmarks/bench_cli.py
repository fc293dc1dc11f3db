"""Benchmark: how long the ``plantkg`` command line takes to start, against a bare Python start.

Each row is a whole process, as a person types it (wall time, ``N`` runs, interleaved so that load
drift hits every row alike):

- ``python -c pass`` (baseline): the same interpreter and virtual environment doing nothing;
- ``python -c "import click"``: the floor of any click command line;
- ``plantkg --help`` and ``plantkg --version``: only the command line (issue 16: < 0.15 s);
- ``plantkg validate EXAMPLE``: load + validate the robot cell (no agents);
- ``plantkg plan EXAMPLE --agents A``: validate, reason, derive, ask two real local agents
  (``plantkg agent``, started once before the runs) what runs, plan. Nothing is changed.

The console script is the ``plantkg`` next to this interpreter (``.venv/bin/plantkg``). Results go to
``benchmarks/results/cli.json`` (raw) and ``cli.md`` (table with the ratio to the baseline).

Usage: ``python -m benchmarks.bench_cli [--runs 15]``
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, command_line, machine, summarize, write_results

EXAMPLE = ROOT / "ontology" / "examples" / "robot-cell.ttl"
HOSTS = ["127.0.0.2", "127.0.0.3"]  # the robot cell's machines (its pk:ip values)
HELP_GOAL_S = 0.15  # issue 16: `plantkg --help` < 0.15 s


def plantkg_script() -> str:
    """The ``plantkg`` console script of this interpreter's environment."""
    script = Path(sys.executable).parent / "plantkg"
    if not script.is_file():
        raise SystemExit(f"no plantkg console script next to {sys.executable}: run `make setup` first")
    return str(script)


def rows(agents_file: Path | None) -> dict[str, list[str]]:
    """Name -> command line of every row (plan only when agents run)."""
    plantkg = plantkg_script()
    out = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "python -c 'import click'": [sys.executable, "-c", "import click"],
        "plantkg --help": [plantkg, "--help"],
        "plantkg --version": [plantkg, "--version"],
        "plantkg validate EXAMPLE": [plantkg, "validate", str(EXAMPLE)],
    }
    if agents_file is not None:
        out["plantkg plan EXAMPLE"] = [plantkg, "plan", str(EXAMPLE), "--agents", str(agents_file)]
    return out


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def time_once(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one whole process; a failing command fails the
    benchmark. CPU time is less disturbed than wall time when others share the machine."""
    cpu, start = _children_cpu(), time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, cwd=ROOT, timeout=120, check=False)
    seconds, cpu = time.perf_counter() - start, _children_cpu() - cpu
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} exited {proc.returncode}: {proc.stderr[-2000:]}")
    return seconds, cpu


def measure(commands: dict[str, list[str]], runs: int) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Wall and CPU seconds of ``runs`` rounds; each round runs every command once (after one
    warm-up round)."""
    for argv in commands.values():
        time_once(argv)  # warm the page cache and .pyc files
    wall: dict[str, list[float]] = {name: [] for name in commands}
    cpu: dict[str, list[float]] = {name: [] for name in commands}
    for _ in range(runs):
        for name, argv in commands.items():
            w, c = time_once(argv)
            wall[name].append(w)
            cpu[name].append(c)
    return wall, cpu


def markdown(stats: dict[str, dict[str, float]], cpu: dict[str, dict[str, float]], baseline: str,
             argv: list[str] | None, info: dict[str, object]) -> str:
    base, base_cpu = stats[baseline]["p50"], cpu[baseline]["p50"]
    lines = ["# Command-line start-up", "",
             f"Command: `{command_line('benchmarks.bench_cli', argv)}`", "",
             f"Machine: {info['cpus']} CPUs, Python {info['python']}, load average at start "
             f"{', '.join(f'{x:.2f}' for x in info['load_average'])}; commit {info['commit']}.", "",
             "Whole processes, wall time in ms (median of the runs, interleaved); ratio = median / "
             f"median of `{baseline}` in the same run. CPU = user + system time of the process.", "",
             "| command | n | p50 ms | min ms | max ms | × bare python | CPU p50 ms | CPU × bare |",
             "|---|---|---|---|---|---|---|---|"]
    for name, s in stats.items():
        c = cpu[name]["p50"]
        lines.append(f"| `{name}` | {s['n']} | {s['p50']:.1f} | {s['min']:.1f} | {s['max']:.1f} | "
                     f"{s['p50'] / base:.2f} | {c:.1f} | {c / base_cpu:.2f} |")
    help_s = stats["plantkg --help"]["p50"] / 1000
    verdict = "met" if help_s < HELP_GOAL_S else "NOT met"
    lines += ["", f"Goal `plantkg --help` < {HELP_GOAL_S:g} s: {help_s:.3f} s — {verdict}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.bench_cli", description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=15, help="rounds of every command (default 15)")
    parser.add_argument("--no-agents", action="store_true", help="skip the plan row (starts no agent)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    info = machine()
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-cli-") as tmp:
        agents = None
        if not args.no_agents:
            from engine.agent.local import start_local_agents  # noqa: PLC0415 - only with agents

            agents = start_local_agents(HOSTS, Path(tmp) / "agents")
        try:
            seconds, cpu_seconds = measure(rows(agents.agents_file if agents else None), args.runs)
        finally:
            if agents is not None:
                agents.stop()
    stats = {name: summarize(values) for name, values in seconds.items()}
    cpu = {name: summarize(values) for name, values in cpu_seconds.items()}
    data = {"machine": info, "runs": args.runs, "baseline": "python -c pass", "seconds": seconds,
            "cpu_seconds": cpu_seconds, "stats_ms": stats, "cpu_stats_ms": cpu, "help_goal_s": HELP_GOAL_S,
            "median_s": {name: statistics.median(values) for name, values in seconds.items()}}
    write_results(args.out, "cli", data, markdown(stats, cpu, "python -c pass", argv, info))
    return 0


if __name__ == "__main__":
    sys.exit(main())

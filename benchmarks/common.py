"""What every benchmark shares: where results go, how a measurement runs in a fresh process, and
the description of the machine that goes next to every figure."""

from __future__ import annotations

import json
import math
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"


def run_child(script: str, *args: str, timeout: float | None = None) -> dict[str, object]:
    """Run ``script`` (Python source printing one JSON line last) in a fresh interpreter, so
    memory and import costs are not shared between measurements; returns that JSON."""
    proc = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True,
                          cwd=ROOT, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def machine() -> dict[str, object]:
    """The machine a run happened on (figures drift between machines and loads), and the code."""
    return {"cpus": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform(), "load_average": os.getloadavg(), "commit": commit()}


#: What a benchmark run writes: changes there are results, not a difference in the code measured.
RESULT_PATHS = (":(exclude)benchmarks/results", ":(exclude)benchmarks/RESULTS.md")


def commit() -> str:
    """The checked-out commit, with ``+changes`` when the working tree differs from it outside the
    results (so a series of runs that rewrite benchmarks/results/ one after the other all record
    the commit they measured, not ``+changes`` from the runs before them)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=ROOT, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".", *RESULT_PATHS],
                               capture_output=True, text=True, cwd=ROOT, timeout=10).stdout.strip()
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return f"{head or 'unknown'}{'+changes' if dirty else ''}"


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (all its threads) so far, from /proc; NaN once it
    is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return float("nan")
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def summarize(seconds: list[float]) -> dict[str, float]:
    """n, min, max, mean, standard deviation, p50 and p99 of ``seconds``, in milliseconds."""
    ms = sorted(x * 1000 for x in seconds)
    if not ms:
        return {"n": 0}
    return {"n": len(ms), "min": ms[0], "max": ms[-1], "mean": statistics.fmean(ms),
            "stdev": statistics.stdev(ms) if len(ms) > 1 else 0.0,
            "p50": percentile(ms, 50), "p99": percentile(ms, 99)}


def percentile(sorted_values: list[float], q: float) -> float:
    """The nearest-rank ``q``-th percentile of an ascending list (p50 of 50 values is the 25th)."""
    rank = max(1, math.ceil(q / 100 * len(sorted_values)))
    return sorted_values[rank - 1]


def loglog_slope(sizes: list[float], seconds: list[float]) -> float | None:
    """Least-squares slope of log(time) against log(size): 1 is linear growth, 2 quadratic
    (None with fewer than two distinct sizes)."""
    points = [(math.log(n), math.log(t)) for n, t in zip(sizes, seconds) if n > 0 and t > 0]
    if len({x for x, _ in points}) < 2:
        return None
    mx = statistics.fmean(x for x, _ in points)
    my = statistics.fmean(y for _, y in points)
    return (sum((x - mx) * (y - my) for x, y in points)
            / sum((x - mx) ** 2 for x, _ in points))


def command_line(module: str, argv: list[str] | None) -> str:
    """The command that re-runs a benchmark module with the arguments it was given."""
    return " ".join(["python -m", module, *(sys.argv[1:] if argv is None else argv)])


def write_results(out: Path, name: str, data: dict[str, object], markdown: str) -> None:
    """``<out>/<name>.json`` (raw, with the load average at the end of the run next to the one at
    its start in ``machine``) and ``<out>/<name>.md`` (the table), and the table on stdout."""
    out.mkdir(parents=True, exist_ok=True)
    data = {**data, "load_average_end": os.getloadavg()}
    (out / f"{name}.json").write_text(json.dumps(data, indent=2))
    (out / f"{name}.md").write_text(markdown)
    print(markdown)

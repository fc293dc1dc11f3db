"""What every benchmark shares: where results go, how a measurement runs in a fresh process, and
the description of the machine that goes next to every figure."""

from __future__ import annotations

import json
import os
import platform
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
    """The machine a run happened on (figures drift between machines and loads)."""
    return {"cpus": os.cpu_count(), "python": platform.python_version(),
            "platform": platform.platform(), "load_average": os.getloadavg()}


def write_results(out: Path, name: str, data: dict[str, object], markdown: str) -> None:
    """``<out>/<name>.json`` (raw) and ``<out>/<name>.md`` (the table), and the table on stdout."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(data, indent=2))
    (out / f"{name}.md").write_text(markdown)
    print(markdown)

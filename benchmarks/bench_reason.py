"""Benchmark: load → validate → reason → derive on synthetic plants, fast engine vs HermiT.

For each size it writes a synthetic plant (``benchmarks/synthetic.py``: N resources, N/20 brokers,
N topics, every tenth resource a subscriber on a neighbour's broker, so rule R1 requires bridges),
then runs, each in a fresh Python process so imports and memory are not shared:

- ``fast``: ``load_plant``, ``kg.validate.validate`` (auto engine), ``engine.reasoning.reason.reason`` with
  the fast engine, ``engine.derive.derive`` — the stages ``plantkg plan`` runs before it asks the
  agents;
- ``hermit`` (baseline, up to ``--hermit-max`` resources): the same with the owlready2 engine
  (HermiT in a JVM), reasoning only (no validate).

Both report a digest of the inferred graph: the two engines must agree on every size both ran.
Results go to ``benchmarks/results/reason.json`` (raw) and ``reason.md`` (table). Absolute times
drift on shared machines; the ratio fast/HermiT from the same run is the stable figure.

Usage: ``python -m benchmarks.bench_reason [--sizes 100 1000 10000] [--repeat 3] [--hermit-max 1000]
[--hermit-repeat 1]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

from benchmarks.common import RESULTS, machine, run_child, write_results

_CHILD = r"""
import hashlib, json, resource, sys, time
t0 = time.perf_counter()
mode, plant = sys.argv[1], sys.argv[2]
from kg.load import load_plant
from kg.namespaces import GRAPH_INFERRED
from kg.validate import validate
from engine.reasoning.reason import ReasonerTimeoutError, reason
from engine.derive import derive
import pyoxigraph as ox
t1 = time.perf_counter()
p = load_plant([plant])
t2 = time.perf_counter()
out = {"import": t1 - t0, "load": t2 - t1, "triples": p.triple_count}
if mode == "fast":
    report = validate(p)
    t3 = time.perf_counter()
    out["validate"] = t3 - t2
    out["violations"] = len(report.violations)
else:
    t3 = time.perf_counter()
try:
    inf = reason(p, engine="fast" if mode == "fast" else "owlready2", timeout=float(sys.argv[3]))
except ReasonerTimeoutError:
    out.update({"timeout": True, "reason": float(sys.argv[3]), "derive": 0.0, "total": time.perf_counter() - t0,
                "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024})
    print(json.dumps(out))
    sys.exit(0)
t4 = time.perf_counter()
state = derive(p)
t5 = time.perf_counter()
g = ox.NamedNode(GRAPH_INFERRED)
facts = sorted(str(ox.Triple(q.subject, q.predicate, q.object)) for q in p.store.quads_for_pattern(None, None, None, g)
               if q.subject != g)
out.update({"reason": t4 - t3, "derive": t5 - t4, "engine": inf.engine, "inferred": len(facts),
            "digest": hashlib.sha256("\n".join(facts).encode()).hexdigest()[:16],
            "brokers": len(state.brokers), "topics": len(state.topics), "bridges": len(state.bridges),
            "derived_bridges": sum(1 for b in state.bridges if not b.asserted)})
if mode == "fast":
    out["pipeline"] = out["validate"] + out["reason"] + out["derive"]
out["total"] = time.perf_counter() - t0
out["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""

_KEYS = ("import", "load", "validate", "reason", "derive", "pipeline", "total", "max_rss_mb")


def _child(mode: str, plant: Path, timeout: float) -> dict[str, object]:
    return run_child(_CHILD, mode, str(plant), str(timeout), timeout=timeout + 120)


def _summary(runs: list[dict[str, object]]) -> dict[str, object]:
    out: dict[str, object] = {k: statistics.median(float(r[k]) for r in runs) for k in _KEYS if k in runs[0]}
    for k in ("engine", "inferred", "digest", "brokers", "topics", "bridges", "derived_bridges", "violations",
              "timeout"):
        if k in runs[0]:
            out[k] = runs[0][k]
    out["runs"] = [{k: r[k] for k in _KEYS if k in r} for r in runs]
    return out


def measure(sizes: list[int], repeat: int, hermit_max: int, timeout: float,
            hermit_repeat: int = 1) -> dict[str, object]:
    from benchmarks import synthetic

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            plant = synthetic.write_file(n, Path(tmp))
            fast, hermit = [], []
            for i in range(repeat):  # interleaved, so drift hits both alike
                fast.append(_child("fast", plant, timeout))
                if n <= hermit_max and i < hermit_repeat:
                    hermit.append(_child("hermit", plant, timeout))
            row: dict[str, object] = {"resources": n, "triples": fast[0]["triples"], "fast": _summary(fast)}
            if hermit:
                row["hermit"] = _summary(hermit)
                if not row["hermit"].get("timeout"):  # type: ignore[union-attr]
                    row["agree"] = row["fast"]["digest"] == row["hermit"]["digest"]  # type: ignore[index]
                row["ratio_reason"] = row["fast"]["reason"] / row["hermit"]["reason"]  # type: ignore[index]
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items()}, default=str)[:600], flush=True)
    return {
        "benchmark": "reason",
        "machine": machine(),
        "repeat": repeat,
        "hermit_repeat": hermit_repeat,
        "command": "python -m benchmarks.bench_reason " + " ".join(sys.argv[1:]),
        "rows": rows,
    }


def to_markdown(data: dict[str, object]) -> str:
    lines = [
        "# reason: validate → reason → derive, fast engine vs HermiT (owlready2), same run",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']} · median of {data['repeat']} "
        f"(HermiT: {data.get('hermit_repeat', data['repeat'])}), each run a fresh process",
        "",
        "| resources | triples | load s | validate s | reason (fast) s | derive s | validate+reason+derive s "
        "| inferred facts | brokers / topics / bridges (derived) | reason (HermiT) s | fast/HermiT | same facts |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in data["rows"]:  # type: ignore[union-attr]
        f, h = r["fast"], r.get("hermit")
        if h and h.get("timeout"):
            hermit = f"> {h['reason']:.0f} (deadline) | < {r['ratio_reason']:.5f} | –"
        elif h:
            hermit = f"{h['reason']:.2f} | {r['ratio_reason']:.4f} | {'yes' if r['agree'] else 'NO'}"
        else:
            hermit = "– | – | –"
        lines.append(
            f"| {r['resources']} | {r['triples']} | {f['load']:.2f} | {f['validate']:.2f} | {f['reason']:.3f} | "
            f"{f['derive']:.3f} | **{f['pipeline']:.2f}** | {f['inferred']} | {f['brokers']} / {f['topics']} / "
            f"{f['bridges']} ({f['derived_bridges']}) | {hermit} |")
    lines += ["", "HermiT times are the owlready2 engine's `reason` (child Python + JVM + owlready2 "
              "reading back); the plant's load is not counted in either."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="reason benchmark")
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 1000, 10000])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--hermit-max", type=int, default=1000,
                        help="run the HermiT baseline only up to this many resources")
    parser.add_argument("--hermit-repeat", type=int, default=1,
                        help="HermiT runs per size (each takes seconds to minutes)")
    parser.add_argument("--timeout", type=float, default=600.0,
                        help="deadline of one HermiT run, s (a run past it is reported as such)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = measure(args.sizes, args.repeat, args.hermit_max, args.timeout, args.hermit_repeat)
    write_results(args.out, "reason", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

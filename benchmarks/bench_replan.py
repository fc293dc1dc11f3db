"""Benchmark: re-planning a plant that did not change, against planning it from scratch.

For a synthetic plant: ``cold`` = load + validate + reason + derive + plan (what every plan costs
without the cache); ``warm`` = the same through :class:`engine.incremental.desired_cache.DesiredCache` after a
first run (hash the files, read the cached desired state, plan). The observed state is made equal
to the desired one, so both plans are empty, and the agents' HTTP round trip (one per machine,
paid either way) is not included, nor is building the observed state (it stands for the agents'
answers, part of observing; ``observed_build_s`` in the JSON). Each measurement runs in a fresh process.

Each cold run also reports its stages' CPU time (``time.process_time``, which the other processes
of a shared machine do not inflate as they do wall time) and the process's peak RSS. It also reports its stages (load, validate, reason, derive, plan against an empty
observed state, i.e. everything to create) so the study doubles as the plant-size scaling study:
``replan.png`` plots every stage against the number of resources on log-log axes, and the fitted
slope says how it grows (1 = linear, 2 = quadratic).

A third arm measures one-line edits (``--edits``, default on): in a fresh process an
:class:`engine.incremental.replan.ReplanSession` loads the plant and runs every stage once, then each edit of
:func:`edits` (a resource renamed; a subscription to another broker's topic added with the topic
carried, which makes a bridge route; the same taken back; a topic renamed) is written to the file
and re-planned (read the edit, re-validate, re-reason, derive, plan against an empty observed
state, as the cold run's last stage) — CPU and wall time per stage, and the peak RSS of that
process. The session plans once before the first edit (a running session has planned before; its
plan keeps a per-broker memo); that first plan is reported apart. The baseline is the cold run of the same size in the same run (load + validate + reason
+ derive + plan from scratch, what re-planning an edited plant costs without a session).

Usage: ``python -m benchmarks.bench_replan [--sizes 1000 10000 50000] [--repeat 3] [--no-edits]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

from benchmarks import plots
from benchmarks.common import RESULTS, command_line, loglog_slope, machine, run_child, write_results

_CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
from engine.incremental.desired_cache import DesiredCache
from engine.model import BridgeStatus, BrokerStatus, ObservedBridge, ObservedBroker, ObservedState, ObservedTopic
from engine import pipeline
from engine.pipeline import run_pipeline
from engine.plan import plan
cpu = {}
def cpu_timed(stage, fn):
    def wrapper(*args, **kwargs):
        start = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            cpu[stage] = cpu.get(stage, 0.0) + time.process_time() - start
    return wrapper
for stage, name in (("load", "load_plant"), ("validate", "validate"), ("reason", "reason"), ("derive", "derive")):
    setattr(pipeline, name, cpu_timed(stage, getattr(pipeline, name)))
t1 = time.perf_counter()
result = run_pipeline([sys.argv[1]], None, observe=False, cache=DesiredCache(__import__("pathlib").Path(sys.argv[2])))
d = result.desired
t_pipe = time.perf_counter()
observed = ObservedState(tuple(
    ObservedBroker(b, BrokerStatus.RUNNING, tuple(
        ObservedTopic(t.name, t.partitions, t.replication_factor, t.retention_ms, t.qos, t.retain)
        for t in d.topics_of(b.id)))
    for b in d.brokers), bridges=tuple(ObservedBridge(b, BridgeStatus.RUNNING) for b in d.bridges))
t_obs = time.perf_counter()
p = plan(d, observed)
t2 = time.perf_counter()
c2 = time.process_time()
fresh = plan(d, ObservedState(()))
cpu["plan (all new)"] = time.process_time() - c2
t3 = time.perf_counter()
observed_s = t_obs - t_pipe
print(json.dumps({"import": t1 - t0, "replan": t2 - t1 - observed_s, "observed_build": observed_s,
                  "hit": result.plant is None, "pending": len(p.pending),
                  "stages": {**result.timings, "plan (all new)": t3 - t2}, "cpu": cpu,
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "changes": len(fresh.changes)}))
"""
STAGES = ("load", "validate", "reason", "derive", "plan (all new)")

def edits(n: int) -> tuple[tuple[str, str, str], ...]:
    """Small edits of the synthetic plant of ``n`` resources (benchmarks.synthetic), each
    (name, old text, new text), in order; each keeps the plant valid, so every stage runs."""
    brokers = max(1, -(-n // 20))
    carried = f":res7 pk:subscribes :topic8 .\n:broker{7 % brokers} pk:hasTopic :topic8 .\n"
    return (
        ("rename a resource", 'pk:name "Sensor 5" ;', 'pk:name "Sensor 5 (moved)" ;'),
        ("subscribe to another broker's topic (a bridge route)", ":res7 a pk:Resource ;",
         carried + ":res7 a pk:Resource ;"),
        ("take the subscription back", carried + ":res7 a pk:Resource ;", ":res7 a pk:Resource ;"),
        ("rename a topic", 'pk:name "plant.sensor-3.value"', 'pk:name "plant.sensor-3.level"'),
    )


_EDIT_CHILD = r"""
import json, resource, sys, time
from pathlib import Path
from engine.model import ObservedState
from engine.incremental.replan import ReplanSession
plant, edits = Path(sys.argv[1]), json.loads(sys.argv[2])
w, c = time.perf_counter(), time.process_time()
session = ReplanSession([plant])
start = {"wall": time.perf_counter() - w, "cpu": time.process_time() - c}
w, c = time.perf_counter(), time.process_time()
session.refresh(ObservedState(()))  # the first plan (no edit): a running session has planned before
start["first_plan_wall"], start["first_plan_cpu"] = time.perf_counter() - w, time.process_time() - c
text = plant.read_text()
rows = []
for name, old, new in edits:
    assert old in text, name
    text = text.replace(old, new, 1)
    plant.write_text(text)
    w, c = time.perf_counter(), time.process_time()
    result = session.refresh(ObservedState(()))
    wall, cpu = time.perf_counter() - w, time.process_time() - c
    assert result.report.conforms and result.plan is not None, name
    rows.append({"edit": name, "wall": wall, "cpu": cpu, "stages": session.last["timings"],
                 "cpu_stages": session.last["cpu"],
                 "full": session.last["full"], "read": session.last["cut"],
                 "validation": session.last.get("validation", {}), "changes": len(result.plan.changes)})
print(json.dumps({"start": start, "edits": rows,
                  "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def measure_edits(plant: Path, work: Path) -> dict[str, object]:
    """The edit arm on a copy of ``plant`` (the session edits its file)."""
    copy = work / f"edited-{plant.name}"
    copy.write_bytes(plant.read_bytes())
    n = int(plant.stem.rsplit("-", 1)[1])
    return run_child(_EDIT_CHILD, str(copy), json.dumps(edits(n)))


def measure(sizes: list[int], repeat: int, with_edits: bool = True) -> dict[str, object]:
    from benchmarks import synthetic

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            plant = synthetic.write_file(n, Path(tmp))
            cold, warm = [], []
            for i in range(repeat):
                cache = Path(tmp) / f"cache-{n}-{i}"
                cold.append(run_child(_CHILD, str(plant), str(cache)))
                warm.append(run_child(_CHILD, str(plant), str(cache)))
            assert not any(r["hit"] for r in cold) and all(r["hit"] for r in warm)
            assert all(r["pending"] == 0 for r in cold + warm)
            c = statistics.median(r["replan"] for r in cold)
            w = statistics.median(r["replan"] for r in warm)
            stages = {k: statistics.median(r["stages"][k] for r in cold) for k in STAGES}
            stages["validate+reason+derive+plan"] = sum(stages[k] for k in STAGES if k != "load")
            stages["re-plan, no change"] = w
            cpu = {k: statistics.median(r["cpu"][k] for r in cold) for k in STAGES}
            cpu["validate+reason+derive+plan"] = sum(cpu[k] for k in STAGES if k != "load")
            rows.append({"resources": n, "cold_s": c, "warm_s": w, "ratio": w / c, "stages_s": stages,
                         "observed_build_s": statistics.median(r["observed_build"] for r in warm),
                         "cpu_s": cpu, "peak_rss_mib": statistics.median(r["peak_rss_mib"] for r in cold),
                         "changes": cold[0]["changes"]})
            if with_edits:
                rows[-1]["edits"] = measure_edits(plant, Path(tmp))
            print(json.dumps(rows[-1]), flush=True)
    slopes = {k: loglog_slope([r["resources"] for r in rows], [r["stages_s"][k] for r in rows])
              for k in rows[0]["stages_s"]} if rows else {}
    return {"benchmark": "replan", "machine": machine(), "repeat": repeat, "rows": rows, "slopes": slopes}


def to_markdown(data: dict[str, object]) -> str:
    lines = ["# re-plan of an unchanged plant: cached desired state vs from scratch", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · median of {data['repeat']}", "",
             "| resources | from scratch s (load+validate+reason+derive+plan) | cached s (hash+read+plan) | cached / scratch |",
             "|---|---|---|---|"]
    for r in data["rows"]:  # type: ignore[union-attr]
        lines.append(f"| {r['resources']} | {r['cold_s']:.3f} | {r['warm_s']:.3f} | {r['ratio']:.3f} |")
    if data["rows"] and "stages_s" in data["rows"][0]:  # type: ignore[index]
        names = list(data["rows"][0]["stages_s"])  # type: ignore[index]
        lines += ["", "## Scaling: each stage against plant size (median s; slope of log time on log size)", "",
                  "| resources | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
        for r in data["rows"]:  # type: ignore[union-attr]
            lines.append(f"| {r['resources']} | " + " | ".join(f"{r['stages_s'][k]:.3f}" for k in names) + " |")
        slopes = data["slopes"]
        lines.append("| **slope** | " + " | ".join("–" if slopes[k] is None else f"**{slopes[k]:.2f}**"  # type: ignore[index]
                                                  for k in names) + " |")
    edited = [r for r in data["rows"] if r.get("edits")]  # type: ignore[union-attr]
    if edited:
        lines += ["", "## One-line edits re-planned by a session (engine.incremental.replan), against planning the edited plant "
                  "from scratch (the cold run above, same run)", "",
                  "Each edit: read it, re-validate, re-reason, derive, plan against an empty observed state. "
                  "CPU s (wall s); the stage split is CPU time (wall time inflates with the machine's other load).", "",
                  "| resources | edit | re-plan CPU s (wall) | read | validate | reason | derive | plan | from scratch s "
                  "| re-plan / scratch | done in full |", "|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in edited:
            for e in r["edits"]["edits"]:
                st = e.get("cpu_stages", e["stages"])
                lines.append(f"| {r['resources']} | {e['edit']} | **{e['cpu']:.3f}** ({e['wall']:.3f}) | "
                             + " | ".join(f"{st.get(k, 0.0):.3f}" for k in ("read", "validate", "reason", "derive", "plan"))
                             + f" | {r['cold_s']:.2f} | {e['wall'] / r['cold_s']:.3f} | {', '.join(e['full']) or '–'} |")
        lines += ["", "| resources | session start CPU s (wall) | first plan CPU s (wall) | session peak RSS MiB |",
                  "|---|---|---|---|"]
        for r in edited:
            st = r["edits"]["start"]
            lines.append(f"| {r['resources']} | {st['cpu']:.2f} ({st['wall']:.2f}) | {st.get('first_plan_cpu', 0.0):.2f} "
                         f"({st.get('first_plan_wall', 0.0):.2f}) | {r['edits']['peak_rss_mib']:.0f} |")
    if data["rows"] and "cpu_s" in data["rows"][0]:  # type: ignore[index]
        names = list(data["rows"][0]["cpu_s"])  # type: ignore[index]
        lines += ["", "## CPU time of each stage (median s, time.process_time) and peak RSS of the process", "",
                  "| resources | " + " | ".join(names) + " | peak RSS MiB |", "|---" * (len(names) + 2) + "|"]
        for r in data["rows"]:  # type: ignore[union-attr]
            lines.append(f"| {r['resources']} | " + " | ".join(f"{r['cpu_s'][k]:.3f}" for k in names)
                         + f" | {r['peak_rss_mib']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="re-plan benchmark")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 50000])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--no-edits", action="store_true", help="skip the one-line-edit arm")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = measure(args.sizes, args.repeat, with_edits=not args.no_edits)
    data["command"] = command_line("benchmarks.bench_replan", argv)
    write_results(args.out, "replan", data, to_markdown(data))
    plots.scale(data, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``benchmarks/RESULTS.md``: the latest table and plots of every study, the machine and load each
ran under, the command that produced it, the issue's goals as ratios measured in the same run, and
the conclusions (``benchmarks/conclusions.md``, written by a person from these data).

Rebuilt from the results folder alone (``plantkg-bench report``), so it never shows a figure no
result file holds.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from benchmarks.common import ROOT
from benchmarks.staleness import stale_note

CONCLUSIONS = ROOT / "benchmarks" / "conclusions.md"
SECTIONS = (
    ("deploy", "1. Deployment latency (the paper's Table 1)", ()),
    ("load", "2. Load test (the paper's Fig. 12), bring-up and memory; message sizes",
     ("load.png", "load-nodelay.png", "load-sizes.png", "load-bringup.png")),
    ("replan", "3. Plant size scaling and re-planning", ("replan.png",)),
    ("bridge", "Bridges against the raw paths (Mosquitto ↔ Mosquitto, MQTT ↔ Kafka)", ()),
    ("durability", "What a SIGKILL loses, and what Mosquitto's save policies cost", ()),
    ("web", "Dashboard and SPARQL endpoint", ()),
    ("context_broker", "NGSI-v2 context broker against raw Mosquitto", ()),
    ("bridge_ngsi", "MQTT → NGSI bridge worker against direct upserts", ()),
    ("fleet_join", "AGVs joining by plug and play against a bare VDA 5050 master", ()),
    ("fleet_tasks", "LoTLan transport orders over simulated AGVs against the ideal (the task planner)",
     ("fleet_tasks-paths.png", "fleet_tasks-gantt.png")),
    ("cli", "Command-line start-up against a bare Python start", ()),
    ("security", "Mosquitto and a Mosquitto bridge with users, ACLs and TLS against the same open and plain (issue 13)", ()),
    ("kafka_cluster", "A 3-node Kafka cluster against the same nodes by hand; RF 1 vs RF 3; MirrorMaker 2 (issue 14)", ()),
    ("validate", "Validation against pySHACL", ()),
    ("reason", "Reasoning against HermiT", ()),
)


def _read(results: Path, name: str) -> dict[str, Any] | None:
    path = results / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None


def goals(results: Path) -> list[tuple[str, str, str, str]]:
    """(goal, measured, target, verdict) for each goal of the issue that the results cover."""
    out = []
    deploy, load, replan = (_read(results, n) for n in ("deploy", "load", "replan"))
    if deploy:
        ms = deploy["ms"]
        out.append(("deploy through plantkg / bare local deploy (Mosquitto)",
                    f"{ms['plantkg']['mean']:.1f} / {ms['bare']['mean']:.1f} ms = {ms['plantkg']['ratio']:.2f}x",
                    "≤ 1.2x", _verdict(ms["plantkg"]["ratio"] <= 1.2)))
        if "plantkg-cli" in ms:
            cli_row = ms["plantkg-cli"]
            out.append(("`plantkg apply` of one Mosquitto, whole process / bare local deploy",
                        f"{cli_row['mean']:.0f} / {ms['bare']['mean']:.1f} ms = {cli_row['ratio']:.1f}x",
                        "≤ 10x", _verdict(cli_row["ratio"] <= 10)))
        if "plantkg-cli-served" in ms:
            served = ms["plantkg-cli-served"]
            out.append(("`plantkg apply` of one Mosquitto, whole process, a `plantkg serve` of the plant "
                        "running (the command runs in it, warm) / bare local deploy",
                        f"{served['mean']:.0f} / {ms['bare']['mean']:.1f} ms = {served['ratio']:.1f}x",
                        "≤ 10x", _verdict(served["ratio"] <= 10)))
    if load:
        big = max(load["rows"], key=lambda r: r["brokers"])
        b = big["bringup"]
        out.append((f"one apply of {big['brokers']} Mosquitto / spawning them by hand in parallel",
                    f"{b['plantkg_up_s']:.2f} / {b['hand_up_s']:.2f} s = {b['up_ratio']:.2f}x", "≤ 1.5x",
                    _verdict(b["up_ratio"] <= 1.5)))
        out.append((f"one destroy of {big['brokers']} Mosquitto / SIGTERM to all by hand, then wait",
                    f"{b['plantkg_down_s']:.2f} / {b['hand_down_s']:.2f} s = {b['down_ratio']:.2f}x", "≤ 2x",
                    _verdict(b["down_ratio"] <= 2)))
    for row in (replan or {}).get("rows", []):
        if row["resources"] == 10000 and "stages_s" in row:
            total = row["stages_s"]["validate+reason+derive+plan"]
            out.append(("validate+reason+derive+plan, 10k resources", f"{total:.2f} s", "< 3 s", _verdict(total < 3)))
            out.append(("re-plan with no change, 10k resources",
                        f"{row['warm_s']:.3f} s ({row['ratio']:.3f}x of from scratch)", "< 0.3 s",
                        _verdict(row["warm_s"] < 0.3)))
        if row["resources"] == 100000 and "cpu_s" in row:  # issue 16
            cpu = row["cpu_s"]["validate+reason+derive+plan"]
            out.append(("validate+reason+derive+plan, 100k resources (CPU)", f"{cpu:.1f} s", "< 10 s", _verdict(cpu < 10)))
            out.append(("peak RSS of that process, 100k resources", f"{row['peak_rss_mib']:.0f} MiB", "< 500 MiB",
                        _verdict(row["peak_rss_mib"] < 500)))
            edits = (row.get("edits") or {}).get("edits") or []
            if edits:
                worst = max(e["wall"] for e in edits)
                out.append(("one-line-edit re-plan, 100k resources (slowest edit, wall)",
                            f"{worst:.2f} s ({worst / row['cold_s']:.3f}x of from scratch)", "< 0.5 s",
                            _verdict(worst < 0.5)))
    one = next((r for r in (_read(results, "fleet_join") or {}).get("rows", []) if r["count"] == 1), None)
    if one:
        worst = one["ready"]["max"]
        out.append(("one AGV: connection ONLINE -> ready for tasks (plug and play)", f"{worst:.0f} ms (max)",
                    "< 1 s", _verdict(worst < 1000)))
    for g in (_read(results, "fleet_tasks") or {}).get("goals", []):  # verdicts computed by the study
        out.append((f"task planner: {g['goal']}", g["measured"], g["target"], _verdict(g["met"])))
    cli = _read(results, "cli")
    if cli and "plantkg --help" in cli.get("median_s", {}):
        median, bare = cli["median_s"]["plantkg --help"], cli["median_s"].get("python -c pass")
        ratio = f" ({median / bare:.1f}x python -c pass)" if bare else ""
        out.append(("plantkg --help, whole process (median)", f"{median * 1000:.0f} ms{ratio}", "< 0.15 s",
                    _verdict(median < 0.15)))
    for g in (_read(results, "context_broker") or {}).get("goals", []):  # verdicts computed by the study
        out.append((f"context broker: {g['goal']}", g["measured"], g["target"], _verdict(g["met"])))
    for name in ("security", "bridge", "durability", "kafka_cluster"):  # verdicts computed by the study
        for g in (_read(results, name) or {}).get("goals", []):
            out.append((g["goal"], g["measured"], g["target"], _verdict(g["met"])))
    return out


def load_effects(load: dict[str, Any]) -> list[str]:
    """Markdown: how much the number of messages and the number of brokers each move the mean
    latency of the load matrix (ms, same run), and each broker count's mean over all burst sizes
    with the spread between repeats — the figures the conclusions about Fig. 12 rest on."""
    cells = [c for r in load["rows"] for c in r["cells"] if c["study"] == "matrix"]
    if not cells:
        return []
    ns, ms = sorted({c["brokers"] for c in cells}), sorted({c["messages"] for c in cells})
    lines = ["| mode | latency | + messages (" f"{ms[0]} → {ms[-1]}" ", mean over broker counts) | + brokers ("
             f"{ns[0]} → {ns[-1]}, mean over message counts) | " + " | ".join(f"{n} brokers: mean ± stdev of repeats"
                                                                           for n in ns) + " |",
             "|---|---|---|---|" + "---|" * len(ns)]
    for mode in sorted({c["mode"] for c in cells}, reverse=True):
        for kind in ("ack", "delivery"):
            at = {(c["brokers"], c["messages"]): c for c in cells if c["mode"] == mode}

            def mean(key: tuple[int, int]) -> float:
                return float(at[key][kind]["mean"])

            by_m = [mean((n, ms[-1])) - mean((n, ms[0])) for n in ns if (n, ms[0]) in at and (n, ms[-1]) in at]
            by_n = [mean((ns[-1], m)) - mean((ns[0], m)) for m in ms if (ns[0], m) in at and (ns[-1], m) in at]
            per_n = []
            for n in ns:
                row = [at[(n, m)] for m in ms if (n, m) in at]
                avg = sum(c[kind]["mean"] for c in row) / len(row)
                spread = sum(c[f"{kind}_mean_of_repeats_stdev"] for c in row) / len(row)
                per_n.append(f"{avg:.1f} ± {spread:.1f}")
            lines.append(f"| {mode} | {kind} | {_avg(by_m):+.1f} ms | {_avg(by_n):+.1f} ms | " + " | ".join(per_n) + " |")
    return lines


def _avg(xs: list[float]) -> float:
    return sum(xs) / len(xs) if xs else float("nan")


def _verdict(ok: bool) -> str:
    return "met" if ok else "**not met**"


def _run_line(data: dict[str, Any]) -> str:
    m = data.get("machine", {})
    start = ", ".join(f"{x:.2f}" for x in m.get("load_average", ()))
    end = ", ".join(f"{x:.2f}" for x in data.get("load_average_end", ()))
    return (f"Command: `{data.get('command', '?')}` · {m.get('cpus', '?')} CPUs, Python {m.get('python', '?')}, "
            f"{m.get('platform', '?')}, commit {m.get('commit', '?')} · load average (1, 5, 15 min) at start {start or '?'}, at end {end or '?'}")


def _table_of(md: str) -> str:
    """A study's markdown without its title and command line (the report gives its own)."""
    lines = md.splitlines()
    body = ["#" + ln if ln.startswith("## ") else ln for ln in lines[1:] if not ln.startswith("Command:")]
    return "\n".join(body).strip()


def render(results: Path, base: Path) -> str:
    rel = results.relative_to(base) if results.is_relative_to(base) else results
    lines = ["# Benchmark results", "",
             "Rebuilt by `plantkg-bench report` from `benchmarks/results/` (raw JSON and CSV next to each table). "
             "Re-run everything with `make bench` (or `plantkg-bench`); each section gives the exact command of "
             "its run, the machine, and the load average at its start and end, to judge the noise. Absolute "
             "times drift between machines: the ratios to a baseline measured in the same run are the figures.",
             "", "## Goals", "", "| goal | measured | target | |", "|---|---|---|---|"]
    lines += [f"| {g} | {m} | {t} | {v} |" for g, m, t, v in goals(results)]
    load = _read(results, "load")
    effects = load_effects(load) if load else []
    if effects:
        lines += ["", "### What moves the load test's latency (from `results/load.json`)", "", *effects]
    notes = {name: stale_note(ROOT, name, data) for name, _t, _i in SECTIONS
             if (data := _read(results, name)) is not None and (results / f"{name}.md").is_file()}
    stale = [f"- {title}: {notes[name]}" for name, title, _i in SECTIONS if notes.get(name)]
    if stale:
        lines += ["", "### Tables that may not describe the current code", "",
                  "Checked against the commit each run recorded (`benchmarks/staleness.py`):", "", *stale]
    if CONCLUSIONS.is_file():
        lines += ["", CONCLUSIONS.read_text().strip()]
    for name, title, images in SECTIONS:
        data = _read(results, name)
        md = results / f"{name}.md"
        if data is None or not md.is_file():
            continue
        lines += ["", f"## {title}", "", _run_line(data)]
        if notes.get(name):
            lines += ["", str(notes[name])]
        lines += ["", _table_of(md.read_text())]
        lines += [f"\n![{img}]({rel / img})" for img in images if (results / img).is_file()]
    return "\n".join(lines) + "\n"


def write(results: Path, path: Path) -> Path:
    path.write_text(render(results, path.parent))
    return path

"""The benchmarks' plots (PNG, matplotlib's non-interactive backend), drawn from their results'
JSON data so a plot can be redrawn without re-measuring. Small figures at a low resolution keep
each PNG well under 200 KB in the repository."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402 - the backend is chosen first

DPI = 80


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def load(data: dict[str, Any], out: Path) -> list[Path]:
    """``load.png`` (the paper's Fig. 12: mean latency against messages, a line per broker count),
    ``load-sizes.png`` and ``load-bringup.png``."""
    cells = [c for r in data["rows"] for c in r["cells"]]
    paths = [_latency_matrix(cells, out / "load.png")]
    if any(c["study"] == "size" for c in cells):
        paths.append(_sizes(cells, out / "load-sizes.png"))
    if any(c["study"].startswith("tcp-") for c in cells):
        paths.append(_nodelay(cells, out / "load-nodelay.png"))
    paths.append(_bringup(data["rows"], out / "load-bringup.png"))
    return paths


def _nodelay(cells: list[dict[str, Any]], path: Path) -> Path:
    arms = [c for c in cells if c["study"].startswith("tcp-")]
    fig, axes = plt.subplots(1, 2, figsize=(9, 3.2))
    for ax, kind in zip(axes, ("ack", "delivery")):
        for study, style in (("tcp-default", "--"), ("tcp-nodelay", "-")):
            for n in sorted({c["brokers"] for c in arms}):
                pts = sorted((c["messages"], c[kind]["mean"], c[kind]["p99"]) for c in arms
                             if c["study"] == study and c["brokers"] == n)
                ax.plot([p[0] for p in pts], [p[1] for p in pts], style, marker="o", ms=3, label=f"{study}, {n}, mean")
                ax.plot([p[0] for p in pts], [p[2] for p in pts], style, marker="x", ms=3, label=f"{study}, {n}, p99")
        ax.set_title(f"publish → {'PUBACK' if kind == 'ack' else 'delivery'}", fontsize=10)
        ax.set_xlabel("messages in the burst")
        ax.set_ylabel("latency, ms")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=6)
    return _save(fig, path)


def _latency_matrix(cells: list[dict[str, Any]], path: Path) -> Path:
    matrix = [c for c in cells if c["study"] == "matrix"]
    modes = sorted({c["mode"] for c in matrix}, reverse=True)
    fig, axes = plt.subplots(len(modes), 2, figsize=(9, 3.2 * len(modes)), squeeze=False)
    for row, mode in enumerate(modes):
        for col, kind in enumerate(("ack", "delivery")):
            ax = axes[row][col]
            for n in sorted({c["brokers"] for c in matrix}):
                pts = sorted((c["messages"], c[kind]["mean"], c[f"{kind}_mean_of_repeats_stdev"])
                             for c in matrix if c["mode"] == mode and c["brokers"] == n)
                ax.errorbar([p[0] for p in pts], [p[1] for p in pts], yerr=[p[2] for p in pts],
                            marker="o", ms=3, capsize=2, label=f"{n} brokers")
            ax.set_title(f"{mode}: publish → {'PUBACK' if kind == 'ack' else 'delivery'}", fontsize=10)
            ax.set_xlabel("messages in the burst")
            ax.set_ylabel("mean latency, ms")
            ax.grid(alpha=0.3)
    axes[0][1].legend(fontsize=7)
    return _save(fig, path)


def _sizes(cells: list[dict[str, Any]], path: Path) -> Path:
    sized = [c for c in cells if c["study"] == "size"]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for n in sorted({c["brokers"] for c in sized}):
        for kind, style in (("ack", "--"), ("delivery", "-")):
            pts = sorted((c["size"], c[kind]["mean"]) for c in sized if c["brokers"] == n)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], style, marker="o", ms=3, label=f"{n} brokers, {kind}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("payload, bytes")
    ax.set_ylabel("mean latency, ms")
    ax.set_title(f"{sized[0]['messages']} messages at once, spread", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return _save(fig, path)


def _bringup(rows: list[dict[str, Any]], path: Path) -> Path:
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ns = [r["brokers"] for r in rows]
    for key, label, style in (("hand_up_s", "by hand, up", "--"), ("plantkg_up_s", "one apply, up", "-"),
                              ("hand_down_s", "by hand, down", ":"), ("plantkg_down_s", "one destroy", "-.")):
        ax.plot(ns, [r["bringup"][key] for r in rows], style, marker="o", ms=3, label=label)
    ax.set_xlabel("Mosquitto brokers")
    ax.set_ylabel("seconds")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, path)


def scale(data: dict[str, Any], out: Path) -> Path:
    """``replan.png``: time of each stage against plant size, log-log, with the fitted slopes."""
    rows = data["rows"]
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for stage, slope in data["slopes"].items():
        pts = [(r["resources"], r["stages_s"][stage]) for r in rows if r["stages_s"].get(stage)]
        if not pts:
            continue
        label = f"{stage} (slope {slope:.2f})" if slope is not None else stage
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3, label=label)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("resources in the plant")
    ax.set_ylabel("seconds")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    return _save(fig, out / "replan.png")


def fleet_paths(data: dict[str, Any], path: Path) -> Path:
    """``fleet_tasks-paths.png`` (the paper's Fig. 8): every vehicle's sampled positions as a line
    over the map's stations (pick/drop as squares, parking as dots, chargers as triangles)."""
    the_map = data["map"]
    fig, ax = plt.subplots(figsize=(6, 6 * the_map["height"] / the_map["width"] + 0.6))
    for name, track in sorted(data["paths"].items()):
        if track:
            ax.plot([p[1] for p in track], [p[2] for p in track], lw=0.6, alpha=0.6, label=name.split("/")[-1])
    for s in the_map["stations"]:
        marker = "^" if s.get("charger") else "." if s["name"].startswith("park-") else "s"
        ax.plot(s["x"], s["y"], marker, color="black", ms=5 if marker == "s" else 4)
        if marker == "s":
            ax.annotate(s["name"], (s["x"], s["y"]), fontsize=6, xytext=(3, 2), textcoords="offset points")
    ax.set_xlim(0, the_map["width"])
    ax.set_ylim(0, the_map["height"])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"paths of {data['vehicles']} AGVs, {data['orders']} orders")
    if len(data["paths"]) <= 10:
        ax.legend(fontsize=6, loc="upper center", ncol=5)
    return _save(fig, path)


def fleet_gantt(data: dict[str, Any], path: Path) -> Path:
    """``fleet_tasks-gantt.png``: a row per vehicle, a bar per task from ASSIGNED to FINISHED — the
    drive to the pickup and the pick in one shade, the drive to the drop and the drop in another."""
    rows = sorted({t["vehicle"] for t in data["gantt"]})
    fig, ax = plt.subplots(figsize=(8, 0.35 * len(rows) + 1.2))
    for y, vehicle in enumerate(rows):
        for t in (t for t in data["gantt"] if t["vehicle"] == vehicle):
            end = t["finished"]
            if end is None:
                continue
            middle = t["leg0_done"] if t["leg0_done"] is not None else end
            ax.barh(y, middle - t["assigned"], left=t["assigned"], height=0.6, color="tab:blue", edgecolor="white", lw=0.3)
            ax.barh(y, end - middle, left=middle, height=0.6, color="tab:orange", edgecolor="white", lw=0.3)
            if len(data["gantt"]) <= 30:
                ax.annotate(t["id"], (t["assigned"], y), fontsize=6, xytext=(1, 6), textcoords="offset points")
    ax.set_yticks(range(len(rows)), [r.split("/")[-1] for r in rows], fontsize=7)
    ax.set_xlabel("seconds after the job started")
    ax.set_title("tasks per vehicle (blue: to pickup + pick, orange: to drop + drop)", fontsize=9)
    return _save(fig, path)

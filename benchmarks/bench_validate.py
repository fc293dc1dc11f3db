"""Benchmark: load + validate synthetic plants with plantkg, against pySHACL in the same run.

For each size it writes a synthetic plant (``benchmarks/synthetic.py``), then runs, each in a fresh
Python process so memory and import costs are not shared:

- ``plantkg``: ``plantkg validate --engine oxigraph`` as a user runs it (whole command, wall time,
  peak RSS), plus the in-process split into load and validate;
- ``pyshacl`` (baseline): rdflib parses the plant and the ontology, pySHACL validates with the same
  shapes — what the project would cost without the fast engine. The baseline already has
  plantkg's fix for pySHACL's per-focus-node query re-parse (``kg.validate.PreparedQueryGraph``);
  stock pySHACL 0.40 needs over 5 minutes for the 1k plant, so it is not worth a row. With today's
  shapes (44 SHACL-SPARQL constraints, each evaluated per focus node by rdflib) even the baseline
  took ~370 s at 1k resources (Nov 2026), so it runs up to ``--reference-max`` 1000 by default.

Results go to ``benchmarks/results/validate.json`` (raw) and ``validate.md`` (table, ratios).
Absolute times drift on shared machines; the ratio plantkg/pyshacl from the same run is the figure.

Usage: ``python -m benchmarks.bench_validate [--sizes 1000 10000 50000] [--repeat 3]
[--reference-max 1000]``
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS, ROOT, machine, run_child, write_results

_CHILD = r"""
import json, resource, sys, time
t0 = time.perf_counter()
mode, plant = sys.argv[1], sys.argv[2]
if mode == "plantkg":
    from kg.load import load_plant
    from kg.validate import validate
    t1 = time.perf_counter()
    p = load_plant([plant])
    t2 = time.perf_counter()
    report = validate(p, engine="oxigraph")
    t3 = time.perf_counter()
    out = {"import": t1 - t0, "load": t2 - t1, "validate": t3 - t2, "results": len(report.results),
           "conforms": report.conforms, "triples": p.triple_count}
else:
    import rdflib, pyshacl
    from kg import resources
    from kg.validate import PreparedQueryGraph
    t1 = time.perf_counter()
    g = PreparedQueryGraph()  # rdflib parses each SPARQL text once (stock pySHACL: once per focus node)
    g.parse(plant, format="turtle")
    g.parse(resources.ontology_file(), format="turtle")
    sg = rdflib.Graph()
    for f in resources.shapes_files():
        sg.parse(f, format="turtle")
    t2 = time.perf_counter()
    conforms, results, _ = pyshacl.validate(g, shacl_graph=sg, inference="none", advanced=True,
                                            allow_warnings=True, inplace=True)
    t3 = time.perf_counter()
    n = len(set(results.subjects(rdflib.RDF.type, rdflib.URIRef("http://www.w3.org/ns/shacl#ValidationResult"))))
    out = {"import": t1 - t0, "load": t2 - t1, "validate": t3 - t2, "results": n, "conforms": conforms,
           "triples": len(g)}
out["total"] = time.perf_counter() - t0
out["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""


def _child(mode: str, plant: Path) -> dict[str, float]:
    return run_child(_CHILD, mode, str(plant))  # type: ignore[return-value]


def _cli(plant: Path) -> float:
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "engine.cli", "validate", "--engine", "oxigraph", str(plant)],
                          capture_output=True, text=True, cwd=ROOT)
    elapsed = time.perf_counter() - start
    if proc.returncode != 0:
        raise RuntimeError(f"plantkg validate failed ({proc.returncode}): {proc.stdout[-500:]}{proc.stderr[-500:]}")
    return elapsed


def _median(runs: list[dict[str, float]], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def measure(sizes: list[int], repeat: int, reference_max: int) -> dict[str, object]:
    from benchmarks import synthetic

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            plant = synthetic.write_file(n, Path(tmp))
            row: dict[str, object] = {"resources": n, "bytes": plant.stat().st_size}
            ours, cli, ref = [], [], []
            for _ in range(repeat):  # interleaved, so drift hits both alike
                ours.append(_child("plantkg", plant))
                cli.append(_cli(plant))
                if n <= reference_max:
                    ref.append(_child("pyshacl", plant))
            row["plantkg"] = {k: _median(ours, k) for k in ("import", "load", "validate", "total", "max_rss_mb")}
            row["plantkg"]["results"] = ours[0]["results"]  # type: ignore[index]
            row["triples"] = ours[0]["triples"]
            row["plantkg_cli_s"] = statistics.median(cli)
            if ref:
                row["pyshacl"] = {k: _median(ref, k) for k in ("import", "load", "validate", "total", "max_rss_mb")}
                row["pyshacl"]["results"] = ref[0]["results"]  # type: ignore[index]
                row["ratio_total"] = row["plantkg"]["total"] / row["pyshacl"]["total"]  # type: ignore[index]
            rows.append(row)
            print(json.dumps(row), flush=True)
    return {
        "benchmark": "validate",
        "machine": machine(),
        "repeat": repeat,
        "command": "python -m benchmarks.bench_validate " + " ".join(sys.argv[1:]),
        "rows": rows,
    }


def to_markdown(data: dict[str, object]) -> str:
    lines = [
        "# validate: plantkg (Oxigraph + SPARQL-compiled shapes) vs pySHACL, same run",
        "",
        f"Command: `{data['command']}` · machine: {data['machine']} · median of {data['repeat']}",
        "",
        "| resources | triples | plantkg load s | plantkg validate s | plantkg total s | `plantkg validate` CLI s | plantkg RSS MB | pyshacl parse s | pyshacl validate s | pyshacl total s | pyshacl RSS MB | plantkg/pyshacl |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in data["rows"]:  # type: ignore[union-attr]
        p, q = r["plantkg"], r.get("pyshacl")
        ref = (f"{q['load']:.2f} | {q['validate']:.2f} | {q['total']:.2f} | {q['max_rss_mb']:.0f} | {r['ratio_total']:.3f}"
               if q else "– | – | – | – | –")
        lines.append(f"| {r['resources']} | {r['triples']} | {p['load']:.2f} | {p['validate']:.2f} | {p['total']:.2f} | "
                     f"{r['plantkg_cli_s']:.2f} | {p['max_rss_mb']:.0f} | {ref} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="validate benchmark")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 50000])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--reference-max", type=int, default=1000,
                        help="run the pySHACL baseline only up to this many resources")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = measure(args.sizes, args.repeat, args.reference_max)
    write_results(args.out, "validate", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Benchmark: requests/s and latency of ``plantkg serve`` — ``/sparql`` and ``/api/status`` — on a
synthetic plant (benchmarks/synthetic.py), over loopback.

``plantkg serve`` runs as its own process, as a user runs it. Its agents file sends every host to a
closed loopback port, so every agent is *unreachable* (no broker runs; the status document still
lists every broker, topic and bridge, as for a running plant). The load generator is a bounded
loop: ``--threads`` Python threads, each sending ``--requests`` requests one after another on a
fresh connection each (the server speaks HTTP/1.0). Measured: requests per second over the whole
run, and the median and 99th percentile of the latency. Two SPARQL queries: *lookup*, the typical
question "where does resource res-N send" (one row), and *listing*, the dashboard's first example
("which resource sends where", ORDER BY over every resource, LIMIT 200; sent a quarter as often:
Oxigraph sorts 10k rows in about half a second). The status is the full document (no ETag).

Goal of issue 5: the status of a 10k-resource plant under 200 ms at p99.

Usage: ``python -m benchmarks.bench_web [--sizes 10000] [--requests 200] [--threads 4]``
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pyoxigraph as ox

from benchmarks.common import RESULTS, command_line, machine, write_results
from engine import netutil, process
from engine.agent.local import plantkg_command
from engine.web.examples import EXAMPLES
from kg.query import values_clause

GOAL_P99_MS = 200.0
LOOKUP = """SELECT ?broker ?kind ?ip ?port WHERE {
  ?r pk:id ?id ; pk:sendsTo ?b . ?b pk:id ?broker ; pk:brokerType ?kind ; pk:ip ?ip ; pk:port ?port }"""
READY_S = 600.0


def _agents_file(plant: Path, directory: Path) -> Path:
    """Every host of the plant sent to one closed port (agents that do not answer)."""
    closed = netutil.free_port()
    hosts = sorted({line.split('pk:ip "')[1].split('"')[0] for line in plant.read_text().splitlines()
                    if 'pk:ip "' in line})
    lines = []
    for host in hosts:
        lines += [f'[agents."{host}"]', f'url = "http://127.0.0.1:{closed}"', f'token = "{"x" * 20}"', ""]
    path = directory / "agents.toml"
    path.write_text("\n".join(lines))
    os.chmod(path, 0o600)
    return path


def _get(url: str, accept: str) -> tuple[float, int]:
    request = urllib.request.Request(url, headers={"Accept": accept})
    start = time.perf_counter()
    with urllib.request.urlopen(request, timeout=60) as answer:
        size = len(answer.read())
        assert answer.status == 200
    return time.perf_counter() - start, size


def load(url: str, accept: str, threads: int, requests: int) -> dict[str, float]:
    """``threads`` clients, ``requests`` each; requests/s, p50 and p99 latency (ms), answer size."""
    latencies: list[float] = []
    sizes: list[int] = []
    lock = threading.Lock()

    def client() -> None:
        mine = [_get(url, accept) for _ in range(requests)]
        with lock:
            latencies.extend(t for t, _ in mine)
            sizes.extend(s for _, s in mine)

    _get(url, accept)  # warm: the first status after a change is built once, then cached
    began = time.perf_counter()
    workers = [threading.Thread(target=client) for _ in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    wall = time.perf_counter() - began
    latencies.sort()
    assert len(latencies) == threads * requests, "a client failed (see above)"
    return {"requests": len(latencies), "rps": len(latencies) / wall,
            "p50_ms": 1000 * statistics.median(latencies),
            "p99_ms": 1000 * latencies[min(len(latencies) - 1, int(0.99 * len(latencies)))],
            "bytes": statistics.median(sizes)}


def measure_size(n: int, threads: int, requests: int, tmp: Path) -> dict[str, object]:
    from benchmarks import synthetic

    plant = synthetic.write_file(n, tmp)
    agents = _agents_file(plant, tmp)
    token = tmp / "token"
    token.write_text("bench-web-token-0123456789\n")
    os.chmod(token, 0o600)
    port = netutil.free_port()
    began = time.perf_counter()
    child = process.spawn([*plantkg_command(), "serve", plant, "--listen", f"127.0.0.1:{port}",
                           "--agents", agents, "--token-file", token, "--observe-interval", "5",
                           # every load thread is the same client (127.0.0.1): let all of them query
                           "--max-queries", str(max(4, threads)), "--max-client-queries", str(threads)],
                          log_dir=tmp / "logs", name=f"serve-{n}")
    base = f"http://127.0.0.1:{port}"
    try:
        def ready() -> bool:
            with urllib.request.urlopen(base + "/api/status", timeout=30) as answer:
                return json.loads(answer.read())["observed_at"] is not None
        process.wait_until(ready, READY_S, 0.2, what="plantkg serve", child=child, ignore=(OSError,))
        ready_s = time.perf_counter() - began
        lookup = LOOKUP + values_clause({"id": ox.Literal(f"res-{n // 2}")})  # bound, not spliced
        sparql = load(f"{base}/sparql?{urllib.parse.urlencode({'query': lookup})}",
                      "application/sparql-results+json", threads, requests)
        listing = load(f"{base}/sparql?{urllib.parse.urlencode({'query': EXAMPLES[0].query})}",
                       "application/sparql-results+json", threads, max(1, requests // 4))
        status = load(f"{base}/api/status", "application/json", threads, requests)
    finally:
        process.stop(child)
    assert sparql["bytes"] > 100, "the lookup found nothing"
    row = {"resources": n, "ready_s": ready_s, "sparql": sparql, "listing": listing, "status": status}
    print(json.dumps(row), flush=True)
    return row


def measure(sizes: list[int], threads: int, requests: int) -> dict[str, object]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in sizes:
            folder = Path(tmp) / str(n)
            folder.mkdir()
            rows.append(measure_size(n, threads, requests, folder))
    return {"benchmark": "web", "machine": machine(), "threads": threads, "requests_per_thread": requests,
            "goal_status_p99_ms": GOAL_P99_MS, "rows": rows}


def to_markdown(data: dict[str, object]) -> str:
    lines = ["# plantkg serve under load: /sparql and /api/status over loopback", "",
             f"Command: `{data['command']}` · machine: {data['machine']} · {data['threads']} client threads × "
             f"{data['requests_per_thread']} requests · goal: status p99 < {GOAL_P99_MS:.0f} ms", "",
             "| resources | request | req/s | p50 ms | p99 ms | answer bytes |", "|---|---|---|---|---|---|"]
    names = {"sparql": "/sparql lookup (typical)", "listing": "/sparql listing (ORDER BY, LIMIT 200)",
             "status": "/api/status"}
    for r in data["rows"]:  # type: ignore[union-attr]
        for key, name in names.items():
            m = r[key]
            lines.append(f"| {r['resources']} | {name} | {m['rps']:.0f} | {m['p50_ms']:.1f} | {m['p99_ms']:.1f} | "
                         f"{m['bytes']:.0f} |")
    lines.append("")
    for r in data["rows"]:  # type: ignore[union-attr]
        p99 = r["status"]["p99_ms"]
        lines.append(f"- {r['resources']} resources: ready {r['ready_s']:.1f} s after start; status p99 "
                     f"{p99:.1f} ms — goal {'met' if p99 < GOAL_P99_MS else 'NOT met'} (< {GOAL_P99_MS:.0f} ms).")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="plantkg serve benchmark")
    parser.add_argument("--sizes", type=int, nargs="+", default=[10000])
    parser.add_argument("--threads", type=int, default=4)
    parser.add_argument("--requests", type=int, default=200, help="requests per thread")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    data = measure(args.sizes, args.threads, args.requests)
    data["command"] = command_line("benchmarks.bench_web", argv)
    write_results(args.out, "web", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

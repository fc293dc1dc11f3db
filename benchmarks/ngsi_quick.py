"""A quick measurement of the context broker: updates/s and q latency (the full study is
benchmarks/bench_context_broker.py).

- updates: ``PATCH /v2/entities/{id}/attrs`` back to back, 1 and 8 clients (each its own
  keep-alive connection and entity), for ``--duration`` s; the clients run as threads of
  ``--processes`` separate processes (``spawn``, default 1), so they do not share the server's
  interpreter lock. ``--client http`` (default) sends with ``http.client``; ``--client raw``
  writes the same request bytes on a bare socket and reads the answer by its Content-Length,
  at a fraction of the client CPU: on 2 cores, 8 ``http.client`` threads in one process top out
  near 1,900 requests/s even against a WSGI app that does nothing, so the default measures the
  client as much as the server.
- queries: ``--entities`` entities loaded by ``/v2/op/update`` batches, then ``--requests``
  timed ``GET /v2/entities?type=Sensor&q=zone==7;battery>90&limit=1000`` (selective) and
  ``q=battery>=10&limit=100&options=count`` (broad): p50/p99 ms.

Usage: ``python -m benchmarks.ngsi_quick [--duration 5] [--entities 10000] [--requests 200]
[--clients 1 8] [--processes 1] [--client http|raw]``.
Prints one JSON document.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import os
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from benchmarks.context_broker_rig import ContextBroker, Http

JSON = {"Content-Type": "application/json"}


def _clients(host: str, port: int, auth: dict[str, str], ids: list[str], duration: float) -> tuple[int, int]:
    counts = [0] * len(ids)
    errors = [0] * len(ids)
    deadline = time.monotonic() + duration

    def run(k: int) -> None:
        http = Http(host, port)
        n = 0
        while time.monotonic() < deadline:
            n += 1
            body = json.dumps({"counter": {"type": "Number", "value": n}})
            reply = http.request("PATCH", f"/v2/entities/{ids[k]}/attrs", body, {**JSON, **auth})
            if reply.status == 204:
                counts[k] += 1
            else:
                errors[k] += 1
        http.close()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(len(ids))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(counts), sum(errors)


def _raw_clients(host: str, port: int, auth: dict[str, str], ids: list[str], duration: float) -> tuple[int, int]:
    """As :func:`_clients`, each request written whole on a bare keep-alive socket."""
    counts = [0] * len(ids)
    errors = [0] * len(ids)
    deadline = time.monotonic() + duration

    def run(k: int) -> None:
        sock = socket.create_connection((host, port))
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        head = (f"PATCH /v2/entities/{ids[k]}/attrs HTTP/1.1\r\nHost: {host}:{port}\r\n"
                f"Content-Type: application/json\r\n"
                + "".join(f"{name}: {value}\r\n" for name, value in auth.items()))
        buf, n = b"", 0
        while time.monotonic() < deadline:
            n += 1
            body = json.dumps({"counter": {"type": "Number", "value": n}}).encode()
            sock.sendall(f"{head}Content-Length: {len(body)}\r\n\r\n".encode() + body)
            while b"\r\n\r\n" not in buf:
                chunk = sock.recv(65536)
                if not chunk:
                    raise ConnectionError("the server closed the connection")
                buf += chunk
            answer, _, buf = buf.partition(b"\r\n\r\n")
            lines = answer.split(b"\r\n")
            length = next((int(line.split(b":", 1)[1]) for line in lines[1:]
                           if line.lower().startswith(b"content-length:")), 0)
            while len(buf) < length:
                buf += sock.recv(65536)
            buf = buf[length:]
            if lines[0].split(b" ", 2)[1] == b"204":
                counts[k] += 1
            else:
                errors[k] += 1
        sock.close()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(len(ids))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return sum(counts), sum(errors)


def updates(cb: ContextBroker, clients: int, duration: float, processes: int = 1,
            client: str = "http") -> dict[str, Any]:
    http = cb.http()
    ids = [f"quick-u-{k}" for k in range(clients)]
    for entity_id in ids:
        reply = http.request("POST", "/v2/entities?options=upsert", json.dumps(
            {"id": entity_id, "type": "AGV", "counter": {"type": "Number", "value": 0}}), {**JSON, **cb.auth})
        assert reply.status in (201, 204), reply
    http.close()
    send = _raw_clients if client == "raw" else _clients
    processes = max(1, min(processes, clients))
    shares = [ids[k::processes] for k in range(processes)]
    with cf.ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn")) as pool:
        results = [f.result() for f in [pool.submit(send, cb.host, cb.port, cb.auth, share, duration)
                                        for share in shares]]
    done, errors = sum(r[0] for r in results), sum(r[1] for r in results)
    return {"clients": clients, "processes": processes, "client": client, "updates": done,
            "errors": errors, "per_s": round(done / duration, 1)}


def _pct(samples: list[float], p: float) -> float:
    ordered = sorted(samples)
    return round(ordered[min(len(ordered) - 1, int(p * len(ordered)))], 2)


def queries(cb: ContextBroker, entities: int, requests: int) -> dict[str, Any]:
    http = cb.http()
    start = time.perf_counter()
    for first in range(0, entities, 500):
        batch = [{"id": f"quick-q-{k}", "type": "Sensor", "zone": {"type": "Number", "value": k % 50},
                  "battery": {"type": "Number", "value": k % 100}, "state": {"type": "Text", "value": "ok"}}
                 for k in range(first, min(entities, first + 500))]
        reply = http.request("POST", "/v2/op/update", json.dumps({"actionType": "append", "entities": batch}),
                             {**JSON, **cb.auth})
        assert reply.status == 204, reply
    load_s = time.perf_counter() - start
    out: dict[str, Any] = {"entities": entities, "load_s": round(load_s, 2)}
    for name, path in (("selective", "/v2/entities?type=Sensor&q=zone==7;battery%3E90&limit=1000"),
                       ("broad", "/v2/entities?type=Sensor&q=battery%3E=10&limit=100&options=count")):
        samples = []
        for _ in range(requests):
            t0 = time.perf_counter()
            reply = http.request("GET", path)
            samples.append((time.perf_counter() - t0) * 1000)
            assert reply.status == 200, reply
        out[name] = {"answered": len(reply.json()), "total": reply.header("fiware-total-count"),
                     "p50_ms": _pct(samples, 0.5), "p99_ms": _pct(samples, 0.99),
                     "mean_ms": round(statistics.mean(samples), 2)}
    http.close()
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--clients", type=int, nargs="+", default=[1, 8])
    parser.add_argument("--entities", type=int, default=10_000)
    parser.add_argument("--requests", type=int, default=200)
    parser.add_argument("--processes", type=int, default=1, help="client processes (clients split among them)")
    parser.add_argument("--client", choices=("http", "raw"), default="http")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp, ContextBroker(Path(tmp)) as cb:
        result = {"cpus": os.cpu_count(),
                  "load_average": os.getloadavg()[0],
                  "updates": [updates(cb, n, args.duration, args.processes, args.client)
                              for n in args.clients],
                  "queries": queries(cb, args.entities, args.requests)}
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

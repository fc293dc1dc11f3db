"""Load generators of the context broker benchmark, run in worker processes.

- :func:`http_updates`: ``threads`` clients, each with its own keep-alive HTTP connection, each
  sending ``PATCH /v2/entities/{its entity}/attrs`` back to back (one request in flight per
  client) until a shared deadline; or, to calibrate, ``GET /version`` the same way.
- :func:`mqtt_publishes`: the same shape against Mosquitto: ``threads`` paho clients, each
  publishing QoS 1 and waiting for the PUBACK before the next message.

Both return :class:`WorkerResult`: completed requests, errors, and the worker process's own CPU
seconds over the measured window, so the benchmark can show that the load generator was not the
bottleneck (its CPU use next to the server's, :func:`group_cpu_seconds`).

Workers are processes of their own (``python -m benchmarks.context_broker_load http|mqtt ...``,
started by the benchmark through engine.process, so none is left behind), not threads of the
benchmark, so 32 clients are not serialized by one interpreter lock; :func:`split_clients` spreads
the clients over at most a few processes. A worker writes its :class:`WorkerResult` as JSON to
``--result``; it reads the bearer token from ``--token-file`` (never on a command line). Pure
helpers (:func:`split_clients`, :func:`pace_time`, :func:`rate_summary`) are unit tested.
"""

from __future__ import annotations

import argparse
import dataclasses
import http.client
import json
import os
import sys
import resource
import threading
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class WorkerResult:
    completed: int
    errors: int
    first_error: str
    cpu_s: float
    window_s: float
    late_s: float = 0.0  # how long after the window opened the worker's clients were ready


def split_clients(clients: int, max_processes: int) -> list[int]:
    """How many client threads each worker process runs: ``clients`` spread as evenly as possible
    over ``min(clients, max_processes)`` processes (``split_clients(32, 4) == [8, 8, 8, 8]``)."""
    if clients < 1 or max_processes < 1:
        raise ValueError(f"clients and max_processes must be at least 1, got {clients}, {max_processes}")
    procs = min(clients, max_processes)
    base, extra = divmod(clients, procs)
    return [base + (1 if i < extra else 0) for i in range(procs)]


def pace_time(start: float, index: int, rate: float) -> float:
    """When message ``index`` of a stream paced at ``rate`` per second starting at ``start`` is due."""
    if rate <= 0:
        raise ValueError(f"rate must be positive, got {rate}")
    return start + index / rate


def rate_summary(completed: int, window_s: float, cpu_s: float, cores: int | None = None) -> dict[str, float]:
    """Requests per second and CPU use (percent of one core; and of the machine) over a window."""
    if window_s <= 0:
        raise ValueError(f"window must be positive, got {window_s}")
    cores = cores or os.cpu_count() or 1
    return {"per_s": completed / window_s, "cpu_pct_of_core": 100.0 * cpu_s / window_s,
            "cpu_pct_of_machine": 100.0 * cpu_s / window_s / cores}


def group_cpu_seconds(pgid: int) -> float:
    """User + system CPU seconds of every live process of group ``pgid`` (Linux /proc)."""
    ticks = os.sysconf("SC_CLK_TCK")
    total = 0
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid:  # after "state ppid": pgrp
            total += int(fields[11]) + int(fields[12])  # utime, stime
    return total / ticks


def _cpu_now() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _wait_until(moment: float) -> None:
    pause = threading.Event()
    while (ahead := moment - time.time()) > 0:
        pause.wait(min(ahead, 0.5))


def http_updates(host: str, port: int, headers: dict[str, str], entity_ids: list[str],
                 start_at: float, duration: float, calibrate: bool = False) -> WorkerResult:
    """One thread per entity id, each PATCHing its entity's ``counter`` from ``start_at`` for
    ``duration`` seconds on its own keep-alive connection. ``calibrate``: the same clients send
    ``GET /version`` instead (the cheapest route: what this generator and the HTTP server can do
    at all, to compare a PATCH rate with)."""
    counts = [0] * len(entity_ids)
    errors = [0] * len(entity_ids)
    first_error: list[str] = []
    end = start_at + duration
    sent_headers = {"Content-Type": "application/json", **headers}

    def client(k: int, entity: str) -> None:
        conn = http.client.HTTPConnection(host, port, timeout=30)
        conn.connect()
        path = f"/v2/entities/{entity}/attrs"
        i = 0
        _wait_until(start_at)
        while time.time() < end:
            i += 1
            body = json.dumps({"counter": {"type": "Number", "value": i}})
            try:
                if calibrate:
                    conn.request("GET", "/version", headers=headers)
                else:
                    conn.request("PATCH", path, body=body, headers=sent_headers)
                resp = conn.getresponse()
                payload = resp.read()
                if resp.status == (200 if calibrate else 204):
                    counts[k] += 1
                else:
                    errors[k] += 1
                    if not first_error:
                        first_error.append(f"{resp.status} {payload[:200]!r}")
                if resp.will_close:
                    conn.close()
                    conn = http.client.HTTPConnection(host, port, timeout=30)
            except (OSError, http.client.HTTPException) as err:
                errors[k] += 1
                if not first_error:
                    first_error.append(repr(err))
                conn.close()
                conn = http.client.HTTPConnection(host, port, timeout=30)
        conn.close()

    return _run_threads([threading.Thread(target=client, args=(k, e)) for k, e in enumerate(entity_ids)],
                        counts, errors, first_error, start_at, duration)


def mqtt_publishes(host: str, port: int, threads: int, topic: str, start_at: float,
                   duration: float, worker: int) -> WorkerResult:
    """``threads`` paho clients publishing QoS 1, each waiting for its PUBACK before the next."""
    import paho.mqtt.client as mqtt

    counts = [0] * threads
    errors = [0] * threads
    first_error: list[str] = []
    end = start_at + duration
    payload = json.dumps({"counter": {"type": "Number", "value": 0}}).encode()

    def client(k: int) -> None:
        c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-cb-{os.getpid()}-{worker}-{k}")
        c.connect(host, port)
        c.loop_start()
        try:
            _wait_until(start_at)
            while time.time() < end:
                info = c.publish(f"{topic}/{worker}/{k}", payload, qos=1)
                try:
                    info.wait_for_publish(30)
                    counts[k] += 1
                except (RuntimeError, ValueError) as err:
                    errors[k] += 1
                    if not first_error:
                        first_error.append(repr(err))
        finally:
            c.disconnect()
            c.loop_stop()

    return _run_threads([threading.Thread(target=client, args=(k,)) for k in range(threads)],
                        counts, errors, first_error, start_at, duration)


def _run_threads(workers: list[threading.Thread], counts: list[int], errors: list[int],
                 first_error: list[str], start_at: float, duration: float) -> WorkerResult:
    for t in workers:
        t.start()
    _wait_until(start_at)
    late = max(0.0, time.time() - start_at)
    cpu0 = _cpu_now()
    for t in workers:
        t.join()
    cpu = _cpu_now() - cpu0
    return WorkerResult(sum(counts), sum(errors), first_error[0] if first_error else "", cpu, duration, late)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="one load generator worker of the context broker benchmark")
    parser.add_argument("kind", choices=["http", "http-get", "mqtt"])
    parser.add_argument("--host", required=True)
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--start-at", type=float, required=True, help="epoch seconds the window opens")
    parser.add_argument("--duration", type=float, required=True)
    parser.add_argument("--result", type=Path, required=True, help="where to write the result as JSON")
    parser.add_argument("--token-file", type=Path, help="http: the bearer token")
    parser.add_argument("--entities", default="", help="http: comma-separated entity ids, one client each")
    parser.add_argument("--threads", type=int, default=1, help="mqtt: publishing clients")
    parser.add_argument("--topic", default="bench/cb-baseline")
    parser.add_argument("--worker", type=int, default=0)
    args = parser.parse_args(argv)
    if args.kind in ("http", "http-get"):
        headers = {}
        if args.token_file:
            headers["Authorization"] = "Bearer " + args.token_file.read_text(encoding="utf-8").strip()
        result = http_updates(args.host, args.port, headers, [e for e in args.entities.split(",") if e],
                              args.start_at, args.duration, calibrate=args.kind == "http-get")
    else:
        result = mqtt_publishes(args.host, args.port, args.threads, args.topic, args.start_at, args.duration,
                                args.worker)
    args.result.write_text(json.dumps(dataclasses.asdict(result)), encoding="utf-8")
    return 0


def read_result(path: Path) -> WorkerResult:
    return WorkerResult(**json.loads(path.read_text(encoding="utf-8")))


if __name__ == "__main__":
    sys.exit(main())

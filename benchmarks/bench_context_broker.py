"""Benchmark: plantkg's NGSI-v2 context broker against raw Mosquitto, measured in the same run.

Everything runs on loopback: one Mosquitto (rendered by engine.drivers.mosquitto.runtime, as plantkg
deploys it) and one ``python -m engine.context_broker`` (token file, tmp data folder).

- **updates**: ``PATCH /v2/entities/{id}/attrs`` per second with 1, 8 and 32 concurrent clients
  (each its own keep-alive connection and entity, one request in flight), against raw Mosquitto
  QoS-1 publishes per second with the same client counts (each waits for its PUBACK). Clients run
  in up to ``--max-processes`` spawned worker processes (``context_broker_load``); the CPU
  seconds of the generator, of the context broker and of Mosquitto over each window are
  recorded, so the table shows which side was saturated; and, at the largest client count, the
  same generator sending ``GET /version`` (the cheapest route): what generator + HTTP stack can
  do at all, next to the PATCH rate.
- **notification**: a subscription with ``notification.mqtt`` on Mosquitto; updates paced at
  ``--rate`` per second (16 closed-loop sender threads, one entity each), and again at
  ``--capacity-fraction`` (a quarter) of the best updates/s measured (when lower: the notification
  path's own latency, without queueing in front of a saturated broker); latency from just before
  the PATCH to the MQTT message's arrival at a subscriber, p50/p99, lost, and from when the update
  was due (what a sender falling behind adds); against paced raw publish -> receive through the
  same Mosquitto at the same rates.
- **query**: ``GET /v2/entities?q=...`` with ``--entities`` entities (a selective and a broad
  ``q``, answers checked against the expected counts) and ``GET /v2/entities/{id}``: p50/p99.

Goals (met / not met): >= 2,000 updates/s; notification p99 < 50 ms at 500 updates/s; q query
p99 < 100 ms at 10k entities. Results: ``benchmarks/results/context_broker.{json,md}``.

Usage: ``python -m benchmarks.bench_context_broker [--clients 1 8 32] [--duration 10]``
(``--tiny``: a run of a few seconds, what the test suite does).
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt

from benchmarks import bridge_rig as rig
from benchmarks import context_broker_load as load
from benchmarks.common import RESULTS, command_line, machine, summarize, write_results
from benchmarks.context_broker_rig import ContextBroker, Http
from engine import parts, process

JSON = {"Content-Type": "application/json"}
SENDER_THREADS = 16  # closed-loop senders: enough that a slow answer does not hold the offered rate back
STATES = ("idle", "moving", "charging", "loading", "error")
GOAL_UPDATES_PER_S = 2000.0
GOAL_NOTIFY_P99_MS = 50.0
GOAL_QUERY_P99_MS = 100.0
TINY = ["--clients", "1", "2", "--duration", "1", "--start-margin", "1", "--rate", "200", "--notifications", "200",
        "--entities", "300", "--requests", "20"]


def _ok(reply_status: int, expected: int, what: str, body: bytes = b"") -> None:
    if reply_status != expected:
        raise RuntimeError(f"{what}: HTTP {reply_status} (expected {expected}) {body[:300]!r}")


# -- updates/s ---------------------------------------------------------------------------------

def updates_study(cb: ContextBroker, mq: rig.Mosquitto, clients_list: list[int], duration: float,
                  max_processes: int, work: Path, margin: float = 2.0) -> list[dict[str, Any]]:
    http = cb.http()
    try:
        for k in range(max(clients_list)):
            entity = {"id": f"bench-u-{k}", "type": "AGV", "counter": {"type": "Number", "value": 0}}
            reply = http.request("POST", "/v2/entities?options=upsert", json.dumps(entity), {**JSON, **cb.auth})
            if reply.status not in (201, 204):
                _ok(reply.status, 201, "create an update target", reply.body)
    finally:
        http.close()
    rows = []
    for clients in clients_list:
        split = load.split_clients(clients, max_processes)
        ids = iter(f"bench-u-{k}" for k in range(clients))
        groups = [",".join(next(ids) for _ in range(n)) for n in split]
        rows.append(_window(work, "context-broker", clients, duration, cb.child, [
            ["http", "--host", cb.host, "--port", str(cb.port), "--token-file", str(cb.token_file),
             "--entities", group] for group in groups], margin))
        rows.append(_window(work, "mosquitto", clients, duration, mq.child, [
            ["mqtt", "--host", mq.host, "--port", str(mq.port), "--threads", str(n), "--worker", str(w)]
            for w, n in enumerate(split)], margin))
    clients = max(clients_list)  # calibration: the same generator on the cheapest route
    split = load.split_clients(clients, max_processes)
    ids = iter(f"bench-u-{k}" for k in range(clients))
    rows.append(_window(work, "context-broker GET /version", clients, duration, cb.child, [
        ["http-get", "--host", cb.host, "--port", str(cb.port), "--token-file", str(cb.token_file),
         "--entities", ",".join(next(ids) for _ in range(n))] for n in split], margin))
    base = {r["clients"]: r["per_s"] for r in rows if r["target"] == "mosquitto"}
    for row in rows:
        row["vs_mosquitto"] = row["per_s"] / base[row["clients"]] if base.get(row["clients"]) else None
    return rows


def _window(work: Path, target: str, clients: int, duration: float, server: process.Child | None,
            worker_args: list[list[str]], margin: float) -> dict[str, Any]:
    """Run one worker process per ``worker_args`` over a window of ``duration`` s opening
    ``margin`` s from now (time for the workers to start and connect; a late worker shows in
    ``worker_late_s``); the server's CPU seconds are read at the window's edges."""
    assert server is not None
    start = time.time() + margin
    folder = work / f"{target}-{clients}"
    children, results = [], []
    try:
        for w, extra in enumerate(worker_args):
            result = folder / f"worker-{w}.json"
            children.append((process.spawn(
                [sys.executable, "-m", "benchmarks.context_broker_load", *extra, "--start-at", repr(start),
                 "--duration", str(duration), "--result", str(result)],
                log_dir=folder, name=f"worker-{w}", cwd=parts.repo_root()), result))
        load._wait_until(start)
        server_cpu0 = load.group_cpu_seconds(server.pid)
        load._wait_until(start + duration)
        server_cpu = load.group_cpu_seconds(server.pid) - server_cpu0
        for child, result in children:
            process.wait_until(lambda c=child: not c.running(), duration + 120, 0.05,
                               what=f"load worker {child.name} to finish")
            if child.popen.returncode != 0 or not result.is_file():
                raise RuntimeError(f"load worker {child.name} failed ({child.popen.returncode}): {child.log_tail()}")
            results.append(load.read_result(result))
    finally:
        for child, _ in children:
            process.stop(child)
    completed = sum(r.completed for r in results)
    gen_cpu = sum(r.cpu_s for r in results)
    rate = load.rate_summary(completed, duration, gen_cpu)
    return {"target": target, "clients": clients, "processes": len(results), "duration_s": duration,
            "completed": completed, "errors": sum(r.errors for r in results),
            "first_error": next((r.first_error for r in results if r.first_error), ""),
            "worker_late_s": max(r.late_s for r in results),
            "per_s": rate["per_s"], "generator_cpu_pct_of_core": rate["cpu_pct_of_core"],
            "server_cpu_pct_of_core": load.rate_summary(completed, duration, server_cpu)["cpu_pct_of_core"],
            "server_cpu_ms_per_request": 1000 * server_cpu / completed if completed else None}


# -- notification latency ----------------------------------------------------------------------

class Arrivals:
    """Receive time (ns since the epoch) by sequence number; duplicates counted."""

    def __init__(self) -> None:
        self.at: dict[int, int] = {}
        self.duplicates = 0
        self.lock = threading.Lock()

    def got(self, seq: int) -> None:
        now = time.time_ns()
        with self.lock:
            if seq in self.at:
                self.duplicates += 1
            else:
                self.at[seq] = now


def _subscriber(mq: rig.Mosquitto, topic: str, decode: Callable[[bytes], int], arrivals: Arrivals) -> mqtt.Client:
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"bench-cb-sub-{topic.replace('/', '-')}")
    client.on_message = lambda _c, _u, msg: arrivals.got(decode(msg.payload))
    granted = threading.Event()
    client.on_subscribe = lambda *_: granted.set()
    client.connect(mq.host, mq.port)
    client.subscribe(topic, qos=1)
    client.loop_start()
    process.wait_until(granted.is_set, 10.0, what=f"subscription to {topic}")
    return client


def _notified_seq(payload: bytes) -> int:
    return int(json.loads(payload)["data"][0]["seq"])


def _paced(n: int, rate: float, threads: int, send: Callable[[int, int], None]) -> dict[str, float]:
    """Call ``send(thread, seq)`` for seq 0..n-1 at ``rate`` per second, spread over ``threads``
    threads (seq i on thread i mod threads); returns the achieved rate and the worst lag behind
    the schedule."""
    start = time.time() + 0.2
    lags = [0.0] * threads

    def run(k: int) -> None:
        pause = threading.Event()
        for i in range(k, n, threads):
            due = load.pace_time(start, i, rate)
            ahead = due - time.time()
            if ahead > 0.0005:
                pause.wait(ahead)
            lags[k] = max(lags[k], time.time() - due)
            send(k, i)

    workers = [threading.Thread(target=run, args=(k,)) for k in range(threads)]
    for t in workers:
        t.start()
    for t in workers:
        t.join()
    elapsed = time.time() - start
    return {"achieved_rate": n / elapsed if elapsed > 0 else 0.0, "max_lag_ms": 1000 * max(lags), "start": start}


def _collect(n: int, sent: dict[int, int], arrivals: Arrivals, idle_limit: float,
             schedule: tuple[float, float, int] | None = None) -> dict[str, Any]:
    """Wait until the ``n`` messages of ``sent`` (sequence -> send time, ns) arrived, or none came
    for ``idle_limit`` s; arrivals of other sequence numbers (a late warm-up) are ignored.
    ``schedule`` (start s, rate, first sequence number): also the latency from when each message
    was due, which counts the time a sender fell behind (no coordinated omission)."""
    last = [-1, time.monotonic()]

    def count() -> int:
        with arrivals.lock:
            return len(arrivals.at.keys() & sent.keys())

    def done() -> bool:
        got = count()
        if got != last[0]:
            last[:] = [got, time.monotonic()]
        return got >= n or time.monotonic() - last[1] > idle_limit

    process.wait_until(done, 600.0, 0.01, what="the last notification")
    with arrivals.lock:
        latencies = [(arrivals.at[i] - sent[i]) / 1e9 for i in arrivals.at if i in sent]
        due = [] if schedule is None else [arrivals.at[i] / 1e9 - load.pace_time(schedule[0], i - schedule[2], schedule[1])
                                           for i in arrivals.at if i in sent]
        duplicates = arrivals.duplicates
    out = {"messages": n, "received": len(latencies), "lost": n - len(latencies), "duplicates": duplicates,
           "latency_ms": summarize(latencies)}
    if schedule is not None:
        out["from_schedule_ms"] = summarize(due)
    return out


def notification_study(cb: ContextBroker, mq: rig.Mosquitto, n: int, rates: list[tuple[str, float]]
                       ) -> dict[str, Any]:
    """Paced update -> MQTT notification latency at each ``(role, rate)``, then raw Mosquitto at
    the same rates. Role ``goal`` is the rate the goal is stated at; ``below-capacity`` is a
    fraction of the updates/s measured before, to tell the notification path's own latency from
    queueing in front of a saturated broker."""
    http = cb.http()
    try:
        for k in range(SENDER_THREADS):
            entity = {"id": f"bench-n-{k}", "type": "AGV", "seq": {"type": "Number", "value": -1}}
            reply = http.request("POST", "/v2/entities?options=upsert", json.dumps(entity), {**JSON, **cb.auth})
            if reply.status not in (201, 204):
                _ok(reply.status, 201, "create a notifying entity", reply.body)
        sub = {"description": "bench: update to MQTT", "subject": {
            "entities": [{"idPattern": "^bench-n-", "type": "AGV"}], "condition": {"attrs": ["seq"]}},
            "notification": {"mqtt": {"url": f"mqtt://{mq.host}:{mq.port}", "topic": "bench/notify", "qos": 1},
                             "attrs": ["seq"], "attrsFormat": "keyValues"}}
        reply = http.request("POST", "/v2/subscriptions", json.dumps(sub), {**JSON, **cb.auth})
        _ok(reply.status, 201, "create the MQTT subscription", reply.body)
    finally:
        http.close()
    rows = []
    arrivals = Arrivals()
    sub_client = _subscriber(mq, "bench/notify", _notified_seq, arrivals)
    conns = [cb.http() for _ in range(SENDER_THREADS)]
    failures: list[str] = []
    try:
        # warm-up: connections, the subscription's MQTT link
        warm_sent: dict[int, int] = {}
        _paced(50, rates[0][1], SENDER_THREADS, lambda k, i: _update(conns[k], cb, k, i, warm_sent, failures))
        _collect(50, warm_sent, arrivals, 10.0)
        for run, (role, rate) in enumerate(rates, start=1):
            failures.clear()
            sent: dict[int, int] = {}
            with arrivals.lock:
                arrivals.duplicates = 0
            offset = run * 1_000_000  # fresh sequence numbers: a late notification of a run before is not counted
            answered: list[float] = []
            pace = _paced(n, rate, SENDER_THREADS,
                          lambda k, i, s=sent, o=offset, a=answered: _update(conns[k], cb, k, o + i, s, failures, a))
            start = pace.pop("start")
            got = _collect(n, sent, arrivals, 10.0, (start, rate, offset))
            rows.append({"path": "context-broker -> mqtt", "role": role, "offered_rate": rate, **pace, **got,
                         "patch_answered_ms": summarize(answered),
                         "update_failures": len(failures), "first_failure": failures[0] if failures else ""})
    finally:
        for c in conns:
            c.close()
        sub_client.disconnect()
        sub_client.loop_stop()
    rows += [{**_raw_paced(mq, n, rate), "role": role} for role, rate in rates]
    return {"rows": rows}


def _update(conn: Http, cb: ContextBroker, k: int, seq: int, sent: dict[int, int], failures: list[str],
            answered: list[float] | None = None) -> None:
    body = json.dumps({"seq": {"type": "Number", "value": seq}})
    sent[seq] = t0 = time.time_ns()
    reply = conn.request("PATCH", f"/v2/entities/bench-n-{k}/attrs", body, {**JSON, **cb.auth})
    if answered is not None:
        answered.append((time.time_ns() - t0) / 1e9)
    if reply.status != 204:
        failures.append(f"{reply.status} {reply.body[:200]!r}")


def _raw_paced(mq: rig.Mosquitto, n: int, rate: float) -> dict[str, Any]:
    arrivals = Arrivals()
    sub_client = _subscriber(mq, "bench/raw", lambda p: int(p.split(b" ", 1)[0]), arrivals)
    pub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id="bench-cb-raw-pub")
    pub.max_inflight_messages_set(1000)
    pub.connect(mq.host, mq.port)
    pub.loop_start()
    sent: dict[int, int] = {}
    lock = threading.Lock()

    def send(_k: int, i: int) -> None:
        with lock:  # one publisher connection, as a device would have
            sent[i] = time.time_ns()
            pub.publish("bench/raw", f"{i} {{\"seq\": {i}}}".encode(), qos=1)

    try:
        pace = _paced(n, rate, 1, send)
        got = _collect(n, sent, arrivals, 10.0, (pace.pop("start"), rate, 0))
    finally:
        for c in (pub, sub_client):
            c.disconnect()
            c.loop_stop()
    return {"path": "raw mosquitto", "offered_rate": rate, **pace, **got, "update_failures": 0, "first_failure": ""}


# -- queries -----------------------------------------------------------------------------------

def sensor(i: int) -> dict[str, Any]:
    return {"id": f"bench-q-{i}", "type": "Sensor", "zone": {"type": "Number", "value": i % 100},
            "battery": {"type": "Number", "value": (i * 37) % 101},
            "state": {"type": "Text", "value": STATES[i % len(STATES)]}}


def query_study(cb: ContextBroker, entities: int, requests: int) -> dict[str, Any]:
    http = cb.http()
    try:
        t0 = time.perf_counter()
        for lo in range(0, entities, 500):
            batch = {"actionType": "append", "entities": [sensor(i) for i in range(lo, min(entities, lo + 500))]}
            reply = http.request("POST", "/v2/op/update", json.dumps(batch), {**JSON, **cb.auth})
            _ok(reply.status, 204, "load the query entities", reply.body)
        load_s = time.perf_counter() - t0
        selective = [sensor(i) for i in range(entities) if i % 100 == 7 and (i * 37) % 101 > 90]
        broad = [sensor(i) for i in range(entities) if (i * 37) % 101 >= 10]
        queries = {
            "q selective (zone==7;battery>90)": ("/v2/entities?type=Sensor&q=zone==7;battery%3E90&limit=1000",
                                                 len(selective), len(selective)),
            "q broad (battery>=10, count, limit 100)": (
                "/v2/entities?type=Sensor&q=battery%3E=10&limit=100&options=count", min(100, len(broad)), len(broad)),
        }
        rows = []
        for name, (path, n_expected, total) in queries.items():
            rows.append(_timed(http, cb, name, lambda: path, requests, n_expected, total))
        rng = random.Random(7)
        rows.append(_timed(http, cb, "GET /v2/entities/{id}",
                           lambda: f"/v2/entities/bench-q-{rng.randrange(entities)}", requests, None, None))
    finally:
        http.close()
    return {"entities": entities, "requests": requests, "load_s": load_s, "rows": rows}


def _timed(http: Http, cb: ContextBroker, name: str, path: Callable[[], str], n: int,
           expected: int | None, total: int | None) -> dict[str, Any]:
    times = []
    for _ in range(n + 5):  # 5 warm-up requests, not timed
        p = path()
        t0 = time.perf_counter()
        reply = http.request("GET", p, headers=cb.auth)
        times.append(time.perf_counter() - t0)
        _ok(reply.status, 200, name, reply.body)
        body = reply.json()
        if expected is not None and len(body) != expected:
            raise RuntimeError(f"{name}: {len(body)} entities, expected {expected}")
        if total is not None and "count" in p and reply.header("fiware-total-count") != str(total):
            raise RuntimeError(f"{name}: Fiware-Total-Count {reply.header('fiware-total-count')}, expected {total}")
    return {"query": name, "results": expected if expected is not None else 1, "matching": total,
            "latency_ms": summarize(times[5:])}


# -- goals, table, CLI -------------------------------------------------------------------------

def goals(data: dict[str, Any]) -> list[dict[str, Any]]:
    """Each goal of the task with the figure measured and met / not met."""
    out = []
    cb_rows = [r for r in data.get("updates", []) if r["target"] == "context-broker"]
    if cb_rows:
        best = max(cb_rows, key=lambda r: r["per_s"])
        out.append({"goal": "attribute updates/s (best client count)",
                    "measured": f"{best['per_s']:.0f}/s with {best['clients']} clients",
                    "target": f">= {GOAL_UPDATES_PER_S:.0f}/s", "met": best["per_s"] >= GOAL_UPDATES_PER_S})
    notify = [r for r in data.get("notification", {}).get("rows", [])
              if r["path"].startswith("context-broker") and r.get("role", "goal") == "goal"]
    for r in notify:  # counted from when each update was due, so a sender falling behind is not hidden
        p99 = r.get("from_schedule_ms", r["latency_ms"]).get("p99")
        ok = p99 is not None and p99 < GOAL_NOTIFY_P99_MS and r["lost"] == 0
        out.append({"goal": f"update -> MQTT notification p99 at {r['offered_rate']:.0f} updates/s",
                    "measured": "-" if p99 is None else f"{p99:.1f} ms (lost {r['lost']})",
                    "target": f"< {GOAL_NOTIFY_P99_MS:.0f} ms, none lost", "met": ok})
    query = data.get("query")
    for r in (query or {}).get("rows", []):
        if not r["query"].startswith("q "):
            continue
        p99 = r["latency_ms"]["p99"]
        out.append({"goal": f"{r['query']} p99 at {query['entities']} entities", "measured": f"{p99:.1f} ms",
                    "target": f"< {GOAL_QUERY_P99_MS:.0f} ms", "met": p99 < GOAL_QUERY_P99_MS})
    return out


def _pair(summary: dict[str, float] | None) -> str:
    """p50 / p99 of a summary, "-" when the run has none."""
    return f"{_ms(summary, 'p50')} / {_ms(summary, 'p99')}" if summary else "-"


def _num(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def _ms(summary: dict[str, float], key: str) -> str:
    return f"{summary[key]:.2f}" if key in summary else "-"


def to_markdown(data: dict[str, Any]) -> str:
    lines = ["# context_broker: the NGSI-v2 context broker against raw Mosquitto (same run)", "",
             f"Command: `{data['command']}` · machine: {data['machine']}", "",
             "## Goals", "", "| goal | measured | target | |", "|---|---|---|---|"]
    lines += [f"| {g['goal']} | {g['measured']} | {g['target']} | {'met' if g['met'] else '**not met**'} |"
              for g in data["goals"]]
    lines += ["", f"## Updates per second ({data['duration_s']} s windows; one request or QoS-1 publish in "
              "flight per client; CPU in % of one core over the window)", "",
              "| target | clients | worker processes | per s | vs Mosquitto | errors | generator CPU % | server CPU % | "
              "server CPU ms per request | workers late s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["updates"]:
        vs = "-" if r["vs_mosquitto"] is None else f"{r['vs_mosquitto']:.2f}"
        lines.append(f"| {r['target']} | {r['clients']} | {r['processes']} | {r['per_s']:.0f} | {vs} | {r['errors']} | "
                     f"{r['generator_cpu_pct_of_core']:.0f} | {r['server_cpu_pct_of_core']:.0f} | "
                     f"{_num(r.get('server_cpu_ms_per_request'))} | {r.get('worker_late_s', 0.0):.2f} |")
    lines += ["", "## Notification latency (paced; ms from just before the PATCH / publish to the MQTT message's "
              "arrival)", "",
              "| path | rate | offered/s | achieved/s | max sender lag ms | received | lost | dup | p50 ms | p99 ms | max ms "
              "| from schedule p50 / p99 ms | PATCH answered p50 / p99 ms |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in data["notification"]["rows"]:
        lat = r["latency_ms"]
        lines.append(f"| {r['path']} | {r.get('role', 'goal')} | {r['offered_rate']:.0f} | {r['achieved_rate']:.0f} | "
                     f"{r['max_lag_ms']:.1f} | {r['received']} | {r['lost']} | {r['duplicates']} | {_ms(lat, 'p50')} | "
                     f"{_ms(lat, 'p99')} | {_ms(lat, 'max')} | {_pair(r.get('from_schedule_ms'))} | "
                     f"{_pair(r.get('patch_answered_ms'))} |")
    q = data["query"]
    lines += ["", f"## Queries ({q['entities']} entities loaded in {q['load_s']:.1f} s by /v2/op/update batches "
              f"of 500; {q['requests']} requests each, one keep-alive client)", "",
              "| request | entities answered | matching | p50 ms | p99 ms | max ms |", "|---|---|---|---|---|---|"]
    for r in q["rows"]:
        lat = r["latency_ms"]
        lines.append(f"| {r['query']} | {r['results']} | {r['matching'] if r['matching'] is not None else '-'} | "
                     f"{_ms(lat, 'p50')} | {_ms(lat, 'p99')} | {_ms(lat, 'max')} |")
    return "\n".join(lines) + "\n"


def measure(args: argparse.Namespace, work: Path, argv: list[str] | None) -> dict[str, Any]:
    stops: list[Callable[[], object]] = []
    try:
        mq = rig.Mosquitto(work / "mq").start()
        stops.append(mq.stop)
        cb = ContextBroker(work / "cb").start()
        stops.append(cb.stop)
        data: dict[str, Any] = {"benchmark": "context_broker", "machine": machine(),
                                "command": command_line("benchmarks.bench_context_broker", argv),
                                "duration_s": args.duration, "max_processes": args.max_processes}
        data["updates"] = updates_study(cb, mq, args.clients, args.duration, args.max_processes, work,
                                        args.start_margin)
        best = max(r["per_s"] for r in data["updates"] if r["target"] == "context-broker")
        rates = [("goal", args.rate)]
        if 0 < args.capacity_fraction * best < args.rate:
            rates.append(("below-capacity", round(args.capacity_fraction * best)))
        data["notification"] = notification_study(cb, mq, args.notifications, rates)
        data["query"] = query_study(cb, args.entities, args.requests)
        if "Traceback" in cb.log_text():
            raise RuntimeError(f"the context broker logged a traceback: {cb.log_text()[-3000:]}")
    finally:
        for stop in reversed(stops):
            stop()
    data["goals"] = goals(data)
    return data


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="NGSI-v2 context broker benchmark")
    parser.add_argument("--clients", type=int, nargs="+", default=[1, 8, 32])
    parser.add_argument("--duration", type=float, default=10.0, help="seconds per updates window")
    parser.add_argument("--max-processes", type=int, default=4, help="load generator worker processes")
    parser.add_argument("--start-margin", type=float, default=2.0,
                        help="seconds for the worker processes to start before a window opens")
    parser.add_argument("--rate", type=float, default=500.0, help="paced updates per second")
    parser.add_argument("--notifications", type=int, default=5000)
    parser.add_argument("--capacity-fraction", type=float, default=0.25,
                        help="also measure notifications at this fraction of the best updates/s, when below --rate")
    parser.add_argument("--entities", type=int, default=10_000)
    parser.add_argument("--requests", type=int, default=300, help="timed requests per query")
    parser.add_argument("--tiny", action="store_true", help="a few seconds: " + " ".join(TINY))
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.tiny:
        args = parser.parse_args([*TINY, *(sys.argv[1:] if argv is None else argv)])
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-cb-") as tmp:
        data = measure(args, Path(tmp), argv)
    write_results(args.out, "context_broker", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    sys.exit(main())

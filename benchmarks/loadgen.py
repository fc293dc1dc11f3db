"""Run the Go load generator (``tools/loadgen``, built by ``make setup`` into
``.plantkg/loadgen/loadgen``) and read its JSON lines into typed results.

The benchmarks' clients run in their own processes, so a benchmark measures the brokers and
bridges instead of Python clients sharing their cores. A subscriber or consumer is started first
and reports ``{"event": "ready"}`` once it listens; :func:`start` waits for that line (polling
with a deadline), so the publisher only starts after the receiver is in place. Passwords go to
the child in ``$LOADGEN_PASSWORD``, never on its command line (``ps`` shows argv).
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
BINARY = ROOT / ".plantkg" / "loadgen" / "loadgen"


class LoadgenError(RuntimeError):
    """The load generator is missing, failed to start, or reported an error."""


@dataclass(frozen=True)
class Target:
    """Where a client connects: ``host:port`` (Kafka: comma-separated bootstrap list), login and TLS."""

    address: str
    username: str | None = None
    password: str | None = None
    ca_file: Path | None = None
    sasl: str | None = None  # Kafka only: "SCRAM-SHA-512"


@dataclass(frozen=True)
class Result:
    """One mode's report. ``received``/``missing``/``duplicates`` are receivers' (a publisher's
    are 0); ``acked`` is a publisher's. Latencies in ms: publish→PUBACK for a publisher, send time
    in the payload → delivery for receivers. ``first_ns``/``last_ns``/``start_ns``: wall clock."""

    mode: str
    count: int
    elapsed_s: float
    rate_per_s: float
    p50_ms: float | None
    p99_ms: float | None
    max_ms: float | None
    cpu_s: float
    exit_code: int
    acked: int = 0
    received: int = 0
    missing: int = 0
    duplicates: int = 0
    timed_out: bool = False
    start_ns: int | None = None
    first_ns: int | None = None
    last_ns: int | None = None
    error: str | None = None


def binary() -> Path:
    """The built load generator, or a :class:`LoadgenError` saying what to install."""
    if not BINARY.is_file() or not os.access(BINARY, os.X_OK):
        raise LoadgenError(f"the Go load generator is not built ({BINARY.relative_to(ROOT)} is missing): "
                           "install Go >= 1.22 (https://go.dev/dl, `go` on PATH) and run `make setup`")
    return BINARY


def parse_report(line: str, exit_code: int) -> Result:
    """A :class:`Result` from the tool's final JSON line (an error if it is not one)."""
    try:
        data: dict[str, Any] = json.loads(line)
    except json.JSONDecodeError as err:
        raise LoadgenError(f"loadgen printed {line!r}, not a JSON report: {err}") from err
    if "mode" not in data or ("elapsed_s" not in data and "error" not in data):
        raise LoadgenError(f"loadgen's report lacks mode/elapsed_s: {line!r}")
    if "elapsed_s" not in data:
        raise LoadgenError(f"loadgen {data['mode']} failed: {data['error']}")
    return Result(mode=data["mode"], count=int(data["count"]), elapsed_s=float(data["elapsed_s"]),
                  rate_per_s=float(data["rate_per_s"]), p50_ms=data.get("latency_p50_ms"),
                  p99_ms=data.get("latency_p99_ms"), max_ms=data.get("latency_max_ms"),
                  cpu_s=float(data["cpu_user_s"]) + float(data["cpu_sys_s"]), exit_code=exit_code,
                  acked=int(data.get("acked", 0)), received=int(data.get("received", 0)),
                  missing=int(data.get("missing", 0)), duplicates=int(data.get("duplicates", 0)),
                  timed_out=bool(data.get("timed_out", False)), start_ns=data.get("start_unix_ns"),
                  first_ns=data.get("first_unix_ns"), last_ns=data.get("last_unix_ns"), error=data.get("error"))


def _argv(mode: str, target: Target, topic: str, count: int, deadline: float, extra: list[str]) -> list[str]:
    address_flag = "--brokers" if mode.startswith("kafka") else "--broker"
    argv = [str(binary()), mode, address_flag, target.address, "--topic", topic, "--n", str(count),
            "--deadline", f"{deadline:.3f}s"]
    if target.ca_file is not None:
        argv += ["--ca-file", str(target.ca_file)]
    if target.username:
        argv += ["--username", target.username]
    if target.sasl:
        argv += ["--sasl", target.sasl]
    return argv + extra


class Running:
    """A started load generator: its stdout lines arrive on a queue read by a thread."""

    def __init__(self, argv: list[str], password: str | None) -> None:
        env = {k: v for k, v in os.environ.items() if k != "LOADGEN_PASSWORD"}
        if password is not None:
            env["LOADGEN_PASSWORD"] = password
        self.argv = argv
        self.child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.child.stdout is not None
        for line in self.child.stdout:
            self.lines.put(line.strip())
        self.lines.put(None)

    def _next(self, deadline: float) -> str | None:
        try:
            return self.lines.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            raise LoadgenError(f"{self.argv[1]}: no output within the deadline") from None

    def wait_ready(self, timeout: float) -> None:
        """Block until the child prints its ready line; an error if it exits or reports first."""
        deadline = time.monotonic() + timeout
        line = self._next(deadline)
        if line is None or '"ready"' not in line:
            self.stop()
            report = line if line else self._stderr()
            raise LoadgenError(f"{self.argv[1]} did not get ready: {report}")

    def result(self, timeout: float) -> Result:
        """The child's report once it exits (killed and an error past ``timeout`` seconds)."""
        deadline = time.monotonic() + timeout
        last = None
        while (line := self._next(deadline)) is not None:
            last = line
        try:
            code = self.child.wait(timeout=max(1.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            self.stop()
            raise LoadgenError(f"{self.argv[1]} did not exit within the deadline") from None
        if last is None:
            raise LoadgenError(f"{self.argv[1]} exited {code} without a report: {self._stderr()}")
        return parse_report(last, code)

    def _stderr(self) -> str:
        assert self.child.stderr is not None
        try:
            self.child.wait(timeout=5)
        except subprocess.TimeoutExpired:
            return "(still running)"
        return self.child.stderr.read().strip()

    def stop(self) -> None:
        if self.child.poll() is None:
            self.child.kill()
        self.child.wait()


def start(mode: str, target: Target, topic: str, count: int, deadline: float, extra: tuple[str, ...] = (),
          ready_timeout: float = 60.0) -> Running:
    """Start a receiver (``mqtt-sub``, ``kafka-consume``) and return once it listens."""
    running = Running(_argv(mode, target, topic, count, deadline, list(extra)), target.password)
    running.wait_ready(ready_timeout)
    return running


def publish(target: Target, topic: str, count: int, window: int, deadline: float, size: int = 64) -> Result:
    """Run ``mqtt-pub`` to the end: ``count`` QoS-1 messages, at most ``window`` awaiting PUBACK."""
    extra = ["--window", str(window), "--size", str(size)]
    running = Running(_argv("mqtt-pub", target, topic, count, deadline, extra), target.password)
    return running.result(deadline + 30.0)

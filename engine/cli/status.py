"""``plantkg status FILE...``: what each broker of the plant is doing, as its agent reports it.

One row per broker: id, kind, host:port, status, pid, uptime, restarts, topics (present/asked),
access (who may use it: ``users (N)``, ``principals (N)``, ``token``, ``open``; engine.derived.access);
then, if the plant has bridges, one row per bridge: its address, mechanism, status, routes,
messages forwarded, its forwarding rate (``rate/s``: messages per second over the worker's last
~10 s) and messages retried (Mosquitto's own bridges count nothing: "-"), last error.
A broker no agent runs is ``absent``; one whose agent did not answer is ``unknown``; brokers the
agents run that the plant does not name are listed after, marked ``not in plant``. The answer is
also written into the observed graph (see docs/reconciliation.md). Read-only.

A bridge forwarding more than ``--max-bridge-rate`` messages/s (default 10,000) gets a warning:
defence in depth for what the plan cannot see (bridge rings are refused at plan time, see
engine/derived/bridge_cycles.py, but not a loop through a bridge set up outside the plant, nor a publisher
flooding); a bridge loop once delivered one publish ~36,000 times per broker in 5 s.

Exit codes: 0 the plant has converged (every agent answered, a plan would change nothing and no
bridge runs away); 2 it has not (something to create, change or delete, an agent that did not
answer, whose brokers show ``unknown`` with ``?`` topics, or a bridge above the rate limit);
1 an error (an invalid plant, unusable input).
``--format json`` gives typed values: numbers as numbers, ``null`` where a table shows ``-``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import click

from engine.cli.common import fail, file_argument
from engine.cli.options import agents_option
from kg.errors import EXIT_VIOLATIONS, PlantKGError

if TYPE_CHECKING:
    from engine.model import BrokerSpec, DesiredState, ObservedBroker, ObservedState

# The model, the pipeline and the progress display are imported where they are used, so that
# `plantkg --help` (which lists this command) does not load them.

EXIT_CONVERGED, EXIT_ERROR, EXIT_NOT_CONVERGED = 0, 1, 2
#: Messages/s above which ``plantkg status`` says a bridge runs away (``--max-bridge-rate``).
DEFAULT_MAX_BRIDGE_RATE = 10_000.0

HEADERS = ("id", "kind", "host:port", "status", "pid", "uptime", "restarts", "topics", "access")
_COLOURS = {"running": "green", "starting": "yellow", "connecting": "yellow", "stopped": "yellow", "crashed": "red",
            "failed": "red", "absent": "red", "unknown": "red"}


def status_rows(desired: DesiredState, observed: ObservedState, now: float) -> list[dict[str, str]]:
    """The table's rows as strings (desired brokers first, then others the agents run). ``access``
    is who may use the broker as it runs (``-`` when nothing runs: engine.derived.access.access_label)."""
    from engine.derived.access import access_label  # noqa: PLC0415

    rows = []
    for spec in desired.brokers:
        have = observed.broker(spec.id)
        wanted = {t.name for t in desired.topics_of(spec.id)}
        if have is None:
            state = "unknown" if spec.host in observed.unreachable else "absent"
            rows.append({**_row(spec.id, spec.kind, spec.host, spec.port, state, None, now, wanted),
                         "access": "-"})
        else:
            rows.append({**_row(spec.id, have.spec.kind, have.spec.host, have.spec.port,
                                have.status.value, have, now, wanted), "access": access_label(have.spec)})
    named = {b.id for b in desired.brokers}
    for have in observed.brokers:
        if have.spec.id not in named:
            row = _row(have.spec.id, have.spec.kind, have.spec.host, have.spec.port,
                       have.status.value, have, now, set())
            row["status"] += " (not in plant)"
            rows.append({**row, "access": access_label(have.spec)})
    return rows


BRIDGE_HEADERS = ("bridge", "mechanism", "status", "routes", "forwarded", "rate/s", "retried", "lag", "error")


def show_rate(value: float | None) -> str:
    """A forwarding rate for the table: one decimal, ``-`` where the mechanism does not count."""
    return "-" if value is None else f"{value:.1f}"


def bridge_rows(desired: DesiredState, observed: ObservedState) -> list[dict[str, str]]:
    """One row per bridge the plant asks for (then bridges the agents run that it does not)."""
    def show(value: int | None) -> str:
        return "-" if value is None else str(value)

    rows = []
    wanted = {b.address for b in desired.bridges}
    for spec in desired.bridges:
        have = observed.bridge(spec.address)
        routes = ", ".join(f"{r.topic} {r.direction.value}" for r in spec.routes)
        if have is None:
            host = spec.local.host
            state = "unknown" if host in observed.unreachable else "absent"
            rows.append({"bridge": spec.address, "mechanism": spec.mechanism.value, "status": state,
                         "routes": routes, "forwarded": "-", "rate/s": "-", "retried": "-", "lag": "-",
                         "error": ""})
            continue
        rows.append({"bridge": spec.address, "mechanism": spec.mechanism.value,
                     "status": have.status.value, "routes": routes,
                     "forwarded": show(have.forwarded), "rate/s": show_rate(have.forwarded_per_s),
                     "retried": show(have.retried), "lag": show(have.lag),
                     # a running bridge's last error is history (the worker keeps it): not shown;
                     # messages its remote refused (dropped, not retried) are shown while running
                     "error": (have.last_error.splitlines()[0][:60]
                               if have.last_error and have.status.value != "running"
                               else f"{have.refused} refused by the remote" if have.refused else "")})
    for have in observed.bridges:
        if have.spec.address not in wanted:
            rows.append({"bridge": have.spec.address, "mechanism": have.spec.mechanism.value,
                         "status": f"{have.status.value} (not in plant)",
                         "routes": ", ".join(r.topic for r in have.spec.routes),
                         "forwarded": show(have.forwarded), "rate/s": show_rate(have.forwarded_per_s),
                         "retried": show(have.retried), "lag": show(have.lag), "error": ""})
    return rows


@dataclass(frozen=True)
class RunawayBridge:
    """A bridge forwarding more messages per second than ``limit``."""

    address: str
    rate: float
    limit: float

    @property
    def warning(self) -> str:
        return (f"bridge {self.address} forwards {self.rate:,.1f} messages/s, above the limit of "
                f"{self.limit:,.1f} (--max-bridge-rate): look for a loop through a bridge set up "
                f"outside the plant (a broker bridged by hand) or a publisher flooding its topics")


def runaway_bridges(observed: ObservedState, limit: float) -> tuple[RunawayBridge, ...]:
    """Every observed bridge (in the plant or not) whose forwarding rate is above ``limit``."""
    return tuple(RunawayBridge(b.spec.address, b.forwarded_per_s, limit) for b in observed.bridges
                 if b.forwarded_per_s is not None and b.forwarded_per_s > limit)


def verdict(*, plan_empty: bool, unreachable: bool, runaway: bool) -> int:
    """The exit code: converged only if every agent answered, nothing is pending and no bridge
    runs away."""
    return EXIT_CONVERGED if plan_empty and not unreachable and not runaway else EXIT_NOT_CONVERGED


def _row(broker_id: str, kind: str, host: str, port: int, state: str, have: ObservedBroker | None,
         now: float, wanted: set[str]) -> dict[str, str]:
    from engine.cli.progress import duration  # noqa: PLC0415
    from engine.model import BrokerStatus  # noqa: PLC0415

    present = {t.name for t in have.topics} if have else set()
    alive = have is not None and have.status in (BrokerStatus.RUNNING, BrokerStatus.STARTING)
    uptime = duration(max(0.0, now - have.started_at)) if alive and have and have.started_at else "-"
    host_port = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
    topics = f"{len(present & wanted)}/{len(wanted)}" if state != "unknown" else f"?/{len(wanted)}"
    if present - wanted:
        topics += f" +{len(present - wanted)}"
    return {
        "id": broker_id, "kind": kind, "host:port": host_port, "status": state,
        "pid": str(have.pid) if have and have.pid else "-", "uptime": uptime,
        "restarts": str(have.restarts) if have else "-", "topics": topics,
    }


def render_table(rows: list[dict[str, str]], headers: tuple[str, ...] = HEADERS) -> str:
    widths = {h: max([len(h)] + [len(r[h]) for r in rows]) for h in headers}
    lines = ["  ".join(click.style(h.upper().ljust(widths[h]), bold=True) for h in headers)]
    for row in rows:
        cells = []
        for h in headers:
            text = row[h].ljust(widths[h])
            if h == "status":
                text = click.style(text, fg=_COLOURS.get(row[h].split()[0], "white"))
            cells.append(text)
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


@click.command("status")
@file_argument
@agents_option
@click.option("--format", "fmt", type=click.Choice(["table", "json"]), default="table",
              show_default=True)
@click.option("--max-bridge-rate", "max_rate", type=click.FloatRange(min=0, min_open=True),
              default=DEFAULT_MAX_BRIDGE_RATE, show_default=True, metavar="N",
              help="Messages/s a bridge may forward (over its last ~10 s); above it status warns "
                   "and exits 2.")
def status_command(files: tuple[str, ...], agents_file: Path | None, fmt: str, max_rate: float) -> int:
    """Show what each broker of the plant in FILE(s) is doing, as its agent reports it.

    \b
    Example:
      plantkg status ontology/examples/robot-cell.ttl --agents agents.toml
    """
    from engine.cli.reconcile import prepare, print_violations  # noqa: PLC0415 - only when run
    from engine.model import to_dict  # noqa: PLC0415

    try:
        result, _ = prepare(files, agents_file)
    except PlantKGError as error:
        fail(error)
        return EXIT_ERROR
    if not result.valid:
        print_violations(result)
        return EXIT_VIOLATIONS
    assert result.desired is not None and result.observed is not None
    runaway = runaway_bridges(result.observed, max_rate)
    code = verdict(plan_empty=result.plan is not None and result.plan.empty,
                   unreachable=bool(result.observed.unreachable), runaway=bool(runaway))
    converged = code == EXIT_CONVERGED
    if fmt == "json":
        click.echo(json.dumps({"converged": converged,
                               "brokers": typed_broker_rows(result.desired, result.observed, time.time()),
                               "bridges": [_typed_bridge(r, result.observed)
                                           for r in bridge_rows(result.desired, result.observed)],
                               "max_bridge_rate": max_rate,
                               "runaway_bridges": [{"bridge": r.address, "forwarded_per_s": r.rate,
                                                    "warning": r.warning} for r in runaway],
                               "unreachable": list(result.observed.unreachable),
                               "observed": to_dict(result.observed)}, indent=2))
        return code
    click.echo(render_table(status_rows(result.desired, result.observed, time.time())))
    bridges = bridge_rows(result.desired, result.observed)
    if bridges:
        click.echo("")
        click.echo(render_table(bridges, BRIDGE_HEADERS))
    for r in runaway:
        click.echo(click.style(f"warning: {r.warning}", fg="red"), err=True)
    if result.observed.unreachable:
        click.echo(click.style("agents that did not answer: " + ", ".join(result.observed.unreachable),
                               fg="red"), err=True)
    if result.plan is not None and not result.plan.empty:
        click.echo(click.style(f"not converged: {len(result.plan.pending)} change(s) pending (plantkg plan shows them)",
                               fg="yellow"), err=True)
    return code


def typed_broker_rows(desired: DesiredState, observed: ObservedState, now: float) -> list[dict[str, object]]:
    """The table's rows with typed values: ints, seconds, ``None`` for what is not known."""
    from engine.model import BrokerStatus  # noqa: PLC0415

    out: list[dict[str, object]] = []
    for row in status_rows(desired, observed, now):
        have = observed.broker(row["id"])
        present, _, wanted = row["topics"].split()[0].partition("/")
        alive = have is not None and have.status in (BrokerStatus.RUNNING, BrokerStatus.STARTING)
        out.append({
            "id": row["id"], "kind": row["kind"], "host_port": row["host:port"],
            "status": row["status"].split()[0], "in_plant": "(not in plant)" not in row["status"],
            "pid": have.pid if have and have.pid else None,
            "uptime_s": round(now - have.started_at, 3) if alive and have and have.started_at else None,
            "restarts": have.restarts if have else None,
            "topics_present": None if present == "?" else int(present), "topics_wanted": int(wanted),
            # who may use it as it runs, and whether its listener speaks TLS (None: nothing runs)
            "anonymous": None if have is None else _anonymous(have.spec),
            "users": None if have is None else len(have.spec.users),
            "tls": None if have is None else have.spec.tls,
            # the listener for plant-CA client certificates (None: none, or nothing runs)
            "certificate_port": None if have is None else have.spec.certificate_port,
        })
    return out


def _anonymous(spec: BrokerSpec) -> bool:
    """Whether a running broker admits clients without credentials (a context broker: reads and writes)."""
    return spec.allow_anonymous is not False


def _typed_bridge(row: dict[str, str], observed: ObservedState) -> dict[str, object]:
    def number(text: str) -> int | None:
        return None if text == "-" else int(text)
    have = observed.bridge(row["bridge"])
    typed: dict[str, object] = {k: v for k, v in row.items() if k != "rate/s"}
    return {**typed, "forwarded": number(row["forwarded"]), "retried": number(row["retried"]),
            "lag": number(row["lag"]),
            "forwarded_per_s": have.forwarded_per_s if have is not None else None}

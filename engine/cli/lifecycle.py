"""``plantkg stop|start|restart BROKER``: the operator's verbs for one running broker.

The first paper's client can start, stop and restart a broker; maintenance needs "stop this
broker for an hour, keep its data, then start it" and "restart it now". The agent that runs the
broker does it (``POST /v1/brokers/<id>/stop|start|restart``): ``stop`` keeps the broker's spec,
config and data and marks it stopped-by-operator — ``plan``/``apply``/``serve --auto-apply`` then
leave it stopped (no drift, no restart) until ``start``; ``restart`` stops it gracefully and starts
it again with a new pid.

BROKER is the broker's id as the plan names it (``mosquitto`` or ``broker.mosquitto``). The agent
is found by asking the agents of the agents file (or only the one of ``--host``) which runs it.

Exit codes: 0 done; 2 an unknown broker, no agent to ask, an agent that refused or did not answer.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from engine.cli.options import agents_option
from engine.errors import EngineError

if TYPE_CHECKING:
    from engine.agent.client import AgentClient
    from engine.agents_config import AgentDirectory
    from engine.model import ObservedBroker

# The agents file and the client are imported where they are used (`plantkg --help` lists these
# commands without loading them).


class LifecycleError(EngineError):
    """The broker to stop, start or restart cannot be found, or not on one agent only."""


def broker_id_of(text: str) -> str:
    """``broker.ID`` or ``ID`` -> ID; anything else (a topic or bridge address) is refused."""
    kind, dot, rest = text.partition(".")
    if dot and kind in ("topic", "bridge"):
        raise LifecycleError(f"{text!r} is a {kind}: only a broker is stopped, started or restarted",
                             hint="name the broker that carries it (broker.ID)")
    broker_id = rest if dot and kind == "broker" else text
    from engine.agent.wire import BROKER_ID  # noqa: PLC0415 - small, but only when run

    if not BROKER_ID.fullmatch(broker_id):
        raise LifecycleError(f"{text!r} is not a broker id",
                             hint="give the id as `plantkg plan` names it: broker.ID or ID")
    return broker_id


def find_agent(directory: AgentDirectory, broker_id: str,
               host: str | None) -> tuple[str, AgentClient, ObservedBroker]:
    """The (host, client, broker) of the one agent that runs ``broker_id``."""
    from engine.errors import TemporaryDispatchError  # noqa: PLC0415

    hosts = [host] if host else list(directory.hosts)
    if not hosts:
        where = f" {directory.source}" if directory.source else ""
        raise LifecycleError(f"no agent to ask: the agents file{where} names no host",
                             hint="give --host HOST (the broker's machine), or --agents FILE")
    by_url: dict[str, str] = {}
    for h in hosts:
        by_url.setdefault(directory.url_for(h), h)
    found: list[tuple[str, AgentClient, ObservedBroker]] = []
    silent: list[str] = []
    for url, h in by_url.items():
        client = directory.client_for(h)
        try:
            have = client.get_broker(broker_id)
        except TemporaryDispatchError:
            silent.append(f"{h} ({url})")
            continue
        if have is not None:
            found.append((h, client, have))
    if len(found) == 1:
        return found[0]
    if found:
        raise LifecycleError(f"broker {broker_id!r} runs on several agents: "
                             + ", ".join(h for h, _, _ in found),
                             hint="give --host HOST to choose one")
    asked = ", ".join(by_url.values())
    extra = f"; did not answer: {', '.join(silent)}" if silent else ""
    raise LifecycleError(f"no agent runs broker {broker_id!r} (asked: {asked}{extra})",
                         hint="check the id (`plantkg status` lists them) and the agents file")


def _run(verb: str, broker: str, agents_file: Path | None, host: str | None) -> int:
    from engine.agents_config import AgentDirectory  # noqa: PLC0415 - only when run

    broker_id = broker_id_of(broker)
    directory = AgentDirectory.load(agents_file)
    where, client, before = find_agent(directory, broker_id, host)
    after = client.broker_verb(broker_id, verb)
    click.echo(describe(verb, where, before, after))
    return 0


def describe(verb: str, host: str, before: ObservedBroker, after: ObservedBroker) -> str:
    """One line for the operator: what the broker is now."""
    name = f"broker.{after.spec.id} on {host}"
    if verb == "stop":
        return (f"{name}: {after.status.value} (its config and data are kept; "
                f"`plantkg start {after.spec.id}` starts it)")
    pid = f"pid {after.pid}" if after.pid else "no pid"
    if verb == "restart" and before.pid:
        pid = f"pid {before.pid} → {after.pid}"
    return f"{name}: {after.status.value}, {pid}"


_HOST = click.option("--host", default=None, metavar="HOST",
                     help="the broker's host (default: ask every agent of the agents file)")


@click.command("stop")
@click.argument("broker")
@agents_option
@_HOST
def stop_command(broker: str, agents_file: Path | None, host: str | None) -> int:
    """Stop BROKER and keep it stopped, its config and data kept, until `plantkg start`.

    Plans show it as stopped by the operator (no change), and `serve --auto-apply` leaves it.

    \b
    Example:
      plantkg stop broker.kafka --agents agents.toml
    """
    return _run("stop", broker, agents_file, host)


@click.command("start")
@click.argument("broker")
@agents_option
@_HOST
def start_command(broker: str, agents_file: Path | None, host: str | None) -> int:
    """Start BROKER again as it was (after `plantkg stop`); returns once it is healthy.

    \b
    Example:
      plantkg start broker.kafka --agents agents.toml
    """
    return _run("start", broker, agents_file, host)


@click.command("restart")
@click.argument("broker")
@agents_option
@_HOST
def restart_command(broker: str, agents_file: Path | None, host: str | None) -> int:
    """Stop BROKER gracefully and start it again now (a new pid; its data kept).

    \b
    Example:
      plantkg restart broker.mosquitto --agents agents.toml
    """
    return _run("restart", broker, agents_file, host)

"""``plantkg import ADDRESS FILE...``: take over a broker nobody owns (Terraform's ``import``).

A broker made before ownership existed, or by hand through the agent API, is owned by nobody:
``plan`` refuses to change it and lists it as foreign. ``import broker.ID`` records this plant as
its owner on its agent — and as the owner of its topics and bridges nobody owns — without
restarting or changing anything; the next ``plan`` then shows what it takes to make the broker
match the plant. The plant must declare the broker (else the next apply would delete it), and a
broker another plant owns is never taken (exit 2).

Exit codes: 0 imported (or already this plant's), 1 the plant has violations, 2 anything else.
"""

from __future__ import annotations

from pathlib import Path

import click

from engine.cli.common import file_argument
from engine.cli.options import agents_option, owner_option
from engine.errors import EngineError
from kg.errors import EXIT_VIOLATIONS


class ImportRefusedError(EngineError):
    """The address cannot be imported (not a broker of the plant, not running, owned by another)."""


@click.command("import")
@click.argument("address")
@file_argument
@agents_option
@owner_option
def import_command(address: str, files: tuple[str, ...], agents_file: Path | None,
                   owner: str | None) -> int:
    """Make the plant in FILE(s) the owner of the running broker ADDRESS (broker.ID).

    Nothing is restarted or changed but the owner the agent records; topics and bridges of the
    broker that nobody owns come along. Run `plantkg plan` afterwards to see what differs.

    \b
    Example:
      plantkg import broker.mosquitto ontology/examples/robot-cell.ttl --agents agents.toml
    """
    from engine.cli.reconcile import prepare, print_violations  # noqa: PLC0415 - only when run
    from engine.plan import Ownership, ownership  # noqa: PLC0415

    kind, _, broker_id = address.partition(".")
    if kind != "broker" or not broker_id:
        raise ImportRefusedError(f"cannot import {address!r}: only a broker is imported (broker.ID)",
                           hint="import the broker that carries the topic or bridge: it comes "
                                "with its topics and bridges nobody owns")
    result, directory = prepare(files, agents_file, owner=owner)
    if not result.valid:
        print_violations(result)
        return EXIT_VIOLATIONS
    desired, observed = result.desired, result.observed
    assert desired is not None and observed is not None and directory is not None
    if desired.owner is None:
        raise ImportRefusedError("the plant has no owner to import into",
                           hint='give its owl:Ontology header an IRI or pk:plantName "name", or '
                                "pass --owner NAME")
    spec = desired.broker(broker_id)
    if spec is None:
        raise ImportRefusedError(f"the plant does not declare {address}",
                           hint="add the broker to the plant first (else the next apply would "
                                "delete what you import), then import it")
    have = observed.broker(broker_id)
    if have is None:
        where = "its agent did not answer" if spec.host in observed.unreachable \
            else f"no agent runs it (the agent of {spec.host} was asked)"
        raise ImportRefusedError(f"cannot import {address}: {where}",
                           hint="`plantkg apply` creates a broker that does not run yet")
    whose = ownership(have.owner, desired.owner)
    if whose is Ownership.MINE:
        click.echo(f"{address} is already owned by {desired.owner}; nothing to import.")
        return 0
    if whose is Ownership.OTHER:
        raise ImportRefusedError(f"{address} is owned by plant {have.owner}; plantkg never takes "
                           "another plant's things",
                           hint="destroy it from its own plant, or give yours another pk:id")
    taken = directory.client_for(have.spec.host).set_owner(broker_id, desired.owner)
    topics = sum(1 for t in taken.topics if t.owner == desired.owner)
    click.echo(f"Imported {address} (on {have.spec.host}, {topics} topic(s)) into {desired.owner}.")
    click.echo("Run `plantkg plan` to see what it takes to make it match the plant.")
    return 0

"""``plantkg destroy FILE...``: stop and remove the brokers (and their topics) the plant deployed.

Only brokers the plant names are touched; other brokers on the same agents stay. Same
confirmation rules and exit codes as ``plantkg apply``.
"""

from __future__ import annotations

from pathlib import Path

import click

from engine.apply import PlanNotApplicableError, apply
from engine.cli.common import file_argument
from engine.cli.progress import Progress, result_lines
from engine.cli.reconcile import agents_option, confirm, prepare, print_violations, yes_option
from engine.render_plan import render_plan
from kg.errors import EXIT_VIOLATIONS

EXIT_NOT_CONVERGED = 3


@click.command("destroy")
@file_argument
@yes_option
@agents_option
@click.option("--parallelism", type=click.IntRange(1, 64), default=8, show_default=True,
              help="how many brokers are removed at once")
def destroy_command(files: tuple[str, ...], yes: bool, agents_file: Path | None, parallelism: int) -> int:
    """Stop and remove every broker of the plant in FILE(s), with its topics.

    \b
    Example:
      plantkg destroy ontology/examples/robot-cell.ttl --agents agents.toml --yes
    """
    result, directory = prepare(files, agents_file, destroy=True)
    if not result.valid:
        print_violations(result)
        return EXIT_VIOLATIONS
    plan, desired = result.plan, result.desired
    assert plan is not None and desired is not None and directory is not None
    if plan.empty and plan.applicable:
        click.echo("Nothing to destroy: no broker of this plant runs.")
        return 0
    click.echo(render_plan(plan, color=True))
    if not plan.applicable:
        raise PlanNotApplicableError(plan)
    confirm("Do you really want to destroy these brokers? Their data is removed.", yes=yes,
            what="destroy")
    click.echo("")
    with Progress() as progress:
        outcome = apply(plan, desired, directory, parallelism=parallelism, on_event=progress,
                        destroy=True)
    click.echo("")
    for line in result_lines(outcome, verb="Destroy"):
        click.echo(line)
    return 0 if outcome.ok else EXIT_NOT_CONVERGED

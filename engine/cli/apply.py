"""``plantkg apply FILE...``: make the brokers match the plant.

Validates (an invalid plant: violations printed, exit 1, no agent asked), plans, shows the plan,
asks for confirmation (``--yes`` to skip; without a terminal and without ``--yes`` it refuses),
applies with progress, checks the result and prints a summary.

Exit codes: 0 the plant runs as described, 1 the plant has violations, 2 unusable input, a plan
that cannot be applied, or no confirmation possible, 3 some changes failed or did not take effect
(run apply again once fixed), 130 cancelled.
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


@click.command("apply")
@file_argument
@yes_option
@agents_option
@click.option("--parallelism", type=click.IntRange(1, 64), default=8, show_default=True,
              help="how many brokers are changed at once")
def apply_command(files: tuple[str, ...], yes: bool, agents_file: Path | None, parallelism: int) -> int:
    """Make the brokers run as the plant in FILE(s) describes.

    \b
    Example:
      plantkg apply ontology/examples/robot-cell.ttl --agents agents.toml
    """
    result, directory = prepare(files, agents_file)
    if not result.valid:
        print_violations(result)
        return EXIT_VIOLATIONS
    plan, desired = result.plan, result.desired
    assert plan is not None and desired is not None and directory is not None
    click.echo(render_plan(plan, color=True))
    if not plan.applicable:
        raise PlanNotApplicableError(plan)
    if plan.empty:
        return 0
    confirm("Do you want to perform these actions?", yes=yes, what="apply")
    click.echo("")
    with Progress() as progress:
        outcome = apply(plan, desired, directory, parallelism=parallelism, on_event=progress)
    click.echo("")
    for line in result_lines(outcome, verb="Apply"):
        click.echo(line)
    return 0 if outcome.ok else EXIT_NOT_CONVERGED

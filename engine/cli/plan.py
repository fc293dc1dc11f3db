"""``plantkg plan FILE...``: show what apply would change; nothing is changed.

Exit codes: 0 the plan was made, 1 the plant has violations, 2 unusable input, an agent problem,
or a plan that cannot be applied (refusals, unreachable agents). With ``--detailed-exitcode`` they
are Terraform's: 0 the plan was made and is empty, 2 changes are pending, 1 anything else (an
invalid plant, unusable input, an agent problem, a plan that cannot be applied).
"""

from __future__ import annotations

from pathlib import Path

import click

from engine.cli.common import fail, file_argument
from engine.cli.options import agents_option, owner_option, prune_option
from kg.errors import EXIT_UNUSABLE, EXIT_VIOLATIONS, PlantKGError

EXIT_CHANGES = 2  # --detailed-exitcode, as terraform plan -detailed-exitcode
EXIT_ERROR = 1   # --detailed-exitcode: any error


@click.command("plan")
@file_argument
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text for people, json for programs")
@agents_option
@click.option("--detailed-exitcode", is_flag=True,
              help="exit 2 when changes are pending, 0 when none, 1 on any error (as terraform plan)")
@owner_option
@prune_option
def plan_command(files: tuple[str, ...], fmt: str, agents_file: Path | None,
                 detailed_exitcode: bool, owner: str | None, prune: bool) -> int:
    """Compare the plant in FILE(s) with what the agents run and show the changes apply would make.

    The plant is validated, reasoned over and derived; every agent of the plant's hosts is asked
    what it runs. Nothing is started, stopped or changed. Only what the plant owns is planned;
    other plants' things, and things nobody owns, are listed as foreign (--prune: deleted if
    nobody owns them).

    \b
    Example:
      plantkg plan ontology/examples/robot-cell.ttl --agents agents.toml
    """
    from engine.cli.reconcile import prepare, print_violations  # noqa: PLC0415 - only when run
    from engine.render.plan import plan_json, render_plan  # noqa: PLC0415

    try:
        result, _ = prepare(files, agents_file, owner=owner, prune=prune)
    except PlantKGError as error:
        if not detailed_exitcode:
            raise
        fail(error)  # printed as always; the code is Terraform's "error", never "changes pending"
        return EXIT_ERROR
    if not result.valid:
        print_violations(result, fmt)
        return EXIT_ERROR if detailed_exitcode else EXIT_VIOLATIONS
    plan = result.plan
    assert plan is not None
    if fmt == "json":
        click.echo(plan_json(plan))
    else:
        click.echo(render_plan(plan, color=True))
    if not plan.applicable:
        return EXIT_ERROR if detailed_exitcode else EXIT_UNUSABLE
    if detailed_exitcode and not plan.empty:
        return EXIT_CHANGES
    return 0

"""``plantkg destroy FILE...``: stop and remove the brokers (and their topics) the plant deployed.

Only what the plant owns is touched (a plant without an owner: the unowned brokers it names);
other plants' brokers, and brokers nobody owns, stay. Same
confirmation rules and exit codes as ``plantkg apply``.
"""

from __future__ import annotations

from pathlib import Path

import click

from engine.cli.common import file_argument
from engine.cli.options import agents_option, local_option, owner_option, result_format_option, yes_option


@click.command("destroy")
@file_argument
@yes_option
@agents_option
@click.option("--parallelism", type=click.IntRange(1, 64), default=8, show_default=True,
              help="how many agents are sent their removals at once (an agent stops all its brokers at once)")
@owner_option
@result_format_option
@local_option
def destroy_command(files: tuple[str, ...], yes: bool, agents_file: Path | None, parallelism: int,
                    owner: str | None, local: bool, fmt: str = "text") -> int:
    """Stop and remove every broker of the plant in FILE(s), with its topics.

    As apply, it runs in a `plantkg serve` of the same FILE(s), agents file and owner when one runs
    (--local: here).

    \b
    Example:
      plantkg destroy ontology/examples/robot-cell.ttl --agents agents.toml --yes
    """
    if not local:
        from engine.control.client import run_in_server  # noqa: PLC0415 - standard library only

        code = run_in_server("destroy", files, agents_file, owner,
                             {"yes": yes, "parallelism": parallelism, "format": fmt})
        if code is not None:
            return code
    from engine.cli.reconcile import make_changes  # noqa: PLC0415 - the pipeline: only when run

    return make_changes(files, agents_file, yes=yes, parallelism=parallelism, destroy=True, fmt=fmt,
                        owner=owner)

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

from engine.cli.common import file_argument
from engine.cli.options import (agents_option, local_option, owner_option, prune_option, result_format_option,
                                yes_option)


@click.command("apply")
@file_argument
@yes_option
@agents_option
@click.option("--parallelism", type=click.IntRange(1, 64), default=8, show_default=True,
              help="how many agents are sent their changes at once (each gets one request per wave; an agent changes all its brokers at once)")
@owner_option
@result_format_option
@prune_option
@local_option
def apply_command(files: tuple[str, ...], yes: bool, agents_file: Path | None, parallelism: int,
                  owner: str | None, prune: bool, local: bool, fmt: str = "text") -> int:
    """Make the brokers run as the plant in FILE(s) describes.

    When `plantkg serve` serves the same FILE(s), agents file and owner, this runs in that server
    (warm: no imports, shapes or rules to load; its dashboard sees it at once) and prints the same
    plan, prompt, progress and exit code; --local runs it here.

    \b
    Example:
      plantkg apply ontology/examples/robot-cell.ttl --agents agents.toml
    """
    if not local:
        from engine.control.client import run_in_server  # noqa: PLC0415 - standard library only

        code = run_in_server("apply", files, agents_file, owner,
                             {"yes": yes, "parallelism": parallelism, "prune": prune, "format": fmt})
        if code is not None:
            return code
    from engine.cli.reconcile import make_changes  # noqa: PLC0415 - the pipeline: only when run

    return make_changes(files, agents_file, yes=yes, parallelism=parallelism, destroy=False, fmt=fmt,
                        owner=owner, prune=prune)

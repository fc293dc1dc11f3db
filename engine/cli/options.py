"""Options that plan, apply, destroy, import, status and serve share (click only: cheap to import,
so ``plantkg --help`` does not load what the commands run)."""

from __future__ import annotations

from pathlib import Path

import click

agents_option = click.option(
    "--agents", "agents_file", type=click.Path(path_type=Path, dir_okay=False), default=None,
    metavar="FILE",
    help="agents file (TOML); default $PLANTKG_AGENTS or ~/.config/plantkg/agents.toml",
)
yes_option = click.option("--yes", "-y", is_flag=True, help="do not ask for confirmation")
owner_option = click.option(
    "--owner", default=None, metavar="NAME",
    help="the plant's owner name (default: its pk:plantName, else its owl:Ontology IRI); only "
         "what this owner owns is changed")
prune_option = click.option(
    "--prune", is_flag=True,
    help="also delete what nobody owns (made before ownership, or by hand); other plants' "
         "things are never deleted")


result_format_option = click.option(
    "--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
    help="text for people; json: one typed document on stdout at the end (no prompt: needs --yes "
         "when there are changes)")
local_option = click.option(
    "--local", is_flag=True,
    help="run in this process even when a `plantkg serve` of this plant runs (by default it runs "
         "there, with its pipeline warm: docs/web.md)")

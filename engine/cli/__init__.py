"""The ``plantkg`` command line: one click group, one module per command.

User mistakes (a bad file, an invalid plant, a malformed query) end with a one-paragraph message on
stderr and an exit code — never a traceback. Exit codes: 0 success, 1 the plant has violations,
2 unusable input.
"""

from __future__ import annotations

import sys
from importlib.metadata import entry_points

import click

from engine.cli.agent import agent_command
from engine.cli.common import run_guarded
from engine.cli.demo import demo_command
from engine.cli.apply import apply_command
from engine.cli.destroy import destroy_command
from engine.cli.import_ import import_command
from engine.cli.plan import plan_command
from engine.cli.query import query_command
from engine.cli.serve import serve_command
from engine.cli.status import status_command
from engine.cli.validate import validate_command


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="plantkg", prog_name="plantkg")
def cli() -> None:
    """plantkg — configure a plant's message brokers from a knowledge graph.

    The plant is written as Turtle against the plantkg ontology; shapes say what a valid plant is.
    """


cli.add_command(validate_command)
cli.add_command(query_command)
cli.add_command(plan_command)
cli.add_command(apply_command)
cli.add_command(destroy_command)
cli.add_command(import_command)
cli.add_command(status_command)
cli.add_command(agent_command)
cli.add_command(demo_command)
cli.add_command(serve_command)

#: Commands of other packages (``plantkg fleet ...``): entry points ``name = "module:click_command"``
#: in the group ``plantkg.commands``. The engine never imports them by name; a plugin that fails to
#: load is reported on stderr when its command is used, and the other commands keep working.
PLUGIN_GROUP = "plantkg.commands"


def _add_plugins(group: click.Group) -> None:
    for entry in sorted(entry_points(group=PLUGIN_GROUP), key=lambda e: e.name):
        if entry.name in group.commands:
            continue
        try:
            group.add_command(entry.load(), entry.name)
        except Exception as exc:  # a broken plugin must not take plantkg down
            message = f"plugin command {entry.name!r} ({entry.value}) cannot be loaded: {exc}"

            @click.command(entry.name, help=message)
            def broken(message: str = message) -> None:
                raise click.ClickException(message)

            group.add_command(broken, entry.name)


_add_plugins(cli)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    return run_guarded(cli, argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

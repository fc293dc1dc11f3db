"""What every command shares: turning typed errors into a message and an exit code."""

from __future__ import annotations

from typing import Sequence

import click

from kg.errors import PlantKGError


def fail(error: PlantKGError) -> int:
    """Print ``error`` for a person (stderr, red in a terminal) and give its exit code."""
    click.echo(click.style("error: ", fg="red", bold=True) + str(error), err=True)
    return error.exit_code


def run_guarded(command: click.Command, argv: Sequence[str]) -> int:
    """Run a click command, mapping PlantKGError and click's usage errors to exit codes."""
    try:
        result = command.main(args=list(argv), prog_name="plantkg", standalone_mode=False)
    except PlantKGError as error:
        return fail(error)
    except click.ClickException as error:
        error.show()
        return 2 if isinstance(error, click.UsageError) else error.exit_code
    except click.Abort:
        click.echo("aborted", err=True)
        return 130
    except KeyboardInterrupt:
        click.echo("interrupted", err=True)
        return 130
    except BrokenPipeError:
        return 0
    return result if isinstance(result, int) else 0


file_argument = click.argument(
    "files", nargs=-1, required=True, type=click.Path(path_type=str), metavar="FILE..."
)

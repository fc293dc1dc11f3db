"""The ``plantkg`` command line: one click group, one module per command.

User mistakes (a bad file, an invalid plant, a malformed query) end with a one-paragraph message on
stderr and an exit code — never a traceback. Exit codes: 0 success, 1 the plant has violations,
2 unusable input.

The group is lazy, so the command line starts at once: a command's module is imported only when
that command runs or ``--help`` lists it, and each module imports its heavy needs (rdflib's SPARQL
engine, pyoxigraph, the agent's HTTP server, Flask) inside the command. Plugin commands (entry
points, found by :mod:`engine.cli.plugins` without importing ``importlib.metadata``) are loaded
the same way. ``tests/unit/test_cli_imports.py`` keeps it so.
"""

from __future__ import annotations

import sys
from importlib import import_module
from typing import Any

import click

from engine.cli.common import run_guarded
from engine.cli.plugins import Plugin, find_plugins

#: The built-in commands: name -> ``module:attribute`` of its click command.
BUILTIN_COMMANDS: dict[str, str] = {
    "agent": "engine.cli.agent:agent_command",
    "apply": "engine.cli.apply:apply_command",
    "cert": "engine.cli.cert:cert_command",
    "check": "engine.cli.check:check_command",
    "demo": "engine.cli.demo:demo_command",
    "destroy": "engine.cli.destroy:destroy_command",
    "explain": "engine.cli.explain:explain_command",
    "import": "engine.cli.import_:import_command",
    "plan": "engine.cli.plan:plan_command",
    "query": "engine.cli.query:query_command",
    "restart": "engine.cli.lifecycle:restart_command",
    "serve": "engine.cli.serve:serve_command",
    "start": "engine.cli.lifecycle:start_command",
    "status": "engine.cli.status:status_command",
    "stop": "engine.cli.lifecycle:stop_command",
    "validate": "engine.cli.validate:validate_command",
}

#: Commands of other packages (``plantkg fleet ...``): entry points ``name = "module:click_command"``
#: in the group ``plantkg.commands``. The engine never imports them by name; a plugin that fails to
#: load is reported on stderr when its command is used, and the other commands keep working.
PLUGIN_GROUP = "plantkg.commands"


def _load_builtin(target: str) -> click.Command:
    module, _, attribute = target.partition(":")
    command: click.Command = getattr(import_module(module), attribute)
    return command


def _broken_plugin(entry: Plugin, exc: Exception) -> click.Command:
    message = f"plugin command {entry.name!r} ({entry.value}) cannot be loaded: {exc}"

    @click.command(entry.name, help=message)
    def broken() -> None:
        raise click.ClickException(message)

    return broken


class LazyGroup(click.Group):
    """A click group whose commands are imported on first use (built-ins, then plugins).

    Commands added with ``add_command`` win over both. The plugin entry points are read once, and
    only when a name is not a built-in or when all names are listed (``--help``).
    """

    def __init__(self, *args: Any, builtins: dict[str, str], plugin_group: str, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.builtins = dict(builtins)
        self.plugin_group = plugin_group
        self._plugins: dict[str, Plugin] | None = None

    def plugins(self) -> dict[str, Plugin]:
        """The plugin entry points by command name: built-in names are never shadowed, and of two
        plugins of one name the first found wins."""
        if self._plugins is None:
            self._plugins = {}
            for entry in find_plugins(self.plugin_group):
                if entry.name not in self.builtins:
                    self._plugins.setdefault(entry.name, entry)
        return self._plugins

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(self.commands) | set(self.builtins) | set(self.plugins()))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name in self.commands:
            return self.commands[cmd_name]
        if cmd_name in self.builtins:
            command = _load_builtin(self.builtins[cmd_name])
        elif (entry := self.plugins().get(cmd_name)) is not None:
            try:
                command = entry.load()
            except Exception as exc:  # a broken plugin must not take plantkg down
                command = _broken_plugin(entry, exc)
        else:
            return None
        self.add_command(command, cmd_name)
        return command


@click.group(cls=LazyGroup, builtins=BUILTIN_COMMANDS, plugin_group=PLUGIN_GROUP,
             context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(package_name="plantkg", prog_name="plantkg")
def cli() -> None:
    """plantkg — configure a plant's message brokers from a knowledge graph.

    The plant is written as Turtle against the plantkg ontology; shapes say what a valid plant is.
    """


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the exit code."""
    return run_guarded(cli, argv if argv is not None else sys.argv[1:])


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

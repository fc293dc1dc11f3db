"""The ``plantkg`` console script: a command that a running ``plantkg serve`` runs starts without click.

``plantkg apply`` or ``destroy`` of a served plant costs the command its interpreter and the
socket conversation (engine.control.client); importing click and the command line would be half
of it (~40 ms of ~100). So the entry point reads those two commands' options itself, in the plain
forms click accepts (``--agents FILE``, ``--agents=FILE``, ``-y`` ...), and asks the server of the
plant first. Any other command line — another command, ``--help``, ``--local``, an option it does
not know, a value click would refuse — goes to :func:`engine.cli.main` unchanged, which also runs
the command when no server answers. ``tests/unit/control/test_entry.py`` holds this reading to
click's, case by case.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

TYPE_CHECKING = False  # typing and dataclasses are not imported: this module runs before anything
if TYPE_CHECKING:
    from typing import Any

#: Per command, its flags (option -> field) and the options that take a value.
FLAGS = {"apply": {"--yes": "yes", "-y": "yes", "--prune": "prune"},
         "destroy": {"--yes": "yes", "-y": "yes"}}
VALUES = {"--agents": "agents", "--parallelism": "parallelism", "--owner": "owner", "--format": "format"}
FORMATS = ("text", "json")
MAX_PARALLELISM = 64


#: A command line the server may run: (command, files, agents file, owner, options).
Served = tuple  # (str, tuple[str, ...], str | None, str | None, dict[str, Any])


def read(argv: Sequence[str]) -> Served | None:
    """``argv`` as click would read it, or None when it is not a plain apply/destroy line."""
    if not argv or argv[0] not in FLAGS:
        return None
    verb, flags = argv[0], FLAGS[argv[0]]
    got: dict[str, Any] = {"yes": False, "prune": False, "agents": None, "parallelism": "8", "owner": None,
                           "format": "text"}
    files: list[str] = []
    i = 1
    while i < len(argv):
        arg = argv[i]
        name, eq, value = arg.partition("=")
        if arg in flags:
            got[flags[arg]] = True
        elif name in VALUES:
            if not eq:
                i += 1
                if i == len(argv):
                    return None
                value = argv[i]
            got[VALUES[name]] = value
        elif arg.startswith("-"):
            return None  # --help, --local, "--", an unknown option: the command line decides
        else:
            files.append(arg)
        i += 1
    try:
        parallelism = int(got["parallelism"])
    except ValueError:
        return None
    if (not files or not 1 <= parallelism <= MAX_PARALLELISM or got["format"] not in FORMATS
            or got["agents"] == "" or got["owner"] == ""):
        return None
    options = {"yes": got["yes"], "parallelism": parallelism, "format": got["format"]}
    if verb == "apply":
        options["prune"] = got["prune"]
    return verb, tuple(files), got["agents"], got["owner"], options


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command: in the server of its plant if it may and one answers, else as always."""
    args = list(sys.argv[1:] if argv is None else argv)
    served = read(args)
    if served is not None:
        from engine.control.client import run_in_server  # noqa: PLC0415 - standard library only

        verb, files, agents, owner, options = served
        code = run_in_server(verb, files, agents, owner, options)
        if code is not None:
            return code
    from engine.cli import main as command_line  # noqa: PLC0415 - click and the commands

    return command_line(args)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

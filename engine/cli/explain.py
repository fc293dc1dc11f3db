"""``plantkg explain FILE... ADDRESS``: why a broker, topic or bridge of the plan must exist.

Prints, for the plan address (``broker.ID``, ``topic.BROKER.NAME``, ``bridge.A.B`` as ``plan``
shows them), every reason the reasoner has for it: a fact the plant asserts (and its file), or a
rule that fired and the facts it fired on (:mod:`engine.reasoning.explain`). No agent is asked.

Exit codes, as ``grep`` and ``terraform state show`` / ``kubectl get`` on a missing address:
0 the address is required (reasons printed), 1 it is not required (why, on stdout) or the plant
has violations, 2 unusable input (a malformed address, a bad file, a plant the fast reasoner
cannot explain).
"""

from __future__ import annotations

import json

import click

from kg.errors import EXIT_VIOLATIONS

EXIT_NOT_REQUIRED = 1


@click.command("explain")
@click.argument("files", nargs=-1, required=True, type=click.Path(path_type=str), metavar="FILE...")
@click.argument("address", metavar="ADDRESS")
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text for people, json for programs")
def explain_command(files: tuple[str, ...], address: str, fmt: str) -> int:
    """Say why ADDRESS (a broker, topic or bridge of the plan) must exist: which rule fired on which facts.

    Exit 0: required; 1: not required (or the plant has violations); 2: unusable input.

    \b
    Example:
      plantkg explain ontology/examples/robot-cell.ttl bridge.mosquitto.kafka
    """
    from engine.cli.reconcile import print_violations  # noqa: PLC0415 - only when run
    from engine.reasoning.explain import explain, parse_address  # noqa: PLC0415

    parse_address(address)  # a malformed address fails before the plant is loaded
    result, explanation = explain(files, address)
    if explanation is None:  # an invalid plant: its report, as plan prints it
        print_violations(result, fmt)
        return EXIT_VIOLATIONS
    if fmt == "json":
        click.echo(json.dumps(explanation.to_dict(), indent=2, ensure_ascii=False))
    else:
        click.echo(explanation.text())
    return 0 if explanation.required else EXIT_NOT_REQUIRED

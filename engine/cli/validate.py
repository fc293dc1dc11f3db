"""``plantkg validate FILE...``: check a plant against the shapes; nothing is deployed or changed."""

from __future__ import annotations

import click

from kg.errors import EXIT_VIOLATIONS
from engine.cli.common import file_argument

#: kg.validate.ENGINES, written out so that listing this command does not import the validators
#: (rdflib, pyoxigraph); tests/unit/test_cli_imports.py holds the two equal.
ENGINES: tuple[str, ...] = ("auto", "oxigraph", "pyshacl")


@click.command("validate")
@file_argument
@click.option("--format", "fmt", type=click.Choice(["text", "json"]), default="text", show_default=True,
              help="text for people, json for programs")
@click.option("--engine", type=click.Choice(ENGINES), default="auto", show_default=True,
              help="oxigraph: fast SPARQL engine; pyshacl: the reference engine")
@click.option("--shapes", "shapes_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="shapes file(s) to use instead of the project's shapes/*.ttl")
def validate_command(files: tuple[str, ...], fmt: str, engine: str, shapes_files: tuple[str, ...]) -> int:
    """Validate plant FILE(s) against the SHACL shapes.

    Exit code 0 when valid, 1 when the plant has violations, 2 when a file cannot be used.

    \b
    Example:
      plantkg validate ontology/examples/robot-cell.ttl
    """
    from kg.load import load_plant  # noqa: PLC0415 - the heavy imports: only when run
    from kg.render import validation_json, validation_text  # noqa: PLC0415
    from kg.shapes import load_shapes  # noqa: PLC0415
    from kg.validate import validate  # noqa: PLC0415

    plant = load_plant(files)
    shapes = load_shapes(shapes_files) if shapes_files else None
    report = validate(plant, shapes, engine=engine)  # type: ignore[arg-type]
    if fmt == "json":
        click.echo(validation_json(report))
    else:
        click.echo(validation_text(report, plant.prefixes))
    return 0 if report.conforms else EXIT_VIOLATIONS

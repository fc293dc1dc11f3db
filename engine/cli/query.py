"""``plantkg query FILE... QUERY``: ask a plant a SPARQL question (read-only)."""

from __future__ import annotations

from pathlib import Path

import click

from kg.errors import InputError
from kg.load import load_plant
from kg.query import parse_binding, run_query
from kg.render import query_csv, query_json, query_table


@click.command("query")
@click.argument("args", nargs=-1, required=True, metavar="FILE... [QUERY]")
@click.option("--file", "-f", "query_file", type=click.Path(path_type=Path),
              help="read the query from this .rq file instead of the last argument")
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table",
              show_default=True)
@click.option("--bind", "binds", multiple=True, metavar="NAME=VALUE",
              help="pre-bind ?NAME (<iri>, pk:term, integer or string); repeatable")
def query_command(args: tuple[str, ...], query_file: Path | None, fmt: str, binds: tuple[str, ...]) -> int:
    """Run a SPARQL SELECT, ASK, CONSTRUCT or DESCRIBE over plant FILE(s) and the ontology.

    The prefixes pk:, rdf:, rdfs:, owl:, xsd: and sh: are predeclared. Values given with --bind
    are passed as bound variables, never pasted into the query text.

    \b
    Example:
      plantkg query ontology/examples/robot-cell.ttl \\
        'SELECT ?broker ?ip ?port WHERE { ?broker a pk:Broker ; pk:ip ?ip ; pk:port ?port }'
    """
    if query_file is not None:
        files, text = list(args), _read_query(query_file)
    else:
        if len(args) < 2:
            raise click.UsageError("give plant FILE(s) and then the QUERY (or --file Q.rq)")
        files, text = list(args[:-1]), args[-1]
    bindings = dict(parse_binding(b) for b in binds)
    plant = load_plant(files)
    result = run_query(plant, text, bindings)
    if fmt == "json":
        click.echo(query_json(result))
    elif fmt == "csv":
        click.echo(query_csv(result))
    else:
        click.echo(query_table(result, plant.prefixes))
    return 0


def _read_query(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "no such query file") from None
    except IsADirectoryError:
        raise InputError(path, "is a directory, not a query file") from None
    except UnicodeDecodeError:
        raise InputError(path, "is not UTF-8 text") from None

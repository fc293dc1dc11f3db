"""``plantkg query FILE... QUERY``: ask a plant a SPARQL question (read-only)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from kg.errors import InputError

if TYPE_CHECKING:
    from kg.load import PlantGraph


@click.command("query")
@click.argument("args", nargs=-1, required=True, metavar="FILE... [QUERY]")
@click.option("--file", "-f", "query_file", type=click.Path(path_type=Path),
              help="read the query from this .rq file instead of the last argument")
@click.option("--format", "fmt", type=click.Choice(["table", "csv", "json"]), default="table",
              show_default=True)
@click.option("--bind", "binds", multiple=True, metavar="NAME=VALUE",
              help="pre-bind ?NAME (<iri>, pk:term, integer or string); repeatable")
@click.option("--live", is_flag=True,
              help="query the running plant too: the inferred facts, the context of its context "
                   "brokers and, with --agents, the observed state (the plant must be valid)")
@click.option("--agents", "agents_file", type=click.Path(path_type=Path), default=None,
              help="with --live: agents.toml, to ask the agents what runs (the observed graph)")
def query_command(args: tuple[str, ...], query_file: Path | None, fmt: str, binds: tuple[str, ...],
                  live: bool, agents_file: Path | None) -> int:
    """Run a SPARQL SELECT, ASK, CONSTRUCT or DESCRIBE over plant FILE(s) and the ontology.

    The prefixes pk:, rdf:, rdfs:, owl:, xsd:, sh:, ngsi: and fleet: are predeclared. Values given with --bind
    are passed as bound variables, never pasted into the query text.

    \b
    With --live the plant is validated and reasoned over first (the inferred graph), the context
    brokers' entities are read (one named graph per tenant) and, with --agents, the agents are
    asked what runs (the observed graph): the same graphs the `plantkg serve` endpoint queries.

    \b
    Example:
      plantkg query ontology/examples/robot-cell.ttl \\
        'SELECT ?broker ?ip ?port WHERE { ?broker a pk:Broker ; pk:ip ?ip ; pk:port ?port }'
    """
    from kg.load import load_plant  # noqa: PLC0415 - rdflib, pyoxigraph: only when run
    from kg.query import parse_binding, run_query  # noqa: PLC0415
    from kg.render import query_csv, query_json, query_table  # noqa: PLC0415

    if query_file is not None:
        files, text = list(args), _read_query(query_file)
    else:
        if len(args) < 2:
            raise click.UsageError("give plant FILE(s) and then the QUERY (or --file Q.rq)")
        files, text = list(args[:-1]), args[-1]
    bindings = dict(parse_binding(b) for b in binds)
    if agents_file is not None and not live:
        raise click.UsageError("--agents goes with --live")
    if live:
        plant = _live_plant(files, agents_file)
        if plant is None:
            return 1
    else:
        plant = load_plant(files)
    result = run_query(plant, text, bindings)
    if fmt == "json":
        click.echo(query_json(result))
    elif fmt == "csv":
        click.echo(query_csv(result))
    else:
        click.echo(query_table(result, plant.prefixes))
    return 0


def _live_plant(files: list[str], agents_file: Path | None) -> PlantGraph | None:
    """The plant with its inferred, observed and context graphs; None (after printing the
    report) when the plant is not valid."""
    from engine.cli.reconcile import load_directory, print_violations
    from engine.context_view import agent_tokens, context_sources, write_context
    from engine.pipeline import run_pipeline

    directory = load_directory(agents_file) if agents_file is not None else None
    result = run_pipeline(files, directory, observe=directory is not None)  # no cache: keep the graph
    if result.plant is None or not result.report.conforms:
        print_violations(result)
        return None
    for host in (result.observed.unreachable if result.observed else ()):
        click.echo(f"warning: the agent for {host} did not answer; its brokers are pk:Unknown", err=True)
    tokens = (agent_tokens(result.desired.brokers, directory.token_for)
              if directory is not None and result.desired is not None else {})
    view = write_context(result.plant, context_sources(result.plant, tokens))
    for iri, why in view.unavailable:
        click.echo(f"warning: context broker {iri}: its context could not be read ({why})", err=True)
    return result.plant


def _read_query(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(path, "no such query file") from None
    except IsADirectoryError:
        raise InputError(path, "is a directory, not a query file") from None
    except UnicodeDecodeError:
        raise InputError(path, "is not UTF-8 text") from None

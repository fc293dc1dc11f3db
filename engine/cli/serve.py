"""``plantkg serve FILE...``: dashboard, SPARQL endpoint and JSON API of a running plant (docs/web.md)."""

from __future__ import annotations

from pathlib import Path

import click

from engine.cli.common import file_argument
from engine.cli.options import agents_option, owner_option

DEFAULT_PORT = 8080


@click.command("serve")
@file_argument
@click.option("--listen", default=f"127.0.0.1:{DEFAULT_PORT}", show_default=True, metavar="ADDRESS[:PORT]",
              help="Address to serve on (loopback unless --allow-remote).")
@agents_option
@click.option("--auto-apply", is_flag=True,
              help="Apply the plan after every change of the files (or of the *.ttl in a FILE that "
                   "is a folder), and put back what drifts, every --observe-interval (touches only "
                   "what the plant owns).")
@owner_option
@click.option("--token-file", type=click.Path(dir_okay=False, path_type=Path),
              help="Login token file; created with a random token if missing.  "
                   "[default: $XDG_STATE_HOME/plantkg/web-token]")
@click.option("--allow-remote", is_flag=True, help="Allow a --listen address other than loopback.")
@click.option("--observe-interval", type=click.FloatRange(0.2, 3600), default=5.0, show_default=True,
              help="Seconds between two questions to the agents.")
@click.option("--query-timeout", type=click.FloatRange(0.1, 3600), default=10.0, show_default=True,
              help="Seconds a SPARQL query may run; then its worker process is killed and the "
                   "answer is 503.")
@click.option("--max-queries", type=click.IntRange(1, 64), default=4, show_default=True,
              help="SPARQL queries that may run at once, each in a worker process of its own "
                   "(holding a copy of the plant); more get 503 with Retry-After.")
@click.option("--max-client-queries", type=click.IntRange(1, 64), default=2, show_default=True,
              help="SPARQL queries one client (the logged-in user, else the remote address) may run "
                   "at once; more get 429 with Retry-After. See docs/security.md.")
@click.option("--max-results", type=click.IntRange(1), default=10_000, show_default=True,
              help="Rows (or triples) a SPARQL answer may hold.")
@click.option("--no-control", is_flag=True,
              help="Do not open the control socket: `plantkg apply` of this plant then runs in its "
                   "own process, cold (see docs/web.md).")
@click.option("-v", "--verbose", is_flag=True, help="Log every request.")
def serve_command(files: tuple[str, ...], listen: str, agents_file: Path | None, auto_apply: bool,
                  owner: str | None, token_file: Path | None, allow_remote: bool, observe_interval: float,
                  query_timeout: float, max_results: int, max_queries: int, max_client_queries: int,
                  no_control: bool, verbose: bool) -> int:
    """Serve a dashboard, a SPARQL endpoint and a JSON API for the plant in FILE(s).

    The files are re-read when they change (validate, then plan); a FILE may be a folder (every
    *.ttl inside, e.g. discovered vehicles). The agents are asked what runs every few seconds.
    Nothing is applied unless a logged-in person presses Apply, or --auto-apply (a reconcile loop:
    see docs/operating.md), or this user runs `plantkg apply` of the same files, agents file and
    owner: that command then runs here, with the pipeline warm (a Unix socket only this user can
    open; --no-control closes it).

    \b
    Example:
      plantkg serve ontology/examples/robot-cell.ttl --agents agents.toml
    """
    # Imported here: the web layer imports engine.cli.progress, and other commands need no Flask app.
    from engine.agent.server import parse_listen  # noqa: PLC0415
    import logging  # noqa: PLC0415
    from engine.web.server import run_server  # noqa: PLC0415
    from engine.web.sparql_protocol import Limits  # noqa: PLC0415

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("werkzeug").setLevel(logging.INFO if verbose else logging.WARNING)
    address = parse_listen(listen, allow_remote=allow_remote)
    limits = Limits(timeout_s=query_timeout, max_rows=max_results, workers=max_queries,
                    per_client=max_client_queries)
    return run_server(list(files), address, agents_file=agents_file, token_file=token_file,
                      auto_apply=auto_apply, limits=limits, observe_interval=observe_interval, owner=owner,
                      control=not no_control)

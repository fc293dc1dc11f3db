"""``plantkg agent``: run the agent of this machine (see docs/agent.md)."""

from __future__ import annotations

from pathlib import Path

import click

#: engine.agent.server.DEFAULT_PORT, written out so that listing this command does not import the
#: agent's HTTP server (tests/unit/test_cli_imports.py holds the two equal).
DEFAULT_PORT = 7300


@click.command("agent")
@click.option("--listen", default=f"127.0.0.1:{DEFAULT_PORT}", show_default=True,
              metavar="ADDRESS[:PORT]", help="Address to serve the API on ([::1]:PORT for IPv6).")
@click.option("--state-dir", required=True, type=click.Path(file_okay=False, path_type=Path),
              help="Folder of the agent's brokers (created if missing).")
@click.option("--token-file", type=click.Path(dir_okay=False, path_type=Path),
              help="Bearer token file; created with a random token if missing.  "
                   "[default: STATE_DIR/token]")
@click.option("--tls", is_flag=True,
              help="Serve the API over HTTPS with a certificate of the plant CA (see --ca-dir); "
                   "clients verify it against the CA's ca.pem.")
@click.option("--allow-remote", is_flag=True,
              help="Allow a --listen address other than loopback.")
@click.option("--stop-brokers-on-exit", is_flag=True,
              help="Stop the brokers on SIGTERM/SIGINT (by default they keep running).")
@click.option("--principal-key", type=click.Path(dir_okay=False, path_type=Path),
              help="The plant's principal key (plantkg's own logins at closed brokers derive from "
                   "it; created 0600 if missing; the same file on every machine of the plant).  "
                   "[default: $PLANTKG_PRINCIPAL_KEY, else $XDG_STATE_HOME/plantkg/principal-key]")
@click.option("--ca-dir", type=click.Path(file_okay=False, path_type=Path),
              help="The plant CA folder (ca.pem, ca.key 0600): certificates of TLS brokers are "
                   "issued from it; created if missing; the same CA on every machine.  "
                   "[default: $PLANTKG_CA_DIR, else $XDG_STATE_HOME/plantkg/ca]")
@click.option("--name", help="The agent's name in /v1/health.  [default: its URL]")
@click.option("-v", "--verbose", is_flag=True, help="Log every request.")
def agent_command(listen: str, state_dir: Path, token_file: Path | None, tls: bool, allow_remote: bool,
                  stop_brokers_on_exit: bool, principal_key: Path | None, ca_dir: Path | None,
                  name: str | None, verbose: bool) -> int:
    """Run this machine's agent: start, supervise and configure its brokers over HTTP.

    Brokers outlive the agent: on restart it re-adopts those still running and restarts the
    others. Stop it with SIGTERM or Ctrl-C.
    """
    import logging  # noqa: PLC0415

    from engine.agent.server import parse_listen, run_agent  # noqa: PLC0415 - Flask: only when run

    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    logging.getLogger("werkzeug").setLevel(logging.INFO if verbose else logging.WARNING)
    address = parse_listen(listen, allow_remote=allow_remote)
    if tls:
        from dataclasses import replace  # noqa: PLC0415

        address = replace(address, tls=True)
    return run_agent(address, state_dir, token_file, stop_brokers_on_exit=stop_brokers_on_exit,
                     name=name, principal_key_file=principal_key, ca_dir=ca_dir)

"""``python -m fleet.hmi`` (``plantkg fleet hmi``): serve the operators' screens.

    python -m fleet.hmi --lotlan jobs.tl --map hall.json --manager-data-dir fleet-data \\
        (--planner-data-dir planner-data | --planner-url URL --planner-token-file F) \\
        [--token-file F] [--host 127.0.0.1] [--port 0] [--allow-remote]

The LoTLan file and the map are the planner's own (its jobs and stations; checked together as the
planner checks them). The login token
is the first line of ``--token-file`` (default: the dashboard's, ``$XDG_STATE_HOME/plantkg/
web-token``; created 0600 when missing). Binds to loopback; another address needs
``--allow-remote``. Prints ``fleet HMI listening on URL`` once it serves; SIGTERM/SIGINT stop it
(exit 0); an unusable argument, file or address exits 2 with the reason.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import signal
import sys
import threading
from pathlib import Path

import fleet.lotlan
from fleet.hmi.app import HmiConfig, create_app
from fleet.hmi.auth import default_token_file, load_or_create_token
from fleet.hmi.errors import HmiError
from fleet.hmi.upstream import ManagerLink, PlannerLink
from fleet.lotlan.errors import LotlanError
from fleet.planner import build
from fleet.sim import map as site_map
from kg.errors import PlantKGError

log = logging.getLogger("fleet.hmi")


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m fleet.hmi", description="The fleet's operator screens.")
    p.add_argument("--lotlan", type=Path, required=True, help="the planner's LoTLan file (its jobs)")
    p.add_argument("--map", default="default", help="the planner's map JSON, or 'default'")
    p.add_argument("--manager-data-dir", type=Path, required=True, help="the fleet manager's --data-dir")
    planner = p.add_mutually_exclusive_group(required=True)
    planner.add_argument("--planner-data-dir", type=Path, help="the planner's --data-dir (planner.json, planner.token)")
    planner.add_argument("--planner-url", help="the planner's API (with --planner-token-file)")
    p.add_argument("--planner-token-file", type=Path, help="the planner's token (with --planner-url)")
    p.add_argument("--token-file", type=Path, default=None, help="login token (default: the dashboard's)")
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, default=0, help="0: a free port (printed)")
    p.add_argument("--allow-remote", action="store_true", help="allow a --host that is not loopback")
    return p


def _check_host(host: str, allow_remote: bool) -> None:
    try:
        loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
    except ValueError:
        raise HmiError(f"--host {host!r} is no IP address", hint="give e.g. 127.0.0.1") from None
    if not loopback and not allow_remote:
        raise HmiError(f"--host {host} is not loopback: the HMI's buttons would be reachable from the network",
                       hint="add --allow-remote if that is meant (and put TLS in front of it)")


def config_of(args: argparse.Namespace) -> HmiConfig:
    _check_host(args.host, args.allow_remote)
    if args.planner_url is not None and args.planner_token_file is None:
        raise HmiError("--planner-url needs --planner-token-file (the planner's <data-dir>/planner.token)")
    site = site_map.default_map() if args.map == "default" else site_map.load(Path(args.map))
    program = fleet.lotlan.load(args.lotlan)
    build.check_program(program, site)  # as the planner does: every Location a station of the map
    token_file = (args.token_file or default_token_file()).expanduser().resolve()
    token, created = load_or_create_token(token_file)
    if created:
        log.info("new login token in %s", token_file)
    planner = (PlannerLink(data_dir=args.planner_data_dir.resolve()) if args.planner_data_dir is not None
               else PlannerLink(url=args.planner_url, token_file=args.planner_token_file.resolve()))
    return HmiConfig(program, site, planner, ManagerLink(args.manager_data_dir.resolve()), token)


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    args = parser().parse_args(argv)
    from werkzeug.serving import make_server

    try:
        config = config_of(args)
        server = make_server(args.host, args.port, create_app(config), threaded=True)
    except (PlantKGError, LotlanError, OSError, SystemExit) as exc:  # werkzeug exits when the port is taken
        print(f"error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    thread = threading.Thread(target=server.serve_forever, name="fleet-hmi", daemon=True)
    thread.start()
    print(f"fleet HMI listening on http://{args.host}:{server.server_port}", flush=True)
    try:
        while not stop.wait(0.5):
            pass
    finally:
        server.shutdown()
        thread.join()
        server.server_close()
    log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())

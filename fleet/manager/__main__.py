"""``python -m fleet.manager``: run the fleet manager (plug and play, orders, status).

    python -m fleet.manager PLANT.ttl... --data-dir DIR [--agents agents.toml] [--api-port 0]

The MQTT broker is the one the plant's fleet-manager resource sends to (``--mqtt HOST:PORT``
overrides it). The HTTP API binds to 127.0.0.1 (``--api-host`` to change it); its address and
token are in ``DIR/manager.json`` and ``DIR/manager.token``. SIGTERM/SIGINT stop it cleanly
(exit 0); unusable arguments or plant exit 2 with the reason.
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from pathlib import Path

from engine.agents_config import AgentDirectory
from engine.incremental.warm import WarmPipeline
from fleet.manager import apply_step
from fleet.manager.api import ApiServer
from fleet.manager.plant import binding_and_address
from fleet.manager.service import FleetManager, ManagerConfig
from kg.errors import PlantKGError

log = logging.getLogger("fleet.manager")


def _address(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT with a port from 1 to 65535")
    return host.strip("[]"), int(port)


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m fleet.manager", description="The plantkg fleet manager.")
    p.add_argument("plant", nargs="+", type=Path, metavar="PLANT.ttl", help="the plant's files")
    p.add_argument("--data-dir", type=Path, required=True, help="discovered/, vehicles/, refused/, status.json")
    p.add_argument("--agents", type=Path, default=None, help="agents file (default as plantkg apply)")
    p.add_argument("--mqtt", type=_address, default=None, help="HOST:PORT instead of the plant's broker")
    p.add_argument("--api-host", default="127.0.0.1")
    p.add_argument("--api-port", type=int, default=0, help="0: a free port (see DIR/manager.json)")
    p.add_argument("--batch-window", type=float, default=0.1, help="s: joins within it make one reconcile")
    p.add_argument("--resync", type=float, default=30.0, help="s between reconciles without a change (drift)")
    return p


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    args = parser().parse_args(argv)
    try:
        plant = [p.resolve() for p in args.plant]
        binding, address = binding_and_address(plant)
        directory = AgentDirectory.load(args.agents)
        config = ManagerConfig(tuple(plant), args.data_dir.resolve(), args.mqtt or address, binding,
                               batch_window=args.batch_window, resync=args.resync)
        warm = WarmPipeline()  # one plant for the manager's life: each join re-plans from its edit
        manager = FleetManager(config, lambda files: apply_step.reconcile(files, directory, warm))
        api = ApiServer(manager, config.data_dir, args.api_host, args.api_port)
    except (PlantKGError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    manager.api_url = api.url
    api.start(os.getpid())
    signal.signal(signal.SIGTERM, lambda *_: manager.stop())
    signal.signal(signal.SIGINT, lambda *_: manager.stop())
    log.info("fleet manager: plant %s, MQTT %s:%d, API %s, data %s", " ".join(map(str, plant)),
             *config.mqtt, api.url, config.data_dir)
    try:
        manager.run()
    finally:
        api.stop()
    log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())

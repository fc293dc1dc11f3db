"""``python -m fleet.planner``: run the task planner.

    python -m fleet.planner --plant PLANT.ttl --lotlan jobs.tl --data-dir DIR \\
        --manager-data-dir MANAGER_DIR [--ngsi-url http://127.0.0.3:1026 --ngsi-token-file F] \\
        [--ngsi-ca-file CA.pem] \\
        [--map map.json] [--min-battery 20] [--waiting-area [park|LOCATION]] [--no-charging] [--start] \\
        [--events-mqtt HOST:PORT [--events-topic plantkg/events]] [--events-ngsi [--events-ngsi-listen HOST:PORT]]

The fleet manager is found through its data directory (``manager.json``, ``manager.token``; its
``discovered/*.ttl`` join the plant graph the assignment query runs on), or given as
``--manager-url URL --manager-token-file F [--discovered DIR]``. Vehicles and their VDA 5050
states (position, progress) come from the manager's API; paper-channel vehicles are reached
through the context broker (``--ngsi-url``; without it they are not assigned). A context broker with
``pk:tls true`` is ``https://`` and verified against ``--ngsi-ca-file`` (the plant CA's ``ca.pem``;
an ``https://`` URL without it: the system's store); a certificate the planner does not trust stops
it at start with exit 2 (fleet/planner/ngsi_tls.py). ``--start`` starts one
job of the program's start tasks when the journal has no job yet. ``--waiting-area`` sends the
vehicle of a finished job task to the waiting area: the nearest free ``park-*`` spot (``park``, the
value when none is given) or a Location of the LoTLan file; without it vehicles stay where they
finished. A vehicle below ``--min-battery`` goes to a charger unless ``--no-charging``. The API binds to 127.0.0.1; its
address and token are in ``DIR/planner.json`` and ``DIR/planner.token``. SIGTERM/SIGINT stop it
(exit 0); an unusable argument, plant, map or LoTLan file exits 2 with the reason, nothing started.

LoTLan Events fire through ``POST /v1/events``, and with ``--events-mqtt`` from messages on
``<topic>/<event>`` (fleet/planner/events_mqtt.py), with ``--events-ngsi`` from ``Event`` entities
on the context broker through a subscription whose notifications reach a second loopback server
(``--events-ngsi-listen``, address in ``DIR/planner-notify.json``; fleet/planner/events_ngsi.py).
"""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import fleet.lotlan
from fleet.lotlan.errors import LotlanError
from fleet.manager.client import ManagerClient
from fleet.planner import build
from fleet.loopback_api import token_for
from fleet.planner.api import ApiServer, NotifyServer
from fleet.planner.dispatch import Dispatcher, VdaSender
from fleet.planner.errors import PlannerError
from fleet.planner.events_mqtt import DEFAULT_PREFIX, MqttEvents, check_prefix
from fleet.planner.events_ngsi import NgsiEvents, description_for
from fleet.planner.journal import Journal
from fleet.planner.ngsi import TaskPublisher
from fleet.planner.ngsi_tls import CA_OPTION, NgsiTrust, check_certificate
from fleet.planner.plantview import PlantView
from fleet.planner.service import Planner, PlannerConfig
from fleet.planner.paper import NgsiClient, PaperSender
from fleet.planner.vehicles import Fleet, ManagerHandle
from fleet.sim import map as site_map
from kg.errors import PlantKGError

log = logging.getLogger("fleet.planner")
MANAGER_TIMEOUT = 2.0  # s: the planner's loop calls the manager; a hung manager stalls it at most this long


def _address(text: str, *, port_zero: bool = False) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    low = 0 if port_zero else 1
    if not sep or not host or not port.isdigit() or not low <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: expected HOST:PORT with a port from {low} to 65535")
    return host, int(port)


def _prefix(text: str) -> str:
    try:
        return check_prefix(text)
    except PlannerError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m fleet.planner", description="The plantkg task planner.")
    p.add_argument("--plant", nargs="+", type=Path, required=True, metavar="PLANT.ttl")
    p.add_argument("--lotlan", type=Path, required=True, help="the LoTLan file of the jobs")
    p.add_argument("--data-dir", type=Path, required=True, help="journal.jsonl, planner.json, planner.token")
    manager = p.add_mutually_exclusive_group(required=True)
    manager.add_argument("--manager-data-dir", type=Path, help="the fleet manager's --data-dir")
    manager.add_argument("--manager-url", help="the fleet manager's API (with --manager-token-file)")
    p.add_argument("--manager-token-file", type=Path, help="the manager's token (with --manager-url)")
    p.add_argument("--discovered", type=Path, help="the manager's discovered/ folder (with --manager-url)")
    p.add_argument("--ngsi-url", default=None, help="context broker (NGSI-v2) for the Task entities")
    p.add_argument("--ngsi-token-file", type=Path, default=None, help="its write token (first line)")
    p.add_argument(CA_OPTION, type=Path, default=None, metavar="CA.pem",
                   help="the CA certificate an https:// --ngsi-url is verified against (a pk:tls context "
                        "broker: the plant CA's ca.pem; default: the system's store)")
    p.add_argument("--map", default="default", help="map JSON with the stations, or 'default'")
    p.add_argument("--min-battery", type=float, default=20.0, help="percent a vehicle needs to be assigned")
    p.add_argument("--waiting-area", nargs="?", const="park", default=None, metavar="park|LOCATION",
                   help="after a job task its vehicle goes to the nearest free park-* spot, or to this "
                        "LoTLan Location (default: it stays where it finished)")
    p.add_argument("--no-charging", action="store_true",
                   help="do not send vehicles below --min-battery to a charger")
    p.add_argument("--start", action="store_true", help="start one job when the journal has none")
    p.add_argument("--events-mqtt", type=_address, default=None, metavar="HOST:PORT",
                   help="fire Events from MQTT messages on <--events-topic>/<event> (QoS 1)")
    p.add_argument("--events-topic", type=_prefix, default=DEFAULT_PREFIX, metavar="PREFIX",
                   help=f"topic prefix of --events-mqtt (default {DEFAULT_PREFIX})")
    p.add_argument("--events-ngsi", action="store_true",
                   help="fire Events from entities of type Event on the context broker (needs --ngsi-url)")
    p.add_argument("--events-ngsi-listen", type=lambda t: _address(t, port_zero=True), default=("127.0.0.1", 0),
                   metavar="HOST:PORT", help="where the context broker's notifications arrive "
                                             "(default 127.0.0.1:0, a free port; the subscription names it)")
    p.add_argument("--api-host", default="127.0.0.1")
    p.add_argument("--api-port", type=int, default=0)
    return p


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    args = parser().parse_args(argv)
    journal = None
    try:
        if args.events_ngsi and not args.ngsi_url:
            raise PlannerError("--events-ngsi needs --ngsi-url (the context broker that holds the Event entities)")
        if args.ngsi_ca_file is not None and not args.ngsi_url:
            raise PlannerError(f"{CA_OPTION} needs --ngsi-url (the https:// context broker it verifies)")
        trust = NgsiTrust(args.ngsi_url, args.ngsi_ca_file) if args.ngsi_url else None
        tls = trust.context() if trust is not None else None  # one context for every NGSI client
        plant_files = tuple(p.resolve() for p in args.plant)
        site = site_map.default_map() if args.map == "default" else site_map.load(Path(args.map))
        program = fleet.lotlan.load(args.lotlan)
        build.check_program(program, site)  # before anything is touched: a bad file starts nothing
        if args.manager_data_dir is not None:
            manager_dir = args.manager_data_dir.resolve()
            manager = ManagerHandle(replace(ManagerClient.for_data_dir(manager_dir), timeout=MANAGER_TIMEOUT),
                                    lambda: replace(ManagerClient.for_data_dir(manager_dir), timeout=MANAGER_TIMEOUT))
            discovered: Path | None = manager_dir / "discovered"
        elif args.manager_token_file is None:
            raise PlannerError("--manager-url needs --manager-token-file (the manager's <data-dir>/manager.token)")
        else:
            manager = ManagerHandle(ManagerClient(args.manager_url.rstrip("/"),
                                                  args.manager_token_file.read_text(encoding="utf-8").strip(),
                                                  MANAGER_TIMEOUT))
            discovered = args.discovered
        token = None
        if args.ngsi_token_file is not None:
            token = args.ngsi_token_file.read_text(encoding="utf-8").splitlines()[0].strip()
        plant = PlantView(plant_files, discovered)
        plant.current()
        if trust is not None:
            check_certificate(trust, tls)  # an untrusted certificate: exit 2 now, not retries forever
        journal = Journal(args.data_dir.resolve())
        publisher = TaskPublisher(args.ngsi_url, token, context=tls) if args.ngsi_url else None
        ngsi = NgsiClient(args.ngsi_url, token, context=tls) if args.ngsi_url else None
        dispatch = Dispatcher(VdaSender(manager, site.map_id), PaperSender(ngsi, site) if ngsi else None)
        config = PlannerConfig(site, min_battery=args.min_battery, paper=ngsi is not None,
                               waiting_area=args.waiting_area, charging=not args.no_charging)
        planner = Planner(config, program, journal, Fleet(manager, ngsi.agv_status if ngsi else None), plant,
                          dispatch, publisher, dispatch.cancel, dispatch.stop_charging)
        data_dir = args.data_dir.resolve()
        sources: dict[str, Any] = {}
        mqtt_events: MqttEvents | None = None
        ngsi_events: NgsiEvents | None = None
        notify: NotifyServer | None = None
        if args.events_mqtt is not None:
            mqtt_events = MqttEvents(*args.events_mqtt, args.events_topic, planner.fire, data_dir)
            sources["mqtt"] = mqtt_events.status
        if args.events_ngsi:
            ngsi_events = NgsiEvents(args.ngsi_url, token, planner.fire, description_for(data_dir),
                                     token_for(data_dir, "planner-notify"), context=tls)
            notify = NotifyServer(ngsi_events.notify, data_dir, *args.events_ngsi_listen)
            sources["ngsi"] = ngsi_events.status
        api = ApiServer(planner, data_dir, args.api_host, args.api_port, sources)
    except (PlantKGError, LotlanError, OSError, IndexError) as exc:
        if journal is not None:
            journal.close()
        print(f"error: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: planner.stop())
    signal.signal(signal.SIGINT, lambda *_: planner.stop())
    if publisher is not None:
        publisher.start()
    api.start(os.getpid())
    if notify is not None and ngsi_events is not None:
        notify.start(os.getpid())
        ngsi_events.start(notify.notify_url)
    if mqtt_events is not None:
        mqtt_events.start()
    if args.start and not planner.jobs:
        log.info("started job %s", planner.start_job(None))
    log.info("task planner: LoTLan %s, manager %s, context broker %s, API %s, data %s", args.lotlan,
             manager.client.url, args.ngsi_url or "none", api.url, args.data_dir)
    try:
        planner.run()
    finally:
        if mqtt_events is not None:
            mqtt_events.stop()
        if ngsi_events is not None and notify is not None:
            ngsi_events.stop()
            notify.stop()
        api.stop()
        if publisher is not None:
            publisher.stop()
        journal.close()
    log.info("stopped")
    return 0


if __name__ == "__main__":
    sys.exit(main())

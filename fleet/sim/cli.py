"""``python -m fleet.sim``: N simulated AGVs speaking VDA 5050 2.1 (or the paper's channels) on an MQTT broker.

    python -m fleet.sim --broker 127.0.0.1:1883 --count 3 --manufacturer plantkg \\
        --serial-prefix sim- --map default --rate 2

``--interface paper`` makes them speak the second paper's five channels instead
(``<serial>/motion_channel`` ..., :mod:`fleet.sim.paper_adapter`); ``--rate`` is then the movement
rate and ``--state-interval`` the status heartbeat.

On a closed broker each vehicle logs in as its own user: ``--username agv-{serial}`` and
``--secret-ref file:/dir/{serial}`` (``{serial}`` is replaced by the vehicle's serial; a
reference ``env:NAME`` or ``file:/absolute/path`` as a plant's ``pk:secretRef``, read here, never
a password on the command line).

Vehicle i (1-based) is ``<prefix><i:04d>`` and starts on the map's i-th parking spot. Exit codes:
0 after a clean stop (SIGTERM/SIGINT: OFFLINE published for each vehicle), 2 for unusable
arguments (the message names the option and the value).
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from dataclasses import replace
from pathlib import Path

from fleet.sim import map as site_map
from fleet.sim.kinematics import Limits
from fleet.sim.mqtt_pump import MqttPump
from fleet.sim.paper_adapter import PaperLink, PaperLinkConfig
from fleet.sim.runner import FleetRunner
from fleet.sim.vda5050_adapter import MAX_STATE_INTERVAL, LinkConfig, Vda5050Link
from fleet.sim.vehicle import SimVehicle, VehicleSpec
from fleet.vda5050 import topics
from engine.security.secrets import read_secret
from fleet.vda5050.errors import TopicError
from kg.errors import PlantKGError

log = logging.getLogger("fleet.sim")


def _broker(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"--broker {text!r}: expected HOST:PORT with a port from 1 to 65535")
    return host.strip("[]"), int(port)


def _positive(kind: type, name: str):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} {text!r}: not a number") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"{name} {text!r}: must be > 0")
        return value
    return parse


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m fleet.sim", description="Simulated AGVs speaking VDA 5050 2.1 over MQTT.")
    p.add_argument("--interface", choices=("vda5050", "paper"), default="vda5050",
                   help="VDA 5050 2.1 topics, or the paper's five channels <serial>/<channel>")
    p.add_argument("--broker", type=_broker, default=("127.0.0.1", 1883), help="HOST:PORT of the MQTT broker")
    p.add_argument("--count", type=_positive(int, "--count"), default=1, help="number of vehicles")
    p.add_argument("--manufacturer", default="plantkg", help="the manufacturer topic level")
    p.add_argument("--serial-prefix", default="sim-", help="serial number = prefix + 4-digit index")
    p.add_argument("--map", default="default", help="a map JSON file, or 'default' (40 x 20 m hall, 50 parking spots)")
    p.add_argument("--rate", type=_positive(float, "--rate"), default=1.0, help="visualization messages per second per vehicle")
    p.add_argument("--state-interval", type=_positive(float, "--state-interval"), default=MAX_STATE_INTERVAL,
                   help=f"periodic state every S seconds besides the event-driven ones (at most {MAX_STATE_INTERVAL:g})")
    p.add_argument("--username", default=None,
                   help="log in to the broker as this user; {serial} is replaced by each vehicle's serial (e.g. agv-{serial}, "
                        "the pk:id plug and play gives it)")
    p.add_argument("--secret-ref", default=None,
                   help="where each vehicle's password is: env:NAME or file:/absolute/path, {serial} replaced (needs --username)")
    p.add_argument("--tick", type=_positive(float, "--tick"), default=0.05, help="physics tick in seconds")
    p.add_argument("--vmax", type=_positive(float, "--vmax"), default=1.0, help="m/s")
    p.add_argument("--amax", type=_positive(float, "--amax"), default=0.5, help="m/s²")
    p.add_argument("--omega-max", type=_positive(float, "--omega-max"), default=1.0, help="rad/s")
    p.add_argument("--alpha-max", type=_positive(float, "--alpha-max"), default=1.0, help="rad/s²")
    return p


def build(args: argparse.Namespace) -> FleetRunner:
    site = site_map.default_map() if args.map == "default" else site_map.load(Path(args.map))
    spots = site.parking()
    if args.count > len(spots):
        raise PlantKGError(f"--count {args.count}: map {site.map_id!r} has only {len(spots)} parking spots",
                           hint="lower --count or add stations named park-* to the map")
    topics.check_level("manufacturer", args.manufacturer)
    limits = Limits(args.vmax, args.amax, args.omega_max, args.alpha_max)
    config = LinkConfig(host=args.broker[0], port=args.broker[1], state_interval=args.state_interval,
                        visualization_interval=1.0 / args.rate)
    paper = PaperLinkConfig(host=args.broker[0], port=args.broker[1], movement_interval=1.0 / args.rate,
                            status_interval=args.state_interval)
    pump = MqttPump()
    links: list[Vda5050Link | PaperLink] = []
    if (args.username is None) != (args.secret_ref is None):
        raise PlantKGError("--username and --secret-ref go together: a vehicle logs in with both or anonymously",
                           hint="give both (a closed broker), or neither (a broker open to anonymous clients)")
    for i in range(args.count):
        serial = topics.check_serial(f"{args.serial_prefix}{i + 1:04d}")
        spec = VehicleSpec(args.manufacturer, serial, site, spots[i], limits)
        login = _login(args, serial)
        if args.interface == "paper":
            links.append(PaperLink(SimVehicle(spec), replace(paper, **login), pump))
        else:
            links.append(Vda5050Link(SimVehicle(spec), replace(config, **login), pump))
    return FleetRunner(links, pump, tick=args.tick)


def _login(args: argparse.Namespace, serial: str) -> dict[str, str]:
    """The user name and password of vehicle ``serial`` (none: it connects anonymously). The
    password is read from its reference here, on the vehicle's machine; errors name the option
    and the reference, never the secret."""
    if args.username is None:
        return {}
    return {"username": args.username.replace("{serial}", serial),
            "password": read_secret("--secret-ref", args.secret_ref.replace("{serial}", serial))}


def main(argv: list[str] | None = None) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    args = parser().parse_args(argv)
    try:
        runner = build(args)
    except (PlantKGError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: runner.stop())
    signal.signal(signal.SIGINT, lambda *_: runner.stop())
    host, port = args.broker
    log.info("starting %d vehicles (%s) on %s:%d (manufacturer %s)", args.count, args.interface, host, port,
             args.manufacturer)
    runner.run(on_all_connected=lambda: log.info("all %d vehicles online", args.count))
    confirmed = runner.shutdown()
    log.info("stopped: OFFLINE confirmed for %d of %d vehicles after %d ticks (%d late)",
             confirmed, args.count, runner.ticks, runner.late_ticks)
    return 0

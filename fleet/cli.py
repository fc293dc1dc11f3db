"""``plantkg fleet ...``: the fleet's commands, found by ``plantkg`` through the entry-point group
``plantkg.commands`` (engine never imports fleet).

| command | what |
|---------|------|
| ``plantkg fleet manager PLANT... --data-dir DIR`` | run the fleet manager (as ``python -m fleet.manager``) |
| ``plantkg fleet simulate ...`` | run simulated vehicles (the options of ``python -m fleet.sim``) |
| ``plantkg fleet vehicles`` | the discovered vehicles of the data directory (and the refused ones) |
| ``plantkg fleet status`` | what the running manager last wrote: states, last reconcile, refusals |
| ``plantkg fleet pin VEHICLE [--unpin]`` | keep a vehicle as it is even if it sends another factsheet |
| ``plantkg fleet rename VEHICLE NAME`` | set its ``pk:name`` |
| ``plantkg fleet remove VEHICLE`` | forget it (its file and record); it is discovered again when it comes back online |
| ``plantkg fleet admit SERIAL PLANT... --manufacturer M --secret-file F`` | admit a vehicle to a closed broker before it connects (``fleet/discovery/admission.py``) |
| ``plantkg fleet order SERIAL NODE...`` | send a VDA 5050 order through the running manager's API |
| ``plantkg fleet hmi ...`` | serve the operators' screens (the options of ``python -m fleet.hmi``) |
| ``plantkg fleet planner ...`` | run the task planner (the options of ``python -m fleet.planner``), restarted when it crashes (``fleet/supervise.py``) |
| ``plantkg fleet demo`` | the fleet end to end on this machine (``fleet/demo.py``), nothing left running |

The data directory is ``--data-dir`` or ``$PLANTKG_FLEET_DATA``. pin/rename/remove change the data
directory under its lock; a running manager notices within its poll interval (0.5 s) and
reconciles. Heavy imports happen inside the commands, so ``plantkg --help`` stays fast.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import click

from kg.errors import PlantKGError

data_dir_option = click.option(
    "--data-dir", type=click.Path(path_type=Path, file_okay=False), envvar="PLANTKG_FLEET_DATA",
    required=True, help="the fleet manager's data directory (or $PLANTKG_FLEET_DATA)")


@click.group("fleet")
def fleet_group() -> None:
    """AGV fleet: plug and play (discovered vehicles), orders, simulated vehicles."""


@fleet_group.command("manager", context_settings={"ignore_unknown_options": True, "help_option_names": []})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def manager_command(args: tuple[str, ...]) -> int:
    """Run the fleet manager (options of python -m fleet.manager; --help lists them)."""
    from fleet.manager.__main__ import main

    try:
        return main(list(args))
    except SystemExit as exc:  # argparse's --help and usage errors
        return int(exc.code or 0)


@fleet_group.command("simulate", context_settings={"ignore_unknown_options": True, "help_option_names": []})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def simulate_command(args: tuple[str, ...]) -> int:
    """Run simulated VDA 5050 vehicles (options of python -m fleet.sim; --help lists them)."""
    from fleet.sim.cli import main

    try:
        return main(list(args))
    except SystemExit as exc:  # argparse's --help and usage errors
        return int(exc.code or 0)


@fleet_group.command("hmi", context_settings={"ignore_unknown_options": True, "help_option_names": []})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def hmi_command(args: tuple[str, ...]) -> int:
    """Serve the operators' screens: stations, live map (options of python -m fleet.hmi; --help lists them)."""
    from fleet.hmi.__main__ import main

    try:
        return main(list(args))
    except SystemExit as exc:  # argparse's --help and usage errors
        return int(exc.code or 0)


@fleet_group.command("planner", context_settings={"ignore_unknown_options": True, "help_option_names": []})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def planner_command(args: tuple[str, ...]) -> int:
    """Run the task planner, restarted when it crashes (options of python -m fleet.planner; --help lists them)."""
    import sys

    if "--help" in args or "-h" in args:
        from fleet.planner.__main__ import main as planner_main

        try:
            return planner_main(["--help"])
        except SystemExit as exc:
            return int(exc.code or 0)
    from fleet.supervise import main

    return main(["--name", "planner", "--", sys.executable, "-m", "fleet.planner", *args])


@fleet_group.command("demo")
@click.option("--vehicles", type=click.IntRange(1, 50), default=3, show_default=True,
              help="simulated VDA 5050 vehicles (one more speaks the paper's channels)")
@click.option("--work-dir", type=click.Path(path_type=Path, file_okay=False), default=None,
              help="where the plant, the agents, the data and the logs go (default: a new temporary folder)")
@click.option("--deadline", type=click.FloatRange(10), default=300.0, show_default=True,
              help="seconds the jobs may take")
@click.option("--keep", type=click.FloatRange(0), default=0.0, show_default=True,
              help="seconds to keep everything running after the jobs (to look around)")
@click.option("--speed", type=click.FloatRange(1, 10), default=1.0, show_default=True,
              help="the simulated vehicles drive and turn this many times as fast (the same paths, "
                   "sooner): 1 is 1 m/s at 0.5 m/s², turns 1 rad/s at 1 rad/s²")
def demo_command(vehicles: int, work_dir: Path | None, deadline: float, keep: float, speed: float) -> int:
    """The second paper's fleet end to end: plant, plug and play, SPARQL, LoTLan jobs, Task entities."""
    from fleet.demo import run_fleet_demo

    return run_fleet_demo(vehicles=vehicles, work_dir=work_dir, deadline=deadline, keep=keep, speed=speed)


def _data(data_dir: Path) -> Any:
    from fleet.discovery.records import DataDir
    from fleet.manager.service import render_record

    if not data_dir.is_dir():
        raise PlantKGError(f"{data_dir}: no such data directory",
                           hint="give the --data-dir the fleet manager was started with")
    return DataDir(data_dir, render_record)


@fleet_group.command("vehicles")
@data_dir_option
@click.option("--format", "fmt", type=click.Choice(["table", "json"]), default="table", show_default=True)
def vehicles_command(data_dir: Path, fmt: str) -> int:
    """List the discovered vehicles (and the refused ones, with their reason)."""
    data = _data(data_dir)
    rows = [{"vehicle": r.label, "interface": r.interface, "name": r.name or r.description.get("name"),
             "connectionState": r.connection_state, "pinned": r.pinned, "discoveredAt": r.discovered_at,
             "admitted": r.secret_ref is not None, "heard": not r.awaiting_description,
             "skills": list(r.description.get("skills", ())), "file": str(data.turtle_path(r))}
            for r in data.records()]
    refused = data.refused_list()
    if fmt == "json":
        click.echo(json.dumps({"vehicles": rows, "refused": refused}, indent=1))
        return 0
    if not rows:
        click.echo("no discovered vehicles")
    for r in rows:
        flag = (" pinned" if r["pinned"] else "") + (" admitted" if r["admitted"] else "") \
            + ("" if r["heard"] else " (not heard yet)")
        click.echo(f"{r['vehicle']:<32} {r['connectionState']:<16} {r['interface']:<14} "
                   f"{r['name']!s:<20}{flag}  skills: {', '.join(r['skills'])}")
    for r in refused:
        click.echo(f"refused {r['vehicle']}: {r['reason']}")
    return 0


@fleet_group.command("status")
@data_dir_option
def status_command(data_dir: Path) -> int:
    """What the running manager last wrote (status.json): vehicles and their last state, the
    last reconcile, refusals."""
    try:
        status = json.loads((data_dir / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise PlantKGError(f"{data_dir / 'status.json'}: cannot be read ({exc})",
                           hint="start the fleet manager with this --data-dir") from None
    manager = status.get("manager", {})
    click.echo(f"manager pid {manager.get('pid')}, API {manager.get('api')}, MQTT {manager.get('mqtt')} "
               f"({'connected' if manager.get('connected') else 'not connected'}), updated {status.get('updated')}")
    last = status.get("lastReconcile") or {}
    click.echo(f"last reconcile {last.get('at', '-')}: {last.get('summary', 'none yet')}")
    for v in status.get("vehicles", []):
        state = v.get("state") or {}
        ready = f"{v['readySeconds']:.3f} s" if v.get("readySeconds") is not None else "-"
        click.echo(f"  {v['vehicle']:<32} {v['connectionState']:<16} ready {ready:<9} "
                   f"order {state.get('orderId') or '-'} last node {state.get('lastNodeId') or '-'} "
                   f"battery {state.get('batteryCharge', '-')}")
    for r in status.get("refused", []):
        click.echo(f"  refused {r['vehicle']}: {r['reason'][:200]}")
    for m in status.get("refusedMessages", [])[-5:]:
        click.echo(f"  refused message on {m['topic']}: {m['reason'][:200]}")
    return 0


@fleet_group.command("pin")
@click.argument("vehicle")
@click.option("--unpin", is_flag=True, help="accept its next factsheet again")
@data_dir_option
def pin_command(vehicle: str, unpin: bool, data_dir: Path) -> int:
    """Keep VEHICLE (SERIAL or MANUFACTURER/SERIAL) as it is, whatever factsheet it sends."""
    data = _data(data_dir)
    with data.lock():
        record = data.update(data.find(vehicle), pinned=not unpin)
    click.echo(f"{record.label}: {'pinned' if record.pinned else 'not pinned'}")
    return 0


@fleet_group.command("rename")
@click.argument("vehicle")
@click.argument("name")
@data_dir_option
def rename_command(vehicle: str, name: str, data_dir: Path) -> int:
    """Give VEHICLE the pk:name NAME (kept when it sends its factsheet again)."""
    if not name.strip() or any(c in name for c in "\n\r\t") or len(name) > 200:
        raise PlantKGError(f"name {name!r}: one line of at most 200 characters, not blank")
    data = _data(data_dir)
    with data.lock():
        record = data.update(data.find(vehicle), name=name)
    click.echo(f"{record.label}: pk:name {name!r}")
    return 0


@fleet_group.command("remove")
@click.argument("vehicle")
@data_dir_option
def remove_command(vehicle: str, data_dir: Path) -> int:
    """Forget VEHICLE: its file and record are deleted; the plant no longer has it."""
    data = _data(data_dir)
    with data.lock():
        record = data.find(vehicle)
        data.remove(record)
    click.echo(f"{record.label}: removed")
    return 0


@fleet_group.command("admit")
@click.argument("serial")
@click.argument("plant", nargs=-1, required=True, type=click.Path(path_type=Path, dir_okay=False, exists=True))
@click.option("--manufacturer", required=True,
              help="the vehicle's manufacturer, as in its topics (uagv/v2/MANUFACTURER/SERIAL/...) and factsheet")
@click.option("--interface", type=click.Choice(["vda5050", "paper-channels"]), default="vda5050", show_default=True)
@click.option("--secret-file", type=click.Path(path_type=Path, dir_okay=False), required=True,
              help="where its new password goes (created 0600, never written over): give it to the vehicle")
@data_dir_option
def admit_command(serial: str, plant: tuple[Path, ...], manufacturer: str, interface: str, secret_file: Path,
                  data_dir: Path) -> int:
    """Admit vehicle SERIAL to the fleet's closed broker before it connects (PLANT: the plant's
    files, as the manager is given them). A new password goes to --secret-file; the running
    manager's next reconcile makes the vehicle's user. `plantkg fleet remove` takes it back."""
    from fleet.discovery import model_api
    from fleet.discovery.admission import admit

    data_dir.mkdir(parents=True, exist_ok=True)
    binding = model_api.binding_to_json(model_api.plant_binding(list(plant)))
    done = admit(_data(data_dir), binding, interface, manufacturer, serial, secret_file)
    click.echo(f"{done.record.label}: admitted as user {done.user}; its password is in {done.secret_file} "
               f"(0600, give it to the vehicle); the vehicle: {done.turtle}")
    return 0


@fleet_group.command("order")
@click.argument("serial")
@click.argument("nodes", nargs=-1, required=True)
@click.option("--manufacturer", default=None, help="when two vehicles share the serial")
@click.option("--order-id", default=None)
@click.option("--map", "map_file", default="default", show_default=True,
              help="map JSON whose stations NODE names (as python -m fleet.sim --map)")
@data_dir_option
def order_command(serial: str, nodes: tuple[str, ...], manufacturer: str | None, order_id: str | None,
                  map_file: str, data_dir: Path) -> int:
    """Send SERIAL a VDA 5050 order through NODEs: STATION or NAME@X,Y, each optionally
    followed by :ACTION[,ACTION] (e.g. park-1 pick-1:pick drop-1:drop)."""
    from fleet.manager.client import ManagerClient
    from fleet.manager.orders import parse_node
    from fleet.sim import map as site_map

    site = site_map.default_map() if map_file == "default" else site_map.load(Path(map_file))
    specs = [parse_node(n, site) for n in nodes]
    reply = ManagerClient.for_data_dir(data_dir).order(serial, specs, manufacturer=manufacturer, order_id=order_id)
    click.echo(f"order {reply['orderId']} sent to {reply['vehicle']} ({reply['topic']})")
    return 0

"""``plantkg fleet demo``: the AGV fleet of the second paper, end to end on this machine.

The steps a plant would take, each with its real part:

1. the fleet plant (``ontology/examples/agv-fleet.ttl``: Mosquitto for the vehicles, the NGSI-v2
   context broker for the task planner and screens) copied onto free ports, an agent per machine,
   ``apply``;
2. the fleet manager starts (``python -m fleet.manager``); the vehicles are admitted to the
   fleet's Mosquitto, which the demo closes (the example opens it as a lab broker): ``plantkg fleet
   admit`` gives each a password file (0600) and its user; then simulated AGVs of two interfaces
   log in and connect — VDA 5050 vehicles and one speaking the paper's channels — and join **by
   plug and play**: each is asked for its factsheet (or announces its description), becomes
   triples in the graph, is validated, reasoned over, planned and applied; the time each took is
   printed;
3. one SPARQL query over the plant and the discovered vehicles shows who can do what;
4. the task planner (``python -m fleet.planner``) takes the LoTLan jobs (``fleet/examples/jobs.tl``),
   assigns each transport to a vehicle by a SPARQL query, sends VDA 5050 orders (or the paper's
   items) and follows them; the operator screens (``python -m fleet.hmi``) show the map live;
   when a vehicle waits at the loading station the demo presses **Loaded** for the operator (the
   HMI shows the same button); every task change is printed;
5. the Task entities on the context broker, as any NGSI client sees them;
6. everything stops: planner, vehicles, manager, brokers, agents. Nothing is left running.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
import time
import urllib.error
import urllib.request
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import click

from engine import process
from engine.cli.progress import result_lines
from engine.demo.local_plant import LocalPlant, copy_on_free_ports, processes_under
from fleet.discovery import model_api
from fleet.discovery.admission import admit
from fleet.discovery.records import DataDir, now_iso
from fleet.manager.service import render_record
from fleet.planner.ngsi_tls import NgsiTrust, plant_trust
from fleet.sim.kinematics import Limits
from kg.errors import PlantKGError
from kg.load import load_plant
from kg.query import run_query

ROOT = Path(__file__).resolve().parents[1]
PLANT = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
JOBS = Path(__file__).resolve().parent / "examples" / "jobs.tl"
MQTT_ID, CONTEXT_ID = "fleet-mqtt", "fleet-context"

WHO_CAN_DO_WHAT = """
SELECT ?vehicle ?interface (GROUP_CONCAT(DISTINCT ?skill; separator=" ") AS ?skills) WHERE {
    ?v pk:isType fleet:agv ; pk:id ?vehicle ; fleet:interface ?interface ; fleet:discovered true ;
       pk:executes/pk:id ?skill .
} GROUP BY ?vehicle ?interface ORDER BY ?vehicle"""


#: what the example says of its open lab broker, and what the demo's closed copy says instead
OPENED = (("    pk:allowAnonymous true ;\n", ""),
          ("Open to anonymous clients on purpose (a lab broker): plug and play means a vehicle the plant does "
           "not know yet announces itself here, before it has a user (plan warns).",
           "Closed (the demo's copy of the example): a vehicle the plant does not know is admitted "
           "(plantkg fleet admit) before it connects."))
PAPER_MANUFACTURER = "plantkg"  # what python -m fleet.sim --interface paper says by default


def close_fleet_broker(plant_file: Path) -> None:
    """Close the fleet's Mosquitto in the demo's copy of the example (the example keeps it open)."""
    text = plant_file.read_text(encoding="utf-8")
    for old, new in OPENED:
        if text.count(old) != 1:
            raise PlantKGError(f"{plant_file}: expected {old.strip()[:60]!r} once, to close the fleet's broker",
                               hint=f"keep {PLANT.name}'s fleet-mqtt as it is, or update fleet/demo.py with it")
        text = text.replace(old, new)
    plant_file.write_text(text, encoding="utf-8")


def admit_vehicles(plant_file: Path, data_dir: Path, secret_dir: Path,
                   vehicles: list[tuple[str, str, str]]) -> None:
    """``plantkg fleet admit`` each (interface, manufacturer, serial): its password in
    ``secret_dir/<serial>.pw`` (0600), its record in the manager's data directory."""
    secret_dir.mkdir(mode=0o700, parents=True, exist_ok=True)
    data = DataDir(data_dir, render_record)
    binding = model_api.binding_to_json(model_api.plant_binding([plant_file]))
    for interface, manufacturer, serial in vehicles:
        admit(data, binding, interface, manufacturer, serial, secret_dir / f"{serial}.pw")


@dataclass(frozen=True)
class Api:
    """A fleet process's loopback API, found through its ``<name>.json`` and ``<name>.token``."""

    data_dir: Path
    name: str

    def where(self) -> dict[str, Any]:
        try:
            return json.loads((self.data_dir / f"{self.name}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}

    def call(self, method: str, path: str, body: Any = None) -> tuple[int, Any]:
        token = (self.data_dir / f"{self.name}.token").read_text(encoding="utf-8").strip()
        request = urllib.request.Request(
            self.where()["url"] + path, method=method,
            data=None if body is None else json.dumps(body).encode("utf-8"),
            headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=10) as reply:  # noqa: S310 - loopback URL we wrote
                return reply.status, json.loads(reply.read())
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read() or b"null")


def _spawn(stack: ExitStack, argv: list[str | Path], logs: Path, name: str) -> process.Child:
    child = process.spawn([sys.executable, *argv], log_dir=logs, name=name, cwd=ROOT)
    stack.callback(process.stop, child)
    return child


def _manager_status(data: Path) -> dict[str, Any]:
    try:
        return json.loads((data / "status.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def limit_flags(speed: float) -> list[str]:
    """``fleet.sim`` flags for vehicles ``speed`` times as fast as its defaults on the same paths:
    speeds times ``speed``, accelerations times its square (every drive and turn takes 1/speed
    of the time)."""
    base = Limits()
    return ["--vmax", f"{base.v_max * speed:g}", "--amax", f"{base.a_max * speed ** 2:g}",
            "--omega-max", f"{base.omega_max * speed:g}", "--alpha-max", f"{base.alpha_max * speed ** 2:g}"]


def run_fleet_demo(*, vehicles: int, work_dir: Path | None, deadline: float, keep: float,
                   speed: float = 1.0) -> int:
    """Run the demo; returns the exit code (0 when every task finished). ``speed`` > 1 makes the
    simulated vehicles drive and turn that many times as fast (see :func:`limit_flags`)."""
    base = work_dir or Path(tempfile.mkdtemp(prefix="plantkg-fleet-demo-"))
    base.mkdir(parents=True, exist_ok=True)
    logs, manager_data, planner_data = base / "logs", base / "fleet-manager", base / "planner"
    plant_file = base / "agv-fleet.ttl"
    ports = copy_on_free_ports(PLANT, plant_file)
    close_fleet_broker(plant_file)
    mqtt = f"127.0.0.2:{ports[MQTT_ID]}"
    click.secho(f"1. the fleet plant ({PLANT.name}) on free ports, its Mosquitto closed: Mosquitto {mqtt}, "
                f"context broker 127.0.0.3:{ports[CONTEXT_ID]}; agents, apply", bold=True)
    with ExitStack() as stack:
        plant = stack.enter_context(LocalPlant.start([plant_file], base / "plant"))
        result = plant.apply()
        for line in result_lines(result):
            click.echo(f"   {line}")
        if not result.ok:
            click.secho("   the plant did not apply; see the agents' logs under " + str(base), fg="red")
            return 1

        click.secho(f"\n2. the fleet manager; {vehicles} VDA 5050 vehicles and 1 on the paper's channels "
                    "admitted, then they join by plug and play", bold=True)
        manager = _spawn(stack, ["-m", "fleet.manager", plant_file, "--data-dir", manager_data,
                                 "--agents", plant.agents.agents_file], logs, "fleet-manager")
        process.wait_until(lambda: (_manager_status(manager_data).get("lastReconcile") or {}).get("ok"),
                           120, 0.1, what="the fleet manager to start", child=manager)
        secret_dir = base / "secrets"
        admitted = [("vda5050", "plantkg-sim", f"demo-{i:04d}") for i in range(1, vehicles + 1)]
        admitted.append(("paper-channels", PAPER_MANUFACTURER, "paper-0001"))
        since = now_iso()
        admit_vehicles(plant_file, manager_data, secret_dir, admitted)
        serials = {serial for _, _, serial in admitted}

        def users_made() -> bool:
            status = _manager_status(manager_data)
            last = status.get("lastReconcile") or {}
            listed = {v.get("serial") for v in status.get("vehicles", [])}
            return bool(last.get("ok")) and str(last.get("at", "")) > since and serials <= listed
        process.wait_until(users_made, 120, 0.1, what="the manager to make the admitted vehicles' users",
                           child=manager)
        click.echo(f"   admitted {len(admitted)} vehicles (plantkg fleet admit): passwords under {secret_dir} (0600), "
                   "users made by the manager's reconcile; anonymous clients are refused")
        login = ["--username", "agv-{serial}", "--secret-ref", f"file:{secret_dir}/{{serial}}.pw"]
        _spawn(stack, ["-m", "fleet.sim", "--broker", mqtt, "--count", str(vehicles),
                       "--manufacturer", "plantkg-sim", "--serial-prefix", "demo-", *login, *limit_flags(speed)],
               logs, "vda5050-vehicles")
        _spawn(stack, ["-m", "fleet.sim", "--interface", "paper", "--broker", mqtt, "--count", "1",
                       "--manufacturer", PAPER_MANUFACTURER, "--serial-prefix", "paper-", *login,
                       *limit_flags(speed)], logs, "paper-vehicle")
        expected = vehicles + 1

        def joined() -> list[dict[str, Any]] | None:
            rows = [v for v in _manager_status(manager_data).get("vehicles", [])
                    if v.get("readySeconds") is not None and str(v.get("serial", "")).startswith(("demo-", "paper-"))]
            return rows if len(rows) >= expected else None

        rows = process.wait_until(joined, 60 + 5 * expected, 0.1, what="the vehicles to join", child=manager)
        for row in sorted(rows, key=lambda r: r["serial"]):
            click.echo(f"   {row['vehicle']:<28} {row['interface']:<15} ready {row['readySeconds'] * 1000:6.0f} ms "
                       f"after ONLINE, skills: {' '.join(row.get('skills', []))}")

        click.secho("\n3. plantkg query: the discovered vehicles and their skills (SPARQL over the graph)", bold=True)
        discovered = sorted((manager_data / "discovered").glob("*.ttl"))
        answer = run_query(load_plant([plant_file, *discovered]), WHO_CAN_DO_WHAT)
        click.echo("   " + " | ".join(answer.variables))
        for row in answer.rows:
            click.echo("   " + " | ".join("" if term is None else term.value for term in row))

        click.secho(f"\n4. the task planner takes {JOBS.name}; the demo presses 'Loaded' for the operator",
                    bold=True)
        cb_token = plant.agents.agents["127.0.0.3"].state_dir / "token"
        context_broker = plant_trust(load_plant([plant_file]))  # https:// and the plant CA with pk:tls true
        planner = _spawn(stack, ["-m", "fleet.planner", "--plant", plant_file, "--lotlan", JOBS,
                                 "--data-dir", planner_data, "--manager-data-dir", manager_data,
                                 *context_broker.flags(), "--ngsi-token-file", cb_token], logs, "planner")
        api = Api(planner_data, "planner")
        process.wait_until(lambda: api.where().get("pid") == planner.pid, 60, 0.05,
                           what="the planner's API", child=planner)
        hmi_token = base / "hmi-token"
        hmi = _spawn(stack, ["-m", "fleet.hmi", "--lotlan", JOBS, "--map", "default",
                             "--manager-data-dir", manager_data, "--planner-data-dir", planner_data,
                             "--token-file", hmi_token, "--port", "0"], logs, "hmi")
        url = process.wait_until(lambda: _listening(hmi), 60, 0.05, what="the operator screens", child=hmi)
        click.echo(f"   operator screens (HMI): {url}/  — the fleet map; log in with the token in {hmi_token}")
        status, job = api.call("POST", "/v1/jobs", {})
        if status != 201:
            click.secho(f"   the planner refused the job: {job}", fg="red")
            return 1
        finished = _follow(api, planner, deadline)

        click.secho("\n5. the Task entities on the context broker (GET /v2/entities?type=Task)", bold=True)
        cb_read_token = cb_token.read_text(encoding="utf-8").strip()  # closed by default: reads need it
        entities = _task_entities(context_broker, cb_read_token)
        if finished:  # the planner writes each Task entity after its own state changed: wait for it
            try:
                entities = process.wait_until(lambda: _ended(_task_entities(context_broker, cb_read_token)), 30, 0.1,
                                              what="the context broker to show every task ended")
            except process.WaitTimeoutError as exc:
                click.secho(f"   {exc}", fg="red")
        for entity in entities:
            click.echo(f"   {entity.get('id')}: {entity.get('state')} {entity.get('vehicle', '')}")
        if keep > 0:
            click.echo(f"\n   keeping everything running for {keep:g} s (logs under {logs})")
            end = time.monotonic() + keep
            process.wait_until(lambda: time.monotonic() >= end, keep + 5, 0.5, what="the end of --keep")
        click.secho("\n6. stopping the planner, the vehicles, the manager, the brokers and the agents", bold=True)
    ours = _ancestors()
    left = [line for line in processes_under(base) if int(line.split(":", 1)[0]) not in ours]
    if left:
        click.secho("   still running: " + "; ".join(left), fg="red")
        return 1
    click.echo("   nothing left running")
    return 0 if finished else 1


def _listening(child: process.Child) -> str | None:
    """The URL the HMI printed when it started listening (it picks a free port)."""
    found = re.search(r"listening on (http://\S+)", child.log_tail())
    return found.group(1) if found else None


def _ancestors() -> set[int]:
    """This process and its parents (their command lines may name the work folder too)."""
    pids, pid = set(), os.getpid()
    while pid > 1 and pid not in pids:
        pids.add(pid)
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return pids


def _follow(api: Api, planner: process.Child, deadline: float) -> bool:
    """Print every task state change; press Loaded when a task waits for it. True when all finished."""
    seen: dict[str, str] = {}
    pressed: set[str] = set()
    end = time.monotonic() + deadline

    def step() -> bool:
        status, body = api.call("GET", "/v1/tasks")
        if status != 200:
            return False
        tasks = body["tasks"]
        for task in tasks:
            legs = " ".join(f"{leg['station']}:{leg['state']}" for leg in task["legs"])
            line = f"{task['state']} {task['vehicle']} [{legs}]"
            if seen.get(task["id"]) != line:
                seen[task["id"]] = line
                click.echo(f"   {time.strftime('%H:%M:%S')} {task['lotlanTask']:<16} {line}")
            acted = [leg for leg in task["legs"] if leg["state"] == "ACTED"]
            if acted and task["id"] + str(acted[0]["index"]) not in pressed:
                pressed.add(task["id"] + str(acted[0]["index"]))
                api.call("POST", "/v1/events", {"event": "Loaded", "value": True})
                click.echo(f"   {time.strftime('%H:%M:%S')} operator at {acted[0]['station']}: Loaded")
        return bool(tasks) and all(t["state"] in ("FINISHED", "FAILED", "WITHDRAWN") for t in tasks)

    try:
        process.wait_until(step, max(end - time.monotonic(), 1), 0.2, what="every task to end", child=planner)
    except process.WaitTimeoutError as exc:
        click.secho(f"   {exc}", fg="red")
        return False
    _, body = api.call("GET", "/v1/tasks")
    return all(t["state"] == "FINISHED" for t in body["tasks"])


def _ended(entities: list[dict[str, Any]]) -> list[dict[str, Any]] | None:
    """The Task entities once every one has ended (None before: the poll goes on)."""
    done = ("FINISHED", "FAILED", "WITHDRAWN")
    return entities if entities and all(e.get("state") in done for e in entities) else None


def _task_entities(context_broker: NgsiTrust, token: str) -> list[dict[str, Any]]:
    """The Task entities, read with the context broker's agent's token (reads need it too), over
    https trusting the plant CA when the plant says ``pk:tls true``, as the planner."""
    request = urllib.request.Request(f"{context_broker.url}/v2/entities?type=Task&options=keyValues&limit=100",
                                     headers={"Authorization": f"Bearer {token}"})
    try:
        with urllib.request.urlopen(request, timeout=5,  # noqa: S310 - the plant's own broker
                                    context=context_broker.context()) as reply:
            return json.loads(reply.read())
    except (OSError, ValueError) as exc:
        return [{"id": "(the context broker did not answer)", "state": str(exc)}]

"""The reconcile loop against real agents and Mosquitto (issue 11, "Continuous reconciliation").

One agent on 127.0.0.2. The loop watches a plant file and a folder (where a fleet manager drops
discovered vehicles as files). In file order on one loop: it applies the plant by itself → a
broker deleted behind its back through the agent API comes back within the observe interval → a
file with a new broker dropped into the folder plus a burst of pokes is applied in one run → an
invalid file changes nothing, the status says why, and drift is still corrected with the last
valid plant. A broker made by hand (owned by nobody) runs beside it all and is never touched.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from engine import netutil, process
from engine.agents_config import AgentDirectory
from engine.apply import apply
from engine.model import BrokerSpec, BrokerStatus
from engine.pipeline import run_pipeline
from engine.reconcile_loop import LoopRun, ReconcileLoop, plant_files
from tests.integration.agents import AgentFleet, start_agents

pytestmark = pytest.mark.integration

HOST = "127.0.0.2"
OWNER = "loop-test-plant"
INTERVAL = 1.0
#: How long one run of the loop (load, validate, reason, plan, apply) may take: seconds on a quiet
#: machine, but over 30 s on a 2-core one running four test workers with Kafka clusters and the
#: 50 MB plant beside it (a deadline, not a goal: the waits return as soon as the run is done).
RUN_DEADLINE = 120.0
#: The interval, plus a run that observes the drift and starts a Mosquitto again.
COMES_BACK_WITHIN = INTERVAL + RUN_DEADLINE

BASE = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
@prefix : <http://example.org/loop-plant#> .
<http://example.org/loop-plant> a owl:Ontology .
:cell a pk:Broker ; pk:id "cell" ; pk:name "cell broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {port} ; pk:hasTopic :pose .
:pose a pk:Topic ; pk:id "pose" ; pk:name "cell/pose" ; pk:qos 1 .
"""
VEHICLE = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/loop-plant#> .
:agv a pk:Broker ; pk:id "agv-7" ; pk:name "AGV 7 broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {port} ; pk:hasTopic :agvstate .
:agvstate a pk:Topic ; pk:id "agvstate" ; pk:name "uagv/v2/acme/7/state" ; pk:qos 0 .
"""
INVALID = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/loop-plant#> .
:bad a pk:Broker ; pk:id "bad" ; pk:name "bad broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port 70000 .
"""


@dataclass
class Looped:
    fleet: AgentFleet
    directory: AgentDirectory
    loop: ReconcileLoop
    folder: Path
    ports: dict[str, int]
    runs: list[LoopRun]

    def brokers(self) -> dict[str, object]:
        return self.fleet.brokers()

    def wait_running(self, broker_id: str, deadline: float) -> float:
        """Seconds until ``broker_id`` runs (owned by the loop's plant)."""
        start = time.monotonic()

        def running() -> bool:
            b = self.fleet.client(HOST).get_broker(broker_id)
            return b is not None and b.status is BrokerStatus.RUNNING and b.owner == OWNER

        process.wait_until(running, deadline, 0.05, what=f"broker {broker_id} to run")
        return time.monotonic() - start


@pytest.fixture(scope="module")
def looped(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Looped]:
    tmp = tmp_path_factory.mktemp("reconcile-loop")
    fleet = start_agents([HOST], tmp)
    loop = None
    try:
        ports: dict[str, int] = {}
        for name in ("cell", "agv", "manual"):
            port = netutil.free_port(HOST)
            while port in ports.values():
                port = netutil.free_port(HOST)
            ports[name] = port
        plant, folder = tmp / "plant.ttl", tmp / "discovered"
        folder.mkdir()
        plant.write_text(BASE.format(host=HOST, port=ports["cell"]))
        fleet.client(HOST).put_broker(BrokerSpec("manual", "urn:test:manual", "by hand",
                                                 "mosquitto", HOST, ports["manual"]))
        directory = AgentDirectory.load(fleet.agents_file)
        runs: list[LoopRun] = []
        loop = ReconcileLoop([plant, folder], directory, owner=OWNER, interval=INTERVAL,
                             on_run=runs.append)
        yield Looped(fleet, directory, loop, folder, ports, runs)
    finally:
        if loop is not None:
            loop.stop()
            files = plant_files(loop.paths)
            for bad in folder.glob("bad*.ttl"):
                bad.unlink()
            result = run_pipeline(plant_files(loop.paths), directory, destroy=True, owner=OWNER)
            if result.plan is not None and not result.plan.empty:
                apply(result.plan, result.desired, directory, destroy=True)  # type: ignore[arg-type]
            assert files
        fleet.client(HOST).delete_broker("manual")
        fleet.stop()


def test_the_loop_applies_the_plant_by_itself(looped: Looped) -> None:
    manual = looped.fleet.client(HOST).get_broker("manual")
    looped.loop.start()
    looped.wait_running("cell", RUN_DEADLINE)
    process.wait_until(lambda: looped.loop.last_run is not None and looped.loop.last_run.converged,
                       RUN_DEADLINE, 0.05, what="a converged run")
    status = looped.loop.status
    assert status.owner == OWNER and status.invalid is None and status.digest
    first = looped.runs[0]
    assert first.trigger == "start" and first.applied and first.summary["create"] == 2
    assert first.foreign == 1  # the hand-made broker, shown and left alone
    assert looped.fleet.client(HOST).get_broker("manual").pid == manual.pid  # type: ignore[union-attr]


def test_a_broker_deleted_behind_its_back_comes_back(looped: Looped) -> None:
    before = len(looped.runs)
    looped.fleet.client(HOST).delete_broker("cell")
    assert looped.fleet.client(HOST).get_broker("cell") is None
    took = looped.wait_running("cell", COMES_BACK_WITHIN)
    assert took < COMES_BACK_WITHIN
    # the broker runs before the run that started it has finished and been recorded: wait for it
    drift = process.wait_until(lambda: [r for r in looped.runs[before:] if r.applied], RUN_DEADLINE, 0.05,
                               what="the drift run's record")
    assert drift[0].trigger == "drift" and drift[0].summary["create"] >= 1
    print(f"broker deleted behind the loop's back running again after {took:.2f} s "
          f"(interval {INTERVAL} s)")


def test_a_dropped_file_and_a_burst_of_pokes_make_one_run(looped: Looped) -> None:
    (looped.folder / "agv-7.ttl").write_text(VEHICLE.format(host=HOST, port=looped.ports["agv"]))
    before = len(looped.runs)
    for _ in range(5):  # within the 100 ms debounce
        looped.loop.poke()
    looped.wait_running("agv-7", RUN_DEADLINE)
    process.wait_until(lambda: any(r.trigger == "poke" for r in looped.runs[before:]),
                       RUN_DEADLINE, 0.05, what="the poke's run")
    new = looped.runs[before:]
    pokes = [r for r in new if r.trigger == "poke"]
    assert len(pokes) == 1, [(r.trigger, r.summary) for r in new]
    assert pokes[0].applied and pokes[0].summary["create"] == 2  # the broker and its topic
    assert not [r for r in new if r.trigger == "change"], "the poke's run already read the file"
    topics = looped.fleet.client(HOST).get_broker("agv-7").topics  # type: ignore[union-attr]
    assert [(t.name, t.owner) for t in topics] == [("uagv/v2/acme/7/state", OWNER)]


def test_an_invalid_file_changes_nothing_and_the_status_says_why(looped: Looped) -> None:
    pids = {k: b.pid for k, b in looped.brokers().items()}  # type: ignore[attr-defined]
    digest = looped.loop.status.digest
    (looped.folder / "bad.ttl").write_text(INVALID.format(host=HOST))
    looped.loop.poke()
    process.wait_until(lambda: looped.loop.status.invalid is not None, RUN_DEADLINE, 0.05,
                       what="the loop to notice the invalid file")
    status = looped.loop.status
    assert "violations" in status.invalid and "pk:port" in status.invalid, status.invalid  # type: ignore[operator]
    assert status.digest == digest, "the last valid plant stays in force"
    assert "bad" not in looped.brokers()
    # drift is still corrected, with the last valid plant
    looped.fleet.client(HOST).delete_broker("agv-7")
    looped.wait_running("agv-7", COMES_BACK_WITHIN)
    now = {k: b.pid for k, b in looped.brokers().items()}  # type: ignore[attr-defined]
    assert {k: v for k, v in now.items() if k != "agv-7"} == \
        {k: v for k, v in pids.items() if k != "agv-7"}
    # fixed: the loop applies again
    (looped.folder / "bad.ttl").unlink()
    looped.loop.poke()
    process.wait_until(lambda: looped.loop.status.invalid is None, RUN_DEADLINE, 0.05,
                       what="the loop to take the fixed plant")

"""BrokerManager in-process with real Mosquitto brokers: supervision (crash -> backoff restart)
and what happens when a manager opens a state dir an earlier one left (re-adoption, strays,
recycled pids). The subprocess agent is covered by tests/integration/test_agent.py."""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine import netutil, process
from engine.agent.folder import BrokerFolder, PidRecord
from engine.agent.manager import BrokerManager
from engine.agent.procs import SpawnedProcess, proc_info, processes_mentioning, processes_of
from engine.drivers.registry import DriverRegistry
from engine.model import BrokerSpec, BrokerStatus

REGISTRY = DriverRegistry.from_entry_points()


def mqtt(broker_id: str = "m1", port: int | None = None) -> BrokerSpec:
    return BrokerSpec(id=broker_id, iri=f"urn:plant:{broker_id}", name=broker_id,
                      kind="mosquitto", host="127.0.0.1", port=port or netutil.free_port())


class Managers:
    """Managers opened on one state dir; at the end: stop every broker, reap our children."""

    def __init__(self, state_dir: Path) -> None:
        self.state_dir = state_dir
        self.opened: list[BrokerManager] = []
        self.children: list[SpawnedProcess] = []

    def open(self, **options) -> BrokerManager:
        manager = BrokerManager(self.state_dir, REGISTRY, **{"backoff_base": 0.3, **options}).open()
        self.opened.append(manager)
        return manager

    def leave(self, manager: BrokerManager) -> None:
        """Close like an agent that exits without stopping its brokers."""
        self.children += [b.proc for b in manager._all() if isinstance(b.proc, SpawnedProcess)]
        manager.close(stop_brokers=False)

    def finish(self) -> None:
        for manager in self.opened:
            manager.close(stop_brokers=True)
        for child in self.children:  # brokers re-adopted by a later manager are still our children
            process.stop(child.child, grace=5.0)


@pytest.fixture
def managers(tmp_path: Path) -> Iterator[Managers]:
    found = Managers(tmp_path / "state")
    yield found
    found.finish()
    left = processes_mentioning(tmp_path)
    assert not left, f"processes left: {left}"


def wait_status(manager: BrokerManager, broker_id: str, predicate, what: str, deadline: float = 10.0):
    return process.wait_until(lambda: (b := manager.get(broker_id)) is not None and predicate(b) and b,
                              deadline, 0.01, what=what)


def test_a_crashed_broker_is_restarted_with_backoff(managers: Managers) -> None:
    manager = managers.open()
    first = manager.put(mqtt())
    os.kill(first.pid, signal.SIGKILL)
    crashed = wait_status(manager, "m1", lambda b: b.status is BrokerStatus.CRASHED, "CRASHED")
    assert crashed.pid is None and "exited unexpectedly" in crashed.last_error
    assert "code -9" in crashed.last_error and "restart in 0.3 s" in crashed.last_error
    second = wait_status(manager, "m1", lambda b: b.status is BrokerStatus.RUNNING, "restart")
    assert second.restarts == 1 and second.pid != first.pid
    assert second.last_error == crashed.last_error  # kept for the operator

    os.kill(second.pid, signal.SIGKILL)
    crashed = wait_status(manager, "m1", lambda b: b.status is BrokerStatus.CRASHED, "2nd crash")
    assert "restart in 0.6 s" in crashed.last_error  # doubled
    third = wait_status(manager, "m1", lambda b: b.status is BrokerStatus.RUNNING, "2nd restart")
    assert third.restarts == 2
    assert json.loads((manager.brokers_dir / "m1" / "pid.json").read_text())["restarts"] == 2


def test_backoff_is_capped() -> None:
    manager = BrokerManager(Path("/nonexistent"), REGISTRY, backoff_base=1.0, backoff_cap=30.0)
    assert [manager._backoff(n) for n in range(1, 8)] == [1, 2, 4, 8, 16, 30, 30]


def test_a_new_manager_adopts_running_brokers(managers: Managers) -> None:
    first = managers.open()
    observed = first.put(mqtt())
    managers.leave(first)
    assert proc_info(observed.pid) is not None  # the broker outlives its manager

    second = managers.open()
    adopted = second.get("m1")
    assert adopted.pid == observed.pid and adopted.status is BrokerStatus.RUNNING
    assert adopted.started_at == pytest.approx(observed.started_at, abs=0.02)
    assert [p.pid for p in processes_of(second.brokers_dir / "m1", observed_program(second))] \
        == [observed.pid]
    # Same essence: the adopted process is kept.
    assert second.put(observed.spec).pid == observed.pid
    # An adopted broker is supervised too: it is restarted when killed.
    os.kill(observed.pid, signal.SIGKILL)
    restarted = wait_status(second, "m1", lambda b: b.restarts == 1
                            and b.status is BrokerStatus.RUNNING, "restart of an adopted broker")
    assert restarted.pid != observed.pid


def observed_program(manager: BrokerManager) -> str:
    return json.loads((manager.brokers_dir / "m1" / "pid.json").read_text())["argv"][0]


def test_a_broker_gone_while_no_manager_ran_is_restarted(managers: Managers) -> None:
    first = managers.open()
    observed = first.put(mqtt())
    managers.leave(first)
    os.kill(observed.pid, signal.SIGKILL)
    os.waitpid(observed.pid, 0)  # our child: reap it (an agent's broker would be init's)

    second = managers.open()
    running = wait_status(second, "m1", lambda b: b.status is BrokerStatus.RUNNING, "restart")
    assert running.pid != observed.pid and running.restarts == 1
    assert f"process {observed.pid} was gone" in running.last_error


def test_stopped_brokers_start_again_with_the_next_manager(managers: Managers) -> None:
    first = managers.open()
    spec = mqtt()
    first.put(spec)
    first.close(stop_brokers=True)
    assert not netutil.port_open(spec.host, spec.port)
    second = managers.open()
    running = wait_status(second, "m1", lambda b: b.status is BrokerStatus.RUNNING, "start")
    assert running.restarts == 0 and running.last_error is None


def test_a_stray_process_of_a_broker_folder_is_stopped(managers: Managers) -> None:
    first = managers.open()
    observed = first.put(mqtt())
    managers.leave(first)
    (first.brokers_dir / "m1" / "pid.json").unlink()  # the agent lost track of it

    second = managers.open()
    running = wait_status(second, "m1", lambda b: b.status is BrokerStatus.RUNNING, "start")
    assert running.pid != observed.pid
    assert proc_info(observed.pid) is None or proc_info(observed.pid).start_ticks == 0
    assert [p.pid for p in processes_of(second.brokers_dir / "m1", observed_program(second))] \
        == [running.pid]


def test_a_recycled_pid_is_neither_adopted_nor_killed(managers: Managers) -> None:
    """pid.json names a live process that is not the broker (here: this test process)."""
    spec = mqtt()
    folder = BrokerFolder(managers.state_dir / "brokers" / "m1")
    folder.path.mkdir(parents=True)
    folder.write_spec(spec)
    me = proc_info(os.getpid())
    for start_ticks in (me.start_ticks, me.start_ticks + 1):  # same start time, or another one
        folder.write_pid(PidRecord(pid=os.getpid(), start_ticks=start_ticks,
                                   argv=("/usr/sbin/mosquitto",), essence={}))
        manager = managers.open()
        running = wait_status(manager, "m1", lambda b: b.status is BrokerStatus.RUNNING, "start")
        assert running.pid != os.getpid()
        manager.close(stop_brokers=True)


def test_a_broker_of_an_uninstalled_kind_is_reported_failed(managers: Managers) -> None:
    folder = BrokerFolder(managers.state_dir / "brokers" / "z1")
    folder.path.mkdir(parents=True)
    folder.write_spec(BrokerSpec(id="z1", iri="urn:z1", name="z", kind="zeromq",
                                 host="127.0.0.1", port=5555))
    manager = managers.open()
    failed = manager.get("z1")
    assert failed.status is BrokerStatus.FAILED and "no driver for broker kind 'zeromq'" in failed.last_error
    manager.delete("z1")
    assert manager.get("z1") is None

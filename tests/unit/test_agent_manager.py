"""BrokerManager in-process with real Mosquitto brokers: supervision (crash -> backoff restart)
and what happens when a manager opens a state dir an earlier one left (re-adoption, strays,
recycled pids). The subprocess agent is covered by tests/integration/test_agent.py."""

from __future__ import annotations

import json
import os
import signal
import threading
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.agent.folder import BrokerFolder, PidRecord
from engine.agent.manager import BrokerManager
from engine.agent.procs import SpawnedProcess, proc_info, processes_mentioning, processes_of
from engine.drivers.base import PeriodicSave
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


def _saves_logged(manager: BrokerManager, broker_id: str) -> int:
    log = manager.brokers_dir / broker_id / "logs" / "mosquitto.log"
    return log.read_text(errors="replace").count("Saving in-memory database") if log.exists() else 0


def _session(port: int, client_id: str) -> paho.Client:
    client = paho.Client(CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False)
    client.connect("127.0.0.1", port)
    client.loop_start()
    return client


def test_what_a_mosquitto_queued_survives_a_sigkill_once_its_agent_told_it_to_save(managers: Managers) -> None:
    # issue 16: with default settings, what Mosquitto queued for an offline persistent session
    # (a bridge, a worker) lived in memory until its own save by time (every 1-2 s). Its agent
    # now tells it to save every 0.25 s while clients send it anything.
    manager = managers.open()
    spec = mqtt()
    manager.put(spec)
    subscribed = threading.Event()
    offline = paho.Client(CallbackAPIVersion.VERSION2, client_id="offline", clean_session=False)
    offline.on_connect = lambda c, *_: c.subscribe("t/#", qos=1)
    offline.on_subscribe = lambda *_: subscribed.set()
    offline.connect("127.0.0.1", spec.port)
    offline.loop_start()
    assert subscribed.wait(10), "the persistent session's SUBACK"
    offline.disconnect()
    offline.loop_stop()

    publisher = _session(spec.port, "publisher")
    infos = [publisher.publish("t/x", str(i), qos=1) for i in range(500)]
    for info in infos:
        info.wait_for_publish(20)
    broker = manager._brokers["m1"]

    def sent() -> int:
        return broker.saves.sent if broker.saves is not None else 0

    def saved(count: int) -> None:
        process.wait_until(lambda: sent() >= before + count and _saves_logged(manager, "m1") >= logged + count,
                           20, 0.02, what=f"{count} saves after the last PUBACK")

    logged, before = _saves_logged(manager, "m1"), sent()
    saved(1)  # the agent asked for a save, and it began
    # Mosquitto saves in its one main loop: once a later save began, the first has finished. The
    # agent asks again only once the broker read something (a probe nobody subscribes to).
    publisher.publish("probe", "1", qos=1).wait_for_publish(10)
    saved(2)
    publisher.disconnect()
    publisher.loop_stop()
    pid = manager.get("m1").pid
    os.kill(pid, signal.SIGKILL)
    wait_status(manager, "m1", lambda b: b.status is BrokerStatus.RUNNING and b.pid != pid, "restart", 20)

    got: list[str] = []
    back = paho.Client(CallbackAPIVersion.VERSION2, client_id="offline", clean_session=False)
    back.on_message = lambda _c, _u, m: got.append(m.payload.decode())
    back.connect("127.0.0.1", spec.port)
    back.loop_start()
    try:
        process.wait_until(lambda: len(set(got)) >= 500, 20, 0.05, what="500 queued messages")
    finally:
        back.disconnect()
        back.loop_stop()
    assert set(got) == {str(i) for i in range(500)}


def test_the_save_signal_is_mosquittos_unless_the_plant_chose_a_policy() -> None:
    driver = REGISTRY.get("mosquitto")
    save = driver.save_signal(mqtt())
    assert save is not None and save.signal is signal.SIGUSR1 and 0 < save.every < 1
    assert driver.save_signal(replace(mqtt(), persist_every=100)) is None
    assert not isinstance(REGISTRY.get("kafka"), PeriodicSave)


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


def test_closing_stops_every_broker_though_the_stop_of_one_fails(managers: Managers) -> None:
    """Broker b's stop fails (its pid.json cannot be removed: a directory stands there); a and c,
    before and after it by id, are stopped all the same, and b's error is raised."""
    manager = managers.open()
    observed = {name: manager.put(mqtt(name)) for name in ("a", "b", "c")}
    blocker = manager.brokers_dir / "b" / "pid.json"
    blocker.unlink()
    (blocker / "kept").mkdir(parents=True)
    with pytest.raises(IsADirectoryError) as failed:
        manager.close(stop_brokers=True)
    assert str(blocker) in str(failed.value)
    for name in ("a", "c"):
        assert not netutil.port_open("127.0.0.1", observed[name].spec.port)
        assert manager.get(name).status is BrokerStatus.STOPPED
        assert not (manager.brokers_dir / name / "pid.json").exists()
    assert proc_info(observed["b"].pid) is None  # its process went; only its record stayed
    (blocker / "kept").rmdir()
    blocker.rmdir()


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

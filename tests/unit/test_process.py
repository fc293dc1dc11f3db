"""engine.process with harmless real processes (sh, sleep): spawn, wait, stop, nothing left."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from engine import netutil, process
from engine.errors import ProcessError, WaitTimeoutError


def test_spawn_logs_and_stop_kills_the_whole_group(tmp_path: Path) -> None:
    # The shell forks a grandchild; stopping must end both (same process group).
    child = process.spawn(["sh", "-c", "echo started; sleep 60 & wait"], log_dir=tmp_path, name="t")
    process.wait_until(lambda: "started" in child.log_tail(), 5.0, 0.01, what="output")
    assert child.running() and child.group_alive()
    assert process.stop(child, grace=5.0) != 0
    assert not child.group_alive()
    assert (tmp_path / "t.log").read_text() == "started\n"


def test_stop_escalates_to_sigkill(tmp_path: Path) -> None:
    child = process.spawn(["sh", "-c", "trap '' TERM; echo ready; while :; do sleep 0.05; done"],
                          log_dir=tmp_path, name="stubborn")
    process.wait_until(lambda: "ready" in child.log_tail(), 5.0, 0.01)
    start = time.monotonic()
    assert process.stop(child, grace=0.3) == -9
    assert time.monotonic() - start < 5
    assert not child.group_alive()


def test_wait_until_timeout_names_what_it_waited_for() -> None:
    with pytest.raises(WaitTimeoutError, match="timed out after 0.1 s waiting for the moon"):
        process.wait_until(lambda: False, 0.1, 0.01, what="the moon")


def test_wait_until_quotes_last_ignored_error() -> None:
    def boom():
        raise ConnectionError("refused")

    with pytest.raises(WaitTimeoutError, match="refused"):
        process.wait_until(boom, 0.05, 0.01, ignore=(ConnectionError,))


def test_wait_until_returns_value() -> None:
    assert process.wait_until(lambda: 42, 1.0) == 42


def test_wait_until_fails_fast_when_child_exits(tmp_path: Path) -> None:
    child = process.spawn(["sh", "-c", "echo bad config; exit 3"], log_dir=tmp_path, name="dies")
    start = time.monotonic()
    with pytest.raises(ProcessError, match="exited with code 3") as err:
        process.wait_until(lambda: False, 30.0, 0.01, what="never", child=child)
    assert time.monotonic() - start < 10
    assert "bad config" in str(err.value)
    process.stop(child)


def test_spawn_missing_binary(tmp_path: Path) -> None:
    with pytest.raises(ProcessError, match="cannot start"):
        process.spawn([str(tmp_path / "nope")], log_dir=tmp_path, name="nope")


def test_free_ports_are_distinct_and_free() -> None:
    ports = netutil.free_ports(3)
    assert len(set(ports)) == 3
    assert not any(netutil.port_open("127.0.0.1", p) for p in ports)


def test_touch_all_connects_to_every_listener_at_once_and_closes_unused() -> None:
    """Each listener gets one connection, closed without a byte; a port nobody listens on and an
    IPv6 one are no error; it counts the connections made."""
    listeners = [socket.create_server(("127.0.0.1", 0)) for _ in range(5)]
    try:
        closed = netutil.free_port()
        addresses = [("127.0.0.1", l.getsockname()[1]) for l in listeners] + [("127.0.0.1", closed)]
        assert netutil.touch_all(addresses, timeout=5.0) == 5
        for listener in listeners:
            listener.settimeout(5)
            conn, _ = listener.accept()
            conn.settimeout(5)
            assert conn.recv(1) == b""  # closed unused
            conn.close()
        assert netutil.touch_all([], timeout=0.01) == 0
    finally:
        for listener in listeners:
            listener.close()


def test_touch_all_gives_up_at_its_timeout() -> None:
    """A listener whose backlog is full does not answer the handshake: touch_all returns at its
    timeout with what connected (no hang, no error)."""
    with socket.socket() as full:
        full.bind(("127.0.0.1", 0))
        full.listen(0)
        port = full.getsockname()[1]
        start = time.monotonic()
        made = netutil.touch_all([("127.0.0.1", port)] * 8, timeout=0.2)
        assert time.monotonic() - start < 5
        assert 1 <= made < 8


def test_stop_all_signals_every_child_before_waiting_for_any(tmp_path: Path) -> None:
    """Each child exits on SIGTERM only once all of them got it: stopping one after another would
    wait for the first until its grace ran out and SIGKILL it (-9)."""
    shared = tmp_path / "got"
    shared.touch()
    script = (f"trap 'echo got >> {shared}; while [ $(wc -l < {shared}) -lt 4 ]; do sleep 0.01; done; "
              "exit 0' TERM; echo ready; while :; do sleep 0.05; done")
    children = [process.spawn(["sh", "-c", script], log_dir=tmp_path, name=f"c{i}") for i in range(4)]
    for child in children:
        process.wait_until(lambda c=child: "ready" in c.log_tail(), 5.0, 0.01)
    assert process.stop_all(children, grace=20.0) == [0, 0, 0, 0]
    assert not any(c.group_alive() for c in children)


def test_wait_exit_wakes_when_the_process_exits(tmp_path: Path) -> None:
    child = process.spawn(["sleep", "60"], log_dir=tmp_path, name="sleeper")
    assert process.wait_exit(child.popen, 0.05) is False
    assert process.wait_exit(child.pid, 0.05) is False  # any pid, not only a Popen
    child.popen.terminate()
    assert process.wait_exit(child.popen, 10.0) is True
    assert child.popen.wait() != 0 and process.wait_exit(child.popen, 0.0) is True


def test_wait_until_asks_a_callable_interval_before_each_pause() -> None:
    asked: list[int] = []
    calls = iter([False, False, True])

    def interval() -> float:
        asked.append(1)
        return 0.001

    assert process.wait_until(lambda: next(calls), 5.0, interval) is True
    assert len(asked) == 2


def test_stop_each_waits_for_each_child_its_own_grace(tmp_path: Path) -> None:
    """One child ignores SIGTERM (SIGKILL after its short grace: -9), the others exit on it; the
    long grace of the others does not hold up the stubborn one, and each answers its own code."""
    stubborn = "trap '' TERM; echo ready; while :; do sleep 0.05; done"
    polite = "trap 'exit 7' TERM; echo ready; while :; do sleep 0.05; done"
    children = [process.spawn(["sh", "-c", script], log_dir=tmp_path, name=f"c{i}")
                for i, script in enumerate((polite, stubborn, polite))]
    for child in children:
        process.wait_until(lambda c=child: "ready" in c.log_tail(), 5.0, 0.01)
    start = time.monotonic()
    assert process.stop_each(children, [20.0, 0.3, 20.0]) == [7, -9, 7]
    assert time.monotonic() - start < 10
    assert not any(c.group_alive() for c in children)


@pytest.mark.parametrize(("wake", "codes"), [(True, [0, 0]), (False, [-9, -9])], ids=["woken", "not woken"])
def test_stop_each_runs_after_signal_between_the_signals_and_the_wait(tmp_path: Path, wake: bool,
                                                                      codes: list[int]) -> None:
    """Children that act on SIGTERM only once something wakes them (as an idle Mosquitto, whose
    driver connects to it): ``after_signal`` runs once, after every child was signalled and before
    the wait, so they exit 0; without it they are SIGKILLed when their grace runs out."""
    woken = tmp_path / "woken"
    script = (f"trap 'while [ ! -e {woken} ]; do sleep 0.01; done; exit 0' TERM; "
              "echo ready; while :; do sleep 0.05; done")
    children = [process.spawn(["sh", "-c", script], log_dir=tmp_path, name=f"w{i}") for i in range(2)]
    for child in children:
        process.wait_until(lambda c=child: "ready" in c.log_tail(), 5.0, 0.01)
    calls: list[int] = []

    def after_signal() -> None:
        calls.append(1)
        woken.touch()

    assert process.stop_each(children, [1.0, 1.0], after_signal if wake else None) == codes
    assert calls == ([1] if wake else [])
    assert not any(c.group_alive() for c in children)

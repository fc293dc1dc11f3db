"""``plantkg apply`` of a plant that ``plantkg serve`` serves runs in that server, warm, and prints
what it would print alone (engine.control): real agent, real Mosquitto, both commands as processes.

One deployment for the file; the tests run in order:

1. ``apply --yes`` says it runs in the server (its pid), applies, and the broker acknowledges a
   QoS-1 publish; the dashboard's status shows it running within seconds (the server observes once
   more after the command: its own observe interval is an hour here);
2. a second ``apply`` has nothing to do;
3. an edit that breaks the plant: the server's answer is the violations and exit 1, nothing runs;
4. a change without ``--yes`` and without a terminal is refused (exit 2), nothing changes;
5. ``--local`` runs it in the command's own process;
6. ``destroy --yes`` runs in the server too: the broker is gone; ``apply`` brings it back;
7. after ``kill -9`` of the server (its socket file left behind), ``apply`` runs alone and works.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import urllib.request
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil
from engine.control.address import socket_path
from engine.process import wait_until
from tests.integration.agents import AgentFleet, start_agents

HOST = "127.0.0.2"
PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://w3id.org/plantkg/examples/served#> .
<https://w3id.org/plantkg/examples/served> a <http://www.w3.org/2002/07/owl#Ontology> .
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "served" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {port} ; pk:allowAnonymous true ; pk:hasTopic :t {more_topics}.
:t a pk:Topic ; pk:id "t" ; pk:name "served.t" ; pk:qos 1 .
:u a pk:Topic ; pk:id "u" ; pk:name "served.u" ; pk:qos 1 .
:r a pk:Resource ; pk:id "r" ; pk:name "publisher" ; pk:sendsTo :mqtt ; pk:publishes :t .
"""
PLANTKG = str(Path(sys.executable).parent / "plantkg")


@dataclass
class Served:
    fleet: AgentFleet
    plant: Path
    port: int
    env: dict[str, str]
    server: subprocess.Popen[str]
    url: str
    log: Path

    def write(self, *, port: int | None = None, more_topics: str = "") -> None:
        self.plant.write_text(PLANT.format(host=HOST, port=port or self.port, more_topics=more_topics))

    def run(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([PLANTKG, *args, "--agents", str(self.fleet.agents_file), str(self.plant)],
                              env=self.env, capture_output=True, text=True, timeout=180, check=False,
                              stdin=subprocess.DEVNULL)

    def socket(self) -> Path:
        """The server's control socket (in the folder the commands' environment names)."""
        return Path(self.env["PLANTKG_RUN_DIR"]) / socket_path([str(self.plant)], self.fleet.agents_file, None).name

    def broker(self) -> dict:  # type: ignore[type-arg]
        """The broker's row of the dashboard's status document."""
        with urllib.request.urlopen(f"{self.url}/api/status", timeout=10) as answer:
            return {b["id"]: b for b in json.load(answer)["brokers"]}["mqtt"]


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    tmp = tmp_path_factory.mktemp("served")
    short = Path(tempfile.mkdtemp(prefix="pks-", dir="/tmp"))  # a socket path stays under ~100 bytes
    fleet = start_agents([HOST], tmp)
    env = {**os.environ, "PLANTKG_RUN_DIR": str(short / "run"), "XDG_STATE_HOME": str(tmp / "state"),
           "PLANTKG_CACHE_DIR": str(tmp / "cache")}
    env.pop("PLANTKG_AGENTS", None)
    plant = tmp / "plant.ttl"
    web_port = netutil.free_port()
    log = tmp / "serve.log"
    made = Served(fleet, plant, netutil.free_port(HOST), env, None, f"http://127.0.0.1:{web_port}", log)  # type: ignore[arg-type]
    made.write()
    with log.open("w") as out:
        made.server = subprocess.Popen(
            [PLANTKG, "serve", str(plant), "--agents", str(fleet.agents_file), "--listen", f"127.0.0.1:{web_port}",
             "--observe-interval", "3600"], env=env, stdout=out, stderr=subprocess.STDOUT, text=True)
    try:
        wait_until(lambda: made.socket().exists() and "runs here, warm" in log.read_text(), 60,
                   what="serve's control socket")
        yield made
    finally:
        if made.server.poll() is None:
            made.server.send_signal(signal.SIGTERM)
            made.server.wait(30)
        made.write()
        done = made.run("destroy", "--yes")
        fleet.stop()
        shutil.rmtree(short, ignore_errors=True)
        assert done.returncode == 0, done.stdout + done.stderr


def acked(port: int) -> bool:
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-served-{uuid.uuid4().hex[:8]}")
    client.connect(HOST, port)
    client.loop_start()
    try:
        info = client.publish("served.t", b"hello", qos=1)
        info.wait_for_publish(timeout=10)
        return info.is_published()
    finally:
        client.loop_stop()
        client.disconnect()


def test_apply_runs_in_the_server_and_the_broker_serves(served: Served) -> None:
    done = served.run("apply", "--yes")
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"runs in plantkg serve (pid {served.server.pid})" in done.stderr
    assert "Plan: 2 to create" in done.stdout and "Apply complete: 2 changed, 0 failed" in done.stdout
    assert acked(served.port)
    wait_until(lambda: served.broker()["status"] == "running", 30, what="the dashboard showing the broker")


def test_a_second_apply_has_nothing_to_do(served: Served) -> None:
    done = served.run("apply", "--yes")
    assert done.returncode == 0 and "No changes." in done.stdout and "runs in plantkg serve" in done.stderr


def test_a_broken_plant_is_refused_by_the_server_with_its_violations(served: Served) -> None:
    served.write(port=70000)
    try:
        done = served.run("apply", "--yes")
        assert done.returncode == 1, done.stdout + done.stderr
        assert "runs in plantkg serve" in done.stderr and "70000" in done.stdout
        assert "nothing was planned, started or stopped" in done.stderr
    finally:
        served.write()
    assert acked(served.port)  # the running broker was not touched


def test_without_yes_and_without_a_terminal_nothing_changes(served: Served) -> None:
    served.write(more_topics="; pk:hasTopic :u ")
    try:
        done = served.run("apply")
        assert done.returncode == 2, done.stdout + done.stderr
        assert "refusing to apply without confirmation" in done.stderr and "runs in plantkg serve" in done.stderr
        assert "topic.mqtt.served.u will be created" in done.stdout
        plan = served.run("plan", "--detailed-exitcode")
        assert plan.returncode == 2 and "served.u" in plan.stdout  # still to do: nothing was applied
    finally:
        served.write()


def test_local_runs_in_the_commands_own_process(served: Served) -> None:
    served.write(more_topics="; pk:hasTopic :u ")
    done = served.run("apply", "--yes", "--local")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "runs in plantkg serve" not in done.stderr and "topic.mqtt.served.u: Created" in done.stdout


def test_destroy_runs_in_the_server_too(served: Served) -> None:
    done = served.run("destroy", "--yes")
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"runs in plantkg serve (pid {served.server.pid})" in done.stderr and "Destroy complete" in done.stdout
    assert "mqtt" not in served.fleet.brokers()
    wait_until(lambda: served.broker()["status"] == "absent", 30, what="the dashboard showing no broker")
    again = served.run("apply", "--yes")
    assert again.returncode == 0 and acked(served.port), again.stdout + again.stderr


def test_after_the_server_is_killed_apply_runs_alone(served: Served) -> None:
    served.server.send_signal(signal.SIGKILL)
    served.server.wait(30)
    assert served.socket().exists()  # left behind
    served.write()  # topic u goes again
    done = served.run("apply", "--yes")
    assert done.returncode == 0, done.stdout + done.stderr
    assert "runs in plantkg serve" not in done.stderr and "topic.mqtt.served.u" in done.stdout

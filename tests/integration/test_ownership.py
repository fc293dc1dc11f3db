"""Two plants on the same agents never touch each other; --prune; import (issue 15).

Agents on 127.0.0.2 and 127.0.0.3 (real ``plantkg agent`` processes, real Mosquitto). Plant A has
a bridged pair of brokers (a-src on .2 bridged to a-dst on .3), plant B one broker on .2; a third
broker is made by hand through the agent API (owned by nobody). The tests run in file order on
one deployment: both plants apply and record their owners → each plan lists the other's things
as foreign and changes nothing → the agents refuse a request that names the wrong owner → --prune
removes only what nobody owns → import takes over a hand-made broker without restarting it →
destroying A leaves B running (same pid), destroying B leaves nothing. A last test kills an agent
with -9 and checks the owners survive its restart and the re-adoption of its broker.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from engine import netutil
from engine.cli import main
from engine.errors import PermanentDispatchError
from engine.model import BrokerSpec, TopicSpec
from tests.integration.agents import AgentFleet, start_agents
from tests.integration.test_agent import Agents, agents, mqtt_spec  # noqa: F401 - fixture

pytestmark = pytest.mark.integration

H2, H3 = "127.0.0.2", "127.0.0.3"
PLANT_A = "http://example.org/plant-a"
PLANT_B = "http://example.org/plant-b"

HEADER = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
@prefix : <{iri}#> .
<{iri}> a owl:Ontology .
"""
A_BODY = """\
:src a pk:Broker ; pk:id "a-src" ; pk:name "A cell" ; pk:brokerType "mosquitto" ;
    pk:ip "{h2}" ; pk:port {src} ; pk:hasTopic :pose ; pk:bridgesTo :dst .
:dst a pk:Broker ; pk:id "a-dst" ; pk:name "A line" ; pk:brokerType "mosquitto" ;
    pk:ip "{h3}" ; pk:port {dst} ; pk:hasTopic :pose .
:pose a pk:Topic ; pk:id "pose" ; pk:name "a/robot/pose" ; pk:qos 1 .
"""
LEGACY = """\
:legacy a pk:Broker ; pk:id "legacy" ; pk:name "legacy" ; pk:brokerType "mosquitto" ;
    pk:ip "{h3}" ; pk:port {legacy} ; pk:hasTopic :alarm .
:alarm a pk:Topic ; pk:id "alarm" ; pk:name "a/alarm" ; pk:qos 0 .
"""
B_BODY = """\
:mq a pk:Broker ; pk:id "b-mq" ; pk:name "B broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{h2}" ; pk:port {mq} ; pk:hasTopic :state .
:state a pk:Topic ; pk:id "state" ; pk:name "b/state" ; pk:qos 1 .
"""


@dataclass
class Plants:
    fleet: AgentFleet
    a: Path
    b: Path
    ports: dict[str, int]

    def run(self, capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
        code = main([str(a) for a in args])
        out, err = capsys.readouterr()
        return code, out + err

    def owners(self) -> dict[str, str | None]:
        """Owner of every broker, topic and bridge the agents report, by plan address."""
        found: dict[str, str | None] = {}
        for host in (H2, H3):
            client = self.fleet.client(host)
            for b in client.list_brokers():
                found[b.spec.address] = b.owner
                for t in b.topics:
                    found[f"topic.{b.spec.id}.{t.name}"] = t.owner
            for bridge in client.list_bridges():
                found[bridge.spec.address] = bridge.owner
        return found

    def pids(self) -> dict[str, int | None]:
        return {i: b.pid for i, b in self.fleet.brokers().items()}  # type: ignore[attr-defined]


@pytest.fixture(scope="module")
def plants(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plants]:
    tmp = tmp_path_factory.mktemp("ownership")
    fleet = start_agents([H2, H3], tmp)
    try:
        ports = {"src": netutil.free_port(H2), "dst": netutil.free_port(H3),
                 "legacy": netutil.free_port(H3)}
        ports["mq"] = netutil.free_port(H2)
        while ports["mq"] == ports["src"]:
            ports["mq"] = netutil.free_port(H2)
        ports["manual"] = netutil.free_port(H2)
        while ports["manual"] in (ports["src"], ports["mq"]):
            ports["manual"] = netutil.free_port(H2)
        a, b = tmp / "plant-a.ttl", tmp / "plant-b.ttl"
        a.write_text(HEADER.format(iri=PLANT_A) + A_BODY.format(h2=H2, h3=H3, **ports))
        b.write_text(HEADER.format(iri=PLANT_B) + B_BODY.format(h2=H2, **ports))
        yield Plants(fleet, a, b, ports)
    finally:
        fleet.stop()


def test_both_plants_apply_and_record_their_owner(plants: Plants, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = plants.run(capsys, "apply", plants.a, "--agents", plants.fleet.agents_file, "--yes")
    assert code == 0, out
    code, out = plants.run(capsys, "apply", plants.b, "--agents", plants.fleet.agents_file, "--yes")
    assert code == 0, out
    assert "broker.a-src" not in out.split("Foreign")[0], "B's apply must not change A's brokers"
    assert plants.owners() == {
        "broker.a-src": PLANT_A, "broker.a-dst": PLANT_A, "bridge.a-src.a-dst": PLANT_A,
        "topic.a-src.a/robot/pose": PLANT_A, "topic.a-dst.a/robot/pose": PLANT_A,
        "broker.b-mq": PLANT_B, "topic.b-mq.b/state": PLANT_B,
    }


def test_each_plan_shows_the_other_plant_as_foreign(plants: Plants, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = plants.run(capsys, "plan", plants.a, "--agents", plants.fleet.agents_file,
                           "--detailed-exitcode")
    assert code == 0, out
    assert f"broker.b-mq: owned by {PLANT_B}" in out
    code, out = plants.run(capsys, "plan", plants.b, "--agents", plants.fleet.agents_file,
                           "--format", "json")
    assert code == 0, out
    data = json.loads(out)
    assert data["empty"] and not [c for c in data["changes"] if c["action"] == "delete"]
    assert {"address": "broker.a-src", "owner": PLANT_A,
            "reason": f"owned by plant {PLANT_A}: left alone"} in data["foreign"]


def test_the_agent_refuses_requests_naming_another_owner(plants: Plants) -> None:
    client = plants.fleet.client(H2)
    with pytest.raises(PermanentDispatchError, match="409.*owned by plant"):
        client.delete_broker("b-mq", owner=PLANT_A)
    with pytest.raises(PermanentDispatchError, match="409.*owned by plant"):
        client.delete_topic("b-mq", "b/state", owner=PLANT_A)
    spec = client.get_broker("b-mq").spec  # type: ignore[union-attr]
    with pytest.raises(PermanentDispatchError, match="409.*owned by plant"):
        client.put_broker(spec, owner=PLANT_A)
    with pytest.raises(PermanentDispatchError, match="409.*owned by plant"):
        client.set_owner("b-mq", PLANT_A)
    assert plants.owners()["broker.b-mq"] == PLANT_B


def test_prune_removes_only_what_nobody_owns(plants: Plants, capsys: pytest.CaptureFixture[str]) -> None:
    client = plants.fleet.client(H2)
    manual = BrokerSpec("manual", "urn:test:manual", "made by hand", "mosquitto", H2,
                        plants.ports["manual"])
    client.put_broker(manual)  # no owner: as before ownership existed
    client.put_topic(TopicSpec("manual", "hand/made", "urn:test:hand", qos=0))
    before = plants.pids()
    code, out = plants.run(capsys, "apply", plants.a, "--agents", plants.fleet.agents_file, "--yes")
    assert code == 0, out
    assert "broker.manual: owned by nobody" in out and "b-mq" in out
    assert plants.pids() == before, "without --prune nothing foreign is touched"

    code, out = plants.run(capsys, "plan", plants.a, "--agents", plants.fleet.agents_file, "--prune")
    assert code == 0, out
    assert "- broker.manual" in out and "- topic.manual.hand/made" in out
    assert "- broker.b-mq" not in out
    code, out = plants.run(capsys, "apply", plants.a, "--agents", plants.fleet.agents_file,
                           "--prune", "--yes")
    assert code == 0, out
    after = plants.pids()
    assert "manual" not in after
    assert after["b-mq"] == before["b-mq"] and after["a-src"] == before["a-src"]


def test_import_takes_over_a_broker_nobody_owns(plants: Plants, capsys: pytest.CaptureFixture[str]) -> None:
    client = plants.fleet.client(H3)
    legacy = BrokerSpec("legacy", f"{PLANT_A}#legacy", "legacy", "mosquitto", H3,
                        plants.ports["legacy"])
    made = client.put_broker(legacy)
    client.put_topic(TopicSpec("legacy", "a/alarm", f"{PLANT_A}#alarm", qos=0))
    plants.a.write_text(plants.a.read_text() + LEGACY.format(h3=H3, **plants.ports))

    code, out = plants.run(capsys, "plan", plants.a, "--agents", plants.fleet.agents_file)
    assert code == 2, out
    assert "nobody owns it" in out and "plantkg import broker.legacy" in out
    code, out = plants.run(capsys, "import", "broker.b-mq", plants.a, "--agents",
                           plants.fleet.agents_file)
    assert code == 2 and "does not declare broker.b-mq" in out, out
    code, out = plants.run(capsys, "import", "broker.legacy", plants.a, "--agents",
                           plants.fleet.agents_file)
    assert code == 0, out
    owners = plants.owners()
    assert owners["broker.legacy"] == PLANT_A and owners["topic.legacy.a/alarm"] == PLANT_A
    assert client.get_broker("legacy").pid == made.pid  # type: ignore[union-attr]  # not restarted
    code, out = plants.run(capsys, "apply", plants.a, "--agents", plants.fleet.agents_file, "--yes")
    assert code == 0, out


def test_destroying_one_plant_leaves_the_other_running(plants: Plants, capsys: pytest.CaptureFixture[str]) -> None:
    before = plants.pids()
    code, out = plants.run(capsys, "destroy", plants.a, "--agents", plants.fleet.agents_file, "--yes")
    assert code == 0, out
    after = plants.pids()
    assert set(after) == {"b-mq"} and after["b-mq"] == before["b-mq"]
    assert plants.owners() == {"broker.b-mq": PLANT_B, "topic.b-mq.b/state": PLANT_B}
    code, out = plants.run(capsys, "destroy", plants.b, "--agents", plants.fleet.agents_file, "--yes")
    assert code == 0, out
    assert plants.pids() == {}


def test_owners_survive_an_agent_restart(agents: Agents, tmp_path: Path) -> None:  # noqa: F811
    state = tmp_path / "state"
    agent = agents.start(state)
    spec = mqtt_spec()
    first = agent.client().put_broker(spec, owner=PLANT_A)
    agent.client().put_topic(TopicSpec(spec.id, "x/y", "urn:t", qos=1), owner=PLANT_A)
    agent.kill9()
    again = agents.start(state, port=agent.port)
    adopted = again.client().get_broker(spec.id)
    assert adopted is not None and adopted.pid == first.pid
    assert adopted.owner == PLANT_A and [t.owner for t in adopted.topics] == [PLANT_A]
    with pytest.raises(PermanentDispatchError, match="409"):
        again.client().delete_broker(spec.id, owner=PLANT_B)
    again.client().delete_broker(spec.id, owner=PLANT_A)
    assert again.client().list_brokers() == []
    assert again.terminate() == 0

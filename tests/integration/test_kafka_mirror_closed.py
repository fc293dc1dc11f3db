"""A MirrorMaker 2 between two Kafka brokers closed by default (issue 13), from a plant file, on
real agents and real JVMs.

The plant: a Kafka ``src`` on 127.0.0.2 and a Kafka ``dst`` on 127.0.0.3, neither saying anything
about anonymous clients (closed by default); both carry ``plant.kpi``. The PLC publishes it on
``src``, the MES reads it on ``dst``; both have a ``pk:secretRef`` to a throwaway password file
(SCRAM users). Rule R1 bridges the two: a MirrorMaker 2 on ``dst``'s agent, which logs in to each
end as plantkg's own Kafka principal (SASL/PLAIN). One deployment is shared by the module (two
brokers and a MirrorMaker take a minute to come up on two cores); the tests run in file order:

1. ``apply`` deploys it; the mirror's spec says both ends are closed; ``plan`` has no change;
2. an anonymous confluent-kafka client is refused by both brokers, as a producer and for metadata;
3. what the PLC produces on ``src`` (as its SCRAM user) arrives on ``dst``, read by the MES, none
   missing; the mirror reports lag 0;
4. plantkg's password is in no plan or apply output, no log, and in no file the agents wrote but
   the mirror's login file and its agent's password file, both 0600: not in ``mm2.properties``
   and not in the target's log segments of MirrorMaker 2's config topic (which stores a reference
   to the login file, resolved by Kafka's FileConfigProvider);
5. ``src`` says ``pk:tls true``: ``plan`` replaces it and updates the mirror (its source end
   changed), ``apply`` restarts both; the mirror now speaks SASL_SSL to ``src`` (trusting the plant
   CA) and SASL_PLAINTEXT to ``dst``, and what the PLC produces over TLS arrives on ``dst``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine import process
from engine.cli import main
from engine.model import BridgeStatus
from engine.security import ca, kafka_client
from tests.integration.agents import AgentFleet, deployment
from tests.integration.kafka_clients import password_files, read_topic
from tests.integration.plant_cli import files_holding
from tests.integration.test_kafka_auth import _as, _produce

pytestmark = pytest.mark.integration

SRC, DST = "127.0.0.2", "127.0.0.3"
MIRRORED = 2_000
MORE = 500


@dataclass
class Mirror:
    fleet: AgentFleet
    plant: Path
    ports: dict[str, int]
    passwords: dict[str, str]
    files: dict[str, Path]
    outputs: list[str]

    def address(self, broker: str) -> str:
        return f"{SRC if broker == 'src' else DST}:{self.ports[broker]}"

    def run(self, capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str]:
        """``plantkg <args[0]> <plant> --agents ... <args[1:]>``: its exit code and output (kept)."""
        code = main([args[0], str(self.plant), "--agents", str(self.fleet.agents_file), *args[1:]])
        out = capsys.readouterr()
        self.outputs.append(out.out + out.err)
        return code, out.out + out.err


def _plant(ports: dict[str, int], files: dict[str, Path], src_extra: str = "") -> str:
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-mirror-closed#> .
ex:src a pk:Broker ; pk:id "src" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:ip "{SRC}" ;
    pk:port {ports['src']} ; {src_extra} pk:hasTopic ex:kpi .
ex:dst a pk:Broker ; pk:id "dst" ; pk:name "site-kafka" ; pk:brokerType "kafka" ; pk:ip "{DST}" ;
    pk:port {ports['dst']} ; pk:hasTopic ex:kpi .
ex:kpi a pk:Topic ; pk:id "kpi" ; pk:name "plant.kpi" ; pk:partitions 2 .
ex:plc a pk:Resource ; pk:id "plc" ; pk:name "PLC" ; pk:sendsTo ex:src ; pk:publishes ex:kpi ;
    pk:secretRef "file:{files['plc']}" .
ex:mes a pk:Resource ; pk:id "mes" ; pk:name "MES" ; pk:sendsTo ex:dst ; pk:subscribes ex:kpi ;
    pk:secretRef "file:{files['mes']}" .
"""


@pytest.fixture(scope="module")
def mirror(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Mirror]:
    tmp = tmp_path_factory.mktemp("kafka-mirror-closed")
    passwords, files = password_files(tmp, ("plc", "mes"))
    with deployment(tmp, {"src": SRC, "dst": DST}, lambda ports: _plant(ports, files), apply=False) as made:
        yield Mirror(made.fleet, made.plant, made.ports, passwords, files, [])


def test_apply_deploys_a_mirror_between_two_closed_kafkas(mirror: Mirror, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = mirror.run(capsys, "apply", "--yes")
    assert code == 0, out
    assert "admits anonymous clients" not in out, out
    [bridge] = mirror.fleet.client(DST).list_bridges()
    assert bridge.spec.mechanism.value == "kafka-mirror"
    assert (bridge.spec.local.id, bridge.spec.remote.id) == ("dst", "src")
    assert bridge.spec.local.closed and bridge.spec.remote.closed
    code, out = mirror.run(capsys, "plan", "--detailed-exitcode")
    assert code == 0 and "No changes." in out, out


def test_an_anonymous_client_is_refused_by_both_ends(mirror: Mirror) -> None:
    for broker in ("src", "dst"):
        with pytest.raises(KafkaException):
            AdminClient({"bootstrap.servers": mirror.address(broker), "log_level": 0}).list_topics(timeout=5)
        assert _produce(mirror.address(broker), "plant.kpi", {}) != [], broker


def test_what_the_plc_produces_on_the_source_arrives_on_the_target(mirror: Mirror) -> None:
    plc, mes = _as("plc", mirror.passwords["plc"]), _as("mes", mirror.passwords["mes"])
    assert _produce(mirror.address("src"), "plant.kpi", plc, MIRRORED) == []
    got, errors = read_topic(mirror.address("dst"), "plant.kpi", mes, MIRRORED, deadline=240)
    assert (got, errors) == (MIRRORED, set())
    assert _produce(mirror.address("dst"), "plant.kpi", mes) == ["TOPIC_AUTHORIZATION_FAILED"]  # the MES reads only
    _wait_caught_up(mirror, MIRRORED)


def _wait_caught_up(mirror: Mirror, records: int) -> None:
    """Until the mirror reports lag 0 and at least ``records`` copied (60 s at most)."""
    def caught_up() -> object:
        [bridge] = mirror.fleet.client(DST).list_bridges()
        done = bridge.status is BridgeStatus.RUNNING and bridge.lag == 0 and (bridge.forwarded or 0) >= records
        return bridge if done else None

    process.wait_until(caught_up, 60, 0.5, what="the mirror to report every record copied, lag 0")


def test_plantkgs_password_is_only_in_files_others_cannot_read(mirror: Mirror) -> None:
    secret = kafka_client.password()
    assert mirror.outputs and not any(secret in out for out in mirror.outputs)
    holders, checked = files_holding((agent.state_dir for agent in mirror.fleet.agents.values()), secret)
    folder = mirror.fleet.agents[DST].state_dir / "bridges" / "dst--src"
    # each broker's server.properties (its JAAS user), the login file and the agent's password
    # file only: not mm2.properties, and not the target's log segments of MirrorMaker 2's config
    # topic (it stores a reference to the login file)
    brokers = [mirror.fleet.agents[host].state_dir / "brokers" / name / "server.properties"
               for host, name in ((SRC, "src"), (DST, "dst"))]
    assert set(holders) == {*brokers, folder / "mm2-login.properties", folder / "remote.token"}, holders
    assert "${file:" in (folder / "mm2.properties").read_text(encoding="utf-8")
    assert checked > 10 and any((folder / "logs").iterdir())  # the logs were there to be read


def test_a_tls_source_is_mirrored_over_sasl_ssl(mirror: Mirror, capsys: pytest.CaptureFixture[str]) -> None:
    mirror.plant.write_text(_plant(mirror.ports, mirror.files, "pk:tls true ;"), encoding="utf-8")
    code, out = mirror.run(capsys, "plan", "--detailed-exitcode")
    assert code == 2 and "bridge.dst.src" in out and "remote changed" in out, out
    code, out = mirror.run(capsys, "apply", "--yes")
    assert code == 0, out
    folder = mirror.fleet.agents[DST].state_dir / "bridges" / "dst--src"
    lines = (folder / "mm2.properties").read_text(encoding="utf-8").splitlines()
    assert {"source.security.protocol=SASL_SSL", "target.security.protocol=SASL_PLAINTEXT"} <= set(lines), lines
    tls = {"security.protocol": "SASL_SSL", "ssl.ca.location": str(ca.ca_cert_file()),
           "ssl.endpoint.identification.algorithm": "https"}
    assert _produce(mirror.address("src"), "plant.kpi", _as("plc", mirror.passwords["plc"])) != []  # plain: refused
    assert _produce(mirror.address("src"), "plant.kpi", {**_as("plc", mirror.passwords["plc"]), **tls}, MORE) == []
    got, errors = read_topic(mirror.address("dst"), "plant.kpi", _as("mes", mirror.passwords["mes"]),
                             MIRRORED + MORE, deadline=240)
    assert (got, errors) == (MIRRORED + MORE, set())
    _wait_caught_up(mirror, MIRRORED + MORE)
    code, out = mirror.run(capsys, "plan", "--detailed-exitcode")
    assert code == 0 and "No changes." in out, out

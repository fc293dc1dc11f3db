"""A Kafka closed to anonymous clients: SASL/SCRAM users and ACLs derived from the graph (issue 13),
applied from a plant file on real agents.

The plant: a cell Mosquitto (open: pk:allowAnonymous true) on 127.0.0.2 and a Kafka on 127.0.0.3. robot1 publishes
``cell.pos`` on Kafka and the historian reads it, the camera publishes ``cell.cam`` on Mosquitto and
the historian reads that on Kafka too (rule R1: a bridge worker carries it, logging in to Kafka as
plantkg's own principal). robot1 and the historian have ``pk:secretRef``s to throwaway password
files, so the Kafka is closed: SASL_PLAINTEXT, KRaft's StandardAuthorizer, ACLs WRITE/READ as the
rules A1/A2 concluded. Checked with confluent-kafka and with Debian's kcat (an independent client;
its config file, 0600, holds the throwaway password):

- a client without credentials, or with a wrong password, gets nothing;
- robot1 writes cell.pos and may not write cell.cam or read cell.pos;
- the historian reads cell.pos and cell.cam and may not write;
- 1,000 messages published on Mosquitto reach the historian through the bridge, none missing;
- no user password is in a file of the agents' state dirs, and the rendered files are 0600.
"""

from __future__ import annotations

import stat
import subprocess
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from confluent_kafka import KafkaException, Producer
from confluent_kafka.admin import AdminClient

from engine import netutil
from engine.cli import main
from tests.integration.agents import AgentFleet, start_agents
from tests.integration.kafka_clients import password_files, publish_numbered, read_topic

pytestmark = pytest.mark.integration

MQ, KF = "127.0.0.2", "127.0.0.3"
BRIDGED = 1000


@dataclass
class Closed:
    fleet: AgentFleet
    plant: Path
    kafka: str
    mqtt_port: int
    passwords: dict[str, str]


def _plant(tmp: Path, mq_port: int, kf_port: int, files: dict[str, Path]) -> str:
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-auth#> .
ex:mq a pk:Broker ; pk:id "mq" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "{MQ}" ;
    pk:port {mq_port} ; pk:allowAnonymous true ; pk:hasTopic ex:cam .
ex:kf a pk:Broker ; pk:id "kf" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:ip "{KF}" ;
    pk:port {kf_port} ; pk:hasTopic ex:pos , ex:cam .
ex:pos a pk:Topic ; pk:id "pos" ; pk:name "cell.pos" ; pk:partitions 1 .
ex:cam a pk:Topic ; pk:id "cam" ; pk:name "cell.cam" ; pk:qos 1 ; pk:partitions 1 .
ex:robot a pk:Resource ; pk:id "robot1" ; pk:name "Robot" ; pk:sendsTo ex:kf ; pk:publishes ex:pos ;
    pk:secretRef "file:{files['robot1']}" .
ex:hist a pk:Resource ; pk:id "hist" ; pk:name "Historian" ; pk:sendsTo ex:kf ;
    pk:subscribes ex:pos , ex:cam ; pk:secretRef "file:{files['hist']}" .
ex:camera a pk:Resource ; pk:id "camera" ; pk:name "Camera" ; pk:sendsTo ex:mq ; pk:publishes ex:cam .
"""


@pytest.fixture(scope="module")
def closed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Closed]:
    tmp = tmp_path_factory.mktemp("kafka-auth")
    passwords, files = password_files(tmp, ("robot1", "hist"))
    fleet = start_agents([MQ, KF], tmp)
    try:
        mq_port, kf_port = netutil.free_port(MQ), netutil.free_port(KF)
        plant = tmp / "plant.ttl"
        plant.write_text(_plant(tmp, mq_port, kf_port, files), encoding="utf-8")
        code = main(["apply", str(plant), "--agents", str(fleet.agents_file), "--yes"])
        assert code == 0
        yield Closed(fleet, plant, f"{KF}:{kf_port}", mq_port, passwords)
        assert main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
    finally:
        fleet.stop()


def _as(user: str | None, password: str | None = None) -> dict[str, str]:
    if user is None:
        return {}
    return {"security.protocol": "SASL_PLAINTEXT", "sasl.mechanism": "SCRAM-SHA-512",
            "sasl.username": user, "sasl.password": password or ""}


def _produce(bootstrap: str, topic: str, auth: dict[str, str], count: int = 1) -> list[str]:
    """Produce ``count`` records; the delivery errors (empty: all acknowledged)."""
    errors: list[str] = []
    producer = Producer({"bootstrap.servers": bootstrap, "acks": "all", "message.timeout.ms": 15000,
                         "log_level": 0, **auth})
    for n in range(count):
        producer.produce(topic, value=f"{n}".encode(),
                         on_delivery=lambda err, _m: errors.append(err.name()) if err else None)
    producer.flush(30)
    return errors


def test_the_plan_no_longer_warns_that_the_kafka_is_open(closed: Closed, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["plan", str(closed.plant), "--agents", str(closed.fleet.agents_file), "--detailed-exitcode"])
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out
    assert "broker.kf" not in out  # no "admits anonymous clients" warning for the Kafka
    code = main(["status", str(closed.plant), "--agents", str(closed.fleet.agents_file)])
    out = capsys.readouterr().out
    [row] = [line for line in out.splitlines() if line.startswith("kf ")]
    assert "users (2)" in row, out


def test_anonymous_and_wrong_passwords_get_nothing(closed: Closed) -> None:
    with pytest.raises(KafkaException):
        AdminClient({"bootstrap.servers": closed.kafka, "log_level": 0}).list_topics(timeout=5)
    assert _produce(closed.kafka, "cell.pos", {}) != []
    assert _produce(closed.kafka, "cell.pos", _as("robot1", "not-the-password")) != []
    got, _errors = read_topic(closed.kafka, "cell.pos", _as("hist", "not-the-password"), 1, deadline=8)
    assert got == 0


def test_each_user_does_exactly_what_the_graph_says(closed: Closed) -> None:
    robot, hist = _as("robot1", closed.passwords["robot1"]), _as("hist", closed.passwords["hist"])
    assert _produce(closed.kafka, "cell.pos", robot, 5) == []
    assert _produce(closed.kafka, "cell.cam", robot) == ["TOPIC_AUTHORIZATION_FAILED"]
    assert _produce(closed.kafka, "cell.pos", hist) == ["TOPIC_AUTHORIZATION_FAILED"]
    got, errors = read_topic(closed.kafka, "cell.pos", hist, 5)
    assert (got, errors) == (5, set())
    got, errors = read_topic(closed.kafka, "cell.pos", robot, 1, deadline=10)
    assert got == 0 and errors & {"TOPIC_AUTHORIZATION_FAILED", "GROUP_AUTHORIZATION_FAILED"}, errors


def test_kcat_sees_the_same_rights(closed: Closed, tmp_path: Path) -> None:
    def kcat(user: str | None, *args: str, stdin: str = "") -> subprocess.CompletedProcess[str]:
        conf = tmp_path / f"{user}.conf"
        lines = [] if user is None else ["security.protocol=SASL_PLAINTEXT", "sasl.mechanisms=SCRAM-SHA-512",
                                         f"sasl.username={user}", f"sasl.password={closed.passwords[user]}"]
        conf.write_text("\n".join(lines) + "\n", encoding="utf-8")
        conf.chmod(0o600)
        return subprocess.run(["kcat", "-F", str(conf), "-b", closed.kafka, "-m", "10", *args], input=stdin,
                              capture_output=True, text=True, timeout=60)

    marker = uuid.uuid4().hex
    done = kcat("robot1", "-P", "-t", "cell.pos", stdin=marker + "\n")
    assert done.returncode == 0, done.stderr
    done = kcat("hist", "-C", "-t", "cell.pos", "-o", "beginning", "-e")
    assert done.returncode == 0 and marker in done.stdout, done.stderr
    done = kcat("robot1", "-P", "-t", "cell.cam", stdin="nope\n")
    assert done.returncode != 0 or "authorization" in done.stderr.lower(), (done.stdout, done.stderr)
    done = kcat(None, "-L")
    assert done.returncode != 0, done.stdout


def test_the_bridge_worker_reaches_the_closed_kafka_as_plantkg(closed: Closed) -> None:
    publish_numbered(MQ, closed.mqtt_port, "cell.cam", BRIDGED)
    got, errors = read_topic(closed.kafka, "cell.cam", _as("hist", closed.passwords["hist"]), BRIDGED, deadline=90)
    assert (got, errors) == (BRIDGED, set())


def test_no_password_is_in_a_file_of_the_agents(closed: Closed) -> None:
    for agent in closed.fleet.agents.values():
        for path in agent.state_dir.rglob("*"):
            if not path.is_file() or path.stat().st_size > 50_000_000:
                continue
            data = path.read_bytes()
            for name, password in closed.passwords.items():
                assert password.encode() not in data, f"{name}'s password is in {path}"
    folder = closed.fleet.agents[KF].state_dir / "brokers" / "kf"
    for name in ("server.properties", "scram.digest"):
        assert stat.S_IMODE((folder / name).stat().st_mode) == 0o600, name

"""A context broker with ``pk:tls true`` (issue 13), end to end: ``plantkg apply`` of a plant file,
a real agent (127.0.0.3) running a closed Mosquitto and the context broker, whose API then speaks
HTTPS only with a plant-CA certificate for its address.

Checked: the key is 0600 and ``status`` says TLS; FiLiP (its ``requests`` session trusting the
plant CA's ``ca.pem``) creates and reads an entity over https; a plain http client and a client
trusting another CA get nothing; the MQTT -> NGSI bridge worker rule R1 derives carries an AGV's
message into the context broker over https (read back by the planner's principal through FiLiP);
``plantkg query --live`` reads the context over https; a second plan is empty. The plant and its
fixture: tests/integration/cb_tls.py.
"""

from __future__ import annotations

import json
import stat
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests
from click.testing import CliRunner
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import process
from engine.cli import cli, main
from engine.security import ca
from tests.integration.cb_tls import HOST, STATUS_ID, Plant, tls_plant

from filip.models.ngsi_v2.context import ContextAttribute, ContextEntity  # noqa: E402 - after cb_tls's importorskip

pytestmark = pytest.mark.integration

THING_ID = "urn:ngsi-ld:Thing:tls1"


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    with tls_plant(tmp_path_factory.mktemp("cb-tls")) as applied:
        yield applied


def test_status_says_tls_and_the_key_is_private(plant: Plant, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["status", str(plant.plant), "--agents", str(plant.fleet.agents_file)]) == 0
    out = capsys.readouterr().out
    assert "principals (1), TLS" in out, out
    key = plant.fleet.agents[HOST].state_dir / "brokers" / "cb" / "tls-key.pem"
    assert stat.S_IMODE(key.stat().st_mode) == 0o600


def test_filip_creates_and_reads_an_entity_over_https(plant: Plant) -> None:
    client = plant.filip(plant.fleet.agents[HOST].token)  # plantkg's own principal: every right
    client.post_entity(ContextEntity(id=THING_ID, type="Thing",
                                     seq=ContextAttribute(type="Number", value=7)), update=True)
    assert client.get_entity(entity_id=THING_ID).get_attribute("seq").value == 7


def test_a_plain_client_and_a_client_of_another_ca_get_nothing(plant: Plant, tmp_path: Path) -> None:
    token = {"Authorization": f"Bearer {plant.fleet.agents[HOST].token}"}
    with pytest.raises(requests.exceptions.ConnectionError):
        requests.get(f"http://{HOST}:{plant.ports['cb']}/version", timeout=10)
    other = ca.load_or_create_ca(tmp_path / "other-ca")
    with pytest.raises(requests.exceptions.SSLError):
        requests.get(f"{plant.url}/v2/entities", headers=token, timeout=10, verify=str(other.cert_file))
    with pytest.raises(requests.exceptions.SSLError):  # nor the system's store
        requests.get(f"{plant.url}/v2/entities", headers=token, timeout=10)


def test_the_bridge_worker_carries_a_message_over_https(plant: Plant) -> None:
    agv = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-agv-{uuid.uuid4().hex[:8]}")
    agv.username_pw_set("agv", plant.agv_password)
    agv.connect(HOST, plant.ports["mq"], keepalive=10)
    agv.loop_start()
    planner = plant.filip(plant.planner_token)

    def arrived() -> bool:
        agv.publish("agv/1/status", json.dumps({"battery": 80.5}), qos=1).wait_for_publish(5)
        try:
            return planner.get_entity(entity_id=STATUS_ID).get_attribute("battery").value == 80.5
        except requests.RequestException:
            return False
    try:
        process.wait_until(arrived, 60.0, what="the AGV's status in the context broker", interval=1.0)
    finally:
        agv.loop_stop()
        agv.disconnect()


def test_query_live_reads_the_context_over_https(plant: Plant) -> None:
    query = f'SELECT ?v WHERE {{ ?e ngsi:entityId "{THING_ID}" ; ngsi:hasAttribute ?a . ?a ngsi:name "seq" ; ngsi:hasValue ?v }}'
    live = CliRunner().invoke(cli, ["query", str(plant.plant), "--live", "--agents", str(plant.fleet.agents_file),
                                    "--format", "csv", query])
    assert live.exit_code == 0 and "could not be read" not in live.output, live.output
    assert float(live.output.strip().splitlines()[-1]) == 7, live.output


def test_a_second_plan_is_empty(plant: Plant, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    code = main(["plan", str(plant.plant), "--agents", str(plant.fleet.agents_file), "--detailed-exitcode"])
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out

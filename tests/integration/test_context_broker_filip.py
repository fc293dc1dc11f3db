"""The real context broker process driven by FiLiP (FIWARE's Python client, PyPI ``filip``),
unchanged, as it drives Orion; then kill -9 after acknowledged writes, restart, every write there.

The broker runs as ``python -m engine.context_broker`` on a free loopback port with a token file
(benchmarks.context_broker_rig.ContextBroker: no process left behind). FiLiP gets the token
through a ``requests.Session`` header, as a deployment behind a token would.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import requests

from benchmarks.context_broker_rig import ContextBroker
from engine import parts

filip_cb = pytest.importorskip("filip.clients.ngsi_v2")
from filip.clients.exceptions import BaseHttpClientException  # noqa: E402
from filip.models.base import FiwareHeader  # noqa: E402
from filip.models.ngsi_v2.base import NamedMetadata  # noqa: E402
from filip.models.ngsi_v2.context import ActionType, ContextEntity, NamedContextAttribute  # noqa: E402

pytestmark = pytest.mark.integration
JSON = {"Content-Type": "application/json"}


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ContextBroker]:
    rig = ContextBroker(tmp_path_factory.mktemp("cb-filip")).start()
    try:
        yield rig
    finally:
        child = rig.child
        rig.stop()
        assert child is None or not child.group_alive()
        assert "Traceback" not in rig.log_text(), rig.log_text()[-3000:]


@pytest.fixture(scope="module")
def client(broker: ContextBroker) -> Iterator[filip_cb.ContextBrokerClient]:
    session = requests.Session()
    session.headers.update(broker.auth)
    cb = filip_cb.ContextBrokerClient(url=broker.url, session=session,
                                      fiware_header=FiwareHeader(service="plant", service_path="/agv"))
    yield cb
    session.close()


def agv(n: int, state: str = "idle") -> ContextEntity:
    return ContextEntity(id=f"urn:ngsi-ld:AGV:{n}", type="AGV",
                         state={"type": "Text", "value": state},
                         battery={"type": "Number", "value": 80.5,
                                  "metadata": {"source": {"type": "Text", "value": "bms"}}},
                         pose={"type": "StructuredValue", "value": {"x": 1.5, "y": 2, "mapId": "hall1"}})


def test_version_and_entity_crud(client: filip_cb.ContextBrokerClient) -> None:
    assert client.get_version()["orion"]["version"]
    client.post_entity(agv(1))
    got = client.get_entity("urn:ngsi-ld:AGV:1")
    assert got.get_attribute("state").value == "idle"
    assert got.get_attribute("pose").value == {"x": 1.5, "y": 2, "mapId": "hall1"}
    assert got.get_attribute("battery").metadata["source"].value == "bms"
    with pytest.raises(BaseHttpClientException) as info:
        client.post_entity(agv(1))
    assert info.value.response.status_code == 422
    client.post_entity(agv(1, "charging"), update=True)  # 422, then PUT .../attrs as FiLiP does
    assert client.get_attribute_value(entity_id="urn:ngsi-ld:AGV:1", attr_name="state") == "charging"
    client.delete_entity("urn:ngsi-ld:AGV:1", entity_type="AGV")
    with pytest.raises(BaseHttpClientException) as info:
        client.get_entity("urn:ngsi-ld:AGV:1")
    assert info.value.response.status_code == 404


def test_attribute_values_as_filip_sends_them(client: filip_cb.ContextBrokerClient) -> None:
    client.post_entity(agv(2))
    for attr, value in (("state", "moving"), ("battery", 12.5), ("state", "a b/c#d"), ("pose", {"x": 3})):
        client.update_attribute_value(entity_id="urn:ngsi-ld:AGV:2", attr_name=attr, value=value,
                                      entity_type="AGV")
        assert client.get_attribute_value(entity_id="urn:ngsi-ld:AGV:2", attr_name=attr) == value
    client.update_existing_entity_attributes(
        "urn:ngsi-ld:AGV:2", [NamedContextAttribute(name="state", type="Text", value="idle")], entity_type="AGV")
    with pytest.raises(BaseHttpClientException) as info:
        client.update_existing_entity_attributes(
            "urn:ngsi-ld:AGV:2", [NamedContextAttribute(name="speed", type="Number", value=1)], entity_type="AGV")
    assert info.value.response.status_code == 422
    client.update_or_append_entity_attributes(
        "urn:ngsi-ld:AGV:2", [NamedContextAttribute(name="speed", type="Number", value=1.2,
                                                    metadata=[NamedMetadata(name="source", type="Text", value="odometry")])],
        entity_type="AGV")
    entity = client.get_entity("urn:ngsi-ld:AGV:2", entity_type="AGV")
    assert entity.get_attribute("state").value == "idle"
    assert entity.get_attribute("speed").value == 1.2
    assert entity.get_attribute("speed").metadata["source"].value == "odometry"


def test_lists_page_over_a_thousand_with_q_and_types(client: filip_cb.ContextBrokerClient) -> None:
    sensors = [ContextEntity(id=f"sensor-{k:04d}", type="Sensor", zone={"type": "Number", "value": k % 10},
                             level={"type": "Number", "value": k}) for k in range(1500)]
    for first in range(0, len(sensors), 500):
        client.update(entities=sensors[first:first + 500], action_type=ActionType.APPEND)
    everything = client.get_entity_list(entity_types=["Sensor"])
    assert len(everything) == 1500 and len({e.id for e in everything}) == 1500
    zone3 = client.get_entity_list(entity_types=["Sensor"], q="zone==3;level>=100", limit=2000)
    assert sorted(e.id for e in zone3) == [f"sensor-{k:04d}" for k in range(103, 1500, 10)]
    first = client.get_entity_list(entity_types=["Sensor"], limit=5, order_by="!level")
    assert [e.id for e in first] == [f"sensor-{k:04d}" for k in (1499, 1498, 1497, 1496, 1495)]
    types = {t["type"]: t for t in client.get_entity_types()}
    assert types["Sensor"]["count"] == 1500
    assert types["Sensor"]["attrs"]["zone"]["types"] == ["Number"]
    # Orion's batch delete removes the attributes an entity lists, the entity when it lists none
    client.update(entities=sensors[:10], action_type=ActionType.DELETE)
    assert client.get_entity("sensor-0000", entity_type="Sensor").get_attributes() == []
    client.update(entities=[ContextEntity(id=s.id, type="Sensor") for s in sensors[:100]],
                  action_type=ActionType.DELETE)
    assert len(client.get_entity_list(entity_types=["Sensor"])) == 1400


def test_tenants_stay_apart(broker: ContextBroker, client: filip_cb.ContextBrokerClient) -> None:
    session = requests.Session()
    session.headers.update(broker.auth)
    other = filip_cb.ContextBrokerClient(url=broker.url, session=session,
                                         fiware_header=FiwareHeader(service="other", service_path="/"))
    other.post_entity(agv(99))
    assert [e.id for e in other.get_entity_list()] == ["urn:ngsi-ld:AGV:99"]
    assert "urn:ngsi-ld:AGV:99" not in {e.id for e in client.get_entity_list(entity_types=["AGV"])}
    session.close()


def test_acknowledged_writes_survive_kill_9(tmp_path: Path) -> None:
    folder = tmp_path / "cb"
    rig = ContextBroker(folder).start()
    http = rig.http()
    expected: dict[str, object] = {}
    try:
        for k in range(60):
            reply = http.request("POST", "/v2/entities", json.dumps(
                {"id": f"urn:ngsi-ld:AGV:{k}", "type": "AGV", "n": {"type": "Number", "value": 0}}),
                {**JSON, **rig.auth})
            assert reply.status == 201, reply
            expected[f"urn:ngsi-ld:AGV:{k}"] = 0
        for k in range(0, 60, 2):
            reply = http.request("PUT", f"/v2/entities/urn:ngsi-ld:AGV:{k}/attrs/n/value", str(k),
                                 {"Content-Type": "text/plain", **rig.auth})
            assert reply.status == 204, reply
            expected[f"urn:ngsi-ld:AGV:{k}"] = k
        for k in range(1, 60, 10):
            assert http.request("DELETE", f"/v2/entities/urn:ngsi-ld:AGV:{k}", headers=rig.auth).status == 204
            del expected[f"urn:ngsi-ld:AGV:{k}"]
        http.close()
        assert rig.child is not None
        os.killpg(rig.child.pid, signal.SIGKILL)
        rig.child.popen.wait(timeout=30)
        rig.child = None
    finally:
        rig.stop()
    again = ContextBroker(folder).start()
    try:
        http = again.http()
        reply = http.request("GET", "/v2/entities?type=AGV&limit=1000&options=keyValues,count")
        http.close()
        assert reply.status == 200
        assert {e["id"]: e["n"] for e in reply.json()} == expected
        # a second process on the same data folder refuses to start, saying why
        second = subprocess.run([sys.executable, "-m", "engine.context_broker", "--port", "1",
                                 "--data-dir", str(again.data_dir), "--open"],
                                capture_output=True, text=True, timeout=60, cwd=parts.repo_root())
        assert second.returncode == 2 and "in use by another context broker" in second.stderr
    finally:
        again.stop()

"""fleet.model.binding: where the plant's fleet lives, found by SPARQL over the plant files."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from fleet.model.binding import FleetBinding, fleet_binding
from fleet.model.errors import BindingError

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
AF = "https://w3id.org/plantkg/examples/agv-fleet#"

HEAD = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix fleet: <https://w3id.org/plantkg/fleet#> .
@prefix : <http://example.org/p/> .
:m1 a pk:Broker ; pk:id "m1" ; pk:name "m1" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; pk:port 1883 .
:m2 a pk:Broker ; pk:id "m2" ; pk:name "m2" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.4" ; pk:port 1883 .
:k a pk:Broker ; pk:id "k" ; pk:name "k" ; pk:brokerType "kafka" ; pk:ip "127.0.0.5" ; pk:port 9092 .
:c1 a pk:Broker ; pk:id "c1" ; pk:name "c1" ; pk:brokerType "ngsi-v2" ; pk:ip "127.0.0.3" ; pk:port 1026 .
:c2 a pk:Broker ; pk:id "c2" ; pk:name "c2" ; pk:brokerType "ngsi-v2" ; pk:ip "127.0.0.6" ; pk:port 1026 .
"""


def _plant(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "plant.ttl"
    path.write_text(HEAD + body, encoding="utf-8")
    return path


def test_the_example_plant() -> None:
    binding = fleet_binding([EXAMPLE])
    assert binding == FleetBinding(AF + "fleet-mqtt", AF + "fleet-context", AF)


def test_without_a_fleet_view_there_is_no_context_broker(tmp_path: Path) -> None:
    plant = _plant(tmp_path, ':fm a pk:Resource ; pk:id "fm" ; pk:name "fm" ; pk:isType fleet:fleet-manager ; pk:sendsTo :m1 .')
    assert fleet_binding([plant]) == FleetBinding("http://example.org/p/m1", None, "http://example.org/p/")


REFUSED = [
    ("no fleet manager", ':x a pk:Resource ; pk:id "x" ; pk:name "x" ; pk:sendsTo :m1 .', "no fleet manager"),
    ("a fleet manager on Kafka only",
     ':fm a pk:Resource ; pk:id "fm" ; pk:name "fm" ; pk:isType fleet:fleet-manager ; pk:sendsTo :k .', "no fleet manager"),
    ("fleet managers on two Mosquitto brokers",
     ':fm a pk:Resource ; pk:id "fm" ; pk:name "fm" ; pk:isType fleet:fleet-manager ; pk:sendsTo :m1 .\n'
     ':fm2 a pk:Resource ; pk:id "fm2" ; pk:name "fm2" ; pk:isType fleet:fleet-manager ; pk:sendsTo :m2 .', "several Mosquitto"),
    ("fleet views on two context brokers",
     ':fm a pk:Resource ; pk:id "fm" ; pk:name "fm" ; pk:isType fleet:fleet-manager ; pk:sendsTo :m1 .\n'
     ':v1 a pk:Resource ; pk:id "v1" ; pk:name "v1" ; pk:isType fleet:fleet-view ; pk:sendsTo :c1 .\n'
     ':v2 a pk:Resource ; pk:id "v2" ; pk:name "v2" ; pk:isType fleet:fleet-view ; pk:sendsTo :c2 .', "several context"),
]


@pytest.mark.parametrize(("label", "body", "message"), REFUSED, ids=[r[0] for r in REFUSED])
def test_a_plant_without_one_fleet_broker_is_refused(tmp_path: Path, label: str, body: str, message: str) -> None:
    with pytest.raises(BindingError, match=message) as err:
        fleet_binding([_plant(tmp_path, body)])
    assert err.value.hint


def test_a_binding_is_plain_json_data() -> None:
    binding = fleet_binding([EXAMPLE])
    assert FleetBinding(**dataclasses.asdict(binding)) == binding


@pytest.mark.parametrize("fields", [
    {"mqtt_broker_iri": "", "context_broker_iri": None, "base_iri": "http://x/#"},
    {"mqtt_broker_iri": "http://x/#m", "context_broker_iri": None, "base_iri": "http://x/base"},
    {"mqtt_broker_iri": "http://x/#m", "context_broker_iri": 5, "base_iri": "http://x/#"},
    {"mqtt_broker_iri": "not an iri", "context_broker_iri": None, "base_iri": "http://x/#"},
], ids=["empty broker", "base without # or /", "context not a string", "broker not an IRI"])
def test_a_bad_stored_binding_is_refused(fields: dict[str, object]) -> None:
    with pytest.raises(BindingError):
        FleetBinding(**fields)  # type: ignore[arg-type]

"""fleet.discovery.records and files: safe names, atomic writes, the data directory's operations,
with the real Turtle rendering of the AGV model."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import rdflib

from fleet.discovery import files
from fleet.discovery.errors import UnknownVehicleError
from fleet.discovery.inbox import Interface, VehicleKey
from fleet.discovery.records import DataDir, VehicleRecord
from fleet.manager.service import describe, render_record
from fleet.model.binding import FleetBinding
from tests.unit.fleet import discovery_data as d

FLEET = rdflib.Namespace("https://w3id.org/plantkg/fleet#")
PK = rdflib.Namespace("https://w3id.org/plantkg/ontology#")
BINDING = {"mqtt_broker_iri": "https://example.org/plant#fleet-mqtt", "context_broker_iri": None,
           "base_iri": "https://example.org/plant#"}


@pytest.mark.parametrize("manufacturer,serial,expected", [
    ("acme", "agv-42", "acme--agv-42"),
    ("KIT IFL", "0001", "KIT%20IFL--0001"),
    (".hidden", "x", "%2Ehidden--x"),
    ("a\\b", "s:1", "a%5Cb--s:1"),
    ("", "s", "_--s"),
])
def test_stems_are_safe_file_names(manufacturer: str, serial: str, expected: str) -> None:
    assert files.stem(manufacturer, serial) == expected
    assert "/" not in expected and not expected.startswith(".")


def test_atomic_write_leaves_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "a" / "b.ttl"
    files.atomic_write(target, "one")
    files.atomic_write(target, "two")
    assert target.read_text() == "two" and os.listdir(target.parent) == ["b.ttl"]


def record(**changes: object) -> VehicleRecord:
    desc = describe(VehicleKey(Interface.VDA5050, d.MANUFACTURER, d.SERIAL), d.factsheet())
    base = VehicleRecord("vda5050", desc["manufacturer"], d.SERIAL, d.MANUFACTURER, desc, BINDING)
    return VehicleRecord(**{**base.to_json(), **changes})  # type: ignore[arg-type]


def graph(path: Path) -> rdflib.Graph:
    return rdflib.Graph().parse(path, format="turtle")


def test_save_renders_the_vehicle_and_its_record(tmp_path: Path) -> None:
    data = DataDir(tmp_path, render_record)
    path = data.save(record())
    assert path == tmp_path / "discovered" / "acme--agv-42.ttl"
    g = graph(path)
    agv = next(g.subjects(FLEET.serialNumber, rdflib.Literal(d.SERIAL)))
    assert str(g.value(agv, FLEET.connectionState)) == "ONLINE"
    assert g.value(agv, FLEET.discovered).toPython() is True
    assert json.loads((tmp_path / "vehicles" / "acme--agv-42.json").read_text())["serial"] == d.SERIAL
    assert data.records() == [record()]
    FleetBinding(**BINDING)  # the record's binding is the model's


def test_update_rename_pin_and_connection_are_rendered(tmp_path: Path) -> None:
    data = DataDir(tmp_path, render_record)
    data.save(record())
    new = data.update(data.find("acme/agv-42"), name="Carrier 42", pinned=True, connection_state="CONNECTIONBROKEN")
    g = graph(data.turtle_path(new))
    agv = next(g.subjects(FLEET.serialNumber, rdflib.Literal(d.SERIAL)))
    assert (str(g.value(agv, PK.name)), g.value(agv, FLEET.pinned).toPython(),
            str(g.value(agv, FLEET.connectionState))) == ("Carrier 42", True, "CONNECTIONBROKEN")
    assert data.find("agv-42") == new


def test_find_names_the_known_vehicles(tmp_path: Path) -> None:
    data = DataDir(tmp_path, render_record)
    data.save(record())
    with pytest.raises(UnknownVehicleError, match="no discovered vehicle 'nope'") as info:
        data.find("nope")
    assert "acme/agv-42" in str(info.value)


def test_refuse_moves_the_file_and_keeps_the_reason(tmp_path: Path) -> None:
    data = DataDir(tmp_path, render_record)
    path = data.save(record())
    why = data.refuse("acme--agv-42", "the plant would be invalid", turtle=path)
    assert not path.exists() and (tmp_path / "refused" / "acme--agv-42.ttl").exists()
    assert "the plant would be invalid" in why.read_text()
    assert data.records() == [] and data.turtle_files() == []
    assert data.refused_list()[0]["vehicle"] == "acme--agv-42"


def test_remove_forgets_file_and_record(tmp_path: Path) -> None:
    data = DataDir(tmp_path, render_record)
    data.save(record())
    data.remove(data.find("agv-42"))
    assert data.records() == [] and data.turtle_files() == []

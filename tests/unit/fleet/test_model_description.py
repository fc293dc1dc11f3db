"""fleet.model.description: a VDA 5050 factsheet or the paper's description becomes one checked
AgvDescription, and every hostile input is refused with the field path and the value.

The good inputs come from the other implementations in the repository: the simulator's factsheet
(fleet.sim's action catalogue through fleet.vda5050's Factsheet, checked against the official
VDA 5050 schema) and the description payload of the fleet contract (docs/fleet.md).
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable
from typing import Any

import pytest

from fleet.model import values
from fleet.model.description import AgvDescription, AgvProperty, check, from_factsheet, from_paper_description
from fleet.model.errors import DescriptionError
from fleet.sim.actions import catalogue
from fleet.vda5050 import schemas
from fleet.vda5050.factsheet import Factsheet
from fleet.vda5050.headers import HeaderCounter

MANUFACTURER = "plantkg-sim"
SERIAL = "sim-0042"


def sim_factsheet(manufacturer: str = MANUFACTURER, serial: str = SERIAL) -> dict[str, Any]:
    """The simulated vehicle's factsheet, as it publishes it (schema-checked)."""
    sheet = Factsheet(series_name="plantkg-sim", agv_kinematic="DIFF", agv_class="CARRIER", max_load_mass=100.0,
                      speed_min=0.0, speed_max=1.0, acceleration_max=0.5, deceleration_max=0.5, height_max=0.4,
                      width=0.6, length=0.9, agv_actions=catalogue(), angular_speed_max=1.0,
                      angular_acceleration_max=1.0)
    return schemas.check("factsheet", sheet.to_json(HeaderCounter(manufacturer, serial).next("factsheet")))


def paper_description(agv_id: str = "agv-7") -> dict[str, Any]:
    """The description_channel payload of the fleet contract."""
    return {"header": {"seq": 0, "stamp": "2026-11-24T20:00:00.000Z", "frame_id": "map"},
            "agv_id": agv_id, "name": "AGV 7", "manufacturer": "plantkg-sim",
            "skills": ["move", "load", "unload", "wait", "charge"],
            "physical": {"max_velocity": [1.0, 0.0, 1.2], "max_acceleration": [0.5, 0.0, 1.0],
                         "payload_kg": 100.0, "battery_capacity_wh": 1200.0,
                         "footprint": {"length": 1.0, "width": 0.7}}}


# --- good inputs ---------------------------------------------------------------------------------

def test_the_simulators_factsheet() -> None:
    desc = from_factsheet(MANUFACTURER, SERIAL, sim_factsheet())
    assert (desc.serial, desc.manufacturer, desc.interface) == (SERIAL, MANUFACTURER, "vda5050")
    assert desc.name == f"plantkg-sim {SERIAL}"
    assert set(desc.skills) == {a.action_type for a in catalogue()} | {"move"}
    assert list(desc.skills) == sorted(desc.skills)
    props = {p.id: (p.value, p.value_type) for p in desc.properties}
    assert props == {
        "max-speed": ("1.0", "decimal"), "min-speed": ("0.0", "decimal"), "max-acceleration": ("0.5", "decimal"),
        "max-deceleration": ("0.5", "decimal"), "max-angular-speed": ("1.0", "decimal"),
        "max-angular-acceleration": ("1.0", "decimal"), "max-load-mass": ("100.0", "decimal"),
        "length": ("0.9", "decimal"), "width": ("0.6", "decimal"), "height": ("0.4", "decimal"),
    }
    assert check(desc) is desc


def test_the_contracts_paper_description() -> None:
    desc = from_paper_description(paper_description())
    assert (desc.serial, desc.manufacturer, desc.interface, desc.name) == ("agv-7", "plantkg-sim", "paper-channels", "AGV 7")
    assert desc.skills == ("charge", "load", "move", "unload", "wait")
    props = {p.id: p.value for p in desc.properties}
    assert props == {"max-speed": "1.0", "max-lateral-speed": "0.0", "max-angular-speed": "1.2",
                     "max-acceleration": "0.5", "max-lateral-acceleration": "0.0",
                     "max-angular-acceleration": "1.0", "max-load-mass": "100.0",
                     "battery-capacity": "1200.0", "length": "1.0", "width": "0.7"}


def test_optional_fields_may_be_absent_and_move_follows_the_speed() -> None:
    data = paper_description()
    del data["physical"]["battery_capacity_wh"]
    data["skills"] = ["load"]
    data["physical"]["max_velocity"] = [0.0, 0.0, 0.5]  # turns on the spot, does not drive
    desc = from_paper_description(data)
    assert "battery-capacity" not in {p.id for p in desc.properties}
    assert desc.skills == ("load",)
    sheet = sim_factsheet()
    for key in ("speedMin", "decelerationMax", "angularSpeedMax", "angularAccelerationMax"):
        del sheet["physicalParameters"][key]
    assert {p.id for p in from_factsheet(MANUFACTURER, SERIAL, sheet).properties} == {
        "max-speed", "max-acceleration", "max-load-mass", "length", "width", "height"}


def test_numbers_become_plain_decimals() -> None:
    assert [values.decimal_text(x) for x in (1e-05, 3, 2.5, 1e6, 0.1)] == ["0.00001", "3.0", "2.5", "1000000.0", "0.1"]


def test_a_description_is_plain_json_data() -> None:
    """The plug-and-play records keep descriptions as JSON (dataclasses.asdict) and rebuild them."""
    import dataclasses

    desc = from_paper_description(paper_description())
    data = json.loads(json.dumps(dataclasses.asdict(desc)))
    again = AgvDescription(**{**data, "skills": tuple(data["skills"]),
                              "properties": tuple(AgvProperty(**p) for p in data["properties"])})
    assert again == desc


def test_bytes_and_text_payloads_are_read_as_json() -> None:
    text = json.dumps(paper_description())
    assert from_paper_description(text) == from_paper_description(text.encode()) == from_paper_description(paper_description())


# --- hostile inputs: (name, how to break the input, field path named, value named) ---------------

BAD_SERIALS = [("slash", "a/b"), ("hash", "a#b"), ("plus", "a+b"), ("space", "a b"), ("empty", ""),
               ("65 characters", "s" * 65), ("dollar", "$SYS"), ("newline", "sn1\n"), ("non-ascii", "sérial"),
               ("integer", 42), ("none", None), ("list", ["sn1"])]


@pytest.mark.parametrize(("label", "serial"), BAD_SERIALS, ids=[b[0] for b in BAD_SERIALS])
def test_bad_serial_numbers_are_refused_by_both_readers(label: str, serial: object) -> None:
    with pytest.raises(DescriptionError) as err:
        from_factsheet(MANUFACTURER, serial, sim_factsheet())  # type: ignore[arg-type]
    assert err.value.field == "serialNumber" and err.value.value == serial
    assert "serialNumber" in str(err.value) and repr(serial)[:20] in str(err.value)
    data = paper_description()
    data["agv_id"] = serial
    with pytest.raises(DescriptionError) as err:
        from_paper_description(data)
    assert err.value.field == "agv_id" and err.value.value == serial


def test_the_longest_serial_number_is_accepted() -> None:
    serial = "Az09_.:-" * 8
    assert from_factsheet(MANUFACTURER, serial, sim_factsheet(serial=serial)).serial == serial


def _set(path: str, value: object) -> Callable[[dict[str, Any]], None]:
    def edit(data: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for part in parents:
            node = node[int(part)] if part.isdigit() else node[part]
        node[int(last) if last.isdigit() else last] = value
    return edit


def _drop(path: str) -> Callable[[dict[str, Any]], None]:
    def edit(data: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        node: Any = data
        for part in parents:
            node = node[int(part)] if part.isdigit() else node[part]
        del node[last]
    return edit


FACTSHEET_CASES: list[tuple[str, Callable[[dict[str, Any]], None], str, object]] = [
    ("no typeSpecification", _drop("typeSpecification"), "typeSpecification", None),
    ("typeSpecification a string", _set("typeSpecification", "AGV"), "typeSpecification", "AGV"),
    ("no seriesName", _drop("typeSpecification.seriesName"), "typeSpecification.seriesName", None),
    ("empty seriesName", _set("typeSpecification.seriesName", ""), "typeSpecification.seriesName", ""),
    ("seriesName with a newline", _set("typeSpecification.seriesName", "a\nb"), "typeSpecification.seriesName", "a\nb"),
    ("maxLoadMass a string", _set("typeSpecification.maxLoadMass", "100"), "typeSpecification.maxLoadMass", "100"),
    ("no physicalParameters", _drop("physicalParameters"), "physicalParameters", None),
    ("no speedMax", _drop("physicalParameters.speedMax"), "physicalParameters.speedMax", None),
    ("speedMax a string", _set("physicalParameters.speedMax", "fast"), "physicalParameters.speedMax", "fast"),
    ("speedMax a boolean", _set("physicalParameters.speedMax", True), "physicalParameters.speedMax", True),
    ("speedMax negative", _set("physicalParameters.speedMax", -1.0), "physicalParameters.speedMax", -1.0),
    ("speedMax huge", _set("physicalParameters.speedMax", 1e300), "physicalParameters.speedMax", 1e300),
    ("speedMax null", _set("physicalParameters.speedMax", None), "physicalParameters.speedMax", None),
    ("width zero", _set("physicalParameters.width", 0), "physicalParameters.width", 0),
    ("angularSpeedMax a list", _set("physicalParameters.angularSpeedMax", [1]), "physicalParameters.angularSpeedMax", [1]),
    ("no protocolFeatures", _drop("protocolFeatures"), "protocolFeatures", None),
    ("agvActions an object", _set("protocolFeatures.agvActions", {"pick": 1}), "protocolFeatures.agvActions", {"pick": 1}),
    ("an action a string", _set("protocolFeatures.agvActions.2", "pick"), "protocolFeatures.agvActions[2]", "pick"),
    ("actionType missing", _drop("protocolFeatures.agvActions.1.actionType"), "protocolFeatures.agvActions[1].actionType", None),
    ("actionType with a space", _set("protocolFeatures.agvActions.1.actionType", "pick up"),
     "protocolFeatures.agvActions[1].actionType", "pick up"),
    ("actionType a number", _set("protocolFeatures.agvActions.0.actionType", 7), "protocolFeatures.agvActions[0].actionType", 7),
    ("actionType starting with -", _set("protocolFeatures.agvActions.0.actionType", "-x"),
     "protocolFeatures.agvActions[0].actionType", "-x"),
    ("another vehicle's serial", _set("serialNumber", "sim-9999"), "serialNumber", "sim-9999"),
    ("another manufacturer", _set("manufacturer", "acme"), "manufacturer", "acme"),
]


@pytest.mark.parametrize(("label", "edit", "field", "value"), FACTSHEET_CASES, ids=[c[0] for c in FACTSHEET_CASES])
def test_bad_factsheets_name_the_field_and_value(label: str, edit: Callable[[dict[str, Any]], None],
                                                 field: str, value: object) -> None:
    sheet = sim_factsheet()
    edit(sheet)
    with pytest.raises(DescriptionError) as err:
        from_factsheet(MANUFACTURER, SERIAL, sheet)
    assert (err.value.field, err.value.value) == (field, value)
    assert str(err.value).startswith(f"{field} = ")


NAN = object()  # the value is NaN (not equal to itself)
PAPER_CASES: list[tuple[str, Callable[[dict[str, Any]], None], str, object]] = [
    ("no name", _drop("name"), "name", None),
    ("name a number", _set("name", 7), "name", 7),
    ("name of 129 characters", _set("name", "n" * 129), "name", "n" * 129),
    ("manufacturer with a slash", _set("manufacturer", "a/b"), "manufacturer", "a/b"),
    ("manufacturer with a space", _set("manufacturer", "plantkg sim"), "manufacturer", "plantkg sim"),
    ("skills a string", _set("skills", "move"), "skills", "move"),
    ("a skill with a #", _set("skills.1", "lo#ad"), "skills[1]", "lo#ad"),
    ("no physical", _drop("physical"), "physical", None),
    ("two axes", _set("physical.max_velocity", [1.0, 0.0]), "physical.max_velocity", [1.0, 0.0]),
    ("an axis NaN", _set("physical.max_acceleration", [0.5, float("nan"), 1.0]), "physical.max_acceleration[1]", NAN),
    ("an axis a string", _set("physical.max_velocity", [1.0, "0", 1.2]), "physical.max_velocity[1]", "0"),
    ("payload negative", _set("physical.payload_kg", -5), "physical.payload_kg", -5),
    ("battery infinite", _set("physical.battery_capacity_wh", float("inf")), "physical.battery_capacity_wh", float("inf")),
    ("no footprint", _drop("physical.footprint"), "physical.footprint", None),
    ("footprint length a boolean", _set("physical.footprint.length", False), "physical.footprint.length", False),
]


@pytest.mark.parametrize(("label", "edit", "field", "value"), PAPER_CASES, ids=[c[0] for c in PAPER_CASES])
def test_bad_paper_descriptions_name_the_field_and_value(label: str, edit: Callable[[dict[str, Any]], None],
                                                         field: str, value: object) -> None:
    data = paper_description()
    edit(data)
    with pytest.raises(DescriptionError) as err:
        from_paper_description(data)
    assert err.value.field == field
    if value is NAN:
        assert math.isnan(err.value.value)  # type: ignore[arg-type]
    else:
        assert err.value.value == value


@pytest.mark.parametrize("payload", [None, [], "[1]", 7, b"\xff\xfe", "{not json"], ids=repr)
def test_not_an_object(payload: object) -> None:
    with pytest.raises(DescriptionError) as err:
        from_paper_description(payload)  # type: ignore[arg-type]
    assert err.value.field == "description"


def test_a_10_mb_payload_is_refused_quickly_and_named() -> None:
    sheet = sim_factsheet()
    sheet["junk"] = "x" * 10_000_000
    start = time.perf_counter()
    with pytest.raises(DescriptionError) as err:
        from_factsheet(MANUFACTURER, SERIAL, sheet)
    assert time.perf_counter() - start < 0.5
    assert err.value.field == "factsheet" and "larger than" in err.value.problem
    assert len(str(err.value)) < 400  # the value is not repeated in the message
    many = paper_description()
    many["skills"] = ["move"] * 2_000_000  # 10 MB of JSON in small pieces
    with pytest.raises(DescriptionError, match="larger than"):
        from_paper_description(many)
    with pytest.raises(DescriptionError, match="larger than"):
        from_paper_description(json.dumps(sheet).encode())


def test_deep_nesting_is_refused() -> None:
    data = paper_description()
    node: dict[str, Any] = data
    for _ in range(values.MAX_DEPTH + 5):
        node["x"] = {}
        node = node["x"]
    with pytest.raises(DescriptionError, match="nested"):
        from_paper_description(data)


def test_inputs_are_not_changed() -> None:
    sheet = sim_factsheet()
    before = copy.deepcopy(sheet)
    from_factsheet(MANUFACTURER, SERIAL, sheet)
    assert sheet == before


STORED_CASES: list[tuple[str, dict[str, Any], str]] = [
    ("serial", {"serial": "a/b"}, "serial"),
    ("interface", {"interface": "vda5051"}, "interface"),
    ("skills a list", {"skills": ["move"]}, "skills"),
    ("a skill", {"skills": ("move", "x y")}, "skills[1]"),
    ("a property value", {"properties": (AgvProperty("max-speed", "Max", "fast", "decimal"),)}, "properties[0].value"),
    ("a property type", {"properties": (AgvProperty("max-speed", "Max", "1", "date"),)}, "properties[0].value"),
    ("two properties with one id", {"properties": (AgvProperty("a", "A", "1", "decimal"),) * 2}, "properties[1].id"),
]


@pytest.mark.parametrize(("label", "change", "field"), STORED_CASES, ids=[c[0] for c in STORED_CASES])
def test_check_refuses_a_description_built_by_hand(label: str, change: dict[str, Any], field: str) -> None:
    import dataclasses

    desc = dataclasses.replace(from_paper_description(paper_description()), **change)
    with pytest.raises(DescriptionError) as err:
        check(desc)
    assert err.value.field == field

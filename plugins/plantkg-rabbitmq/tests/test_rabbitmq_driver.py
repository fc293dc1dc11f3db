"""The RabbitMQ driver without a running node: registration, shapes, rendering, refusals."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

pytest.importorskip("plantkg_rabbitmq", reason="plugins/plantkg-rabbitmq is not installed (make setup)")

from engine.drivers.base import Driver
from engine.drivers.registry import DriverRegistry
from engine.errors import ConfigValueError
from engine.model import BrokerSpec, TopicSpec
from kg import shape_plugins
from kg.load import load_plant
from kg.validate import load_default_shapes, validate
from plantkg_rabbitmq import amqp, config
from plantkg_rabbitmq.driver import RabbitmqDriver

PLANT = Path(__file__).resolve().parent / "plants" / "rabbitmq-cell.ttl"
SPEC = BrokerSpec(id="amqp1", iri="urn:amqp1", name="cell-amqp", kind="rabbitmq",
                  host="127.0.0.1", port=5672, mqtt_port=1884)


def test_the_entry_points_register_driver_and_shapes() -> None:
    registry = DriverRegistry.from_entry_points()
    assert isinstance(registry.get("rabbitmq"), RabbitmqDriver), registry.errors
    assert isinstance(registry.get("rabbitmq"), Driver)
    assert "rabbitmq" in shape_plugins.registered_broker_types()
    assert [p.name for p in shape_plugins.plugin_shapes_files()] == ["rabbitmq-shapes.ttl"]
    assert [p.name for p in shape_plugins.plugin_ontology_files()] == ["rabbitmq.ttl"]


@pytest.mark.parametrize("engine", ["oxigraph", "pyshacl"])
def test_a_plant_may_ask_for_a_rabbitmq_broker(engine: str) -> None:
    report = validate(load_plant([PLANT]), engine=engine)  # type: ignore[arg-type]
    assert report.conforms, [r.message for r in report.results]
    assert any(f.endswith("rabbitmq-shapes.ttl") for f in report.shapes)


@pytest.mark.parametrize("name", ["amq.pose", "cell/#", "x" * 256])
@pytest.mark.parametrize("engine", ["oxigraph", "pyshacl"])
def test_the_plugin_shapes_refuse_a_bad_queue_name(tmp_path: Path, name: str, engine: str) -> None:
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT.read_text().replace('pk:name "cell/pose"', f'pk:name "{name}"'))
    report = validate(load_plant([plant]), engine=engine)  # type: ignore[arg-type]
    [result] = report.violations
    assert result.value == name and "carried by a RabbitMQ broker" in result.message


def test_an_unknown_type_names_rabbitmq_among_the_allowed(tmp_path: Path) -> None:
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT.read_text().replace('"rabbitmq"', '"rabbit-mq"'))
    [result] = validate(load_plant([plant])).violations
    assert result.value == "rabbit-mq"
    assert "installed drivers are kafka, mosquitto, ngsi-v2 and rabbitmq" in result.message
    assert "rabbitmq-shapes.ttl" in " ".join(map(str, load_default_shapes().files))


@pytest.mark.parametrize("engine", ["oxigraph", "pyshacl"])
@pytest.mark.parametrize(("edit", "value"), [
    (("pk:mqttPort 1884 ;", ""), None),                      # no MQTT port declared
    (("pk:mqttPort 1884 ;", "pk:mqttPort 5672 ;"), 5672),    # the AMQP port again
])
def test_the_plugin_shapes_ask_for_an_mqtt_port_of_its_own(tmp_path: Path, engine: str, edit: tuple,
                                                           value: int | None) -> None:
    plant = tmp_path / "plant.ttl"
    text = PLANT.read_text()
    assert edit[0] in text
    plant.write_text(text.replace(*edit))
    report = validate(load_plant([plant]), engine=engine)  # type: ignore[arg-type]
    [result] = report.violations
    assert result.path.endswith("mqttPort") and "needs pk:mqttPort" in result.message
    if value is not None:  # (without a value, SHACL reports the focus node as the value)
        assert int(result.value) == value


@pytest.mark.parametrize("kind", ["mosquitto", "kafka"])
def test_the_core_shapes_refuse_an_mqtt_port_on_a_built_in_type(tmp_path: Path, kind: str) -> None:
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT.read_text().replace('"rabbitmq"', f'"{kind}"'))
    messages = [r.message for r in validate(load_plant([plant])).violations if r.path.endswith("mqttPort")]
    assert messages and "does not apply to a mosquitto, kafka or ngsi-v2 broker" in messages[0]


def test_render_config(tmp_path: Path) -> None:
    ports = config.NodePorts(dist=21884, epmd=21885)
    files = config.render_files("127.0.0.1", 5672, 21883, tmp_path, ports)
    assert sorted(files) == ["enabled_plugins", "launch.json", "rabbitmq-env.conf", "rabbitmq.conf"]
    conf = files["rabbitmq.conf"].splitlines()
    assert "listeners.tcp.default = 127.0.0.1:5672" in conf
    assert "mqtt.listeners.tcp.default = 127.0.0.1:21883" in conf
    assert "loopback_users.guest = true" in conf
    assert files["enabled_plugins"] == "[rabbitmq_mqtt].\n"
    launch = json.loads(files["launch.json"])
    env = launch["env"]
    assert launch["epmd_port"] == 21885 and env["ERL_EPMD_PORT"] == "21885"
    assert env["RABBITMQ_DIST_PORT"] == "21884"
    assert env["RABBITMQ_CONFIG_FILE"] == str(tmp_path / "rabbitmq.conf")
    assert env["RABBITMQ_ENABLED_PLUGINS_FILE"] == str(tmp_path / "enabled_plugins")
    assert env["RABBITMQ_CONF_ENV_FILE"] == str(tmp_path / "rabbitmq-env.conf")
    assert env["RABBITMQ_MNESIA_BASE"].startswith(str(tmp_path)) and env["HOME"] == str(tmp_path)
    assert env["RABBITMQ_LOG_BASE"] == str(tmp_path / "logs")
    assert env["RABBITMQ_NODENAME"] == config.node_name(tmp_path)
    assert "{127,0,0,1}" in env["RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS"]


def test_prepare_picks_ports_once(tmp_path: Path) -> None:
    driver = RabbitmqDriver()
    driver.prepare(SPEC, tmp_path)
    first = config.read_ports(tmp_path)
    driver.prepare(SPEC, tmp_path)
    assert config.read_ports(tmp_path) == first
    assert first.dist != first.epmd
    assert driver.render_config(SPEC, tmp_path) == driver.render_config(SPEC, tmp_path)
    assert (tmp_path / "data").is_dir()


def test_node_names_differ_by_folder(tmp_path: Path) -> None:
    assert config.node_name(tmp_path / "a") != config.node_name(tmp_path / "b")


@pytest.mark.parametrize(("change", "field"), [
    ({"host": "::1"}, "host"),
    ({"host": "10.0.0.5"}, "host"),
    ({"host": "localhost"}, "host"),
    ({"port": 0}, "port"),
    ({"port": 70000}, "port"),
    ({"mqtt_port": None}, "mqtt_port"),
    ({"mqtt_port": 5672}, "mqtt_port"),
    ({"mqtt_port": 70000}, "mqtt_port"),
])
def test_validate_refuses_naming_the_field(change: dict, field: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        RabbitmqDriver().validate(replace(SPEC, **change))
    assert info.value.field == field


def test_a_folder_with_quotes_or_spaces_is_refused(tmp_path: Path) -> None:
    ports = config.NodePorts(dist=21884, epmd=21885)
    for bad in ("a b", "a'b", 'a"b'):
        with pytest.raises(ConfigValueError) as info:
            config.render_files("127.0.0.1", 5672, 21883, tmp_path / bad, ports)
        assert info.value.field == "broker_dir"


def test_the_amqp_port_may_not_be_the_mqtt_port(tmp_path: Path) -> None:
    with pytest.raises(ConfigValueError, match="AMQP port") as info:
        config.render_files("127.0.0.1", 21883, 21883, tmp_path, config.NodePorts(21884, 21885))
    assert info.value.field == "mqtt_port"


@pytest.mark.parametrize(("name", "problem"), [
    ("amq.x", "reserves"), ("a/+", "filter"), ("a/#", "filter"), ("é" * 128, "255 bytes"),
    ("", "empty"), ("a\nb", "control"),
])
def test_bad_topic_names_are_refused_before_the_broker_is_asked(name: str, problem: str) -> None:
    topic = TopicSpec(broker_id="amqp1", name=name, iri="urn:t")
    with pytest.raises(ConfigValueError, match=problem) as info:
        RabbitmqDriver().ensure_topic(replace(SPEC, port=1), topic)  # port 1: nothing listens
    assert info.value.field == "name"


@pytest.mark.parametrize(("field", "value"), [("partitions", 3), ("entity_id", "urn:x"), ("qos", 3)])
def test_topic_fields_of_other_kinds_are_refused(field: str, value: object) -> None:
    """Kafka's and NGSI's settings do not apply; MQTT's do (clients publish over MQTT), in range."""
    topic = TopicSpec(broker_id="amqp1", name="cell/pose", iri="urn:t", **{field: value})
    with pytest.raises(ConfigValueError) as info:
        RabbitmqDriver().ensure_topic(replace(SPEC, port=1), topic)
    assert info.value.field == field


def test_no_native_bridges(tmp_path: Path) -> None:
    """A Mosquitto bridge to RabbitMQ is carried by the Mosquitto end (test_rabbitmq_node.py)."""
    RabbitmqDriver().prepare(SPEC, tmp_path)

    class Bridge:
        address = "bridge.m1.amqp1"

    with pytest.raises(ConfigValueError) as info:
        RabbitmqDriver().render_config(SPEC, tmp_path, (Bridge(),))  # type: ignore[arg-type]
    assert info.value.field == "bridges"


def test_routing_keys_turn_slashes_into_dots() -> None:
    assert amqp.routing_key("cell/robot.pose") == "cell.robot.pose"


def test_health_is_false_when_nothing_listens() -> None:
    assert RabbitmqDriver().health(replace(SPEC, port=1), 0.5) is False


def test_essence_is_kind_host_ports() -> None:
    assert RabbitmqDriver().essence(SPEC) == {"kind": "rabbitmq", "host": "127.0.0.1", "port": 5672,
                                              "mqtt_port": 1884}

"""The bridge worker's config file: a round trip, and every refusal names its field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.bridge_worker.__main__ import main as worker_main
from engine.bridge_worker.config import Direction, KeyMode, Route, WorkerConfig
from engine.errors import ConfigValueError


def config(**changes: object) -> WorkerConfig:
    values: dict[str, object] = dict(
        bridge_id="mqtt1.kafka1", mqtt_host="127.0.0.2", mqtt_port=1883, kafka_bootstrap="127.0.0.3:9092",
        routes=(Route("cell/temp", "cell.temp", Direction.MQTT_TO_KAFKA),
                Route("cell/cmd", "cell.cmd", Direction.KAFKA_TO_MQTT, qos=0, key=KeyMode.NONE)),
        state_dir=Path("/var/lib/plantkg/bridge"),
    )
    values.update(changes)
    return WorkerConfig(**values)  # type: ignore[arg-type]


def as_json(**changes: object) -> dict[str, object]:
    data = json.loads(config().to_json())
    data.update(changes)
    return data


def refused(text: str) -> ConfigValueError:
    with pytest.raises(ConfigValueError) as info:
        WorkerConfig.from_json(text)
    return info.value


def test_round_trip() -> None:
    cfg = config(stats_interval=0.25)
    back = WorkerConfig.from_json(cfg.to_json())
    assert back == cfg
    assert back.routes[0].direction is Direction.MQTT_TO_KAFKA and back.routes[1].key is KeyMode.NONE
    assert back.client_id == back.group_id == "plantkg-bridge-mqtt1.kafka1"


def test_defaults_of_a_route() -> None:
    data = as_json(routes=[{"mqtt_topic": "a/b", "kafka_topic": "a.b", "direction": "kafka-to-mqtt"}])
    (route,) = WorkerConfig.from_json(json.dumps(data)).routes
    assert (route.qos, route.key) == (1, KeyMode.MQTT_TOPIC)


def test_ipv6_bootstrap_is_accepted() -> None:
    assert config(kafka_bootstrap="[::1]:9092,127.0.0.1:9093").kafka_bootstrap.startswith("[::1]")


@pytest.mark.parametrize("field", ["bridge_id", "mqtt_host", "mqtt_port", "kafka_bootstrap", "routes", "state_dir"])
def test_missing_field_is_named(field: str) -> None:
    data = as_json()
    del data[field]
    assert refused(json.dumps(data)).field == field


def test_unknown_field_is_named() -> None:
    assert refused(json.dumps(as_json(colour="red"))).field == "colour"


def test_unknown_route_field_is_named() -> None:
    route = {"mqtt_topic": "a", "kafka_topic": "a", "direction": "mqtt-to-kafka", "retain": True}
    assert refused(json.dumps(as_json(routes=[route]))).field == "retain"


def test_missing_route_field_is_named() -> None:
    assert refused(json.dumps(as_json(routes=[{"mqtt_topic": "a", "kafka_topic": "a"}]))).field == "direction"


@pytest.mark.parametrize(("field", "value"), [
    ("bridge_id", ""), ("bridge_id", "a b"), ("bridge_id", 7),
    ("mqtt_host", "localhost"), ("mqtt_host", "1.2.3"),
    ("mqtt_port", 0), ("mqtt_port", "1883"), ("mqtt_port", True),
    ("kafka_bootstrap", ""), ("kafka_bootstrap", "127.0.0.1"), ("kafka_bootstrap", "kafka:9092"),
    ("kafka_bootstrap", "127.0.0.1:99999"), ("kafka_bootstrap", "127.0.0.1:x"),
    ("routes", []), ("routes", {}),
    ("state_dir", "relative/dir"), ("state_dir", "/a\nb"), ("state_dir", 3),
    ("stats_interval", 0), ("stats_interval", "1"), ("stats_interval", 3600), ("stats_interval", False),
])
def test_bad_value_is_named(field: str, value: object) -> None:
    assert refused(json.dumps(as_json(**{field: value}))).field == field


def route(**changes: object) -> dict[str, object]:
    return {"mqtt_topic": "cell/temp", "kafka_topic": "cell.temp", "direction": "mqtt-to-kafka", **changes}


@pytest.mark.parametrize(("field", "changes"), [
    ("mqtt_topic", {"mqtt_topic": ""}), ("mqtt_topic", {"mqtt_topic": "cell/+"}),
    ("mqtt_topic", {"mqtt_topic": "cell/#"}), ("mqtt_topic", {"mqtt_topic": "$SYS/x"}),
    ("mqtt_topic", {"mqtt_topic": "a\0b"}), ("mqtt_topic", {"mqtt_topic": 5}),
    ("kafka_topic", {"kafka_topic": "cell/temp"}), ("kafka_topic", {"kafka_topic": ".."}),
    ("kafka_topic", {"kafka_topic": "x" * 250}), ("kafka_topic", {"kafka_topic": ""}),
    ("direction", {"direction": "out"}), ("key", {"key": "partition"}),
    ("qos", {"qos": 2}), ("qos", {"qos": True}), ("qos", {"qos": "1"}),
])
def test_bad_route_value_is_named(field: str, changes: dict[str, object]) -> None:
    assert refused(json.dumps(as_json(routes=[route(**changes)]))).field == field


def test_a_route_twice_is_refused() -> None:
    assert refused(json.dumps(as_json(routes=[route(), route()]))).field == "routes"


def test_one_mqtt_topic_to_two_kafka_topics_is_refused() -> None:
    assert refused(json.dumps(as_json(routes=[route(), route(kafka_topic="other")]))).field == "routes"


def test_both_ways_on_one_topic_pair_is_allowed() -> None:
    data = as_json(routes=[route(), route(direction="kafka-to-mqtt")])
    assert len(WorkerConfig.from_json(json.dumps(data)).routes) == 2


@pytest.mark.parametrize("text", ["not json", "[1, 2]", "null"])
def test_not_a_json_object_is_refused(text: str) -> None:
    assert refused(text).field == "worker.json"


def test_direct_construction_checks_too() -> None:
    with pytest.raises(ConfigValueError) as info:
        config(routes=[Route("a", "a", Direction.MQTT_TO_KAFKA)])  # a list, not a tuple
    assert info.value.field == "routes"


def test_the_process_exits_2_with_one_line_naming_the_field(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "worker.json"
    path.write_text(json.dumps(as_json(mqtt_port=70000)))
    assert worker_main([str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "mqtt_port=70000" in err


def test_a_missing_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert worker_main([str(tmp_path / "absent.json")]) == 2
    assert "cannot be read" in capsys.readouterr().err

"""``plantkg demo`` makes the passwords its plant's resources need (engine.demo.run.make_demo_secrets)."""

from __future__ import annotations

import pytest

from pathlib import Path

from engine.demo.run import feeds, make_demo_secrets, secret_refs
from engine.pipeline import run_pipeline
from engine.model import BrokerSpec
from engine.demo.simulate import Feed

ROBOT_CELL = Path(__file__).resolve().parents[2] / "ontology" / "examples" / "robot-cell.ttl"
BROKER = BrokerSpec(id="m", iri="urn:m", name="m", kind="mosquitto", host="127.0.0.1", port=1883)


def feed(ref: str | None, user: str = "r") -> Feed:
    return Feed("Robot", "t", "position", BROKER, user=user, secret_ref=ref)


def test_unset_environment_references_get_a_random_password_and_others_are_left_alone() -> None:
    env = {"ALREADY": "kept"}
    made = make_demo_secrets(["env:NEW", "env:NEW", "env:ALREADY", "file:/etc/plantkg/r.pw", None], env)
    assert made == ["NEW"] and env["ALREADY"] == "kept"
    assert len(env["NEW"]) >= 32
    make_demo_secrets(["env:OTHER"], env)
    assert env["OTHER"] != env["NEW"]


def test_a_reader_of_the_example_plant_gets_a_password_too() -> None:
    """The robot cell's historian only subscribes (no feed of the demo publishes as it), but the
    Kafka agent needs its password to set its SCRAM user: ``make demo`` on a fresh machine failed
    with 'PLANTKG_HISTORIAN_PASSWORD is not set'. Every broker user's reference counts."""
    desired = run_pipeline([str(ROBOT_CELL)], None, observe=False).desired
    assert desired is not None
    refs = secret_refs(desired, feeds([str(ROBOT_CELL)]))
    users = {u.secret_ref for b in desired.brokers for u in b.users if u.secret_ref}
    assert "env:PLANTKG_HISTORIAN_PASSWORD" in users and users <= set(refs)
    env: dict[str, str] = {}
    assert "PLANTKG_HISTORIAN_PASSWORD" in make_demo_secrets(refs, env)


def test_a_resource_logs_in_with_the_secret_its_reference_names(monkeypatch: pytest.MonkeyPatch) -> None:
    env: dict[str, str] = {}
    make_demo_secrets(["env:PLANTKG_TEST_DEMO_PW"], env)
    monkeypatch.setenv("PLANTKG_TEST_DEMO_PW", env["PLANTKG_TEST_DEMO_PW"])  # Feed.login reads it here
    login = feed("env:PLANTKG_TEST_DEMO_PW", user="ros-machine").login()
    assert login is not None and (login.username, login.password) == ("ros-machine", env["PLANTKG_TEST_DEMO_PW"])
    assert env["PLANTKG_TEST_DEMO_PW"] not in repr(login)
    assert feed(None).login() is None


def test_a_kafka_resource_logs_in_with_scram_only_where_the_kafka_is_closed(monkeypatch: pytest.MonkeyPatch) -> None:
    from dataclasses import replace  # noqa: PLC0415

    from engine.demo.simulate import kafka_login  # noqa: PLC0415
    monkeypatch.setenv("PLANTKG_TEST_DEMO_KAFKA_PW", "s3cret-of-the-pi")
    kafka = replace(BROKER, kind="kafka", port=9092, allow_anonymous=False)
    pi = Feed("Pi", "energy", "energy", kafka, user="raspberry-pi", secret_ref="env:PLANTKG_TEST_DEMO_KAFKA_PW")
    assert kafka_login(pi) == {"security.protocol": "sasl_plaintext", "sasl.mechanism": "SCRAM-SHA-512",
                               "sasl.username": "raspberry-pi", "sasl.password": "s3cret-of-the-pi"}
    assert kafka_login(replace(pi, broker=replace(kafka, allow_anonymous=True))) == {}  # open: anonymous
    assert kafka_login(replace(pi, secret_ref=None, user=None)) == {}  # no secret: refused by the broker

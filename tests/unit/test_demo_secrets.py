"""``plantkg demo`` makes the passwords its plant's resources need (engine.demo.run.make_demo_secrets)."""

from __future__ import annotations

import pytest

from engine.demo.run import make_demo_secrets
from engine.model import BrokerSpec
from engine.demo.simulate import Feed

BROKER = BrokerSpec(id="m", iri="urn:m", name="m", kind="mosquitto", host="127.0.0.1", port=1883)


def feed(ref: str | None, user: str = "r") -> Feed:
    return Feed("Robot", "t", "position", BROKER, user=user, secret_ref=ref)


def test_unset_environment_references_get_a_random_password_and_others_are_left_alone() -> None:
    env = {"ALREADY": "kept"}
    made = make_demo_secrets([feed("env:NEW"), feed("env:NEW"), feed("env:ALREADY"),
                              feed("file:/etc/plantkg/r.pw"), feed(None)], env)
    assert made == ["NEW"] and env["ALREADY"] == "kept"
    assert len(env["NEW"]) >= 32
    make_demo_secrets([feed("env:OTHER")], env)
    assert env["OTHER"] != env["NEW"]


def test_a_resource_logs_in_with_the_secret_its_reference_names(monkeypatch: pytest.MonkeyPatch) -> None:
    env: dict[str, str] = {}
    make_demo_secrets([feed("env:PLANTKG_TEST_DEMO_PW")], env)
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

"""engine.security.kafka_client: what plantkg's own Kafka clients send a closed Kafka."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.drivers.kafka.runtime import KafkaNodeConfig
from engine.model import BrokerSpec, BrokerUser
from engine.security import kafka_client, principal_key

KF = BrokerSpec("kf", "urn:kf", "kf", "kafka", "127.0.0.3", 9092)


def test_the_password_comes_from_the_principal_key_and_fits_the_jaas_line(tmp_path: Path) -> None:
    one, other = tmp_path / "one", tmp_path / "other"
    password = kafka_client.password(one)
    assert password == kafka_client.password(one)  # every machine holding the key agrees
    assert password != kafka_client.password(other)
    assert len(password) == 64 and int(password, 16) >= 0
    assert principal_key.password_for(kafka_client.PRINCIPAL, one) not in password
    KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data", internal_password=password)  # accepted


@pytest.mark.parametrize(("spec", "closed"), [
    (KF, False),                                                     # a spec nobody closed: open
    (BrokerSpec(**{**KF.__dict__, "allow_anonymous": False}), True),  # closed by default (derive)
    (BrokerSpec(**{**KF.__dict__, "allow_anonymous": True}), False),  # the plant opened it
    (BrokerSpec(**{**KF.__dict__, "users": (BrokerUser("u", "env:U"),)}), True),
    (BrokerSpec("mq", "urn:mq", "mq", "mosquitto", "127.0.0.2", 1883, allow_anonymous=False), False),
])
def test_which_kafka_is_closed(spec: BrokerSpec, closed: bool) -> None:
    assert kafka_client.is_closed(spec) is closed


def test_client_settings_by_listener(tmp_path: Path) -> None:
    assert kafka_client.client_settings(False) == {}
    sasl = kafka_client.client_settings(True)
    assert sasl == {"security.protocol": "sasl_plaintext", "sasl.mechanism": "PLAIN",
                    "sasl.username": "plantkg", "sasl.password": kafka_client.password()}
    ca_file = tmp_path / "ca.pem"
    tls = kafka_client.client_settings(False, True, ca_file)
    assert tls == {"security.protocol": "ssl", "ssl.ca.location": str(ca_file),
                   "ssl.endpoint.identification.algorithm": "https"}
    both = kafka_client.client_settings(True, True, ca_file)
    assert both["security.protocol"] == "sasl_ssl" and both["sasl.username"] == "plantkg"


def test_login_settings_from_a_password_held_without_the_key(tmp_path: Path) -> None:
    """A mirror worker reads plantkg's password from a file: the same settings, that password."""
    assert kafka_client.login_settings(None, None) == {}
    assert kafka_client.login_settings("ab" * 32, None) == {
        "security.protocol": "sasl_plaintext", "sasl.mechanism": "PLAIN", "sasl.username": "plantkg",
        "sasl.password": "ab" * 32}
    assert kafka_client.login_settings("ab" * 32, tmp_path / "ca.pem")["security.protocol"] == "sasl_ssl"

"""Where the context broker's kafka:// notifications log in as plantkg (engine.context_broker.subscriptions.kafka):
only at the plant's closed Kafka brokers it was told (``--closed-kafka``), matched by address; and
where they speak TLS: at the plant's Kafka brokers it was told speak it (``--tls-kafka``)."""

from __future__ import annotations

import pytest

from engine.context_broker.subscriptions.kafka import KafkaSender, bootstrap_addresses
from engine.context_broker.subscriptions.model import PlantKafkas

CLOSED = frozenset({("127.0.0.4", 9092), ("::1", 9093)})


def test_a_bootstrap_list_is_its_addresses_normalised() -> None:
    assert bootstrap_addresses("127.0.0.4:9092,[0:0::1]:9093,Kafka.Local:9094") == {
        ("127.0.0.4", 9092), ("::1", 9093), ("kafka.local", 9094)}
    assert bootstrap_addresses("::1:9093") == {("::1", 9093)}  # parse_targets joins IPv6 hosts unbracketed


@pytest.mark.parametrize(("bootstrap", "logs_in"), [
    ("127.0.0.4:9092", True),
    ("127.0.0.9:9092,127.0.0.4:9092", True),   # one of its addresses is the plant's closed Kafka
    ("::1:9093", True),
    ("127.0.0.4:9093", False),                 # another port: not the plant's Kafka
    ("127.0.0.5:9092", False),                 # another Kafka: no credentials sent there
    ("localhost:9092", False),                 # named otherwise than the plant names it
])
def test_it_logs_in_only_at_the_plants_closed_kafkas(bootstrap: str, logs_in: bool) -> None:
    assert KafkaSender(PlantKafkas(closed=CLOSED)).logs_in(bootstrap) is logs_in
    assert KafkaSender(PlantKafkas(tls=CLOSED)).logs_in(bootstrap) is False  # TLS alone: no login
    assert KafkaSender().logs_in(bootstrap) is False  # told none: every Kafka anonymous, as before


@pytest.mark.parametrize(("bootstrap", "tls"), [
    ("127.0.0.4:9092", True),
    ("127.0.0.9:9092,127.0.0.4:9092", True),
    ("127.0.0.4:9093", False),
    ("localhost:9092", False),
])
def test_it_speaks_tls_only_to_the_plants_tls_kafkas(bootstrap: str, tls: bool) -> None:
    assert KafkaSender(PlantKafkas(tls=CLOSED)).speaks_tls(bootstrap) is tls
    assert KafkaSender(PlantKafkas(closed=CLOSED)).speaks_tls(bootstrap) is False

"""The Kafka driver lets go of its AdminClient when a topic call ends, even a failed one whose
error the caller keeps (an agent records errors): a client kept alive by that error's traceback
went on reconnecting every second to a cluster deleted since (seen in an agent's log after
``plantkg destroy`` of a 3-node cluster). No broker here: the client is a stand-in whose lifetime
a weak reference watches, with the cyclic garbage collector off so only references count."""

from __future__ import annotations

import gc
import weakref
from concurrent.futures import Future
from collections.abc import Iterator

import pytest
from confluent_kafka import KafkaError, KafkaException

from engine.drivers.kafka import driver as kafka_driver
from engine.drivers.kafka.topics import Topics
from engine.errors import DriverError
from engine.model import BrokerSpec, TopicSpec


def refused(what: str) -> KafkaException:
    return KafkaException(KafkaError(KafkaError._TRANSPORT, f"{what}: connection refused"))


class DownAdmin:
    """An AdminClient whose brokers do not answer, failing as confluent-kafka's does: a direct
    call raises, a request's futures fail."""

    def list_topics(self, timeout: float) -> object:
        raise refused("list_topics")

    def delete_topics(self, names: list[str], **_kwargs: object) -> dict[str, Future[None]]:
        futures: dict[str, Future[None]] = {}
        for name in names:
            futures[name] = Future()
            futures[name].set_exception(refused("delete_topics"))
        return futures


@pytest.fixture
def no_gc() -> Iterator[None]:
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


@pytest.fixture
def admins(monkeypatch: pytest.MonkeyPatch) -> list[weakref.ref[DownAdmin]]:
    made: list[weakref.ref[DownAdmin]] = []

    def fake_admin(spec: BrokerSpec, **_kwargs: object) -> DownAdmin:
        admin = DownAdmin()
        made.append(weakref.ref(admin))
        return admin

    monkeypatch.setattr(kafka_driver, "_admin", fake_admin)
    return made


def spec() -> BrokerSpec:
    return BrokerSpec(id="k1", iri="https://example.org/plant#k1", name="k1", kind="kafka",
                      host="127.0.0.3", port=19092)


@pytest.mark.parametrize("call", [
    lambda d: d.observe_topics(spec()),
    lambda d: d.ensure_topic(spec(), TopicSpec(broker_id="k1", iri="https://example.org/plant#t", name="t")),
    lambda d: d.delete_topic(spec(), "t"),
], ids=["observe", "ensure", "delete"])
def test_a_failed_topic_call_does_not_keep_its_client(call, admins, no_gc) -> None:
    driver = kafka_driver.KafkaDriver(admin_timeout=0.2)
    with pytest.raises(DriverError) as raised:
        call(driver)
    kept = raised.value  # what an agent does with the error: it keeps it
    assert kept.__traceback__ is not None
    assert admins, "the driver made no client"
    assert all(ref() is None for ref in admins), "a client outlived the call that failed"


def test_a_closed_topics_says_it_is_closed() -> None:
    admin = DownAdmin()
    with Topics(admin, 1.0) as topics:  # type: ignore[arg-type]
        pass
    with pytest.raises(RuntimeError, match="after close"):
        topics.observe()

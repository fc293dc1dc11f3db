"""The Kafka driver package: the driver (:mod:`.driver`), and the KRaft runtime it uses — config
rendering, storage format and the broker's command line (:mod:`.runtime`)."""

from engine.drivers.kafka.driver import KafkaDriver

__all__ = ["KafkaDriver"]

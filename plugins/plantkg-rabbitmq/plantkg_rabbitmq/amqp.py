"""Talk AMQP 0-9-1 to a node with pika: the health check and the topics (queues).

A plantkg topic on a RabbitMQ broker is a durable queue of the same name, bound to the
``amq.topic`` exchange with the routing key the MQTT plugin gives that topic (MQTT's ``/`` is
AMQP's ``.``), so what an MQTT client (or a Mosquitto bridge) publishes to ``cell/pose``
waits in queue ``cell/pose`` for AMQP consumers. Everything goes through AMQP — no management
plugin, no rabbitmqctl (a second Erlang VM per call). The node lets ``guest`` in over loopback only.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

import pika
from pika.adapters.blocking_connection import BlockingChannel
from pika.exceptions import AMQPError, ChannelClosedByBroker

from engine import netutil
from engine.errors import BrokerUnavailableError, DriverError, DriverRefusedError

EXCHANGE = "amq.topic"
#: AMQP reply codes (AMQP 0-9-1 section 1.9).
NOT_FOUND = 404
PRECONDITION_FAILED = 406

T = TypeVar("T")

# pika logs every refused connection attempt at ERROR; a health poll expects refusals.
logging.getLogger("pika").setLevel(logging.CRITICAL)


def routing_key(topic: str) -> str:
    """The routing key RabbitMQ 3.10's MQTT plugin publishes ``topic`` with: each ``/`` becomes
    ``.`` (a ``.`` stays, so ``a/b`` and ``a.b`` share a key; seen on a real node, see
    tests/test_rabbitmq_node.py)."""
    return topic.replace("/", ".")


def parameters(host: str, port: int, timeout: float) -> pika.ConnectionParameters:
    return pika.ConnectionParameters(
        host=host, port=port, credentials=pika.PlainCredentials("guest", "guest"),
        connection_attempts=1, socket_timeout=timeout, stack_timeout=timeout,
        blocked_connection_timeout=timeout, heartbeat=0,
    )


def answers(host: str, port: int, timeout: float) -> bool:
    """An AMQP connection opens (protocol header, Start/Tune/Open) within ``timeout`` s."""
    if not netutil.port_open(host, port, timeout=min(timeout, 0.5)):
        return False
    try:
        connection = pika.BlockingConnection(parameters(host, port, max(timeout, 0.1)))
    except (AMQPError, OSError):
        return False
    try:
        return connection.is_open
    finally:
        _close(connection)


@contextmanager
def channel(host: str, port: int, timeout: float = 5.0) -> Iterator[BlockingChannel]:
    """A channel on a fresh connection; BrokerUnavailableError if the node does not answer."""
    try:
        connection = pika.BlockingConnection(parameters(host, port, timeout))
    except (AMQPError, OSError) as exc:
        raise BrokerUnavailableError(f"RabbitMQ at {host}:{port} does not answer AMQP: "
                                     f"{type(exc).__name__} {exc}") from None
    try:
        yield connection.channel()
    finally:
        _close(connection)


def declare_topic(host: str, port: int, name: str) -> None:
    """Declare the durable queue ``name`` and bind it to ``amq.topic`` (idempotent)."""
    def do(ch: BlockingChannel) -> None:
        ch.queue_declare(queue=name, durable=True)
        ch.queue_bind(queue=name, exchange=EXCHANGE, routing_key=routing_key(name))
    _call(host, port, f"declare queue {name!r}", do)


def delete_topic(host: str, port: int, name: str) -> None:
    """Delete queue ``name``; an absent queue is nothing to do."""
    def do(ch: BlockingChannel) -> None:
        ch.queue_delete(queue=name)
    _call(host, port, f"delete queue {name!r}", do, absent_ok=True)


def queue_exists(host: str, port: int, name: str) -> bool:
    """A passive declare: True if queue ``name`` exists."""
    def do(ch: BlockingChannel) -> bool:
        ch.queue_declare(queue=name, passive=True)
        return True
    return bool(_call(host, port, f"look up queue {name!r}", do, absent_ok=True))


def _call(host: str, port: int, what: str, fn: Callable[[BlockingChannel], T],
          *, absent_ok: bool = False) -> T | None:
    with channel(host, port) as ch:
        try:
            return fn(ch)
        except ChannelClosedByBroker as exc:
            if exc.reply_code == NOT_FOUND and absent_ok:
                return None
            if exc.reply_code == PRECONDITION_FAILED:
                raise DriverRefusedError(f"RabbitMQ refused to {what}: {exc.reply_text}; the "
                                         "queue exists with other settings, delete it first") from None
            raise DriverError(f"RabbitMQ refused to {what}: {exc.reply_code} {exc.reply_text}") from None
        except (AMQPError, OSError) as exc:
            raise BrokerUnavailableError(f"RabbitMQ at {host}:{port}: {what} failed: "
                                         f"{type(exc).__name__} {exc}") from None


def _close(connection: pika.BlockingConnection) -> None:
    try:
        if connection.is_open:
            connection.close()
    except (AMQPError, OSError):
        pass

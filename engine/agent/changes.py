"""What the agent does for each change a client asks for, with no HTTP around it.

The single routes (``PUT /v1/brokers/<id>`` ...) and the batch (``POST /v1/batch``,
:mod:`engine.agent.batch`) call the same functions, so a change means the same whichever way it
came, and both answer an error with the same status (:func:`error_status`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

from engine.agent.manager import (
    BridgeConflictError,
    BrokerManager,
    BrokerNotFoundError,
    BrokerNotRunningError,
)
from engine.agent.owners import OwnershipConflictError
from engine.agent.wire import WireError
from engine.agent.workers import WorkerManager
from engine.errors import (
    BrokerUnavailableError,
    ConfigValueError,
    DriverRefusedError,
    EngineError,
    UnknownDriverError,
)
from engine.model import (
    BridgeMechanism,
    BridgeSpec,
    BrokerSpec,
    ObservedBridge,
    ObservedBroker,
    ObservedTopic,
    TopicSpec,
)

log = logging.getLogger(__name__)

#: The bridge PUT's transport field carrying the remote (context broker's) token; not a spec field.
REMOTE_TOKEN = "remote_token"
MAX_TOKEN = 4096


def check_remote_token(value: Any, mechanism: BridgeMechanism, where: str = REMOTE_TOKEN) -> str | None:
    """A bridge PUT's ``remote_token`` (None if absent): the remote broker's agent token, which only
    an mqtt-ngsi bridge (a context broker's write token) takes. A worker into a closed Kafka takes
    none: its agent derives plantkg's password there from the principal key (``BridgeEnd.closed``)."""
    if value is None:
        return None
    if mechanism is not BridgeMechanism.NGSI:
        raise WireError(where, f"only an mqtt-ngsi bridge takes one, not {mechanism.value}")
    if not isinstance(value, str) or not value.strip() or not value.isprintable() or len(value) > MAX_TOKEN:
        raise WireError(where, f"must be a non-empty printable string of at most {MAX_TOKEN} characters")
    return value.strip()


@dataclass(frozen=True)
class Changes:
    """The agent's brokers and bridge workers (None: this agent refuses worker bridges)."""

    brokers: BrokerManager
    workers: WorkerManager | None = None

    def put_broker(self, spec: BrokerSpec, owner: str | None) -> ObservedBroker:
        return self.brokers.put(spec, owner)

    def put_brokers(self, requests: list[tuple[BrokerSpec, str | None]]) -> list[ObservedBroker | Exception]:
        """:meth:`put_broker` for many (distinct ids) at once; each its answer or its error."""
        return self.brokers.put_many(requests)

    def delete_broker(self, broker_id: str, owner: str | None) -> None:
        """Stop the broker; the bridge workers it carries go with it."""
        (error,) = self.delete_brokers([(broker_id, owner)])
        if error is not None:
            raise error

    def delete_brokers(self, requests: list[tuple[str, str | None]]) -> list[Exception | None]:
        """:meth:`delete_broker` for many (distinct ids) at once (every broker gets SIGTERM before
        any is waited for); each its error (None: deleted)."""
        errors = self.brokers.delete_many(requests)
        if self.workers is None:
            return errors
        for i, (broker_id, _) in enumerate(requests):
            if errors[i] is not None:
                continue
            try:
                for bridge in self.workers.list():
                    if bridge.spec.local.id == broker_id:
                        self.workers.delete(broker_id, bridge.spec.remote.id)
            except Exception as exc:  # noqa: BLE001 - this broker's own error
                errors[i] = exc
        return errors

    def put_topic(self, topic: TopicSpec, owner: str | None) -> ObservedTopic:
        return self.brokers.put_topic(topic, owner)

    def delete_topic(self, broker_id: str, name: str, owner: str | None) -> None:
        self.brokers.delete_topic(broker_id, name, owner)

    def put_bridge(self, spec: BridgeSpec, owner: str | None, remote_token: str | None) -> ObservedBridge:
        """In the local broker's own config (Mosquitto) or as a worker; ``remote_token`` (mqtt-ngsi,
        or mqtt-kafka into a closed Kafka; checked by the caller) is kept in the worker's folder."""
        if spec.mechanism is BridgeMechanism.MOSQUITTO:
            return self.brokers.put_native_bridge(spec, owner)
        broker_id = spec.local.id
        local = self.brokers.get(broker_id)
        if local is None:
            raise BrokerNotFoundError(broker_id)
        if owner is not None and local.owner not in (None, owner):
            raise OwnershipConflictError(f"broker {broker_id!r} is owned by plant {local.owner!r}, "
                                         f"not by {owner!r}",
                                         hint="a plant changes only its own things")
        if (local.spec.host, local.spec.port) != (spec.local.host, spec.local.port):
            raise BridgeConflictError(f"{spec.address}: its local end is not broker {broker_id!r} here",
                                      hint="PUT the broker first, then its bridges")
        if self.workers is None:
            raise EngineError("this agent runs no bridge workers", hint="start it with `plantkg agent`")
        owned = {"owner": owner} if owner is not None else {}  # WorkerManager.put's keyword
        return self.workers.put(spec, remote_token, **owned)

    def delete_bridge(self, local: str, remote: str, owner: str | None) -> None:
        if not self.brokers.delete_native_bridge(local, remote, owner) and self.workers is not None:
            self.workers.delete(local, remote, owner)


#: Error type -> HTTP status, most specific first.
_STATUS: tuple[tuple[type[BaseException], int], ...] = (
    (WireError, 400),
    (ConfigValueError, 400),
    (BrokerNotFoundError, 404),
    (DriverRefusedError, 409),
    (BridgeConflictError, 409),
    (OwnershipConflictError, 409),
    (BrokerNotRunningError, 409),
    (UnknownDriverError, 422),
    (BrokerUnavailableError, 503),
    (EngineError, 422),
)


def error_status(exc: BaseException, what: str) -> tuple[int, dict[str, Any]]:
    """The status and JSON error body ``{"error", "hint", "retryable", "field"?}`` of ``exc``
    raised while doing ``what`` (for the log); 500 for anything that is not an EngineError."""
    for cls, status in _STATUS:
        if isinstance(exc, cls):
            assert isinstance(exc, EngineError)
            if status >= 422 or status == 409:
                log.warning("%s -> %d: %s", what, status, exc.message)
            return status, error_body(exc.message, exc.hint, retryable=status == 503,
                                      field=getattr(exc, "field", None))
    log.error("%s failed", what, exc_info=exc)
    return 500, error_body(f"internal error: {type(exc).__name__}: {exc}",
                           "see the agent's log; this is a bug in plantkg", retryable=True)


def error_body(message: str, hint: str | None, *, retryable: bool, field: str | None = None) -> dict[str, Any]:
    body: dict[str, Any] = {"error": message, "hint": hint, "retryable": retryable}
    if field is not None:
        body["field"] = field
    return body

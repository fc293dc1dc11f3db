"""Typed errors of the engine layer.

They derive from :class:`kg.errors.PlantKGError`, so the CLI handles every user-facing error the
same way: print the message and the hint, exit with the error's code, no traceback.
"""

from __future__ import annotations

from kg.errors import PlantKGError


class EngineError(PlantKGError):
    """Base of every error the engine raises on purpose."""


class PartMissingError(EngineError):
    """A real part (a broker binary, Java, the Kafka jars) is not installed where we look."""

    def __init__(self, part: str, looked_in: str) -> None:
        super().__init__(
            f"{part} not found (looked in {looked_in})",
            hint="run `make setup` in the plantkg checkout; it installs the missing parts",
        )
        self.part = part
        self.looked_in = looked_in


class MosquittoMissingError(PartMissingError):
    """No ``mosquitto`` executable on PATH nor in /usr/sbin."""


class JavaMissingError(PartMissingError):
    """No ``java`` executable on PATH nor under JAVA_HOME."""


class KafkaMissingError(PartMissingError):
    """No Kafka jars in the Kafka home (``.plantkg/kafka/<version>`` or PLANTKG_KAFKA_HOME)."""


class ProcessError(EngineError):
    """A child process could not be started, or exited while we waited for it."""


class WaitTimeoutError(EngineError):
    """A condition polled with a deadline did not become true in time."""

    def __init__(self, what: str, timeout: float, detail: str = "") -> None:
        text = f"timed out after {timeout:.1f} s waiting for {what}"
        super().__init__(f"{text}: {detail}" if detail else text)
        self.what = what
        self.timeout = timeout


class ConfigValueError(EngineError, ValueError):
    """A value refused before it reaches a rendered config file (port, host, path, ...)."""

    def __init__(self, field: str, value: object, problem: str) -> None:
        super().__init__(f"{field}={value!r}: {problem}", hint=f"give {field} a valid value")
        self.field = field
        self.value = value
        self.problem = problem


class DispatchError(EngineError):
    """Sending a change to an agent failed."""

    retryable = False

    def __init__(self, message: str, *, hint: str | None = None, host: str | None = None) -> None:
        super().__init__(message, hint=hint)
        self.host = host


class TemporaryDispatchError(DispatchError):
    """Worth retrying with backoff: connection refused, timeout, 503, a broker still starting."""

    retryable = True


class PermanentDispatchError(DispatchError):
    """Retrying will not help: the agent refused the request or the driver failed for good."""


class AgentAuthError(PermanentDispatchError):
    """The agent answered 401: the token is missing or wrong."""


class UnknownDriverError(EngineError):
    """No driver is registered (entry-point group ``plantkg.drivers``) for a broker kind."""

    def __init__(self, kind: str, known: list[str]) -> None:
        super().__init__(
            f"no driver for broker kind {kind!r} (installed: {', '.join(known) or 'none'})",
            hint="install the package that provides this driver on the agent's machine, "
            "or correct pk:brokerType",
        )
        self.kind = kind


class DriverError(EngineError):
    """A driver could not do what was asked; ``retryable`` says whether trying again may help."""

    retryable = False


class DriverRefusedError(DriverError):
    """The broker cannot make this change (fewer Kafka partitions, another replication factor);
    permanent: the plant must change."""


class BrokerUnavailableError(DriverError):
    """The broker did not answer in time (down, still starting, restarting): worth retrying."""

    retryable = True


class AccessNotSpreadError(BrokerUnavailableError):
    """A node of a closed Kafka cluster does not enforce yet the users and ACLs set through its
    lead (engine.drivers.kafka.spread): the node takes them from the cluster's metadata log, so
    it may only be slow or restarting; retryable."""

    def __init__(self, cluster: str, node: str, lacks: tuple[str, ...], timeout: float, *,
                 others: tuple[str, ...] = ()) -> None:
        shown = "; ".join(lacks[:5]) + (f"; and {len(lacks) - 5} more" if len(lacks) > 5 else "")
        also = f" (nor yet node(s) {', '.join(others)})" if others else ""
        super().__init__(
            f"Kafka cluster {cluster!r}: node {node} does not enforce the plant's users and ACLs "
            f"{timeout:.0f} s after they were set through the lead node: it {shown}{also}",
            hint="that node applies them from the cluster's metadata log: check that it runs and "
            f"follows the quorum (`plantkg status`, its kafka.log), then apply again",
        )
        self.cluster = cluster
        self.node = node
        self.lacks = lacks

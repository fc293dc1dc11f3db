"""What one of plantkg's own Kafka clients sends a closed Kafka to log in (docs/security.md).

A Kafka broker of its own is closed unless the plant says ``pk:allowAnonymous true``
(engine.derived.access): every listener is SASL, and plantkg's own clients (the driver's
AdminClient, the bridge workers, ``plantkg check``'s taps and probes, the dashboard's rates, the
demo's taps) log in as plantkg's Kafka principal ``plantkg``, a super user authenticated with
SASL/PLAIN. Its password is derived from the plant's principal key
(:mod:`engine.security.principal_key`) on the machine that needs it, like the MQTT principals'
(engine.security.mqtt_client): nothing secret travels in a spec, a plan or a request, and every
plantkg machine holding the key computes the same password.
"""

from __future__ import annotations

import hashlib
import hmac
from pathlib import Path
from typing import Any

from engine.model import BrokerSpec
from engine.security import principal_key

#: The Kafka user of plantkg's own clients (a super user of every closed Kafka).
USER = "plantkg"
#: The principal-key name its password is derived under.
PRINCIPAL = "plantkg.kafka"


def is_closed(spec: BrokerSpec) -> bool:
    """A Kafka whose listeners authenticate every client: one the engine closed (no
    ``pk:allowAnonymous true``: engine.derived.access) or that has users."""
    return spec.kind == "kafka" and (spec.allow_anonymous is False or bool(spec.users))


def internal_password(secret: str) -> str:
    """64 hex digits derived from ``secret`` (a JAAS-safe value that reveals nothing of it)."""
    return hmac.new(secret.encode("utf-8"), b"plantkg kafka internal principal", hashlib.sha256).hexdigest()


def password(key_path: Path | None = None) -> str:
    """plantkg's own password on every closed Kafka of the plant (the key loaded, or created)."""
    return internal_password(principal_key.password_for(PRINCIPAL, key_path))


def client_settings(closed: bool, tls: bool = False, ca_file: Path | None = None) -> dict[str, Any]:
    """librdkafka settings of one of plantkg's clients of a Kafka: SASL/PLAIN as ``plantkg`` when
    it is ``closed``, TLS trusting the plant CA only (the broker's address checked against its
    certificate) when it speaks TLS; nothing for an open, plain Kafka."""
    if tls and ca_file is None:
        from engine.security import ca  # noqa: PLC0415 - only for TLS: a bridge worker need not load cryptography
        ca_file = ca.ca_cert_file()
    return login_settings(password() if closed else None, ca_file if tls else None)


def login_settings(secret: str | None, ca_file: Path | None) -> dict[str, Any]:
    """librdkafka settings given plantkg's password (``secret``; None: the Kafka is open) and the
    plant CA's certificate file (None: the Kafka is plain), for a process that holds the password
    but not the principal key (a mirror worker reads it from a 0600 file its agent wrote)."""
    out: dict[str, Any] = {}
    if secret is not None:
        out |= {"sasl.mechanism": "PLAIN", "sasl.username": USER, "sasl.password": secret}
    if ca_file is not None:
        out |= {"ssl.ca.location": str(ca_file), "ssl.endpoint.identification.algorithm": "https"}
    if secret is not None or ca_file is not None:
        out["security.protocol"] = ("sasl_ssl" if ca_file else "sasl_plaintext") if secret else "ssl"
    return out

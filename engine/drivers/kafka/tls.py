"""TLS for a Kafka broker of its own or every node of a Kafka cluster (``pk:tls true`` on the
broker or on the cluster; docs/security.md, "TLS (Kafka)").

The node's listeners (client, inter-broker, controller) speak TLS only, with a certificate for its
address issued by its agent from the plant CA (engine.security.ca), the same way as a
Mosquitto's; a cluster's nodes each get their own, and verify each other against the plant CA.
Kafka 3.x reads PEM stores, so the broker folder holds:

- ``tls-keystore.pem`` (0600, like every rendered file): the broker's private key (unencrypted
  PKCS#8) followed by its certificate (``ssl.keystore.type=PEM``);
- ``tls-ca.pem``: the plant CA's certificate (``ssl.truststore.type=PEM``).

The key and certificate are kept while current (so re-rendering gives the same files and does not
restart the broker) and issued again when there is none, when the certificate expires within 30
days, names another address or was signed by another CA.

plantkg's own Kafka clients of such a broker or cluster (engine.security.kafka_client: the
driver's AdminClient and health check, the bridge workers, MirrorMaker 2, ``plantkg check``'s taps,
the context broker's ``kafka://`` notifications) speak TLS and verify the broker against the plant
CA only, address included.
"""

from __future__ import annotations

from pathlib import Path

from engine.drivers.kafka.runtime import KafkaTls
from engine.model import BrokerSpec
from engine.security import ca

TLS_CA_FILE = "tls-ca.pem"
TLS_KEYSTORE_FILE = "tls-keystore.pem"
_CERT_BEGIN = "-----BEGIN CERTIFICATE-----"


def node_tls(spec: BrokerSpec, broker_dir: Path) -> KafkaTls | None:
    """Where the node's TLS files are, for a ``tls`` spec; None for a plain one."""
    return KafkaTls(broker_dir / TLS_KEYSTORE_FILE, broker_dir / TLS_CA_FILE) if spec.tls else None


def split_keystore(text: str | None) -> tuple[bytes | None, bytes | None]:
    """(certificate PEM, key PEM) of a rendered keystore (None, None when absent or unreadable)."""
    if not text or _CERT_BEGIN not in text:
        return None, None
    at = text.index(_CERT_BEGIN)
    return text[at:].encode("ascii"), text[:at].encode("ascii")


def tls_files(spec: BrokerSpec, broker_dir: Path) -> dict[str, str]:
    """The CA certificate and the keystore of a ``tls`` broker (none for a plain one): the previous
    key and certificate while current, else new ones for the broker's address."""
    if not spec.tls:
        return {}
    authority = ca.load_or_create_ca(ca.ca_dir())
    old_cert, old_key = split_keystore(_read(broker_dir / TLS_KEYSTORE_FILE))
    cert, key = ca.current_server_cert(old_cert, old_key, authority, (spec.host,),
                                       name=f"plantkg broker {spec.id}")
    return {TLS_CA_FILE: ca.ca_pem(authority).decode("ascii"),
            TLS_KEYSTORE_FILE: key.decode("ascii") + cert.decode("ascii")}


def renewal(spec: BrokerSpec, broker_dir: Path) -> str | None:
    """Why the broker's certificate must be issued again (engine.security.ca.renewal_reason);
    None if current or the broker is plain."""
    if not spec.tls:
        return None
    cert, _key = split_keystore(_read(broker_dir / TLS_KEYSTORE_FILE))
    return ca.renewal_reason(cert, (spec.host,))


def _read(path: Path) -> str | None:
    try:
        return path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError):
        return None

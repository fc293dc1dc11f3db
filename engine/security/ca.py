"""The plant's certificate authority and the certificates it issues (docs/security.md, TLS).

One CA per plant: ``ca.pem`` (its certificate, public: every client that verifies a broker or an
agent needs it) and ``ca.key`` (its private key, mode 0600) in the CA folder. plantkg creates them
with the ``cryptography`` package the first time a certificate is needed (an EC P-256 key, ten
years); a plant that brings its own CA puts its certificate and key there instead (PEM, the key
unencrypted, 0600). Where the folder is: ``--ca-dir`` of ``plantkg agent`` (exported to its
brokers and workers as ``$PLANTKG_CA_DIR``), else ``$PLANTKG_CA_DIR``, else
``$XDG_STATE_HOME/plantkg/ca``. Like the principal key, the CA key is on every machine that
issues certificates (each agent issues its own brokers' and its API's): the plant's machines are
one trust domain.

:func:`current_server_cert` keeps a server certificate current (:func:`ensure_server_cert`: in
a folder): a new key and certificate (EC P-256, :data:`LIFETIME_DAYS`, the broker's IP address as subjectAltName, signed by
the CA) when there is none, when it expires within :data:`RENEW_BEFORE_DAYS`, when it names other
addresses, or when another CA signed it. Keys are written 0600; nothing is ever passed to openssl.
"""

from __future__ import annotations

import datetime as dt
import ipaddress
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from engine.errors import EngineError
from engine.security.locations import state_path
from engine.whole_file import create_once, write_whole

CA_ENV = "PLANTKG_CA_DIR"
CA_CERT = "ca.pem"
CA_KEY = "ca.key"
CERT_FILE = "cert.pem"
KEY_FILE = "key.pem"
CA_LIFETIME_DAYS = 3650
LIFETIME_DAYS = 90
RENEW_BEFORE_DAYS = 30
#: Seconds a process waits for the certificate of a CA another process is creating.
CREATE_WAIT = 10.0


class CaError(EngineError):
    """The plant CA's files are unusable (unreadable, not PEM, key readable by others)."""


@dataclass(frozen=True)
class Ca:
    """The loaded CA: its certificate and private key."""

    folder: Path
    cert: x509.Certificate
    key: ec.EllipticCurvePrivateKey

    @property
    def cert_file(self) -> Path:
        return self.folder / CA_CERT


def ca_dir(explicit: Path | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """The CA folder: ``explicit``, else ``$PLANTKG_CA_DIR``, else ``$XDG_STATE_HOME/plantkg/ca``."""
    return state_path("ca", CA_ENV, explicit, environ)


def ca_cert_file(explicit: Path | None = None) -> Path:
    """The CA certificate clients verify against (created with the CA if missing)."""
    return load_or_create_ca(ca_dir(explicit)).cert_file


def _now() -> dt.datetime:
    return dt.datetime.now(dt.timezone.utc)


def _write_private(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` mode 0600, whole (aside, then renamed)."""
    write_whole(path, data, mode=0o600)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def load_or_create_ca(folder: Path) -> Ca:
    """The CA in ``folder``; a new one if neither file exists (the folder made 0700). Processes
    creating it at once (two agents of one machine rendering TLS brokers) agree on one: the first
    to link its key in place writes the certificate, the others wait for it (bounded)."""
    cert_path, key_path = folder / CA_CERT, folder / CA_KEY
    if not cert_path.exists() and not key_path.exists():
        _create_ca(folder)
    end = time.monotonic() + CREATE_WAIT
    while key_path.exists() and not cert_path.exists() and time.monotonic() < end:
        time.sleep(0.05)  # another process linked its key and is writing the certificate
    return load_ca(folder)


def _create_ca(folder: Path) -> None:
    """Write a new CA's key, then its certificate, each linked into place (never over another's);
    nothing if another process's key is already there."""
    cert_path, key_path = folder / CA_CERT, folder / CA_KEY
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "plantkg plant CA")])
    now = _now()
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=CA_LIFETIME_DAYS))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False, False),
                           critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    try:  # the key first: a folder with a certificate and no key is not a usable CA
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        if not _link_new(key_path, _key_pem(key), 0o600):
            return  # another process's CA: it writes the certificate
        _link_new(cert_path, cert.public_bytes(serialization.Encoding.PEM), 0o644)
    except OSError as exc:
        raise CaError(f"cannot create the plant CA in {folder}: {exc.strerror}",
                      hint="give a CA folder that exists and is writable") from None


def _link_new(path: Path, data: bytes, mode: int) -> bool:
    """Write ``data`` aside (``mode``), then link it to ``path`` unless ``path`` exists (False)."""
    return create_once(path, data, mode)


def load_ca(folder: Path) -> Ca:
    """The CA in ``folder`` (both files PEM; the key 0600, unencrypted, matching the certificate)."""
    cert_path, key_path = folder / CA_CERT, folder / CA_KEY
    try:
        cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
        mode = key_path.stat().st_mode & 0o777
        key = serialization.load_pem_private_key(key_path.read_bytes(), password=None)
    except (OSError, ValueError, TypeError) as exc:
        raise CaError(f"the plant CA in {folder} is unusable: {exc}",
                      hint=f"put the CA's certificate ({CA_CERT}) and unencrypted key ({CA_KEY}, "
                           "mode 0600) there, or remove both to let plantkg create a CA") from None
    if mode & 0o077:
        raise CaError(f"the CA key {key_path} is readable by others (mode {mode:o})", hint=f"chmod 600 {key_path}")
    if not isinstance(key, ec.EllipticCurvePrivateKey) or key.public_key() != cert.public_key():
        raise CaError(f"{key_path} is not the EC private key of {cert_path}",
                      hint="put the CA's own key there (plantkg issues with EC keys)")
    return Ca(folder, cert, key)


def _signed_by(cert: x509.Certificate, ca: Ca) -> bool:
    try:
        cert.verify_directly_issued_by(ca.cert)
    except (ValueError, TypeError, InvalidSignature):
        return False
    return True


def _addresses(cert: x509.Certificate) -> set[str]:
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return set()
    return {str(ip) for ip in san.get_values_for_type(x509.IPAddress)}


def needs_new_cert(cert_pem: bytes | None, ca: Ca, addresses: tuple[str, ...],
                   now: dt.datetime | None = None) -> str | None:
    """Why a server certificate (PEM, None: there is none) must be issued again; None: it is
    current (signed by ``ca``, for exactly ``addresses``, not expiring within
    :data:`RENEW_BEFORE_DAYS`)."""
    if not cert_pem:
        return "none yet"
    try:
        cert = x509.load_pem_x509_certificate(cert_pem)
    except ValueError:
        return "unreadable"
    if not _signed_by(cert, ca):
        return "signed by another CA"
    if _addresses(cert) != {str(ipaddress.ip_address(a)) for a in addresses}:
        return "for other addresses"
    if cert.not_valid_after_utc - (now or _now()) < dt.timedelta(days=RENEW_BEFORE_DAYS):
        return f"expires {cert.not_valid_after_utc:%Y-%m-%d}"
    return None


def renewal_reason(cert_pem: bytes | None, addresses: tuple[str, ...]) -> str | None:
    """Why a broker's server certificate (PEM, None: none) must be issued again by the plant CA
    of this machine (:func:`needs_new_cert`, or the CA is unusable); None if it is current."""
    try:
        authority = load_ca(ca_dir())
    except CaError as exc:
        return f"the plant CA is unusable: {exc}"
    return needs_new_cert(cert_pem, authority, addresses)


def issue_server_cert(ca: Ca, addresses: tuple[str, ...], *, name: str,
                      now: dt.datetime | None = None) -> tuple[bytes, bytes]:
    """A new server key and certificate for ``addresses`` signed by ``ca``: (cert PEM, key PEM)."""
    key = ec.generate_private_key(ec.SECP256R1())
    start = now or _now()
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name[:64])]))
            .issuer_name(ca.cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start - dt.timedelta(minutes=5))
            .not_valid_after(start + dt.timedelta(days=LIFETIME_DAYS))
            .add_extension(x509.SubjectAlternativeName(
                [x509.IPAddress(ipaddress.ip_address(a)) for a in addresses]), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca.key.public_key()),
                           critical=False)
            .sign(ca.key, hashes.SHA256()))
    return cert.public_bytes(serialization.Encoding.PEM), _key_pem(key)


def current_server_cert(cert_pem: bytes | None, key_pem: bytes | None, ca: Ca,
                        addresses: tuple[str, ...], *, name: str,
                        now: dt.datetime | None = None) -> tuple[bytes, bytes]:
    """The given certificate and key if still current (and both present), else new ones."""
    if key_pem and needs_new_cert(cert_pem, ca, addresses, now) is None:
        return cert_pem, key_pem  # type: ignore[return-value]
    return issue_server_cert(ca, addresses, name=name, now=now)


def ca_pem(ca: Ca) -> bytes:
    return ca.cert.public_bytes(serialization.Encoding.PEM)


def _read(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except OSError:
        return None


def ensure_server_cert(folder: Path, addresses: tuple[str, ...], ca: Ca, *, name: str,
                       now: dt.datetime | None = None) -> bool:
    """Keep ``folder``'s ``cert.pem``/``key.pem`` and a copy of the CA certificate (all 0600)
    current for a server at ``addresses``; True if a new certificate was issued."""
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    if _read(folder / CA_CERT) != ca_pem(ca):
        _write_private(folder / CA_CERT, ca_pem(ca))
    old_cert, old_key = _read(folder / CERT_FILE), _read(folder / KEY_FILE)
    cert, key = current_server_cert(old_cert, old_key, ca, addresses, name=name, now=now)
    if (cert, key) == (old_cert, old_key):
        return False
    _write_private(folder / KEY_FILE, key)
    _write_private(folder / CERT_FILE, cert)
    return True


def cert_expiry(folder: Path) -> dt.datetime | None:
    """When the certificate in ``folder`` expires (None: there is none)."""
    try:
        return x509.load_pem_x509_certificate((folder / CERT_FILE).read_bytes()).not_valid_after_utc
    except (OSError, ValueError):
        return None

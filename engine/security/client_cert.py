"""Client certificates of the plant CA for resources that say ``pk:clientCertificate true``
(docs/security.md, Client certificates; issue 13).

A resource's certificate names it: its subject's common name is the resource's ``pk:id`` (the
user name a broker takes from the certificate), its extended key usage is clientAuth only, it is
signed by the plant CA (:mod:`engine.security.ca`) and lives :data:`LIFETIME_DAYS` days. The key
is a new EC P-256 key made here; it is written once, 0600, to the folder the operator names, and
never printed, logged or kept anywhere else (the CA keeps no copy).

:func:`write_client_bundle` writes what a device needs: ``<id>.key`` (0600), ``<id>.pem`` (its
certificate) and ``ca.pem`` (the plant CA's certificate, to verify the broker). Nothing is passed
to openssl; the id is checked against the pattern of ``pk:id`` before anything is made.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from engine.errors import EngineError
from engine.values import BROKER_USER
from engine.security.ca import CA_CERT, Ca, ca_pem
from engine.whole_file import write_whole

#: Days a client certificate is valid (as the brokers' server certificates).
LIFETIME_DAYS = 90
#: The pattern of ``pk:id`` (shape ``pks:PlantElement-idValue``): a certificate names a resource.
ID_PATTERN = BROKER_USER  # the certificate's common name is the broker user name
#: plantkg's own principals' names: a resource may not take one (docs/security.md).
RESERVED_PREFIX = "plantkg."
#: The longest common name X.509 allows (RFC 5280 ub-common-name).
MAX_CN = 64


class ClientCertError(EngineError):
    """A client certificate cannot be issued (a bad resource id, an unusable output folder)."""


@dataclass(frozen=True)
class ClientBundle:
    """Where :func:`write_client_bundle` wrote a resource's files, and until when it is valid."""

    resource_id: str
    key_file: Path
    cert_file: Path
    ca_file: Path
    not_after: dt.datetime


def check_resource_id(resource_id: str) -> str:
    """``resource_id`` if it can name a client certificate (a ``pk:id``, not a ``plantkg.`` name)."""
    if not ID_PATTERN.fullmatch(resource_id):
        raise ClientCertError(
            f"resource id {resource_id!r} is not a pk:id (1 to 128 characters from A-Z a-z 0-9 _ . -, "
            "starting with a letter, a digit or _)",
            hint="give the pk:id of the resource that says pk:clientCertificate true")
    if len(resource_id) > MAX_CN:
        raise ClientCertError(f"resource id {resource_id!r} is longer than {MAX_CN} characters: a "
                              "certificate's common name (the user name a broker takes from it) holds at most 64",
                              hint="shorten the resource's pk:id, or authenticate it with a pk:secretRef")
    if resource_id.startswith(RESERVED_PREFIX):
        raise ClientCertError(f"resource id {resource_id!r} starts with {RESERVED_PREFIX!r}: "
                              "those are plantkg's own principals' names",
                              hint="give the pk:id of a resource of the plant")
    return resource_id


def issue_client_cert(ca: Ca, resource_id: str, *,
                      now: dt.datetime | None = None) -> tuple[bytes, bytes]:
    """A new key and client certificate for ``resource_id`` signed by ``ca``: (cert PEM, key PEM).
    Common name the id, extended key usage clientAuth, digital signature only, not a CA."""
    check_resource_id(resource_id)
    key = ec.generate_private_key(ec.SECP256R1())
    start = now or dt.datetime.now(dt.timezone.utc)
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, resource_id)]))
            .issuer_name(ca.cert.subject).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start - dt.timedelta(minutes=5))
            .not_valid_after(start + dt.timedelta(days=LIFETIME_DAYS))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(True, False, False, False, False, False, False, False, False),
                           critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca.key.public_key()),
                           critical=False)
            .sign(ca.key, hashes.SHA256()))
    key_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                serialization.NoEncryption())
    return cert.public_bytes(serialization.Encoding.PEM), key_pem


def write_client_bundle(ca: Ca, resource_id: str, out: Path, *,
                        now: dt.datetime | None = None) -> ClientBundle:
    """Issue ``resource_id`` a certificate and write its key (0600), certificate and the CA
    certificate into ``out`` (made 0700 if missing). The key is written first and whole."""
    cert_pem, key_pem = issue_client_cert(ca, resource_id, now=now)
    bundle = ClientBundle(resource_id, out / f"{resource_id}.key", out / f"{resource_id}.pem",
                          out / CA_CERT, x509.load_pem_x509_certificate(cert_pem).not_valid_after_utc)
    try:
        out.mkdir(parents=True, exist_ok=True, mode=0o700)
        write_whole(bundle.key_file, key_pem, mode=0o600)
        write_whole(bundle.cert_file, cert_pem, mode=0o644)
        write_whole(bundle.ca_file, ca_pem(ca), mode=0o644)
    except OSError as exc:
        raise ClientCertError(f"cannot write the certificate of {resource_id} to {out}: {exc.strerror}",
                              hint="give an output folder that exists or can be made, writable") from None
    return bundle


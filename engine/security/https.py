"""HTTPS with the plant CA for plantkg's own HTTP services and their clients (the context broker's
API with ``pk:tls true``; docs/security.md, TLS).

The server side loads the certificate and key its agent issued (engine.security.ca) into a TLS
1.2+ context; the client side trusts the plant CA's ``ca.pem`` only, never the system's store, and
checks the server's address against its certificate. :func:`connection` gives an
``http.client`` connection of either kind, so a client switches on one flag. :func:`check_ca_file`
is the one check of a client's "URL and the CA certificate to verify it with" pair (the bridge
worker's ``ngsi_ca_file``, the task planner's ``--ngsi-ca-file``).
"""

from __future__ import annotations

import http.client
import ssl
from pathlib import Path

from engine.errors import ConfigValueError
from engine.security import ca
from engine.values import check_path


def server_context(cert_file: Path, key_file: Path) -> ssl.SSLContext:
    """A TLS 1.2+ server context with ``cert_file``'s certificate and ``key_file``'s key (raises
    :class:`OSError` or :class:`ssl.SSLError` when they cannot be loaded)."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(cert_file, key_file)
    return context


def client_context(ca_file: Path | None = None) -> ssl.SSLContext:
    """Verifies the server's certificate and address against ``ca_file`` only (default: the plant
    CA's ``ca.pem``), TLS 1.2+."""
    context = ssl.create_default_context(cafile=str(ca_file or ca.ca_cert_file()))
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    return context


def check_ca_file(field: str, url: str, ca_file: object, *, required: bool) -> Path | None:
    """``ca_file``, the CA certificate an ``https://`` ``url`` is verified against, checked: an
    absolute path (:func:`engine.values.check_path`), never beside an ``http://`` url (there is no
    certificate to verify: a CA file there is a mistake, not a no-op), and, when ``required`` (a
    client that trusts the plant CA only), present for an ``https://`` one. Raises
    :class:`ConfigValueError` naming ``field``."""
    path = None if ca_file is None else check_path(field, ca_file)
    tls = isinstance(url, str) and url.startswith("https://")
    if path is not None and not tls:
        raise ConfigValueError(field, str(path), f"a CA certificate verifies an https:// server; {url!r} is "
                                                 "not one (give the https:// URL, or leave the CA file out)")
    if path is None and tls and required:
        raise ConfigValueError(field, ca_file, "an https:// context broker needs the CA certificate to verify it "
                                               "with, and an http:// one none")
    return path


def connection(host: str, port: int, *, timeout: float, tls: bool,
               ca_file: Path | None = None) -> http.client.HTTPConnection:
    """An HTTPS connection verified against the plant CA (``ca_file``, default its ``ca.pem``)
    when ``tls``, else a plain HTTP one."""
    if tls:
        return http.client.HTTPSConnection(host, port, timeout=timeout, context=client_context(ca_file))
    return http.client.HTTPConnection(host, port, timeout=timeout)

"""HTTPS with the plant CA for plantkg's own HTTP services and their clients (the context broker's
API with ``pk:tls true``; docs/security.md, TLS).

The server side loads the certificate and key its agent issued (engine.security.ca) into a TLS
1.2+ context; the client side trusts the plant CA's ``ca.pem`` only, never the system's store, and
checks the server's address against its certificate. :func:`connection` gives an
``http.client`` connection of either kind, so a client switches on one flag.
"""

from __future__ import annotations

import http.client
import ssl
from pathlib import Path

from engine.security import ca


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


def connection(host: str, port: int, *, timeout: float, tls: bool,
               ca_file: Path | None = None) -> http.client.HTTPConnection:
    """An HTTPS connection verified against the plant CA (``ca_file``, default its ``ca.pem``)
    when ``tls``, else a plain HTTP one."""
    if tls:
        return http.client.HTTPSConnection(host, port, timeout=timeout, context=client_context(ca_file))
    return http.client.HTTPConnection(host, port, timeout=timeout)

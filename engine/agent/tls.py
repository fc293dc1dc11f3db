"""The agent API over TLS (``plantkg agent --tls``): its certificate and the server's context.

The agent's certificate (for its listen address) is issued from the plant CA
(:mod:`engine.security.ca`) into ``<state dir>/tls/`` (``cert.pem``, ``key.pem``, ``ca.pem``, all
0600) at start, and renewed while it runs: every :data:`RENEW_EVERY` seconds a certificate due
for renewal (30 days before it expires, or for another address or CA) is issued again and loaded
into the live context, so new connections get it without a restart. Clients verify the agent
against the CA certificate (engine.agent.client); one without it is refused at the handshake.
"""

from __future__ import annotations

import logging
import ssl
import threading
from pathlib import Path

from engine.security import ca

log = logging.getLogger(__name__)

TLS_DIR = "tls"
RENEW_EVERY = 6 * 3600.0


def server_context(state_dir: Path, host: str) -> ssl.SSLContext:
    """A TLS 1.2+ server context with the agent's current certificate for ``host``."""
    folder = state_dir / TLS_DIR
    ca.ensure_server_cert(folder, (host,), ca.load_or_create_ca(ca.ca_dir()), name=f"plantkg agent {host}")
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    context.load_cert_chain(folder / ca.CERT_FILE, folder / ca.KEY_FILE)
    return context


def renew(context: ssl.SSLContext, state_dir: Path, host: str) -> bool:
    """Issue the certificate again if it is due, and load it into ``context``; True if renewed."""
    folder = state_dir / TLS_DIR
    if not ca.ensure_server_cert(folder, (host,), ca.load_or_create_ca(ca.ca_dir()),
                                 name=f"plantkg agent {host}"):
        return False
    context.load_cert_chain(folder / ca.CERT_FILE, folder / ca.KEY_FILE)
    log.info("renewed the agent's TLS certificate (expires %s)", ca.cert_expiry(folder))
    return True


def start_renewer(context: ssl.SSLContext, state_dir: Path, host: str,
                  stop: threading.Event, every: float = RENEW_EVERY) -> threading.Thread:
    """A daemon thread calling :func:`renew` every ``every`` seconds until ``stop`` is set."""
    def run() -> None:
        while not stop.wait(every):
            try:
                renew(context, state_dir, host)
            except (OSError, ca.CaError) as exc:  # keep serving with the current certificate
                log.warning("cannot renew the agent's TLS certificate: %s", exc)

    thread = threading.Thread(target=run, name="plantkg-tls-renew", daemon=True)
    thread.start()
    return thread

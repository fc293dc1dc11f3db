"""How the task planner trusts the context broker it talks NGSI-v2 to (``--ngsi-url``).

A context broker with ``pk:tls true`` serves HTTPS only, with a certificate the plant CA signed
(docs/security.md, TLS): the planner verifies it against that CA's certificate, ``--ngsi-ca-file``
(the plant CA's ``ca.pem``). An ``https://`` URL without it is verified against the system's
store (a real Orion behind a public certificate); a CA file beside an ``http://`` URL is a usage
error (:func:`engine.security.https.check_ca_file`, the bridge worker's check of the same pair).
:meth:`NgsiTrust.context` is the one :class:`ssl.SSLContext` every NGSI client of the planner
passes to ``urlopen`` (the Task entities, the paper's channels, the Event subscription).

:func:`check_certificate` shakes hands once at start: a certificate the planner does not trust is
a permanent mistake, so the planner exits 2 saying which option to give, rather than retrying
forever; a context broker that is not up yet is only logged (it may come later). Afterwards each
client says the same through :func:`unreachable` when a certificate is refused.

:func:`plant_trust` derives the same from a plant (the demo and the benchmark read the plant
file, as ``plantkg query --live`` does, engine/context_view.py): the fleet's context broker (the one
its ``fleet:fleet-view`` resources send to, fleet/model/binding.py) is ``https://`` with the plant
CA's certificate when it says ``pk:tls true``.
"""

from __future__ import annotations

import http.client
import logging
import ssl
import urllib.error
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

import pyoxigraph as ox

from engine.errors import ConfigValueError
from engine.security import ca, https
from engine.values import host_in_url
from fleet.model.binding import binding_of
from fleet.planner.errors import PlannerError
from kg.load import PlantGraph
from kg.query import run_query

log = logging.getLogger("fleet.planner")
CA_OPTION = "--ngsi-ca-file"
_BROKER = "SELECT ?ip ?port ?tls WHERE { ?broker pk:ip ?ip ; pk:port ?port . OPTIONAL { ?broker pk:tls ?tls } }"


@dataclass(frozen=True)
class NgsiTrust:
    """The context broker's URL and the CA certificate it is verified against (None: the
    system's store for ``https://``, nothing for ``http://``)."""

    url: str
    ca_file: Path | None = None

    def __post_init__(self) -> None:
        parts = urlsplit(self.url) if isinstance(self.url, str) else None
        try:
            port_ok = parts is not None and parts.port != 0
        except ValueError:
            port_ok = False
        if parts is None or parts.scheme not in ("http", "https") or not parts.hostname or not port_ok:
            raise PlannerError(f"--ngsi-url {self.url!r}: expected http://HOST:PORT or https://HOST:PORT",
                               hint="give the context broker's URL (https:// for one with pk:tls true)")
        ca_file = self.ca_file.resolve() if isinstance(self.ca_file, Path) else self.ca_file
        try:
            object.__setattr__(self, "ca_file", https.check_ca_file(CA_OPTION, self.url, ca_file, required=False))
        except ConfigValueError as exc:
            raise PlannerError(f"{CA_OPTION} {ca_file}: {exc.problem}",
                               hint="give the plant CA's certificate ($PLANTKG_CA_DIR/ca.pem) with an "
                                    "https:// --ngsi-url") from None

    @property
    def tls(self) -> bool:
        return self.url.startswith("https://")

    def context(self) -> ssl.SSLContext | None:
        """The client context (TLS 1.2+, the server's address checked): the CA file's
        certificate only, or the system's store; None for ``http://``. Raises
        :class:`PlannerError` naming the option when the CA file cannot be read."""
        if not self.tls:
            return None
        if self.ca_file is None:
            context = ssl.create_default_context()
            context.minimum_version = ssl.TLSVersion.TLSv1_2
            return context
        try:
            return https.client_context(self.ca_file)
        except (OSError, ssl.SSLError) as exc:
            raise PlannerError(f"{CA_OPTION} {self.ca_file}: not a readable PEM certificate "
                               f"({getattr(exc, 'strerror', None) or exc})",
                               hint="give the plant CA's ca.pem ($PLANTKG_CA_DIR/ca.pem)") from None

    def flags(self) -> list[str]:
        """The planner's command-line flags for this context broker."""
        return ["--ngsi-url", self.url, *([CA_OPTION, str(self.ca_file)] if self.ca_file is not None else [])]


def untrusted(exc: BaseException, url: str | None = None) -> str | None:
    """What to say when ``exc`` (from ``urlopen`` or a handshake) is a refused certificate; None
    when it is anything else."""
    reason = exc.reason if isinstance(exc, urllib.error.URLError) else exc
    if not isinstance(reason, ssl.SSLCertVerificationError):
        return None
    where = f" at {url}" if url else ""
    return (f"the context broker{where} shows a certificate that is not trusted "
            f"({reason.verify_message or reason}): give {CA_OPTION} with the CA certificate that signed it "
            "(a pk:tls context broker: the plant CA's ca.pem)")


def unreachable(url: str, exc: BaseException) -> str:
    """Why the context broker at ``url`` gave no answer: its certificate, or ``exc`` itself."""
    return untrusted(exc, url) or f"the context broker at {url} does not answer: {getattr(exc, 'reason', exc)}"


def check_certificate(trust: NgsiTrust, context: ssl.SSLContext | None, timeout: float = 5.0) -> None:
    """One TLS handshake with an ``https://`` context broker: :class:`PlannerError` when its
    certificate is not trusted; a broker that does not answer is only logged."""
    if context is None:
        return
    parts = urlsplit(trust.url)
    conn = http.client.HTTPSConnection(parts.hostname or "", parts.port or 443, timeout=timeout, context=context)
    try:
        conn.connect()
    except OSError as exc:  # (ssl's errors and timeouts are OSErrors)
        problem = untrusted(exc, trust.url)
        if problem is not None:
            raise PlannerError(problem, hint="the plant CA's certificate is $PLANTKG_CA_DIR/ca.pem on the "
                                             "plant's machines (plantkg agent --ca-dir)") from None
        log.warning("the context broker at %s does not answer yet (%s); the planner retries", trust.url, exc)
    finally:
        conn.close()


def trust_of(host: str, port: int, tls: bool, ca_dir: Path | None = None) -> NgsiTrust:
    """A plant's context broker (its ``pk:ip``, ``pk:port``, ``pk:tls``): ``https://`` with the
    plant CA's certificate (``ca_dir``, default ``$PLANTKG_CA_DIR``) when it speaks TLS."""
    url = f"{'https' if tls else 'http'}://{host_in_url(host)}:{port}"
    return NgsiTrust(url, ca.ca_cert_file(ca_dir) if tls else None)


def plant_trust(plant: PlantGraph, ca_dir: Path | None = None) -> NgsiTrust:
    """The fleet's context broker in ``plant`` (:func:`fleet.model.binding.binding_of`), as
    :func:`trust_of` makes it; :class:`PlannerError` when the plant has none."""
    iri = binding_of(plant).context_broker_iri
    rows = run_query(plant, _BROKER, {"broker": ox.NamedNode(iri)}).rows if iri is not None else ()
    if not rows or not isinstance(rows[0][0], ox.Literal) or not isinstance(rows[0][1], ox.Literal):
        raise PlannerError("the plant has no context broker for the fleet (with pk:ip and pk:port)",
                           hint="let a fleet:fleet-view resource pk:sendsTo a broker of pk:brokerType \"ngsi-v2\"")
    ip, port, tls = rows[0]
    return trust_of(ip.value, int(port.value), isinstance(tls, ox.Literal) and tls.value in ("true", "1"), ca_dir)

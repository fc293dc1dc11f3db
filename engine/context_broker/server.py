"""The context broker as a process: arguments, token, store, subscriptions, WSGI server, signals.

``python -m engine.context_broker --host H --port P --data-dir D [--token-file F | --open]
[--principals P] [--closed-kafka HOST:PORT ...] [--tls-kafka HOST:PORT ...] [--tls-cert C --tls-key K]
[--log-file L] [--allow-remote] [--threads N] [--fsync]``

- Binds loopback unless ``--allow-remote`` (a non-loopback ``--host`` is refused otherwise).
- Writes need ``Authorization: Bearer <token>`` (the first line of ``--token-file``) unless
  ``--open``; one of the two must be given. ``--principals P`` (with ``--token-file``) closes
  it: reads need a token too, and each principal of ``P`` may use only its entities (:mod:`.access`).
- ``--closed-kafka HOST:PORT`` (repeated; the NGSI driver renders them from the plant): the
  plant's closed Kafka brokers, where ``kafka://`` notifications log in as plantkg's own Kafka
  principal (:mod:`.subscriptions.kafka`); any other Kafka gets no credentials.
- ``--tls-kafka HOST:PORT`` (repeated, likewise): the plant's Kafka brokers that speak TLS, which
  ``kafka://`` notifications reach over TLS, trusting only the plant CA (``$PLANTKG_CA_DIR``).
- ``--tls-cert C --tls-key K`` (the NGSI driver renders them for ``pk:tls true``): the API speaks
  HTTPS only (TLS 1.2+) with that certificate (the plant CA's, issued by the broker's agent); a
  plain HTTP client gets no answer.
- The store lives in ``D/oxigraph`` and its write-ahead log in ``D/context.wal`` (``D/context.lock``
  keeps a second process out, with a clear message and exit code 2); subscriptions in
  ``D/subscriptions``. An answered write survives kill -9; ``--fsync`` also makes it survive a
  power loss (one ``fdatasync`` per write).
- Served by :mod:`.http_server` (asyncio + httptools): requests are read whole, asynchronously,
  before anything runs them, so slow or stalled clients hold nothing; the hot writes run on the
  event loop, everything else in ``--threads`` worker threads. (cheroot was tried: there, 16
  clients stalled mid-body hold all 16 workers; waitress cost ~3x the write per request.)
  SIGTERM or SIGINT stop it cleanly (exit 0). A port in use exits 2 with the reason.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import ssl
import sys
from pathlib import Path

from engine.context_broker.access import Gate
from engine.security.ngsi_principals import PrincipalsFileError, load_principals
from engine.context_broker.app import MAX_BODY, create_app
from engine.context_broker.store import ContextStore, StoreLocked
from engine.context_broker.subscriptions.model import PlantKafkas
from engine.errors import ConfigValueError
from engine.security.https import server_context
from engine.values import check_address

log = logging.getLogger("engine.context_broker")
DEFAULT_THREADS = 8


class ConfigError(Exception):
    """A command line that cannot be run; the message says what to change."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m engine.context_broker",
                                     description="plantkg's NGSI-v2 context broker (Orion's API, RDF store)")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=1026)
    parser.add_argument("--data-dir", type=Path, required=True)
    parser.add_argument("--token-file", type=Path)
    parser.add_argument("--open", action="store_true", help="writes need no token")
    parser.add_argument("--principals", type=Path,
                        help="the principals file (token digests and entities): closes the broker")
    parser.add_argument("--closed-kafka", action="append", default=[], metavar="HOST:PORT",
                        help="a closed Kafka of the plant: kafka:// notifications log in there as "
                             "plantkg's own principal (its password from the principal key)")
    parser.add_argument("--tls-kafka", action="append", default=[], metavar="HOST:PORT",
                        help="a Kafka of the plant that speaks TLS: kafka:// notifications use TLS "
                             "there, trusting the plant CA only")
    parser.add_argument("--tls-cert", type=Path, help="serve HTTPS only, with this certificate (PEM)")
    parser.add_argument("--tls-key", type=Path, help="the private key of --tls-cert (PEM)")
    parser.add_argument("--log-file", type=Path)
    parser.add_argument("--allow-remote", action="store_true", help="allow a non-loopback --host")
    parser.add_argument("--threads", type=int, default=DEFAULT_THREADS)
    parser.add_argument("--fsync", action="store_true",
                        help="fdatasync the write-ahead log before each write is answered "
                             "(survives power loss; slower)")
    return parser.parse_args(argv)


def check_host(host: str, allow_remote: bool) -> None:
    if host == "localhost" or allow_remote:
        return
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        raise ConfigError(f"--host {host!r} is not an IP address: give a loopback address such as "
                          "127.0.0.1 (or add --allow-remote)") from None
    if not loopback:
        raise ConfigError(f"--host {host} is not a loopback address: the context broker binds "
                          "loopback only unless you add --allow-remote")


def read_token(args: argparse.Namespace) -> str | None:
    if args.open and args.token_file:
        raise ConfigError("give either --token-file or --open, not both")
    if args.open:
        return None
    if args.token_file is None:
        raise ConfigError("writes need a token: give --token-file FILE (or --open to allow "
                          "writes without one)")
    try:
        token = args.token_file.read_text(encoding="utf-8").strip().splitlines()
    except OSError as err:
        raise ConfigError(f"cannot read --token-file {args.token_file}: {err.strerror}") from None
    if not token or not token[0].strip():
        raise ConfigError(f"--token-file {args.token_file} is empty: write the token on its first line")
    return token[0].strip()


def read_gate(args: argparse.Namespace, token: str | None) -> Gate | None:
    if args.principals is None:
        return None
    if token is None:
        raise ConfigError("--principals closes the broker: give --token-file (plantkg's own "
                          "token), not --open")
    try:
        return Gate(token, load_principals(args.principals))
    except PrincipalsFileError as err:
        raise ConfigError(str(err)) from None


def read_closed_kafkas(args: argparse.Namespace) -> frozenset[tuple[str, int]]:
    """The addresses of ``--closed-kafka``."""
    return _addresses("--closed-kafka", args.closed_kafka)


def read_plant_kafkas(args: argparse.Namespace) -> PlantKafkas:
    """The plant's Kafka brokers ``kafka://`` notifications treat as the plant's:
    ``--closed-kafka`` (log in as plantkg) and ``--tls-kafka`` (TLS, the plant CA)."""
    return PlantKafkas(closed=read_closed_kafkas(args), tls=_addresses("--tls-kafka", args.tls_kafka))


def read_tls(args: argparse.Namespace) -> ssl.SSLContext | None:
    """The server's TLS context of ``--tls-cert``/``--tls-key`` (both or neither); None: plain HTTP."""
    if (args.tls_cert is None) != (args.tls_key is None):
        raise ConfigError("give --tls-cert and --tls-key together (or neither, for plain HTTP)")
    if args.tls_cert is None:
        return None
    try:
        return server_context(args.tls_cert, args.tls_key)
    except (OSError, ssl.SSLError) as err:
        raise ConfigError(f"cannot load --tls-cert {args.tls_cert} with --tls-key {args.tls_key}: "
                          f"{getattr(err, 'strerror', None) or err}") from None


def _addresses(option: str, given: list[str]) -> frozenset[tuple[str, int]]:
    out = set()
    for address in given:
        try:
            out.add(check_address(option, address))
        except ConfigValueError as err:
            raise ConfigError(f"{option} {address!r}: {err.problem}") from None
    return frozenset(out)


def _logging(log_file: Path | None) -> None:
    try:
        handler: logging.Handler = (logging.FileHandler(log_file, encoding="utf-8") if log_file
                                    else logging.StreamHandler(sys.stderr))
    except OSError as err:
        raise ConfigError(f"cannot write --log-file {log_file}: {err.strerror}") from None
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(logging.INFO)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        check_host(args.host, args.allow_remote)
        token = read_token(args)
        gate = read_gate(args, token)
        kafkas = read_plant_kafkas(args)
        tls = read_tls(args)
        _logging(args.log_file)
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        store = ContextStore(args.data_dir, fsync=args.fsync)
    except StoreLocked as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    from engine.context_broker.fastpath import is_hot_write
    from engine.context_broker.http_server import make_server
    from engine.context_broker.subscriptions import SubscriptionService

    subscriptions = SubscriptionService(args.data_dir / "subscriptions", fsync=args.fsync,
                                        kafkas=kafkas, owners=gate.owners() if gate else {})
    subscriptions.start()
    try:
        app = create_app(store, token=token, gate=gate, listeners=[subscriptions],
                         subscriptions_blueprint=subscriptions.blueprint())
        # with --fsync a write waits for the disk: keep it off the event loop
        server = make_server(app, args.host, args.port, args.threads,
                             inline=None if args.fsync else is_hot_write, max_body=MAX_BODY,
                             ssl_context=tls)
    except OSError as err:
        subscriptions.close()
        store.close()
        print(f"error: cannot listen on {args.host}:{args.port}: {err.strerror or err}", file=sys.stderr)
        return 2
    log.info("context broker on %s://%s:%d (data %s, %d entities, writes %s)",
             "http" if tls is None else "https", args.host,
             args.port, args.data_dir, store.count(),
             "open" if token is None else "need a token" if gate is None else "closed: every request needs a token")
    try:
        stopped_by = server.run()
        log.info("%s: stopping", stopped_by)
    finally:
        server.close()
        subscriptions.close()
        store.close()
        log.info("stopped")
    return 0

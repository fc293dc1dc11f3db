"""The NGSI-v2 context broker driver: ``python -m engine.context_broker`` (FIWARE Orion's REST API).

plantkg's own context broker (:mod:`engine.context_broker`) is a process the agent runs like any
broker: one listener on the spec's address and port, its entities in ``<broker dir>/data/``, its
log in ``<broker dir>/logs/ngsi-v2.log``. It is closed by default: every request but ``GET
/version`` needs ``Authorization: Bearer <token>``, reads included, with the token of the broker's
own agent (so the engine, which reads every agent's token file from agents.toml, can use it) or a
principal's (``principals.json``, rendered always: empty when no client has a ``pk:secretRef``),
unless the plant says ``pk:allowAnonymous true`` (``--open``: reads and writes without a token).
Its ``kafka://`` notifications log in as plantkg's own Kafka principal at the plant's closed Kafka
brokers the engine names in ``closed_kafkas`` (``--closed-kafka HOST:PORT``), and nowhere else,
and speak TLS (trusting the plant CA only) to those it names in ``tls_kafkas`` (``--tls-kafka``).

A context broker holds entities, not topics: a topic it carries is one entity (``entity_id``,
``entity_type``, filled by derive), which needs no creation. So topics are implicit, as on MQTT:
:meth:`NgsiDriver.ensure_topic` checks the entity's identifiers against Orion's rules and the agent
records the result. Health is a real ``GET /version`` answered 200 with an ``orion`` object, the
check FiLiP's client makes first, not just an open port.

With ``pk:tls true`` (``spec.tls``) its API speaks HTTPS only (TLS 1.2+): the agent issues it a
certificate of the plant CA for its address into the broker folder (``tls-cert.pem``,
``tls-key.pem``, 0600 like every rendered file; kept while current, issued again under the same
rules as a Mosquitto's: :meth:`NgsiDriver.tls_renewal`), rendered as ``--tls-cert``/``--tls-key``;
health then speaks HTTPS and verifies it against the plant CA only.

The agent's token file is ``<state dir>/token`` (the agent's default; the broker folder is
``<state dir>/brokers/<id>/``); an agent started with another ``--token-file`` passes it in the
environment variable ``PLANTKG_AGENT_TOKEN_FILE``.
"""

from __future__ import annotations

import http.client
import json
import os
import sys
from pathlib import Path
from typing import Any

from engine import netutil
from engine.drivers.base import (
    AGENT_TOKEN_FILE_ENV,
    DATA_DIR,
    NGSI_TOPIC_FIELDS,
    check_text,
    check_topic_fields,
    log_file,
    refuse_bridges,
    resolve_secret,
    spec_essence,
)
from engine.security import ca, https
from engine.security.ngsi_principals import render_principals
from engine.errors import ConfigValueError
from engine.model import BridgeSpec, BrokerSpec, ObservedTopic, TopicSpec
from engine.values import check_address, check_host, check_ngsi_id, check_path, check_port

#: The module the agent runs (``python -m``), and the agent's token file name in its state dir.
SERVER_MODULE = "engine.context_broker"
TOKEN_FILE = "token"
TOKEN_FILE_ENV = AGENT_TOKEN_FILE_ENV
#: The principals file of a broker with users (token digests and entities; engine.context_broker.access).
PRINCIPALS_FILE = "principals.json"
#: The certificate and key of a ``tls`` broker (its HTTPS listener).
TLS_CERT_FILE = "tls-cert.pem"
TLS_KEY_FILE = "tls-key.pem"
#: How much of a /version answer health reads (Orion's is a few hundred bytes).
MAX_VERSION_BYTES = 65_536


class NgsiDriver:
    """plantkg's NGSI-v2 context broker, started as ``python -m engine.context_broker``."""

    kind = "ngsi-v2"
    implicit_topics = True
    start_deadline = 15.0
    stop_grace = 10.0

    def __init__(self, *, python: str | None = None, token_file: Path | None = None) -> None:
        """``python``: the interpreter (default: the agent's own, so the server runs from the same
        installation). ``token_file``: the write token (default: see the module docstring)."""
        self.python = python or sys.executable
        self._token_file = token_file

    def validate(self, spec: BrokerSpec) -> None:
        check_host("host", spec.host)
        check_port("port", spec.port)
        if spec.allow_anonymous is not None and not isinstance(spec.allow_anonymous, bool):
            raise ConfigValueError("allow_anonymous", spec.allow_anonymous, "must be true or false")
        if spec.users and spec.allow_anonymous:
            raise ConfigValueError("allow_anonymous", True, "a context broker with principals (users) "
                                   "is closed; remove allow_anonymous or the users")
        for user in spec.users:
            check_text(f"users[{user.name}].name", user.name)
            for eid in (*user.write, *user.read):
                check_ngsi_id(f"users[{user.name}] entity", eid)
        if spec.persist_every is not None:
            raise ConfigValueError("persist_every", spec.persist_every,
                                   "does not apply to a context broker (it saves every write)")
        for i, address in enumerate(spec.closed_kafkas):
            check_address(f"closed_kafkas[{i}]", address)
        for i, address in enumerate(spec.tls_kafkas):
            check_address(f"tls_kafkas[{i}]", address)

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        """The principals file of a closed broker (each user's token read here, on the broker's
        machine, and written as its SHA-256 digest only; 0600 like every rendered file; no users:
        an empty list, so only the agent's token gets in); none for an open one. For ``tls`` its
        certificate and key, kept while current. Bridges run as workers beside MQTT."""
        self.validate(spec)
        check_path("broker_dir", broker_dir)
        refuse_bridges(self.kind, bridges)
        files = _tls_files(spec, broker_dir)
        if spec.allow_anonymous:
            return files
        tokens = {u.name: (resolve_secret(u), u.write, u.read) for u in spec.users}
        return {**files, PRINCIPALS_FILE: render_principals(tokens)}

    def token_file(self, broker_dir: Path) -> Path:
        """The agent's token file, which the context broker reads its write token from."""
        if self._token_file is not None:
            return self._token_file
        configured = os.environ.get(TOKEN_FILE_ENV)
        if configured:
            return Path(configured)
        return broker_dir.parent.parent / TOKEN_FILE

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        self.validate(spec)
        check_path("broker_dir", broker_dir)
        argv = [self.python, "-m", SERVER_MODULE, "--host", spec.host, "--port", str(spec.port),
                "--data-dir", str(broker_dir / DATA_DIR), "--log-file", str(log_file(broker_dir, self.kind))]
        for address in spec.closed_kafkas:  # its kafka:// notifications log in there as plantkg
            argv += ["--closed-kafka", address]
        for address in spec.tls_kafkas:  # ... and speak TLS there, trusting the plant CA
            argv += ["--tls-kafka", address]
        if spec.tls:  # its own API: HTTPS only
            argv += ["--tls-cert", str(broker_dir / TLS_CERT_FILE), "--tls-key", str(broker_dir / TLS_KEY_FILE)]
        if spec.allow_anonymous:
            return [*argv, "--open"]
        token = check_path("token_file", self.token_file(broker_dir))
        if not token.is_file():
            raise ConfigValueError("token_file", str(token),
                                   "the agent's token file is missing, and the context broker needs "
                                   f"it for writes (set {TOKEN_FILE_ENV}, or pk:allowAnonymous true)")
        return [*argv, "--token-file", str(token), "--principals", str(broker_dir / PRINCIPALS_FILE)]

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """The data folder the entities are stored in."""
        (broker_dir / DATA_DIR).mkdir(parents=True, exist_ok=True)
        if spec.allow_anonymous:
            (broker_dir / PRINCIPALS_FILE).unlink(missing_ok=True)
        if not spec.tls:  # no key left behind by a broker that no longer speaks TLS
            for name in (TLS_CERT_FILE, TLS_KEY_FILE):
                (broker_dir / name).unlink(missing_ok=True)

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        """``GET /version`` answered 200 with a JSON object holding an ``orion`` object (over
        HTTPS verified against the plant CA for a ``tls`` broker)."""
        if not netutil.port_open(spec.host, spec.port, timeout=min(timeout, 0.5)):
            return False
        try:
            conn = https.connection(spec.host, spec.port, timeout=max(timeout, 0.05), tls=spec.tls)
        except (OSError, ca.CaError):  # (ssl.SSLError is an OSError)
            return False  # no plant CA to verify it with: not healthy as far as plantkg can tell
        try:
            conn.request("GET", "/version", headers={"Accept": "application/json"})
            answer = conn.getresponse()
            body = answer.read(MAX_VERSION_BYTES)
            if answer.status != 200:
                return False
            data = json.loads(body)
            return isinstance(data, dict) and isinstance(data.get("orion"), dict)
        except (OSError, ValueError, http.client.HTTPException):
            return False
        finally:
            conn.close()

    def ensure_topic(self, spec: BrokerSpec, topic: TopicSpec) -> ObservedTopic:
        """Check the topic's entity (no creation: an entity appears with its first write)."""
        check_text("name", topic.name)
        check_topic_fields(topic, self.kind, NGSI_TOPIC_FIELDS)
        for field in NGSI_TOPIC_FIELDS:
            value = getattr(topic, field)
            if value is None:
                raise ConfigValueError(field, None, "a topic on a context broker needs its entity "
                                       "id and type (plantkg derive fills them in)")
            check_ngsi_id(field, value)
        return ObservedTopic(name=topic.name, entity_id=topic.entity_id, entity_type=topic.entity_type)

    def delete_topic(self, spec: BrokerSpec, name: str) -> None:
        """Nothing on the broker: the entity is data, and stays until someone deletes it."""
        check_text("name", name)

    def observe_topics(self, spec: BrokerSpec) -> list[ObservedTopic]:
        return []

    def essence(self, spec: BrokerSpec) -> dict[str, Any]:
        """Listener (and whether it speaks TLS), whether writes need the token, the closed Kafkas
        (all on the command line), and the principals."""
        out = {**spec_essence(spec), "allow_anonymous": bool(spec.allow_anonymous)}
        if spec.closed_kafkas:
            out["closed_kafkas"] = list(spec.closed_kafkas)
        if spec.tls_kafkas:
            out["tls_kafkas"] = list(spec.tls_kafkas)
        if spec.tls:  # only then: a plain broker's essence, and so its config hash, stays as it was
            out["tls"] = True
        if spec.users:  # principals: who they are and their entities (their tokens are not in it)
            out["users"] = [{"name": u.name, "secret_ref": u.secret_ref, "write": sorted(u.write),
                             "read": sorted(u.read)} for u in sorted(spec.users, key=lambda u: u.name)]
        return out

    def tls_renewal(self, spec: BrokerSpec, broker_dir: Path) -> str | None:
        """Why the broker's TLS certificate must be issued again (engine.security.ca); None if
        current or plain. The agent reports it, the plan turns it into an update, and the PUT
        renders a new one (as for a Mosquitto)."""
        if not spec.tls:
            return None
        return ca.renewal_reason(_read(broker_dir / TLS_CERT_FILE), (spec.host,))


def _tls_files(spec: BrokerSpec, broker_dir: Path) -> dict[str, str]:
    """A ``tls`` broker's certificate and key for its address: the previous ones while current (so
    re-rendering gives the same files and does not restart it), else new ones; none when plain."""
    if not spec.tls:
        return {}
    cert, key = ca.current_server_cert(_read(broker_dir / TLS_CERT_FILE), _read(broker_dir / TLS_KEY_FILE),
                                       ca.load_or_create_ca(ca.ca_dir()), (spec.host,),
                                       name=f"plantkg broker {spec.id}")
    return {TLS_CERT_FILE: cert.decode("ascii"), TLS_KEY_FILE: key.decode("ascii")}


def _read(path: Path) -> bytes | None:
    try:
        return path.read_bytes()
    except OSError:
        return None

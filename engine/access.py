"""Broker users and ACLs from the reasoned plant graph (docs/security.md).

A resource that sends to a broker and has a ``pk:secretRef`` is one of the broker's users: its
user name is its ``pk:id``, its password is where the reference says (read by the broker's agent,
never by plantkg's planner), and it may publish (``pk:mayWrite``, concluded from ``pk:publishes``
by rule A1 of ``ontology/plantkg-access.ttl``) and subscribe to (``pk:mayRead``, rule A2) those
of its topics the broker carries. Nothing here decides who may do what: the rules did.

- :func:`broker_users` reads them (SPARQL over the asserted and inferred facts);
- :func:`close_brokers` applies them to the derived specs: a broker with users admits nobody else
  unless the plant says ``pk:allowAnonymous true``;
- :func:`check_access_supported` refuses, before anything is deployed, what plantkg cannot run
  yet: users on a broker whose driver renders none (Mosquitto's and Kafka's do; not a Kafka
  cluster's nodes), and a bridge at a closed broker (it would need plantkg's own credentials on
  that broker) — but for a bridge worker into a closed Kafka, which authenticates as plantkg's
  own principal (:func:`kafka_internal_password`);
- :func:`open_broker_warnings` and :func:`access_label` say, in a plan and in ``status``, which
  brokers anyone on the network may use.
"""

from __future__ import annotations

import hashlib
import hmac
from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import replace

import pyoxigraph as ox

from engine.errors import EngineError
from engine.model import BridgeMechanism, BridgeSpec, BrokerSpec, BrokerUser

#: The broker kinds whose driver renders users and ACLs.
USER_KINDS = frozenset({"mosquitto", "kafka"})

USERS = """
SELECT ?b ?r ?rid ?ref ?t ?mode WHERE {
    ?b a pk:DeployedBroker .
    ?r pk:sendsTo ?b ; pk:secretRef ?ref ; pk:id ?rid .
    OPTIONAL {
        ?b pk:mustCarry ?t .
        { ?r pk:mayWrite ?t BIND ("write" AS ?mode) } UNION { ?r pk:mayRead ?t BIND ("read" AS ?mode) }
    }
}"""


class AccessNotSupportedError(EngineError):
    """The plant asks for access control plantkg cannot render yet."""


def broker_users(select: Callable[[str], Iterable[ox.QuerySolution]],
                 topic_names: Mapping[tuple[str, str], str]) -> dict[str, tuple[BrokerUser, ...]]:
    """Broker IRI -> its users, sorted by name, each with its sorted topic names.
    ``topic_names`` maps (broker IRI, topic IRI) to the topic's name on that broker."""
    refs: dict[tuple[str, str], str] = {}
    rights: dict[tuple[str, str], dict[str, set[str]]] = defaultdict(lambda: {"write": set(), "read": set()})
    for row in select(USERS):
        broker, name = row["b"].value, row["rid"].value
        refs[(broker, name)] = row["ref"].value
        rights[(broker, name)]  # a user with no right still exists: it may connect, nothing more
        if row["t"] is not None and (broker, row["t"].value) in topic_names:
            rights[(broker, name)][row["mode"].value].add(topic_names[(broker, row["t"].value)])
    out: dict[str, list[BrokerUser]] = defaultdict(list)
    for (broker, name), ref in sorted(refs.items()):
        got = rights[(broker, name)]
        out[broker].append(BrokerUser(name=name, secret_ref=ref, write=tuple(sorted(got["write"])),
                                      read=tuple(sorted(got["read"]))))
    return {broker: tuple(users) for broker, users in out.items()}


def close_brokers(brokers: Iterable[BrokerSpec], users: Mapping[str, tuple[BrokerUser, ...]],
                  anonymous_said: frozenset[str]) -> list[BrokerSpec]:
    """The specs with their users; a broker with users and no ``pk:allowAnonymous`` of its own
    (``anonymous_said``: IRIs that state one) is closed (``allow_anonymous`` False)."""
    out = []
    for spec in brokers:
        mine = users.get(spec.iri, ())
        if mine:
            closed = spec.allow_anonymous if spec.iri in anonymous_said else False
            spec = replace(spec, users=mine, allow_anonymous=closed)
        out.append(spec)
    return out


def is_closed(spec: BrokerSpec) -> bool:
    """A Mosquitto or a Kafka that admits only its users."""
    return spec.kind in USER_KINDS and spec.allow_anonymous is False


def kafka_internal_password(agent_token: str) -> str:
    """plantkg's own password on a closed Kafka (engine.drivers.kafka.access): derived from the
    token of the broker's agent, so the engine (which knows every agent's token) can give it to a
    bridge worker on another machine, and the password reveals nothing of the token."""
    return hmac.new(agent_token.encode("utf-8"), b"plantkg kafka internal principal", hashlib.sha256).hexdigest()


def check_access_supported(brokers: Iterable[BrokerSpec], bridges: Iterable[BridgeSpec]) -> None:
    """Refuse users on a broker whose driver renders none, and bridges at a closed broker."""
    by_id = {b.id: b for b in brokers}
    for spec in by_id.values():
        if spec.users and spec.kind not in USER_KINDS:
            names = ", ".join(u.name for u in spec.users)
            raise AccessNotSupportedError(
                f"broker {spec.id!r} ({spec.kind}): its clients {names} have a pk:secretRef, but "
                f"plantkg renders users and ACLs for {', '.join(sorted(USER_KINDS))} brokers only (yet)",
                hint="remove pk:secretRef from those resources, or let them send to a Mosquitto broker")
    for spec in by_id.values():
        if spec.users and spec.kafka is not None:
            raise AccessNotSupportedError(
                f"broker {spec.id!r} is a node of Kafka cluster {spec.kafka.cluster!r}, whose clients "
                "have a pk:secretRef: plantkg renders SASL users and ACLs for a Kafka broker of its "
                "own only (yet); its nodes would need one shared secret for plantkg's own principal",
                hint="remove pk:secretRef from the cluster's clients, or let them send to a Kafka "
                     "broker of its own")
    for bridge in bridges:
        # a bridge worker reaches a closed Kafka as plantkg's own principal; nothing else does yet
        closed = [end.id for end in (bridge.local, bridge.remote) if end.id in by_id and is_closed(by_id[end.id])
                  and not (by_id[end.id].kind == "kafka" and bridge.mechanism is BridgeMechanism.WORKER)]
        if closed:
            raise AccessNotSupportedError(
                f"{bridge.address}: broker {closed[0]!r} is closed to anonymous clients (its clients "
                "have a pk:secretRef), and a bridge at a closed broker needs plantkg's own "
                "credentials there, which plantkg does not manage yet",
                hint=f"keep {closed[0]!r} open (pk:allowAnonymous true) while it is bridged, or "
                     "move the bridged topics to another broker")


def access_label(spec: BrokerSpec) -> str:
    """Who may use the broker, in a word or two (``status``): ``users (N)`` for a closed
    Mosquitto, ``token`` for a context broker whose writes need its agent's token, ``open``
    (anyone who reaches it) otherwise. No broker plantkg runs speaks TLS yet."""
    if spec.kind in USER_KINDS:
        if spec.allow_anonymous is False:
            return f"users ({len(spec.users)})"
        return f"open + users ({len(spec.users)})" if spec.users else "open"
    if spec.kind == "ngsi-v2":
        return "open" if spec.allow_anonymous else "token for writes"
    return "open"


def open_broker_warnings(brokers: Iterable[BrokerSpec]) -> tuple[str, ...]:
    """One line per deployed broker anyone on the network may use (a Mosquitto or a Kafka open to
    anonymous clients, a context broker open to writes), saying why and how to close it (a plan
    shows them; docs/security.md)."""
    out = []
    for spec in sorted(brokers, key=lambda b: b.id):
        if spec.kind in USER_KINDS and spec.allow_anonymous is not False:
            why = ("the plant says pk:allowAnonymous true" if spec.allow_anonymous
                   else "none of its clients has a pk:secretRef")
            out.append(f"broker.{spec.id} admits anonymous clients ({why}): anyone who reaches "
                       f"{spec.host}:{spec.port} may publish and read every topic; give its "
                       "clients a pk:secretRef to close it")
        elif spec.kind == "ngsi-v2" and spec.allow_anonymous:
            out.append(f"broker.{spec.id} (context broker) takes writes without its agent's token "
                       "(the plant says pk:allowAnonymous true): anyone who reaches "
                       f"{spec.host}:{spec.port} may change every entity")
    return tuple(out)

"""Broker users and ACLs from the reasoned plant graph (docs/security.md).

A resource that sends to a broker and has a ``pk:secretRef`` is one of the broker's users: its
user name is its ``pk:id``, its password is where the reference says (read by the broker's agent,
never by plantkg's planner), and it may publish (``pk:mayWrite``, concluded from ``pk:publishes``
by rule A1 of ``ontology/plantkg-access.ttl``) and subscribe to (``pk:mayRead``, rule A2) those
of its topics the broker carries. Nothing here decides who may do what: the rules did.

- :func:`broker_users` reads them (SPARQL over the asserted and inferred facts);
- :func:`close_brokers` applies them to the derived specs: a Mosquitto or a Kafka broker of its
  own admits only its users and plantkg's principals (closed by default) unless the plant says
  ``pk:allowAnonymous true``;
- :func:`with_bridge_principals` adds plantkg's own principal of each bridge to the broker it
  logs in to (engine.security.principals): a Mosquitto bridge on its remote, a worker on its MQTT
  broker, with exactly the topics it forwards there; and, for an MQTT <-> NGSI bridge that brings
  entities back, the context broker's notify principal, writing exactly those topics;
- :func:`run_principals` and :func:`with_run_principals` make a resource plantkg runs itself (its
  type says ``pk:principalName``: the fleet manager, ``plantkg.fleet``) that principal on each
  Mosquitto with a users file it sends to, with the rights the rules gave the resource;
- :func:`check_access_supported` refuses, before anything is deployed, what plantkg cannot run
  yet: users on a broker whose driver renders none (Mosquitto's and Kafka's do, a Kafka
  cluster's nodes included) and a resource whose ``pk:id`` is one of plantkg's principal names
  (a bridge worker into a closed Kafka and a MirrorMaker 2 at each closed end authenticate as
  plantkg's own principal, engine.security.kafka_client; bridges at a closed Mosquitto as their
  bridge principal);
- :func:`with_plant_kafkas` tells each context broker the plant's closed Kafka brokers (a
  cluster's nodes included), where its ``kafka://`` notifications log in as plantkg's own
  principal, and those that speak TLS;
- :func:`check_kafka_tls_supported` refuses a Kafka cluster whose nodes would not all speak TLS;
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
from engine.model import BridgeDirection, BridgeMechanism, BridgeSpec, BrokerSpec, BrokerUser
from engine.security import kafka_client, mqtt_client, principals
from engine.values import host_in_url

#: The broker kinds whose driver renders users and ACLs.
USER_KINDS = frozenset({"mosquitto", "kafka"})
#: The broker kinds that take users as principals with tokens (the context broker), not passwords.
TOKEN_KINDS = frozenset({"ngsi-v2"})
#: The broker kinds whose brokers plantkg's own MQTT principals log in to (closed by default).
MQTT_USER_KINDS = mqtt_client.USER_KINDS
#: The broker kinds closed by default: unless the plant says ``pk:allowAnonymous true``, only
#: their users and plantkg's own principals get in (a Kafka cluster's nodes too).
CLOSED_BY_DEFAULT = MQTT_USER_KINDS | {"kafka"}

#: A resource that logs in with a password (``pk:secretRef``), a client certificate
#: (``pk:clientCertificate true``) or both is a user of every broker it sends to. The users are
#: found first (the subquery): Oxigraph does not push the ``BOUND`` filter below the rights'
#: OPTIONAL, so filtering last evaluated every resource's rights on every broker (4 s at 100k
#: resources of which none is a user, against milliseconds).
USERS = """
SELECT ?b ?r ?rid ?ref ?cert ?t ?mode WHERE {
    { SELECT DISTINCT ?r WHERE {
        { ?r pk:secretRef ?any } UNION { ?r pk:clientCertificate ?flag . FILTER (STR(?flag) IN ("true", "1")) }
    } }
    ?r pk:sendsTo ?b ; pk:id ?rid .
    ?b a pk:DeployedBroker .
    OPTIONAL { ?r pk:secretRef ?ref }
    OPTIONAL { ?r pk:clientCertificate ?cert . FILTER (STR(?cert) IN ("true", "1")) }
    OPTIONAL {
        ?b pk:mustCarry ?t .
        { ?r pk:mayWrite ?t BIND ("write" AS ?mode) } UNION { ?r pk:mayRead ?t BIND ("read" AS ?mode) }
    }
}"""


#: Resources plantkg runs itself (their type says ``pk:principalName``: the fleet manager): each
#: logs in as that principal of plantkg's own, with the rights the rules gave the resource.
RUN_PRINCIPALS = """
SELECT ?b ?name ?t ?mode WHERE {
    { SELECT ?r ?name WHERE { ?type pk:principalName ?name . ?r pk:isType ?type } }
    ?r pk:sendsTo ?b .
    ?b a pk:DeployedBroker .
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
    ``topic_names`` maps (broker IRI, topic IRI) to the topic's name on that broker. A resource
    with ``pk:clientCertificate true`` is a certificate user (``certificate``); without a
    ``pk:secretRef`` it gets no password (``secret_ref`` None): it can log in only with its
    certificate."""
    logins: dict[tuple[str, str], tuple[str | None, bool]] = {}
    rights: dict[tuple[str, str], dict[str, set[str]]] = defaultdict(lambda: {"write": set(), "read": set()})
    for row in select(USERS):
        broker, name = row["b"].value, row["rid"].value
        logins[(broker, name)] = (None if row["ref"] is None else row["ref"].value, row["cert"] is not None)
        rights[(broker, name)]  # a user with no right still exists: it may connect, nothing more
        if row["t"] is not None and (broker, row["t"].value) in topic_names:
            rights[(broker, name)][row["mode"].value].add(topic_names[(broker, row["t"].value)])
    out: dict[str, list[BrokerUser]] = defaultdict(list)
    for (broker, name), (ref, certificate) in sorted(logins.items()):
        got = rights[(broker, name)]
        out[broker].append(BrokerUser(name=name, secret_ref=ref, write=tuple(sorted(got["write"])),
                                      read=tuple(sorted(got["read"])), certificate=certificate))
    return {broker: tuple(users) for broker, users in out.items()}


def run_principals(select: Callable[[str], Iterable[ox.QuerySolution]],
                   topic_names: Mapping[tuple[str, str], str]) -> dict[str, tuple[BrokerUser, ...]]:
    """Broker IRI -> the principals of plantkg's own that resources of the plant run as there
    (``pk:principalName`` of their type, e.g. ``plantkg.fleet``), each with the topics its
    resources may write and read that the broker carries (two resources of one such type on one
    broker: one principal with the union of their rights). Their ``secret_ref`` is the principal
    key's: nobody configures their password. A name that is not one of plantkg's (``plantkg.``)
    is refused."""
    rights: dict[tuple[str, str], dict[str, set[str]]] = defaultdict(lambda: {"write": set(), "read": set()})
    for row in select(RUN_PRINCIPALS):
        broker, name = row["b"].value, row["name"].value
        if not principals.is_reserved(name) or name in principals.FIXED:
            raise AccessNotSupportedError(
                f"pk:principalName {name!r}: a resource type's principal is one of plantkg's own, "
                f"named {principals.PREFIX}<something> and not one of {', '.join(sorted(principals.FIXED))}",
                hint=f"name it {principals.PREFIX}<what runs it>, e.g. plantkg.fleet")
        got = rights[(broker, name)]
        if row["t"] is not None and (broker, row["t"].value) in topic_names:
            got[row["mode"].value].add(topic_names[(broker, row["t"].value)])
    out: dict[str, list[BrokerUser]] = defaultdict(list)
    for (broker, name), got in sorted(rights.items()):
        out[broker].append(BrokerUser(name=name, secret_ref=principals.PRINCIPAL_REF,
                                      write=tuple(sorted(got["write"])), read=tuple(sorted(got["read"]))))
    return {broker: tuple(users) for broker, users in out.items()}


def with_run_principals(brokers: Iterable[BrokerSpec],
                        users: Mapping[str, tuple[BrokerUser, ...]]) -> list[BrokerSpec]:
    """The specs with the principals of :func:`run_principals` added where they log in: a
    Mosquitto with a users file (closed, or given users by the plant). As for a bridge's
    principal, an open Mosquitto without plant users gets none (its login is not checked there,
    and a users file would cost its anonymous persistent sessions messages at a restart)."""
    out = []
    for spec in brokers:
        extra = users.get(spec.iri, ())
        if extra and spec.kind in MQTT_USER_KINDS and (is_closed(spec) or spec.users):
            spec = replace(spec, users=tuple(sorted((*spec.users, *extra), key=lambda u: u.name)))
        out.append(spec)
    return out


def close_brokers(brokers: Iterable[BrokerSpec], users: Mapping[str, tuple[BrokerUser, ...]],
                  anonymous_said: frozenset[str]) -> list[BrokerSpec]:
    """The specs with their users. A Mosquitto or a Kafka broker of its own with no
    ``pk:allowAnonymous`` of its own (``anonymous_said``: IRIs that state one) is closed
    (``allow_anonymous`` False): closed by default, whether or not its clients have a
    ``pk:secretRef``. A Kafka cluster's nodes are closed or open together: the caller counts a
    node as saying ``pk:allowAnonymous`` when its cluster says it (engine.derive)."""
    out = []
    for spec in brokers:
        mine = users.get(spec.iri, ())
        said = spec.iri in anonymous_said
        if spec.kind in CLOSED_BY_DEFAULT and not said:
            spec = replace(spec, allow_anonymous=False)
        if mine:
            spec = replace(spec, users=mine, allow_anonymous=spec.allow_anonymous if said else False)
        out.append(spec)
    return out


def with_bridge_principals(brokers: Iterable[BrokerSpec], bridges: Iterable[BridgeSpec]) -> list[BrokerSpec]:
    """The specs with each bridge's principal as a user of the closed broker the bridge logs in to:
    a Mosquitto bridge on its remote (writes what it sends there, reads what it fetches), a
    worker on its MQTT broker (reads what it forwards to Kafka or the context broker, writes what
    it brings back; an MQTT <-> NGSI worker writes nothing: the context broker publishes what comes
    back, as the bridge's notify principal). A broker that admits anonymous clients and has no plant users gets none: it
    has no users file, the bridge's login is not checked there, and a users file would cost its
    anonymous persistent sessions the messages that arrive between a restart and their
    reconnection (docs/security.md). Only a Mosquitto takes these principals: a worker or a MirrorMaker 2
    logs in to a closed Kafka as plantkg's own principal (engine.security.kafka_client). Users stay sorted
    by name."""
    extra: dict[str, list[BrokerUser]] = defaultdict(list)
    for bridge in bridges:
        at = bridge.remote if bridge.mechanism is BridgeMechanism.MOSQUITTO else bridge.local
        if at.kind not in MQTT_USER_KINDS:
            continue
        # seen from the broker it logs in to: a Mosquitto bridge sends OUT routes to the remote;
        # a worker reads OUT routes from its (local) MQTT broker
        sends = {BridgeDirection.OUT, BridgeDirection.BOTH}
        fetches = {BridgeDirection.IN, BridgeDirection.BOTH}
        write, read = (sends, fetches) if bridge.mechanism is BridgeMechanism.MOSQUITTO else (fetches, sends)
        if bridge.mechanism is BridgeMechanism.NGSI:
            # the context broker, not the worker, publishes what comes back: a principal of its own
            back = tuple(sorted(r.topic for r in bridge.routes if r.direction in fetches))
            if back:
                extra[at.id].append(BrokerUser(name=principals.notify_principal(bridge.local.id, bridge.remote.id),
                                               secret_ref=principals.PRINCIPAL_REF, write=back))
            write = set()
        extra[at.id].append(BrokerUser(
            name=principals.bridge_principal(bridge.local.id, bridge.remote.id),
            secret_ref=principals.PRINCIPAL_REF,
            write=tuple(sorted(r.topic for r in bridge.routes if r.direction in write)),
            read=tuple(sorted(r.topic for r in bridge.routes if r.direction in read))))
    out = []
    for spec in brokers:
        if (is_closed(spec) or spec.users) and extra.get(spec.id):  # a broker with a users file
            spec = replace(spec, users=tuple(sorted((*spec.users, *extra[spec.id]), key=lambda u: u.name)))
        out.append(spec)
    return out


def with_plant_kafkas(brokers: Iterable[BrokerSpec]) -> list[BrokerSpec]:
    """The specs with each context broker told the plant's closed Kafka brokers
    (``closed_kafkas``, ``host:port`` sorted): its ``kafka://`` notifications log in there as
    plantkg's own Kafka principal (engine.security.kafka_client), and only there, so plantkg's
    password never goes to a Kafka a subscription names that is not the plant's; and those that
    speak TLS (``tls_kafkas``): its notifications reach them over TLS, trusting the plant CA only.
    A Kafka cluster's nodes with the broker role count each (a subscription's bootstrap names one
    or more of them); a controller-only node serves no client."""
    brokers = list(brokers)
    own = [b for b in brokers if b.kind == "kafka" and (b.kafka is None or "broker" in b.kafka.roles)]
    closed = tuple(sorted(f"{host_in_url(b.host)}:{b.port}" for b in own if kafka_client.is_closed(b)))
    tls = tuple(sorted(f"{host_in_url(b.host)}:{b.port}" for b in own if b.tls))
    return [replace(b, closed_kafkas=closed, tls_kafkas=tls) if b.kind in TOKEN_KINDS else b for b in brokers]


def is_closed(spec: BrokerSpec) -> bool:
    """A Mosquitto or a Kafka that admits only its users."""
    return spec.kind in USER_KINDS and spec.allow_anonymous is False


def check_access_supported(brokers: Iterable[BrokerSpec]) -> None:
    """Refuse users on a broker whose driver renders none, plant users named like plantkg's own
    principals (``plantkg.``...), principals on a context broker open to anonymous writes, and
    users on a Kafka open to anonymous clients (a Kafka is either SASL or open: it cannot admit
    both)."""
    by_id = {b.id: b for b in brokers}
    for spec in by_id.values():
        if spec.users and spec.kind in TOKEN_KINDS and spec.allow_anonymous:
            raise AccessNotSupportedError(
                f"broker {spec.id!r} (context broker): the plant says pk:allowAnonymous true, but its "
                f"clients {', '.join(u.name for u in spec.users)} have a pk:secretRef (principals "
                "close it)", hint="remove pk:allowAnonymous, or the clients' pk:secretRef")
        if spec.users and spec.kind == "kafka" and spec.allow_anonymous:
            raise AccessNotSupportedError(
                f"broker {spec.id!r} (kafka): the plant says pk:allowAnonymous true, but its clients "
                f"{', '.join(u.name for u in spec.users)} have a pk:secretRef: a Kafka's listener "
                "either authenticates every client (SASL) or none, so it cannot be open and have users",
                hint="remove pk:allowAnonymous (the Kafka is then closed, and only its users get in), "
                     "or the clients' pk:secretRef")
        if spec.users and spec.kind not in USER_KINDS | TOKEN_KINDS:
            names = ", ".join(u.name for u in spec.users)
            raise AccessNotSupportedError(
                f"broker {spec.id!r} ({spec.kind}): its clients {names} have a pk:secretRef, but "
                f"plantkg renders users and ACLs for {', '.join(sorted(USER_KINDS | TOKEN_KINDS))} brokers only (yet)",
                hint="remove pk:secretRef from those resources, or let them send to a Mosquitto broker")
        reserved = [u.name for u in spec.users
                    if principals.is_reserved(u.name) and u.secret_ref != principals.PRINCIPAL_REF]
        if reserved:
            raise AccessNotSupportedError(
                f"broker {spec.id!r}: the resource with pk:id {reserved[0]!r} has a pk:secretRef or a "
                "client certificate, "
                f"but user names starting with {principals.PREFIX!r} are plantkg's own principals",
                hint="give the resource another pk:id")


def access_label(spec: BrokerSpec) -> str:
    """Who may use the broker, in a word or two (``status``): ``users (N)`` for a closed
    Mosquitto or Kafka (N: the plant's users and the bridges' principals; plantkg's fixed principals not
    counted), ``token`` for a closed context broker without principals (its agent's token only), ``open``
    (anyone who reaches it) otherwise; ``, TLS`` when its listener speaks TLS only, and
    ``, certificates :PORT`` when it has a certificate listener."""
    if spec.kind in USER_KINDS:
        tls = ", TLS" if spec.tls else ""
        if spec.certificate_port is not None:
            tls += f", certificates :{spec.certificate_port}"
        if spec.allow_anonymous is False:
            return f"users ({len(spec.users)}){tls}"
        return (f"open + users ({len(spec.users)}){tls}" if spec.users else f"open{tls}")
    if spec.kind == "ngsi-v2":
        tls = ", TLS" if spec.tls else ""
        if spec.users:
            return f"principals ({len(spec.users)}){tls}"
        return ("open" if spec.allow_anonymous else "token") + tls
    return "open"


def open_broker_warnings(brokers: Iterable[BrokerSpec]) -> tuple[str, ...]:
    """One line per deployed broker anyone on the network may use (a Mosquitto or a Kafka open to
    anonymous clients, a context broker open to writes), saying why and how to close it (a plan
    shows them; docs/security.md)."""
    out = []
    for spec in sorted(brokers, key=lambda b: b.id):
        if spec.kind in USER_KINDS and spec.allow_anonymous is not False:
            if spec.kafka is not None:
                why = f"a node of Kafka cluster {spec.kafka.cluster}, which says pk:allowAnonymous true"
                fix = (f"remove pk:allowAnonymous from cluster {spec.kafka.cluster} (closed by default) "
                       "and give its clients a pk:secretRef")
            else:
                why = ("the plant says pk:allowAnonymous true" if spec.allow_anonymous
                       else "its spec does not close it")
                fix = "remove pk:allowAnonymous (closed by default) and give its clients a pk:secretRef"
            out.append(f"broker.{spec.id} admits anonymous clients ({why}): anyone who reaches "
                       f"{spec.host}:{spec.port} may publish and read every topic; {fix}")
        elif spec.kind == "ngsi-v2" and spec.allow_anonymous:
            out.append(f"broker.{spec.id} (context broker) admits anonymous clients (the plant says "
                       "pk:allowAnonymous true): anyone who reaches "
                       f"{spec.host}:{spec.port} may read and change every entity; remove "
                       "pk:allowAnonymous (closed by default) and give its clients its agent's token "
                       "or a pk:secretRef")
    return tuple(out)


def check_kafka_tls_supported(brokers: Iterable[BrokerSpec]) -> None:
    """Refuse, before anything runs, a Kafka cluster whose nodes do not all speak TLS or all speak
    plain (a node that says ``pk:tls true`` of its own while its cluster does not: the shapes
    refuse it first). A cluster's nodes talk to each other on the listeners clients use, so a
    mixed cluster could not form its quorum. A cluster that says ``pk:tls true`` speaks TLS on
    every node (engine.derive); bridge workers, MirrorMaker 2 and plantkg's other clients speak
    TLS to it."""
    by_cluster: dict[str, list[BrokerSpec]] = defaultdict(list)
    for spec in brokers:
        if spec.kind == "kafka" and spec.kafka is not None:
            by_cluster[spec.kafka.cluster].append(spec)
    for cluster, nodes in sorted(by_cluster.items()):
        tls = sorted(n.id for n in nodes if n.tls)
        if tls and len(tls) != len(nodes):
            raise AccessNotSupportedError(
                f"Kafka cluster {cluster!r}: its nodes {', '.join(tls)} say pk:tls true but not the "
                "cluster: a cluster's nodes speak TLS all together or none",
                hint=f"say pk:tls true on cluster {cluster!r} (every node then speaks TLS), and remove "
                     "pk:tls from its nodes")

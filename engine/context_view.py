"""Live context in the plant's graph: the entities of every context broker the plant names.

A context broker keeps its context as RDF (docs/context-broker.md, "The context as RDF") and
serves all of it as N-Quads at ``GET /plantkg/v1/graph``, one named graph per tenant under
``NGSI_GRAPH_BASE``. ``plantkg serve`` reads it on every observation and puts those graphs into the
plant's store beside the plant, the inferred facts and the observed state, so one SPARQL query can
ask "which broker carries AGV 7's state, and what does it say now".

- Which brokers: every individual the reasoner classified ``pk:ContextBroker`` (brokerType
  "ngsi-v2"), deployed by plantkg or ``pk:external`` (a real Orion does not serve this route: it is
  reported unavailable, nothing else breaks).
- The graphs of all context brokers are replaced together; tenants of the same name on two
  context brokers meet in one named graph (the context is one data space; entity nodes are keyed
  by their ids).
- A context broker that does not answer keeps nothing of its old context in the graph and is
  named in :attr:`ContextView.unavailable`, so the dashboard can say so; it never fails the
  observation of brokers.

A context broker plantkg deploys is read with its agent's token (:func:`agent_tokens`: the
engine's agents file holds every agent's), plantkg's own principal there: a closed one (with
principals) answers 401 without it, and its reads of the whole graph are plantkg's only
(docs/security.md). A ``pk:external`` context broker (a real Orion) is read without a token, so no
agent's token ever goes to a broker plantkg does not run; only loopback or plant addresses the
plant itself names are asked. One that says ``pk:tls true`` is read over HTTPS, verified against the
plant CA only (engine.security.https).
"""

from __future__ import annotations

import http.client
from collections.abc import Callable, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import pyoxigraph as ox

from engine.errors import EngineError
from engine.model import BrokerSpec
from engine.security import https
from engine.values import host_in_url
from kg.load import PlantGraph
from kg.namespaces import NGSI_GRAPH_BASE
from kg.query import run_query

GRAPH_PATH = "/plantkg/v1/graph"
#: Largest context read (bytes); a bigger answer is refused rather than held in memory twice.
MAX_CONTEXT_BYTES = 256 * 1024 * 1024

_CONTEXT_BROKERS = """SELECT ?broker ?ip ?port ?tls WHERE {
  ?broker a pk:ContextBroker ; pk:ip ?ip ; pk:port ?port . OPTIONAL { ?broker pk:tls ?tls } } ORDER BY ?broker"""


@dataclass(frozen=True)
class ContextSource:
    """A context broker of the plant: its individual, where it answers, the token it is read
    with (None: none sent) and whether it speaks HTTPS (``pk:tls true``)."""

    iri: str
    host: str
    port: int
    token: str | None = field(default=None, repr=False)  # never shown
    tls: bool = False

    @property
    def url(self) -> str:
        return f"{'https' if self.tls else 'http'}://{host_in_url(self.host)}:{self.port}{GRAPH_PATH}"


@dataclass(frozen=True)
class ContextView:
    """What one read of the context put into the plant's store."""

    quads: int = 0
    sources: tuple[ContextSource, ...] = ()
    unavailable: tuple[tuple[str, str], ...] = ()   # (broker IRI, why)


def agent_tokens(brokers: Iterable[BrokerSpec], token_for: Callable[[str], str]) -> dict[str, str]:
    """Broker IRI -> the token of its agent, for each context broker plantkg deploys (``brokers``:
    the desired state's, so no ``pk:external`` one); ``token_for(host)`` is the agents file's
    (:meth:`engine.agents_config.AgentDirectory.token_for`). A broker whose agent has no token is
    left out (it is then read without one, and a closed one is reported unavailable)."""
    out = {}
    for spec in brokers:
        if spec.kind == "ngsi-v2":
            try:
                out[spec.iri] = token_for(spec.host)
            except EngineError:
                continue
    return out


def context_sources(plant: PlantGraph, tokens: Mapping[str, str] | None = None) -> list[ContextSource]:
    """The plant's context brokers (needs the inferred classes: run after reasoning), each with
    its token from ``tokens`` (broker IRI -> token, :func:`agent_tokens`) if there."""
    tokens = tokens or {}
    found = []
    for broker, ip, port, tls in run_query(plant, _CONTEXT_BROKERS).rows:
        if isinstance(broker, ox.NamedNode) and isinstance(ip, ox.Literal) and isinstance(port, ox.Literal):
            try:
                found.append(ContextSource(broker.value, ip.value, int(port.value), tokens.get(broker.value),
                                           tls=isinstance(tls, ox.Literal) and tls.value in ("true", "1")))
            except ValueError:
                continue   # a port the shapes refused already; nothing to ask
    return found


def fetch_context(source: ContextSource, timeout: float = 3.0) -> list[ox.Quad]:
    """The context broker's whole context, parsed; raises :class:`OSError` or
    :class:`ValueError` saying why it could not be read."""
    try:
        conn = https.connection(source.host, source.port, timeout=timeout, tls=source.tls)
    except EngineError as exc:  # no usable plant CA to verify an https broker with
        raise ValueError(f"{source.url}: {exc}") from None
    try:
        headers = {"Accept": "application/n-quads"}
        if source.token is not None:
            headers["Authorization"] = f"Bearer {source.token}"
        conn.request("GET", GRAPH_PATH, headers=headers)
        response = conn.getresponse()
        body = response.read(MAX_CONTEXT_BYTES + 1)
    finally:
        conn.close()
    if response.status != 200:
        raise ValueError(f"{source.url} answered HTTP {response.status}")
    if len(body) > MAX_CONTEXT_BYTES:
        raise ValueError(f"{source.url}: the context is larger than {MAX_CONTEXT_BYTES} bytes")
    quads = list(ox.parse(body, format=ox.RdfFormat.N_QUADS))
    outside = next((q for q in quads if not _context_graph(q.graph_name)), None)
    if outside is not None:
        raise ValueError(f"{source.url}: a quad outside the context graphs ({outside.graph_name})")
    return quads


def write_context(plant: PlantGraph, sources: Iterable[ContextSource], *, timeout: float = 3.0,
                  parallelism: int = 4) -> ContextView:
    """Replace every context graph in the plant's store with what the context brokers serve now.
    The caller holds the store's write lock."""
    sources = tuple(sources)
    unavailable: list[tuple[str, str]] = []
    quads: list[ox.Quad] = []

    def read(source: ContextSource) -> list[ox.Quad] | str:
        try:
            return fetch_context(source, timeout)
        except (OSError, ValueError, http.client.HTTPException) as exc:
            return f"{type(exc).__name__}: {exc}"

    with ThreadPoolExecutor(max_workers=max(1, min(parallelism, len(sources) or 1))) as pool:
        for source, got in zip(sources, pool.map(read, sources)):
            if isinstance(got, str):
                unavailable.append((source.iri, got))
            else:
                quads.extend(got)
    for graph in [g for g in plant.store.named_graphs() if _context_graph(g)]:
        plant.store.remove_graph(graph)
    plant.store.extend(quads)
    return ContextView(len(quads), sources, tuple(unavailable))


def _context_graph(graph: object) -> bool:
    return isinstance(graph, ox.NamedNode) and graph.value.startswith(NGSI_GRAPH_BASE)

"""What the dashboard shows, as JSON-able data made from the engine's values (pure functions).

One status document per snapshot (:func:`status_document`) feeds the overview tables, the graph
and the live updates, so the browser renders from one source. Uptimes are not computed here: the
document carries ``started_at`` and the page counts from it, so the document only changes when
the plant or what runs changes.

Bridges are shown as the plant asks for them (``DesiredState.bridges``) with what their agent
reports (``ObservedState.bridges``): status, forwarded and retried messages, restarts.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from engine.context_view import ContextView
from engine.model import BridgeSpec, BrokerStatus, DesiredState, ObservedBridge, ObservedState, Plan
from engine.render.plan import plan_dict, summary_line
from kg.validate import ValidationReport

#: Above this many resources the graph shows one node per broker ("N resources") instead.
GRAPH_RESOURCE_LIMIT = 150
#: The status document lists this many topic rows at most (a 10k plant has 10k; SPARQL has all).
TOPIC_ROWS_SHOWN = 500
_ALIVE = {BrokerStatus.RUNNING.value, BrokerStatus.STARTING.value}


@dataclass(frozen=True)
class ResourceLink:
    """A resource of the plant and the broker it sends to (``pk:sendsTo``)."""

    id: str
    name: str
    broker_id: str


def broker_rows(desired: DesiredState | None, observed: ObservedState | None) -> list[dict[str, Any]]:
    """One row per broker: desired ones first (absent/unknown when nothing runs), then extras."""
    observed = observed or ObservedState()
    rows = []
    named = set()
    for spec in desired.brokers if desired else ():
        named.add(spec.id)
        have = observed.broker(spec.id)
        wanted = sorted(t.name for t in desired.topics_of(spec.id)) if desired else []
        status = (have.status.value if have else
                  "unknown" if spec.host in observed.unreachable else "absent")
        rows.append(_broker_row(spec.id, spec.name, spec.kind, spec.host, spec.port, status, have,
                                wanted, in_plant=True))
    for have in observed.brokers:
        if have.spec.id not in named:
            rows.append(_broker_row(have.spec.id, have.spec.name, have.spec.kind, have.spec.host,
                                    have.spec.port, have.status.value, have, [], in_plant=False))
    return rows


def _broker_row(broker_id: str, name: str, kind: str, host: str, port: int, status: str, have: Any,
                wanted: list[str], *, in_plant: bool) -> dict[str, Any]:
    present = sorted(t.name for t in have.topics) if have else []
    return {
        "id": broker_id, "name": name, "kind": kind, "host": host, "port": port,
        "address": f"[{host}]:{port}" if ":" in host else f"{host}:{port}",
        "status": status, "in_plant": in_plant,
        "pid": have.pid if have else None,
        "started_at": have.started_at if have and status in _ALIVE else None,
        "restarts": have.restarts if have else None,
        "last_error": have.last_error if have else None,
        "topics_wanted": len(wanted), "topics_present": len(set(present) & set(wanted)),
        "topics_extra": len(set(present) - set(wanted)),
    }


def topic_rows(desired: DesiredState | None, observed: ObservedState | None) -> list[dict[str, Any]]:
    """One row per (broker, topic) the plant asks for, with whether the broker has it."""
    observed = observed or ObservedState()
    rows = []
    for t in desired.topics if desired else ():
        have = observed.broker(t.broker_id)
        settings = {k: v for k, v in (("partitions", t.partitions), ("replication", t.replication_factor),
                                      ("retention_ms", t.retention_ms), ("qos", t.qos), ("retain", t.retain),
                                      ("entity_id", t.entity_id), ("entity_type", t.entity_type))
                    if v is not None}
        rows.append({"broker_id": t.broker_id, "name": t.name, "settings": settings,
                     "present": bool(have and any(o.name == t.name for o in have.topics))})
    return rows


def topic_section(desired: DesiredState | None, observed: ObservedState | None) -> dict[str, Any]:
    """``topics`` (the first :data:`TOPIC_ROWS_SHOWN` rows) and ``topics_total``."""
    rows = topic_rows(desired, observed)
    return {"topics": rows[:TOPIC_ROWS_SHOWN], "topics_total": len(rows)}


def _bridge_base(spec: BridgeSpec) -> dict[str, Any]:
    return {"address": spec.address, "local": spec.local.id, "remote": spec.remote.id,
            "mechanism": spec.mechanism.value, "asserted": spec.asserted,
            "routes": [{"topic": r.topic, "direction": r.direction.value, "qos": r.qos} for r in spec.routes]}


def bridge_rows(desired: DesiredState | None, observed: ObservedState | None) -> list[dict[str, Any]]:
    """One row per bridge the plant asks for or an agent runs, with its status and counters."""
    running = {b.spec.address: b for b in observed.bridges} if observed else {}
    rows, seen = [], set()
    for spec in desired.bridges if desired else ():
        seen.add(spec.address)
        rows.append({**_bridge_base(spec), **_bridge_observed(running.get(spec.address)), "in_plant": True})
    for address, have in running.items():
        if address not in seen:
            rows.append({**_bridge_base(have.spec), **_bridge_observed(have), "in_plant": False})
    return rows


def _bridge_observed(have: ObservedBridge | None) -> dict[str, Any]:
    if have is None:
        return {"status": "absent", "forwarded": None, "retried": None, "refused": None, "restarts": None,
                "started_at": None, "last_error": None}
    return {"status": have.status.value, "forwarded": have.forwarded, "retried": have.retried,
            "refused": have.refused, "restarts": have.restarts, "started_at": have.started_at, "last_error": have.last_error}


def machine_rows(brokers: list[dict[str, Any]], observed: ObservedState | None,
                 agent_urls: Mapping[str, str]) -> list[dict[str, Any]]:
    """One row per host (machine): its agent, whether it answered, its brokers."""
    unreachable = set(observed.unreachable) if observed else set()
    by_host: dict[str, list[str]] = defaultdict(list)
    for row in brokers:
        by_host[row["host"]].append(row["id"])
    hosts = sorted(set(by_host) | set(agent_urls))
    return [{"host": h, "agent": agent_urls.get(h), "brokers": by_host.get(h, []),
             "agent_status": ("not asked" if observed is None else
                              "unreachable" if h in unreachable else "answered")} for h in hosts]


def graph_elements(brokers: list[dict[str, Any]], bridges: list[dict[str, Any]],
                   resources: Iterable[ResourceLink]) -> dict[str, Any]:
    """Nodes and edges for the picture: resources → brokers, bridges between brokers."""
    resources = list(resources)
    nodes = [{"id": f"broker:{b['id']}", "label": f"{b['id']}\n{b['kind']} {b['address']}",
              "type": "broker", "status": b["status"]} for b in brokers]
    known = {b["id"] for b in brokers}
    edges = []
    if len(resources) <= GRAPH_RESOURCE_LIMIT:
        for r in resources:
            nodes.append({"id": f"resource:{r.id}", "label": r.name or r.id, "type": "resource",
                          "status": "resource"})
            if r.broker_id in known:
                edges.append({"id": f"sends:{r.id}:{r.broker_id}", "source": f"resource:{r.id}",
                              "target": f"broker:{r.broker_id}", "type": "sends"})
    else:
        counts: dict[str, int] = defaultdict(int)
        for r in resources:
            counts[r.broker_id] += 1
        for broker_id, n in sorted(counts.items()):
            if broker_id in known:
                nodes.append({"id": f"resources:{broker_id}", "label": f"{n} resources",
                              "type": "resource", "status": "resource"})
                edges.append({"id": f"sends:*:{broker_id}", "source": f"resources:{broker_id}",
                              "target": f"broker:{broker_id}", "type": "sends"})
    for b in bridges:
        if b["local"] in known and b["remote"] in known:
            edges.append({"id": b["address"], "source": f"broker:{b['local']}",
                          "target": f"broker:{b['remote']}", "type": "bridge", "status": b["status"],
                          "label": ", ".join(r["topic"] for r in b["routes"][:3])})
    return {"nodes": nodes, "edges": edges, "resources": len(resources),
            "aggregated": len(resources) > GRAPH_RESOURCE_LIMIT}


def report_summary(report: ValidationReport | None) -> dict[str, Any]:
    if report is None:
        return {"conforms": None, "violations": 0, "warnings": 0}
    return {"conforms": report.conforms, "violations": len(report.violations),
            "warnings": len(report.results) - len(report.violations)}


def plan_summary(plan: Plan | None, fingerprint: str | None) -> dict[str, Any] | None:
    if plan is None:
        return None
    data = plan_dict(plan)
    return {"fingerprint": fingerprint, "applicable": data["applicable"], "empty": data["empty"],
            "summary": data["summary"], "line": summary_line(plan),
            "pending": [c.address for c in plan.pending], "unreachable": data["unreachable"],
            "refusals": data["refusals"], "foreign": data["foreign"]}


def context_summary(context: ContextView | None) -> dict[str, Any] | None:
    """The live context read from the plant's context brokers: how many quads, who did not answer."""
    if context is None:
        return None
    return {"quads": context.quads, "brokers": [s.iri for s in context.sources],
            "unavailable": [{"broker": iri, "why": why} for iri, why in context.unavailable]}

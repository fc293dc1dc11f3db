"""Judging one flow from what arrived where (pure: counts in, a frozen result out).

A flow passes when its topic arrived at every watchable broker that must carry it. When the
publishing broker saw it and a broker downstream did not, the flow fails naming the resource, the
topic, the broker that got nothing and the bridge(s) into it (with the bridge's observed status).
When even the publishing broker saw nothing, nothing downstream can be judged: "no traffic".
A context broker (or any kind check cannot watch) is listed as not checked, never as passed.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Mapping

from engine.check.flows import Flow, Link, Stop


class Outcome(str, enum.Enum):
    PASS = "pass"
    FAIL = "fail"
    NO_TRAFFIC = "no-traffic"      # passive: the publishing broker saw nothing
    NOT_CHECKED = "not-checked"    # the publishing broker is of a kind check cannot watch

    @property
    def failed(self) -> bool:
        return self in (Outcome.FAIL, Outcome.NO_TRAFFIC)


@dataclass(frozen=True)
class StopResult:
    stop: Stop
    arrived: int | None    # messages (passive) or probe arrivals (--probe); None: not checked
    note: str = ""         # why not checked


@dataclass(frozen=True)
class FlowResult:
    flow: Flow
    outcome: Outcome
    stops: tuple[StopResult, ...]
    message: str
    warnings: tuple[str, ...] = ()
    probe_id: str | None = None


def _not_checked(stop: Stop) -> str:
    return f"not checked: {stop.broker} is a {stop.kind} broker; check watches MQTT and Kafka brokers only"


def _bridges(links: tuple[Link, ...], bridge_status: Mapping[str, str]) -> str:
    if not links:
        return "no bridge of the plant carries it there"
    return ", ".join(f"bridge {link.bridge} from {link.source} ({link.mechanism}, "
                     f"{bridge_status.get(link.bridge, 'status unknown')})" for link in links)


def judge(flow: Flow, arrived: Mapping[str, int], *, probe_id: str | None, deadline: float,
          bridge_status: Mapping[str, str] | None = None) -> FlowResult:
    """``arrived``: broker id -> messages on the flow's topic (passive) or arrivals of the flow's
    probe (``probe_id`` given); ``bridge_status``: bridge address -> what its agent reports."""
    status = bridge_status or {}
    stops = tuple(StopResult(s, arrived.get(s.broker, 0), "") if s.watchable
                  else StopResult(s, None, _not_checked(s)) for s in flow.stops)
    who = f"{flow.resource} ({flow.resource_id})" if flow.resource != flow.resource_id else flow.resource
    within = f"within {deadline:g} s"
    source = stops[0]
    if source.arrived is None:
        return FlowResult(flow, Outcome.NOT_CHECKED, stops, f"{who} on {flow.topic}: {source.note}",
                          probe_id=probe_id)
    if not source.arrived:
        if probe_id is None:
            message = f"no traffic from {who} on {flow.topic} at {source.stop.broker} {within}"
            return FlowResult(flow, Outcome.NO_TRAFFIC, stops, message)
        message = (f"the probe for {who} on {flow.topic}, published at {source.stop.broker}, "
                   f"did not arrive there {within}")
        return FlowResult(flow, Outcome.FAIL, stops, message, probe_id=probe_id)
    what = "the probe" if probe_id else f"{source.arrived} message(s)"
    missing = [r for r in stops[1:] if r.arrived == 0]
    warnings = tuple(_duplicate(r, status) for r in stops if probe_id and r.arrived and r.arrived > 1)
    if missing:
        lines = [f"{who} on {flow.topic}: {what} reached {source.stop.broker} but nothing arrived at "
                 f"{r.stop.broker} {within}: {_bridges(r.stop.via, status)}" for r in missing]
        return FlowResult(flow, Outcome.FAIL, stops, "\n".join(lines), warnings, probe_id)
    reached = [r.stop.broker for r in stops if r.arrived]
    message = f"{who} on {flow.topic}: {what} arrived at {', '.join(reached)}"
    return FlowResult(flow, Outcome.PASS, stops, message, warnings, probe_id)


def _duplicate(result: StopResult, status: Mapping[str, str]) -> str:
    via = result.stop.via
    if len(via) > 1:
        why = f"two bridge paths deliver the same messages twice ({_bridges(via, status)})"
    else:
        why = "delivered more than once (a redelivery, or a path the plant does not show)"
    return f"the probe arrived {result.arrived} times at {result.stop.broker}: {why}"

"""``plantkg check``'s output: lines for people, one typed JSON document for programs."""

from __future__ import annotations

import json
from collections import Counter
from typing import Any

from engine.check.run import CheckResult
from engine.check.verdict import FlowResult, Outcome

_LABELS = {Outcome.PASS: ("ok", "green"), Outcome.FAIL: ("FAIL", "red"),
           Outcome.NO_TRAFFIC: ("FAIL", "red"), Outcome.NOT_CHECKED: ("skip", "yellow")}


def counts(check: CheckResult) -> dict[str, int]:
    found = Counter(r.outcome.value for r in check.results)
    return {o.value: found.get(o.value, 0) for o in Outcome}


def render_text(check: CheckResult, style: Any = None) -> str:
    """One block per flow: verdict and message, the brokers with what arrived, notes, warnings."""
    paint = style or (lambda text, **_: text)
    unit = "probe arrivals" if check.probe else "messages"
    lines = []
    for result in check.results:
        label, colour = _LABELS[result.outcome]
        first, *rest = result.message.splitlines()
        lines.append(paint(f"{label:<5}", fg=colour, bold=True) + first)
        lines += [f"      {line}" for line in rest]
        for stop in result.stops:
            shown = "not checked" if stop.arrived is None else f"{unit}: {stop.arrived}"
            via = ", ".join(link.bridge for link in stop.stop.via) or "source"
            lines.append(f"        {stop.stop.broker:<20} {stop.stop.kind:<10} {via:<32} {shown}")
            if stop.note and stop is not result.stops[0]:
                lines.append(paint(f"        {stop.note}", fg="yellow"))
        lines += [paint(f"warn  {w}", fg="yellow", bold=True) for w in result.warnings]
    n = counts(check)
    mode = "probe" if check.probe else "passive"
    lines.append(f"{len(check.results)} flow(s), {mode}, deadline {check.deadline:g} s: {n['pass']} passed, "
                 f"{n['fail'] + n['no-traffic']} failed, {n['not-checked']} not checked")
    if check.probe and check.results:
        lines.append("note: --probe published marked test messages (plantkg-check) that real consumers see")
    return "\n".join(lines)


def _flow_dict(result: FlowResult) -> dict[str, Any]:
    flow = result.flow
    return {
        "resource_id": flow.resource_id, "resource": flow.resource, "topic": flow.topic,
        "source": flow.source.broker, "outcome": result.outcome.value, "message": result.message,
        "probe_id": result.probe_id, "warnings": list(result.warnings),
        "brokers": [{"broker": s.stop.broker, "kind": s.stop.kind, "host": s.stop.host, "port": s.stop.port,
                     "hops": s.stop.hops, "checked": s.arrived is not None, "arrived": s.arrived,
                     "note": s.note or None,
                     "via": [{"bridge": link.bridge, "from": link.source, "mechanism": link.mechanism}
                             for link in s.stop.via]}
                    for s in result.stops],
    }


def render_json(check: CheckResult) -> str:
    """Typed: counts, ports and seconds as numbers, ``arrived`` null where not checked."""
    return json.dumps({
        "passed": check.passed, "mode": "probe" if check.probe else "passive",
        "deadline_s": check.deadline, "elapsed_s": round(check.elapsed, 3),
        "counts": counts(check), "flows": [_flow_dict(r) for r in check.results],
    }, indent=2)

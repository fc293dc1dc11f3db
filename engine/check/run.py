"""One check: start a tap at every broker the flows cross, publish the probes (``--probe``), watch
until every flow arrived everywhere or the deadline passed, judge each flow.

Taps get up to ``deadline`` seconds (at least :data:`MIN_CONNECT` s) to connect and subscribe (a
broker that does not answer in that time is unreachable:
:class:`~engine.check.watch.BrokerUnreachableError`, exit 2); the watch then
lasts up to ``deadline`` seconds more and ends early once every flow has arrived everywhere. With
probes, when a broker of some flow is fed by two bridges, the watch goes on for a grace (a tenth of
the deadline, at least 1 s, never past it) after every probe arrived, so that a second delivery
through the other path is counted.
"""

from __future__ import annotations

import threading
import time
import uuid
from dataclasses import dataclass
from typing import Mapping

from engine.check.flows import Flow
from engine.check.verdict import FlowResult, judge
from engine.check.watch import Endpoint, Tap, make_tap, probe_payload, publish_probe

MIN_CONNECT = 10.0  # seconds: a short --deadline must not turn a loaded Kafka's slow metadata into exit 2
MIN_DUPLICATE_GRACE = 1.0  # seconds: how long a probe may lag through a second bridge path


@dataclass(frozen=True)
class CheckResult:
    results: tuple[FlowResult, ...]
    probe: bool
    deadline: float
    elapsed: float      # seconds, taps ready to verdict

    @property
    def passed(self) -> bool:
        return not any(r.outcome.failed for r in self.results)


def _endpoints(flows: tuple[Flow, ...]) -> dict[Endpoint, tuple[str, ...]]:
    wanted: dict[Endpoint, set[str]] = {}
    for flow in flows:
        if not flow.source.watchable:
            continue
        for stop in flow.stops:
            if stop.watchable:
                endpoint = Endpoint(stop.broker, stop.kind, stop.host, stop.port, stop.tls, stop.closed)
                wanted.setdefault(endpoint, set()).add(flow.topic)
    return {e: tuple(sorted(t)) for e, t in sorted(wanted.items(), key=lambda item: item[0].broker)}


def run_check(flows: tuple[Flow, ...], *, deadline: float, probe: bool,
              bridge_status: Mapping[str, str] | None = None) -> CheckResult:
    """Watch (and probe) the plant's flows; raises BrokerUnreachableError when a broker is down."""
    taps: dict[str, Tap] = {}
    stop = threading.Event()
    try:
        setup_end = time.monotonic() + max(deadline, MIN_CONNECT)
        for endpoint, topics in _endpoints(flows).items():
            tap = taps[endpoint.broker] = make_tap(endpoint, topics)
            tap.start(max(setup_end - time.monotonic(), 0.1))
        started = time.monotonic()
        end = started + deadline
        probes: dict[Flow, str] = {}
        if probe:
            for flow in flows:
                if flow.source.watchable:
                    probes[flow] = uuid.uuid4().hex
                    src = flow.source
                    publish_probe(Endpoint(src.broker, src.kind, src.host, src.port, src.tls, src.closed), flow.topic, probes[flow],
                                  probe_payload(probes[flow], flow.resource_id, flow.topic),
                                  max(end - time.monotonic(), 0.1))

        def counts(flow: Flow) -> dict[str, int]:
            if not flow.source.watchable:
                return {}  # not checked: no tap counts for it, no probe was published
            return {s.broker: (taps[s.broker].probe_arrivals(probes[flow]) if probe
                               else taps[s.broker].messages(flow.topic))
                    for s in flow.stops if s.broker in taps}

        def arrived_everywhere() -> bool:
            return all(all(counts(f).values()) for f in flows)

        while time.monotonic() < end and not arrived_everywhere():
            stop.wait(0.05)
        if probe and any(len(s.via) > 1 for f in flows for s in f.stops):
            grace = max(MIN_DUPLICATE_GRACE, deadline / 10)
            stop.wait(max(min(grace, end - time.monotonic()), 0.0))
        elapsed = time.monotonic() - started
        results = tuple(judge(f, counts(f), probe_id=probes.get(f), deadline=deadline,
                              bridge_status=bridge_status) for f in flows)
    finally:
        for tap in taps.values():
            tap.close()
    return CheckResult(results, probe, deadline, elapsed)

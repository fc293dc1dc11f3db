"""``plantkg demo``: a plant brought up, fed and torn down on this machine, end to end.

The steps are the ones a person would take on a real plant, each with its real part: start an agent
per machine of the plant (each on its own loopback address), ``validate``, ``apply``, ``status``,
then simulated resources publish (:mod:`engine.demo.simulate`) and taps on every topic of every broker
show what arrives, live — on Kafka that is the merged stream: the power meter's readings published
there and the robot's pose carried over from Mosquitto by the bridge; at the end (``--duration`` or Ctrl-C) ``destroy`` and the agents stop. Nothing is
left running, whatever happens in between.

A context broker of the plant (``ngsi-v2``, the AGV example) takes part the same way: a resource
publishing there writes the topic's entity with its agent's token, and its tap reads the entities
and shows their attribute values (:mod:`engine.demo.simulate_ngsi`).
"""

from __future__ import annotations

import os
import secrets
import tempfile
import threading
import time
from pathlib import Path
from collections.abc import Iterable
from typing import Callable

import click

from engine.agent.local import LocalAgents, start_local_agents
from engine.model import BridgeDirection, BrokerSpec, DesiredState
from engine.pipeline import run_pipeline
from engine.demo.simulate import Feed, Source, Tap
from engine.demo.simulate_ngsi import NgsiSource, NgsiTap

NGSI = "ngsi-v2"
from kg.query import run_query

FEEDS_QUERY = """
SELECT ?resource ?topic ?value ?broker ?qos ?rid ?ref WHERE {
  ?r pk:publishes ?t ; pk:sendsTo ?b ; pk:name ?resource .
  OPTIONAL { ?r pk:id ?rid } OPTIONAL { ?r pk:secretRef ?ref }
  ?b pk:hasTopic ?t ; pk:id ?broker .
  ?t pk:name ?topic .
  OPTIONAL { ?t pk:valueTopic ?value }
  OPTIONAL { ?t pk:qos ?qos }
} ORDER BY ?broker ?topic ?resource
"""

Runner = Callable[[list[str]], int]


def feeds(files: list[str]) -> list[Feed]:
    """The plant's publishing resources, each with the broker it sends to (from the graph)."""
    result = run_pipeline(files, None, observe=False)
    if result.desired is None:
        return []
    brokers: dict[str, BrokerSpec] = {b.id: b for b in result.desired.brokers}
    # a Kafka cluster runs as its nodes: its resources publish through its lead node
    brokers |= {b.kafka.cluster: b for b in result.desired.brokers if b.kafka is not None and b.kafka.lead}
    out = []
    for row in run_query(result.plant, FEEDS_QUERY).rows:
        resource, topic, value, broker, qos, rid, ref = (t.value if t is not None else None for t in row)
        if broker in brokers:
            out.append(Feed(resource or "", topic or "", value or "", brokers[broker], int(qos or 1),
                            user=rid, secret_ref=ref))
    return out


def make_demo_secrets(refs: Iterable[str | None], environ: dict[str, str] | None = None) -> list[str]:
    """Give each ``pk:secretRef`` that names an unset environment variable a random password in
    this process's environment (the demo's agents inherit it; nothing is written to disk); returns
    the variables set. A ``file:`` reference must exist already."""
    env = os.environ if environ is None else environ
    made = []
    for ref in refs:
        if ref and ref.startswith("env:"):
            name = ref.removeprefix("env:")
            if name not in env:
                env[name] = secrets.token_urlsafe(24)
                made.append(name)
    return made


def secret_refs(desired: DesiredState, plant_feeds: list[Feed]) -> list[str | None]:
    """Every secret the demo's brokers and simulated sources need: each broker user's (readers
    too, such as a historian that only subscribes) and each feed's."""
    return [u.secret_ref for b in desired.brokers for u in b.users] + [f.secret_ref for f in plant_feeds]


def hosts_of(files: list[str]) -> list[str]:
    """The machines (broker addresses) of the plant."""
    rows = run_query(run_pipeline(files, None, observe=False).plant,
                     "SELECT DISTINCT ?ip WHERE { ?b a pk:Broker ; pk:ip ?ip } ORDER BY ?ip").rows
    return [r[0].value for r in rows if r[0] is not None]


def bridged_in(desired: DesiredState) -> dict[tuple[str, str], str]:
    """(broker id, topic) -> the broker a bridge carries the topic over from."""
    found: dict[tuple[str, str], str] = {}
    for bridge in desired.bridges:
        for route in bridge.routes:
            if route.direction in (BridgeDirection.OUT, BridgeDirection.BOTH):
                found[(bridge.remote.id, route.topic)] = bridge.local.id
            if route.direction in (BridgeDirection.IN, BridgeDirection.BOTH):
                found[(bridge.local.id, route.topic)] = bridge.remote.id
    return found


def _table(taps: list[Tap | NgsiTap], started: float, via: dict[tuple[str, str], str],
           published: frozenset[tuple[str, str]] = frozenset()) -> list[str]:
    elapsed = max(time.monotonic() - started, 1e-6)
    width = max([3, *(len(f"bridge from {s}") for s in via.values())])
    bw = max([12, *(len(tap.broker.id) for tap in taps)])
    lines = [f"{'broker':<{bw}} {'topic':<30} {'via':<{width}} {'messages':>8} {'msg/s':>6}  last payload"]
    for tap in taps:
        for topic, seen in sorted(tap.snapshot().items()):
            last = {k: v for k, v in seen.last.items() if k not in ("ts", "source")}
            text = str(last)[:56]
            key = (tap.broker.id, topic)
            source = f"bridge from {via[key]}" if key in via and key not in published else "published"
            lines.append(f"{tap.broker.id:<{bw}} {topic:<30} {source:<{width}} {seen.count:>8} "
                         f"{seen.count / elapsed:>6.1f}  {text}")
    return lines


def _tap(broker: BrokerSpec, desired: DesiredState, agents: LocalAgents, stop: threading.Event) -> Tap | NgsiTap:
    """A tap on every topic of ``broker``: MQTT/Kafka messages, or a context broker's entities
    (read with its agent's token: a context broker is closed to reads too unless the plant opens it)."""
    topics = desired.topics_of(broker.id)
    if broker.kind == NGSI:
        token = None if broker.allow_anonymous else agents.agents[broker.host].token
        return NgsiTap(broker, {t.name: (t.entity_id or "", t.entity_type or "") for t in topics}, stop,
                       token)
    return Tap(broker, [t.name for t in topics], stop)


def _source(feed: Feed, desired: DesiredState, agents: LocalAgents,
            stop: threading.Event) -> Source | NgsiSource:
    """A simulated publisher; on a context broker it writes the topic's entity with the token of
    the broker's agent (none when the broker allows anonymous writes)."""
    if feed.broker.kind != NGSI:
        return Source(feed, stop)
    topic = next(t for t in desired.topics_of(feed.broker.id) if t.name == feed.topic)
    token = None if feed.broker.allow_anonymous else agents.agents[feed.broker.host].token
    return NgsiSource(feed, topic.entity_id or "", topic.entity_type or "", token, stop)


def _watch(taps: list[Tap | NgsiTap], stop: threading.Event, duration: float | None, live: bool,
           via: dict[tuple[str, str], str], published: frozenset[tuple[str, str]]) -> None:
    started = time.monotonic()
    drawn = 0
    while not stop.wait(0.5 if live else 1.0):
        lines = _table(taps, started, via, published)
        if live:
            if drawn:
                click.echo(f"\x1b[{drawn}A", nl=False)
            click.echo("\n".join(f"{line}\x1b[K" for line in lines))
            drawn = len(lines)
        if duration is not None and time.monotonic() - started >= duration:
            stop.set()
    if not live:
        click.echo("\n".join(_table(taps, started, via, published)))


def run_demo(files: list[str], run: Runner, *, duration: float | None, work_dir: Path | None) -> int:
    """The whole demo; ``run`` runs a plantkg command (in-process) and returns its exit code."""
    plant_feeds = feeds(files)
    hosts = hosts_of(files)
    desired = run_pipeline(files, None, observe=False).desired or DesiredState()
    via = bridged_in(desired)
    base = Path(work_dir) if work_dir else Path(tempfile.mkdtemp(prefix="plantkg-demo-"))
    made = make_demo_secrets(secret_refs(desired, plant_feeds))  # before the agents start: they inherit them
    click.secho(f"1. starting an agent on each machine of the plant: {', '.join(hosts)}", bold=True)
    if made:
        click.echo(f"   the resources' passwords: random, in this demo's environment ({', '.join(made)})")
    agents: LocalAgents = start_local_agents(hosts, base)
    stop = threading.Event()
    threads: list[threading.Thread] = []
    try:
        agents_args = ["--agents", str(agents.agents_file)]
        click.secho("\n2. plantkg validate", bold=True)
        if (code := run(["validate", *files])) != 0:
            return code
        click.secho("\n3. plantkg apply", bold=True)
        if (code := run(["apply", *files, *agents_args, "--yes"])) != 0:
            return code
        click.secho("\n4. plantkg status", bold=True)
        run(["status", *files, *agents_args])
        click.secho("\n5. simulated resources publish; taps on each broker show what arrives "
                    + ("(Ctrl-C to stop)" if duration is None else f"for {duration:g} s"), bold=True)
        for feed in plant_feeds:
            what = "entity of topic" if feed.broker.kind == NGSI else "topic"
            click.echo(f"   {feed.resource} -> {feed.broker.kind} {feed.broker.host}:{feed.broker.port} "
                       f"{what} {feed.topic} at {feed.rate_hz:g} Hz")
        for (broker, topic), source in sorted(via.items()):
            click.echo(f"   bridge: {topic} from {source} to {broker}")
        taps = [_tap(b, desired, agents, stop) for b in desired.brokers if desired.topics_of(b.id)]
        threads += taps
        for tap in taps:
            tap.start()
        for tap in taps:
            tap.ready.wait(30)
        sources = [_source(feed, desired, agents, stop) for feed in plant_feeds]
        threads += sources
        for source in sources:
            source.start()
        try:
            _watch(taps, stop, duration, live=click.get_text_stream("stdout").isatty(), via=via,
                   published=frozenset((f.broker.id, f.topic) for f in plant_feeds))
        except KeyboardInterrupt:
            click.echo("\nstopping")
        for source in sources:
            for error in getattr(source, "errors", []):
                click.echo(f"   {source.feed.resource}: the context broker answered {error}")
        return 0
    finally:
        stop.set()
        for thread in threads:
            thread.join(15)
        click.secho("\n6. plantkg destroy, then the agents stop", bold=True)
        try:
            run(["destroy", *files, "--agents", str(agents.agents_file), "--yes"])
        finally:
            agents.stop()

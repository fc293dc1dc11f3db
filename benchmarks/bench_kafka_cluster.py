"""Benchmark: a three-node Kafka cluster through plantkg against the same nodes by hand, produce
throughput with replication factor 1 and 3, and MirrorMaker 2's throughput and lag (issue 14).

Three measures, in one run on this machine:

1. **Bring-up** (goal: plantkg ≤ 1.2× by hand). *plantkg*: ``plantkg apply`` of a plant with one
   three-node cluster (combined nodes on 127.0.0.2-4, each on its own agent; the agents are up
   before the clock starts) and one topic with replication factor 3 — from the command to its
   return (validate, reason, plan, three nodes formatted and started in parallel lanes, each
   healthy, the topic created cluster-wide, the plan made again). *By hand*, the fastest a person
   could: the same three ``server.properties`` (the driver's own rendering), the three storage
   formats and the three JVMs started in parallel threads, then wait for three registered brokers
   and create the topic with an AdminClient. Same heap (512m), same jars. The arms alternate
   order between repeats; each arm starts from empty folders; the cluster is torn down (not
   timed) after each.
2. **Produce throughput, RF 1 against RF 3**, on the cluster plantkg brought up: N records of
   ``--size`` bytes with acks=all, idempotent, from one confluent-kafka producer, into a topic of
   3 partitions with replication factor 1, then 3 (min.insync.replicas 2); alternating order.
3. **MirrorMaker 2**: ``apply`` of the plant with a one-node site cluster whose subscriber makes
   rule R1 derive a mirror of the topic; then M records are produced to the source as fast as
   possible, and the run measures the time from the first produce to the last record present on
   the target (the mirror's throughput), the largest lag ``plantkg status`` reported meanwhile
   (polled every 0.5 s through the agent) and the time until it reported lag 0. A warm-up batch
   of 200 records is mirrored first, uncounted: MirrorMaker's own start (connectors, tasks) is
   not its throughput.

All JVMs share the machine's cores with the Python clients and with whatever else runs: note the
load average in ``machine`` (start) and ``load_average_end``.

Usage: ``python -m benchmarks.bench_kafka_cluster [--repeats 2] [--messages 100000]
[--mirror-messages 50000] [--size 100] [--tiny]``. Results:
``benchmarks/results/kafka_cluster.{json,md}``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import statistics
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from confluent_kafka import Consumer, KafkaError, KafkaException, Producer, TopicPartition
from confluent_kafka.admin import AdminClient, NewTopic

from benchmarks.common import RESULTS, command_line, machine, write_results
from engine import netutil, parts, process
from engine.agent.local import LocalAgents, start_local_agents
from engine.drivers.kafka import runtime
from engine.derived.kafka_cluster import kraft_cluster_id
from engine.drivers.kafka.topics import driver_error
from engine.errors import BrokerUnavailableError

HOSTS = ("127.0.0.2", "127.0.0.3", "127.0.0.4")
SITE = "127.0.0.5"
GOAL = 1.2  # issue 14: bring-up through plantkg at most 1.2x by hand
HEAP = "512m"
TOPIC = "bench.rf3"
WARMUP = 200  # records mirrored before MirrorMaker 2 is measured

PREFIXES = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix b: <https://w3id.org/plantkg/bench/kafka-cluster#> .
"""


def plant(ports: dict[str, int], *, site: bool) -> str:
    """The bench plant: a 3-node combined cluster with TOPIC (RF 3); with ``site``, a one-node
    site cluster whose subscriber makes rule R1 derive a mirror of TOPIC. Both clusters say
    pk:allowAnonymous true: the bench measures open clusters, as its earlier results did (a
    MirrorMaker 2 at a closed Kafka is not built)."""
    nodes = "".join(f"""
b:n{i} a pk:Broker ; pk:id "n{i}" ; pk:name "n{i}" ; pk:brokerType "kafka" ; pk:ip "{host}" ;
    pk:port {ports[f'n{i}']} ; pk:nodeOf b:plant ; pk:nodeId {i} ; pk:kafkaRole "broker" , "controller" ;
    pk:controllerPort {ports[f'c{i}']} .""" for i, host in enumerate(HOSTS, start=1))
    text = PREFIXES + f"""
b:plant a pk:Broker ; pk:id "plant" ; pk:name "plant" ; pk:brokerType "kafka" ; pk:allowAnonymous true ;
    pk:hasTopic b:t .
{nodes}
b:t a pk:Topic ; pk:id "t" ; pk:name "{TOPIC}" ; pk:partitions 3 .
b:producer a pk:Resource ; pk:id "producer" ; pk:name "producer" ; pk:sendsTo b:plant ; pk:publishes b:t .
"""
    if site:
        text += f"""
b:site a pk:Broker ; pk:id "site" ; pk:name "site" ; pk:brokerType "kafka" ; pk:allowAnonymous true ;
    pk:hasTopic b:t .
b:s1 a pk:Broker ; pk:id "s1" ; pk:name "s1" ; pk:brokerType "kafka" ; pk:ip "{SITE}" ; pk:port {ports['s1']} ;
    pk:nodeOf b:site ; pk:nodeId 1 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort {ports['sc1']} .
b:lake a pk:Resource ; pk:id "lake" ; pk:name "lake" ; pk:sendsTo b:site ; pk:subscribes b:t .
"""
    return text


def free_ports() -> dict[str, int]:
    ports: dict[str, int] = {}
    for i, host in enumerate(HOSTS, start=1):
        ports[f"n{i}"], ports[f"c{i}"] = netutil.free_ports(2, host)
    ports["s1"], ports["sc1"] = netutil.free_ports(2, SITE)
    return ports


def cli(*args: object) -> tuple[int, str]:
    """``plantkg ARGS`` in-process, output captured."""
    from engine.cli import main  # noqa: PLC0415
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        code = main([str(a) for a in args])
    return code, out.getvalue()


def bootstrap(ports: dict[str, int]) -> str:
    return ",".join(f"{h}:{ports[f'n{i}']}" for i, h in enumerate(HOSTS, start=1))


# --- 1. bring-up ---------------------------------------------------------------------------

def by_plantkg(agents: LocalAgents, folder: Path, ports: dict[str, int]) -> float:
    path = folder / "plant.ttl"
    path.write_text(plant(ports, site=False), encoding="utf-8")
    start = time.monotonic()
    code, out = cli("apply", path, "--agents", agents.agents_file, "--yes")
    took = time.monotonic() - start
    if code != 0:
        raise RuntimeError(f"plantkg apply failed:\n{out[-3000:]}")
    return took


def destroy(agents: LocalAgents, folder: Path) -> None:
    code, out = cli("destroy", folder / "plant.ttl", "--agents", agents.agents_file, "--yes")
    if code != 0:
        raise RuntimeError(f"plantkg destroy failed:\n{out[-3000:]}")


def by_hand(folder: Path, ports: dict[str, int]) -> tuple[float, list[process.Child]]:
    """The same three nodes, rendered by the driver's runtime, formatted and started in parallel."""
    kafka, java = parts.kafka_parts(), parts.java_binary()
    voters = tuple((i, h, ports[f"c{i}"]) for i, h in enumerate(HOSTS, start=1))
    cid = kraft_cluster_id(f"urn:bench:{uuid.uuid4()}")
    children: list[process.Child] = []
    lock = threading.Lock()
    errors: list[BaseException] = []

    def node(i: int, host: str) -> None:
        try:
            d = folder / f"n{i}"
            cfg = runtime.KafkaNodeConfig(host, ports[f"n{i}"], ports[f"c{i}"], d / "data", node_id=i,
                                          voters=voters, replication=3)
            properties = d / "server.properties"
            d.mkdir(parents=True)
            properties.write_text(runtime.render_server_properties(cfg), encoding="utf-8")
            runtime.format_storage(cfg, properties, d, kafka=kafka, java=java, cluster=cid)
            child = process.spawn(runtime.broker_command(kafka, java, properties, d / "logs", HEAP),
                                  log_dir=d / "logs", name="kafka", cwd=d)
            with lock:
                children.append(child)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller
            errors.append(exc)

    start = time.monotonic()
    threads = [threading.Thread(target=node, args=(i, h)) for i, h in enumerate(HOSTS, start=1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise errors[0]
    admin = AdminClient({"bootstrap.servers": bootstrap(ports), "log_level": 0})
    process.wait_until(lambda: len(admin.list_topics(timeout=2).brokers) == 3, 180, 0.05,
                       what="3 brokers registered", ignore=(KafkaException,))
    process.wait_until(lambda: _create_topic(admin), 60, 0.05, what="the topic to be created")
    process.wait_until(lambda: TOPIC in admin.list_topics(timeout=2).topics, 60, 0.05, what="the topic",
                       ignore=(KafkaException,))
    return time.monotonic() - start, children


def _create_topic(admin: AdminClient) -> bool:
    """One attempt to create TOPIC (RF 3); False on an error the driver would retry too
    (:func:`engine.drivers.kafka.topics.driver_error`: e.g. ``_DESTROY_BROKER``, a request
    librdkafka fails when it replaces a bootstrap connection by the node's own)."""
    try:
        admin.create_topics([NewTopic(TOPIC, 3, 3)])[TOPIC].result(60)
    except KafkaException as exc:
        error = exc.args[0] if exc.args else None
        if isinstance(error, KafkaError) and error.code() == KafkaError.TOPIC_ALREADY_EXISTS:
            return True
        if isinstance(driver_error(error, "creating the topic"), BrokerUnavailableError):
            return False
        raise
    return True


# --- 2. produce throughput -------------------------------------------------------------------

def produce(servers: str, topic: str, count: int, size: int, tag: str = "p") -> tuple[float, float]:
    """(seconds from the first produce to the last acknowledgement, first produce time)."""
    errors: list[str] = []
    producer = Producer({"bootstrap.servers": servers, "acks": "all", "enable.idempotence": True,
                         "linger.ms": 5, "log_level": 0})
    payload = b"x" * max(0, size - 16)

    def done(err, _msg) -> None:  # type: ignore[no-untyped-def]
        if err is not None:
            errors.append(str(err))

    first = time.monotonic()
    for n in range(count):
        while True:
            try:
                producer.produce(topic, value=f"{tag}:{n}:".encode() + payload, on_delivery=done)
                break
            except BufferError:
                producer.poll(0.05)
        producer.poll(0)
    if producer.flush(600) != 0 or errors:
        raise RuntimeError(f"produce failed: {errors[:3]}")
    return time.monotonic() - first, first


def throughput(servers: str, count: int, size: int, repeats: int) -> dict[str, Any]:
    admin = AdminClient({"bootstrap.servers": servers, "log_level": 0})
    topics = {"rf1": NewTopic("bench.tp.rf1", 3, 1), "rf3": NewTopic("bench.tp.rf3", 3, 3,
                                                                    config={"min.insync.replicas": "2"})}
    for name, new in topics.items():
        admin.create_topics([new])[new.topic].result(60)
    runs: dict[str, list[float]] = {"rf1": [], "rf3": []}
    produce(servers, "bench.tp.rf1", min(count, 5000), size)  # warm-up, not counted
    for r in range(repeats):
        for arm in (("rf1", "rf3") if r % 2 == 0 else ("rf3", "rf1")):
            seconds, _ = produce(servers, topics[arm].topic, count, size)
            runs[arm].append(count / seconds)
    med = {arm: statistics.median(v) for arm, v in runs.items()}
    return {"messages": count, "size": size, "msg_per_s": runs, "median_msg_per_s": med,
            "rf3_over_rf1": med["rf3"] / med["rf1"]}


# --- 3. MirrorMaker 2 ------------------------------------------------------------------------

def mirror(agents: LocalAgents, folder: Path, ports: dict[str, int], count: int, size: int) -> dict[str, Any]:
    path = folder / "plant.ttl"
    path.write_text(plant(ports, site=True), encoding="utf-8")
    code, out = cli("apply", path, "--agents", agents.agents_file, "--yes")
    if code != 0:
        raise RuntimeError(f"plantkg apply (site + mirror) failed:\n{out[-3000:]}")
    client = agents.agents[SITE].client()
    process.wait_until(lambda: any(b.status.value == "running" and b.lag == 0 for b in client.list_bridges()),
                       180, 0.5, what="the mirror to run")
    # MirrorMaker 2 takes a while to start its connectors and tasks (tens of seconds on a loaded
    # machine): a warm-up batch, mirrored before the clock starts, keeps that out of the measure.
    target = f"{SITE}:{ports['s1']}"
    produce(bootstrap(ports), TOPIC, WARMUP, size, "warm")
    wait_mirrored(target, TOPIC, WARMUP)
    lags: list[tuple[float, int]] = []
    stop = threading.Event()

    def watch() -> None:
        while not stop.is_set():
            for b in client.list_bridges():
                if b.lag is not None:
                    lags.append((time.monotonic(), b.lag))
            stop.wait(0.5)

    watcher = threading.Thread(target=watch)
    watcher.start()
    tag = uuid.uuid4().hex[:6]
    try:
        produced_s, first = produce(bootstrap(ports), TOPIC, count, size, tag)
        arrived = wait_mirrored(target, TOPIC, WARMUP + count)
        process.wait_until(lambda: lags and lags[-1][1] == 0 and lags[-1][0] > arrived, 120, 0.2,
                           what="status to report lag 0")
    finally:
        stop.set()
        watcher.join()
    zero = next(t for t, lag in lags if t > arrived and lag == 0)
    return {"messages": count, "size": size, "produce_s": produced_s,
            "mirror_s": arrived - first, "mirror_msg_per_s": count / (arrived - first),
            "max_lag": max(lag for _, lag in lags), "lag_zero_after_last_s": zero - arrived,
            "lag_samples": len(lags)}


def wait_mirrored(servers: str, topic: str, count: int) -> float:
    """When the target held the last of the ``count`` records (end offsets summed)."""
    consumer = Consumer({"bootstrap.servers": servers, "group.id": "bench-probe", "log_level": 0})
    try:
        parts_ = list(consumer.list_topics(topic, timeout=10).topics[topic].partitions)
        return process.wait_until(lambda: _all_there(consumer, topic, parts_, count), 600, 0.1,
                                  what=f"{count} records mirrored")
    finally:
        consumer.close()


def _all_there(consumer: Consumer, topic: str, partitions: list[int], count: int) -> float | None:
    """The time, once the target's ``topic`` holds as many records as the source sent (it holds
    only the mirrored records of this measure: the topic is new, and written nowhere else)."""
    ends = sum(consumer.get_watermark_offsets(TopicPartition(topic, p), timeout=10, cached=False)[1]
               for p in partitions)
    return time.monotonic() if ends >= count else None


# --- the run ---------------------------------------------------------------------------------

def goals(data: dict[str, Any]) -> list[dict[str, Any]]:
    ratio = data["bringup"]["ratio"]
    return [{"goal": "3-node cluster bring-up through plantkg / the same nodes by hand, in parallel",
             "measured": f"{data['bringup']['median_s']['plantkg']:.1f} / {data['bringup']['median_s']['hand']:.1f} s "
                         f"= {ratio:.2f}x", "target": f"≤ {GOAL}x", "met": ratio <= GOAL}]


def to_markdown(data: dict[str, Any]) -> str:
    b, t, m = data["bringup"], data["throughput"], data["mirror"]
    lines = [
        f"Machine: {data['machine']['cpus']} CPUs, load average at start {data['machine']['load_average']}, "
        f"at end {data.get('load_average_end', '?')} (other work was running on the machine). "
        f"Command: `{data['command']}`.", "",
        "| measure | plantkg | baseline (same run) | ratio |", "|---|---|---|---|",
        f"| 3-node cluster bring-up (apply; by hand: format + start 3 JVMs in parallel, topic RF 3), "
        f"median of {len(b['seconds']['plantkg'])} | {b['median_s']['plantkg']:.1f} s | "
        f"{b['median_s']['hand']:.1f} s | {b['ratio']:.2f}x |",
        f"| produce, acks=all, {t['messages']} × {t['size']} B, RF 3 / RF 1 (msg/s, median) | "
        f"{t['median_msg_per_s']['rf3']:.0f} | {t['median_msg_per_s']['rf1']:.0f} | {t['rf3_over_rf1']:.2f}x |",
        f"| MirrorMaker 2: {m['messages']} × {m['size']} B, first produce -> last on the target | "
        f"{m['mirror_s']:.1f} s ({m['mirror_msg_per_s']:.0f} msg/s) | produce alone {m['produce_s']:.1f} s | "
        f"{m['mirror_s'] / m['produce_s']:.2f}x |",
        f"| MirrorMaker 2 lag in `plantkg status` | max {m['max_lag']} records; 0 again "
        f"{m['lag_zero_after_last_s']:.1f} s after the last record arrived | | |", "",
    ]
    for g in data["goals"]:
        lines.append(f"Goal: {g['goal']}: {g['measured']} (target {g['target']}) — "
                     f"{'met' if g['met'] else 'NOT met'}.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--messages", type=int, default=100_000)
    parser.add_argument("--mirror-messages", type=int, default=50_000)
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument("--tiny", action="store_true", help="1 repeat, 2000 messages")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.tiny:
        args.repeats, args.messages, args.mirror_messages = 1, 2000, 2000
    for name in ("repeats", "messages", "mirror_messages", "size"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    info = machine()
    seconds: dict[str, list[float]] = {"plantkg": [], "hand": []}
    with tempfile.TemporaryDirectory(prefix="plantkg-bench-kafka-cluster-") as tmp:
        base = Path(tmp)
        agents = start_local_agents([*HOSTS, SITE], base / "agents")
        try:
            for r in range(args.repeats):
                for arm in (("plantkg", "hand") if r % 2 == 0 else ("hand", "plantkg")):
                    folder = base / f"{arm}-{r}"
                    folder.mkdir()
                    ports = free_ports()
                    if arm == "plantkg":
                        seconds[arm].append(by_plantkg(agents, folder, ports))
                        destroy(agents, folder)
                    else:
                        took, children = by_hand(folder, ports)
                        seconds[arm].append(took)
                        for child in children:
                            process.stop(child, 30)
            folder, ports = base / "measures", free_ports()  # a fresh cluster for 2 and 3 (untimed)
            folder.mkdir()
            by_plantkg(agents, folder, ports)
            data_tp = throughput(bootstrap(ports), args.messages, args.size, args.repeats)
            data_mm = mirror(agents, folder, ports, args.mirror_messages, args.size)
            destroy(agents, folder)
        finally:
            agents.stop()
    med = {arm: statistics.median(v) for arm, v in seconds.items()}
    data: dict[str, Any] = {
        "study": "kafka_cluster", "command": command_line("benchmarks.bench_kafka_cluster", argv),
        "machine": info, "goal_ratio": GOAL,
        "bringup": {"seconds": seconds, "median_s": med, "ratio": med["plantkg"] / med["hand"]},
        "throughput": data_tp, "mirror": data_mm,
    }
    data["goals"] = goals(data)
    data["load_average_end"] = os.getloadavg()
    write_results(args.out, "kafka_cluster", data, to_markdown(data))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

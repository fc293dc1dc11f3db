"""Synthetic plants of any size, valid against the shapes, for benchmarks and scale tests.

A plant of N resources has ceil(N/20) brokers (alternately Mosquitto and Kafka, each on its own
loopback address and port), N topics and about 13.6 triples per resource — the proportions used in
``shared/notes/measured-facts.md``, so figures compare. Every resource sends to one broker and
publishes one topic that broker carries; every tenth resource also subscribes to its neighbour's
topic, which its own broker then carries too (so the two brokers share a topic and need a bridge). Names are
valid for both broker kinds. The output is deterministic for a given N.

Usage: ``python -m benchmarks.synthetic 10000 > plant.ttl``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Iterator, TextIO

HEADER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix xsd: <http://www.w3.org/2001/XMLSchema#> .
@prefix : <https://w3id.org/plantkg/examples/synthetic#> .

:type-sensor a pk:ResourceType ; pk:id "type-sensor" ; pk:name "Sensor" .
"""


def _broker_lines(b: int) -> str:
    kind = "mosquitto" if b % 2 == 0 else "kafka"
    ip = f"127.{1 + b // 250 % 250}.{b % 250 + 1}.{1 + b // 62500}"
    port = 1883 if kind == "mosquitto" else 9092
    return (f':broker{b} a pk:Broker ; pk:id "broker-{b}" ; pk:name "Broker {b}" ; '
            f'pk:brokerType "{kind}" ; pk:ip "{ip}" ; pk:port {port} .\n')


def lines(n: int) -> Iterator[str]:
    """The Turtle text of an N-resource plant, a chunk at a time."""
    yield HEADER
    brokers = max(1, -(-n // 20))
    for b in range(brokers):
        yield _broker_lines(b)
    for i in range(n):
        b = i % brokers
        yield (f':topic{i} a pk:Topic ; pk:id "topic-{i}" ; pk:name "plant.sensor-{i}.value" ; '
               f'pk:valueTopic "value" ; pk:typeTopic "json" .\n'
               f':broker{b} pk:hasTopic :topic{i} .\n'
               f':res{i} a pk:Resource ; pk:id "res-{i}" ; pk:name "Sensor {i}" ; '
               f'pk:localization "cell-{i // 100}" ; pk:isType :type-sensor ; pk:sendsTo :broker{b} ; pk:publishes :topic{i}')
        if i % 10 == 9:  # a consumer of its neighbour's topic, on another broker: a bridge is needed
            yield f" ; pk:subscribes :topic{i - 1} .\n:broker{b} pk:hasTopic :topic{i - 1}"
        yield " .\n"


def write(n: int, out: TextIO) -> None:
    """Write an N-resource plant to ``out``."""
    for chunk in lines(n):
        out.write(chunk)


def write_file(n: int, directory: Path) -> Path:
    """Write an N-resource plant to ``directory/plant-N.ttl`` and return its path."""
    path = directory / f"plant-{n}.ttl"
    with path.open("w") as fh:
        write(n, fh)
    return path


def mosquitto_plant(host: str, ports: list[int]) -> str:
    """The Turtle text of a plant of ``len(ports)`` Mosquitto brokers on one machine (``host``),
    each carrying one QoS-1 topic that one resource publishes — the load test's plant. The
    brokers are open (pk:allowAnonymous true; closed is the default): the load's clients, like the
    paper's, publish anonymously."""
    out = [HEADER]
    for b, port in enumerate(ports):
        out.append(f':mqtt{b} a pk:Broker ; pk:id "mqtt-{b}" ; pk:name "Load {b}" ; pk:brokerType "mosquitto" ; '
                   f'pk:ip "{host}" ; pk:port {port} ; pk:allowAnonymous true ; pk:hasTopic :load{b} .\n'
                   f':load{b} a pk:Topic ; pk:id "load-{b}" ; pk:name "bench/load" ; pk:qos 1 .\n'
                   f':pub{b} a pk:Resource ; pk:id "pub-{b}" ; pk:name "Publisher {b}" ; pk:isType :type-sensor ; '
                   f'pk:sendsTo :mqtt{b} ; pk:publishes :load{b} .\n')
    return "".join(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("resources", type=int)
    args = parser.parse_args(argv)
    write(args.resources, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())

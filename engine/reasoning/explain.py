"""Why must a broker, topic or bridge of the plan exist? The reasoner's own derivations, for people.

``explain(files, address)`` runs the pipeline up to the desired state with the fast reasoner, then
asks the reasoner's compiled program (:mod:`engine.reasoning.rules_fast`) which of its rules conclude the fact
behind the address, and with which facts. Nothing here re-guesses the rules: each reason is one
binding of one compiled rule's own body (``FastRule.instances_query``), evaluated on the fixpoint
the reasoner reached, plus the plant's assertions. Every derivation is listed, not only the first
(the fast engine derives a fact once: an asserted ``pk:bridgesTo`` gives ``pk:requiresBridge``
before R1 runs, yet R1 also requires that bridge, and both are reasons).

The fact behind each kind of address (the addresses of :mod:`engine.model`):

- ``broker.ID``: ``ID rdf:type pk:DeployedBroker`` (the definition in ``plantkg-rules.ttl``);
- ``topic.BROKER.NAME``: ``BROKER pk:mustCarry TOPIC`` (R2a, R2b, or an asserted ``pk:hasTopic``);
- ``bridge.A.B``: ``A pk:requiresBridge B`` and/or ``B pk:requiresBridge A`` (R1, or an asserted
  ``pk:bridgesTo``; one bridge spec carries both directions of a pair).

An address of a valid form that the desired state lacks is *not required*: :class:`Explanation`
says so (``required`` False), and why when the reasoner knows of the things it names.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

import pyoxigraph as ox

from engine.errors import EngineError
from engine.model import DesiredState
from engine.pipeline import Pipeline, run_pipeline
from engine.reasoning.reason import INFERRED, input_graphs
from engine.reasoning.rules_errors import UnsupportedConstructError
from engine.reasoning.rules_fast import FastRule, compile_tbox, short_name
from engine.reasoning.rules_tbox import dataset_options, read_tbox
from kg.load import PlantGraph
from kg.namespaces import PK, RDF

__all__ = ["AddressError", "Explanation", "Fact", "Reason", "explain", "explain_plant", "parse_address"]

_TYPE = ox.NamedNode(str(RDF.type))
_DEPLOYED = ox.NamedNode(f"{PK}DeployedBroker")
_MUST_CARRY = ox.NamedNode(f"{PK}mustCarry")
_REQUIRES_BRIDGE = ox.NamedNode(f"{PK}requiresBridge")
_NAME = ox.NamedNode(f"{PK}name")
_ID = ox.NamedNode(f"{PK}id")
#: Derivations listed per fact at most (a topic published by 500 resources has 500 reasons).
MAX_REASONS = 20

#: ``kind.rest``; ids may hold dots (the shapes allow ``[A-Za-z0-9_.-]``), so where a topic's or a
#: bridge's parts split is found against the plant's broker ids (``_split``).
_FORM = re.compile(r"(?P<kind>broker|topic|bridge)\.(?P<rest>\S+)")
_TRIPLE = re.compile(r"(\?\w+|<[^>\s]+>|\ba\b) (\?\w+|<[^>\s]+>|\ba\b) (\?\w+|<[^>\s]+>) \.")


class AddressError(EngineError):
    """``plantkg explain`` was given something that is not a plan address."""

    def __init__(self, address: str) -> None:
        super().__init__(f"{address!r} is not a plan address",
                         hint="use broker.ID, topic.BROKER_ID.TOPIC_NAME or bridge.ID.ID, as "
                              "`plantkg plan` prints them")
        self.address = address


class ExplainEngineError(EngineError):
    """The plant needs the HermiT engine, which records no derivations."""

    def __init__(self, problem: str) -> None:
        super().__init__(f"explain needs the fast reasoner, which cannot reason over this plant: {problem}",
                         hint="`plantkg plan` still works (it falls back to HermiT); explain does not yet")


@dataclass(frozen=True)
class Fact:
    """One triple, for people: labels of its terms, and where it comes from."""

    subject: str
    predicate: str
    object: str
    source: str | None = None   # the plant file asserting it; None when inferred

    @property
    def text(self) -> str:
        where = f"asserted in {self.source}" if self.source else "inferred"
        return f"{self.subject} {self.predicate} {self.object} ({where})"


@dataclass(frozen=True)
class Reason:
    """Why ``conclusion`` holds: asserted in ``source``, or rule ``rule`` fired on ``premises``."""

    conclusion: Fact
    rule: str | None = None
    premises: tuple[Fact, ...] = ()

    def to_dict(self) -> dict[str, object]:
        def fact(f: Fact) -> dict[str, object]:
            return {"subject": f.subject, "predicate": f.predicate, "object": f.object, "source": f.source}
        return {"conclusion": fact(self.conclusion), "asserted": self.rule is None, "rule": self.rule,
                "premises": [fact(p) for p in self.premises]}


@dataclass(frozen=True)
class Explanation:
    """What ``explain`` found for one address."""

    address: str
    kind: str                      # broker, topic, bridge
    required: bool
    reasons: tuple[Reason, ...] = ()
    note: str = ""                 # why not required, or what was left out

    def to_dict(self) -> dict[str, object]:
        return {"address": self.address, "kind": self.kind, "required": self.required,
                "reasons": [r.to_dict() for r in self.reasons], "note": self.note}

    def text(self) -> str:
        if not self.required:
            return f"{self.address} is not required: {self.note}"
        lines = [f"{self.address} is required:"]
        for r in self.reasons:
            c = r.conclusion
            if r.rule is None:
                lines.append(f"  - asserted in {c.source}: {c.subject} {c.predicate} {c.object}")
                continue
            lines.append(f"  - {c.subject} {c.predicate} {c.object}, by rule \"{r.rule}\", from:")
            lines += [f"      {p.text}" for p in r.premises]
        if self.note:
            lines.append(f"  ({self.note})")
        return "\n".join(lines)


def parse_address(address: str) -> tuple[str, str]:
    """``("bridge", "mosquitto.kafka")`` for ``bridge.mosquitto.kafka``; AddressError if it is not
    a plan address (a topic's and a bridge's rest must hold two non-empty parts)."""
    m = _FORM.fullmatch(address)
    if m is None or (m["kind"] != "broker" and not _splits(m["rest"])):
        raise AddressError(address)
    return m["kind"], m["rest"]


def _splits(rest: str) -> list[tuple[str, str]]:
    """Every way ``rest`` is ``left.right`` with both parts non-empty, leftmost dot first."""
    return [(rest[:i], rest[i + 1:]) for i, ch in enumerate(rest) if ch == "." and 0 < i < len(rest) - 1]


def explain(files: Iterable[Path | str], address: str) -> tuple[Pipeline, Explanation | None]:
    """Explain ``address`` for the plant in ``files``: the pipeline's result (no agent asked) and
    the explanation, None when the plant is invalid (the caller reports the violations, as ``plan``
    does). Raises :class:`AddressError` before loading anything."""

    parse_address(address)
    try:
        result = run_pipeline(files, observe=False, reason_engine="fast")
    except UnsupportedConstructError as exc:
        raise ExplainEngineError(exc.message) from None
    if not result.valid:
        return result, None
    assert result.plant is not None and result.desired is not None
    return result, explain_plant(result.plant, result.desired, address)


def explain_plant(plant: PlantGraph, desired: DesiredState, address: str) -> Explanation:
    """Explain ``address`` of ``desired``, derived from ``plant`` reasoned over by the fast engine."""
    kind, rest = parse_address(address)
    ctx = _Context(plant)
    brokers = {b.id: b for b in desired.brokers}
    present = address in {x.address for x in (*desired.brokers, *desired.topics, *desired.bridges)}
    if kind == "broker":
        parts: tuple[str, ...] = (rest,)
        node = ctx.by_id(rest)
        facts = [(node, _TYPE, _DEPLOYED)] if node is not None else []
        missing = f"no broker has pk:id {rest!r}" if node is None else \
            "the reasoner does not conclude it is a pk:DeployedBroker (no resource sends to it, it " \
            "carries no topic, no bridge requires it), or it is pk:external"
    elif kind == "topic":
        topic = next((t for t in desired.topics if t.address == address), None)
        parts = (topic.broker_id, topic.name) if topic else _split(rest, lambda a, _b: ctx.by_id(a) is not None)
        node = ctx.by_id(parts[0])
        tnode = ox.NamedNode(topic.iri) if topic else (ctx.topic_named(node, parts[1]) if node else None)
        facts = [(node, _MUST_CARRY, tnode)] if node is not None and tnode is not None else []
        missing = (f"no broker has pk:id {parts[0]!r}" if node is None else
                   f"no topic named {parts[1]!r} must be carried by {parts[0]} (no resource sending to "
                   "it publishes or subscribes to it, and the plant asserts no pk:hasTopic)")
    else:
        parts = _split(rest, lambda a, b: ctx.by_id(a) is not None and ctx.by_id(b) is not None)
        a = ox.NamedNode(brokers[parts[0]].iri) if parts[0] in brokers else ctx.by_id(parts[0])
        c = ox.NamedNode(brokers[parts[1]].iri) if parts[1] in brokers else ctx.by_id(parts[1])
        facts = [(a, _REQUIRES_BRIDGE, c), (c, _REQUIRES_BRIDGE, a)] if a is not None and c is not None else []
        missing = (f"no broker has pk:id {parts[0] if a is None else parts[1]!r}" if a is None or c is None else
                   f"no rule concludes pk:requiresBridge between {parts[0]} and {parts[1]}: no resource "
                   "publishes a topic on one that a resource subscribes to on the other, and neither "
                   "pk:bridgesTo the other")
    reasons = [r for f in facts if ctx.holds(f) for r in ctx.reasons(f)]
    capped = any(sum(r.conclusion == c for r in reasons) >= MAX_REASONS for c in {r.conclusion for r in reasons})
    if not present and kind == "bridge":
        other = f"bridge.{parts[1]}.{parts[0]}"
        if any(b.address == other for b in desired.bridges):
            return Explanation(address, kind, False, (), f"this pair's bridge is {other} (a bridge "
                               "address names its carrying end first): explain that address")
    if not present:
        note = missing if not reasons else \
            "the reasoner concludes the facts below, but the desired state has no such address " \
            "(an external broker is not deployed; a bridge's address names its carrying end first)"
        return Explanation(address, kind, False, tuple(reasons) if reasons else (), note)
    note = "" if reasons else "no derivation was found (is the fact asserted in the ontology?)"
    if capped:
        note = f"only the first {MAX_REASONS} reasons of each fact are shown; there are more"
    return Explanation(address, kind, True, tuple(reasons), note)


def _split(rest: str, known: Callable[[str, str], bool]) -> tuple[str, str]:
    """The split of ``rest`` whose parts ``known`` accepts (the first such), else the first split."""
    splits = _splits(rest)
    return next((sp for sp in splits if known(*sp)), splits[0])


class _Context:
    """The reasoned plant, the compiled rules, and how to show its terms."""

    def __init__(self, plant: PlantGraph) -> None:
        self.plant = plant
        self.store = plant.store
        inputs = input_graphs(plant)
        self.options = dataset_options(self.store, [*inputs, INFERRED])
        self.rules: list[FastRule] = compile_tbox(read_tbox(self.store, inputs, _plain)).rules
        self.files = {g: str(src.path) for g, src in zip(plant.plant_graphs, plant.sources)}

    def _select(self, query: str) -> list[ox.QuerySolution]:
        return list(self.store.query(query, **self.options))  # type: ignore[arg-type]

    def by_id(self, ident: str) -> ox.NamedNode | None:
        for q in self.store.quads_for_pattern(None, _ID, ox.Literal(ident), None):
            if isinstance(q.subject, ox.NamedNode):
                return q.subject
        return None

    def topic_named(self, broker: ox.NamedNode, name: str) -> ox.NamedNode | None:
        for q in self.store.quads_for_pattern(broker, _MUST_CARRY, None, None):
            if any(True for _ in self.store.quads_for_pattern(q.object, _NAME, ox.Literal(name), None)):
                return q.object if isinstance(q.object, ox.NamedNode) else None
        return None

    def holds(self, fact: tuple[object, object, object]) -> bool:
        s, p, o = fact
        return any(True for _ in self.store.quads_for_pattern(s, p, o, None))  # type: ignore[arg-type]

    def source(self, s: object, p: object, o: object) -> str | None:
        for g, path in self.files.items():
            if any(True for _ in self.store.quads_for_pattern(s, p, o, g)):  # type: ignore[arg-type]
                return path
        return None

    def label(self, term: object) -> str:
        if isinstance(term, ox.NamedNode):
            for q in self.store.quads_for_pattern(term, _NAME, None, None):
                return f"{q.object.value} ({_local(term.value)})"
            return short_name(term.value) if term.value.startswith(str(PK)) else _local(term.value)
        return str(term)

    def fact(self, s: object, p: object, o: object) -> Fact:
        pred = "a" if p == _TYPE else short_name(p.value)  # type: ignore[attr-defined]
        obj = short_name(o.value) if p == _TYPE and isinstance(o, ox.NamedNode) else self.label(o)
        return Fact(self.label(s), pred, obj, self.source(s, p, o))

    def reasons(self, fact: tuple[object, object, object]) -> list[Reason]:
        conclusion = self.fact(*fact)
        out = [Reason(conclusion)] if conclusion.source else []
        seen = set()
        for rule in self.rules:
            query = rule.instances_query(fact)  # type: ignore[arg-type]
            if query is None:
                continue
            for solution in self._select(query):
                premises = tuple(self.fact(*t) for t in _instantiate(rule.where, solution))
                name = _rule_name(rule, solution)
                if premises and (name, premises) not in seen:
                    seen.add((name, premises))
                    out.append(Reason(conclusion, name, premises))
                if len(out) >= MAX_REASONS:
                    return out
        return out


def _instantiate(where: str, solution: ox.QuerySolution) -> list[tuple[object, object, object]]:
    """The triple patterns of a rule body with ``solution``'s values: the facts that matched."""
    out = []
    for m in _TRIPLE.finditer(where):
        terms = []
        for token in m.groups():
            if token == "a":
                terms.append(_TYPE)
            elif token.startswith("?"):
                terms.append(solution[token[1:]])
            else:
                terms.append(ox.NamedNode(token[1:-1]))
        if all(t is not None for t in terms):
            out.append(tuple(terms))
    return out  # type: ignore[return-value]


def _rule_name(rule: FastRule, solution: ox.QuerySolution) -> str:
    """The rule for people: a SWRL rule's label (``R1 publisher ...``); for a table of axioms (e.g.
    sub-properties) the row that fired (``pk:bridgesTo ⊑ pk:requiresBridge``); a class definition
    as ``definition of pk:C``; else the engine's own name."""
    name = rule.name
    m = re.fullmatch(r"SWRL rule '(.*)'", name) or re.fullmatch(r'SWRL rule "(.*)"', name)
    if m:
        return m.group(1)
    if rule.table_vars:
        a, b = (solution[v[1:]] for v in rule.table_vars.split())
        if isinstance(a, ox.NamedNode) and isinstance(b, ox.NamedNode):
            return f"{name}: {short_name(a.value)} ⊑ {short_name(b.value)}"
    m = re.fullmatch(r"\(.*\) ⊑ (pk:\w+)", name)
    return f"definition of {m.group(1)}" if m else name


def _local(iri: str) -> str:
    return re.split(r"[#/]", iri.rstrip("#/"))[-1] or iri


def _plain(node: object) -> str:
    return node.value if isinstance(node, ox.NamedNode) else str(node)

"""The fast reasoner: the TBox's OWL axioms and SWRL rules, compiled to SPARQL, run to a fixpoint.

What it computes: the least set of facts over the plant's named individuals closed under every
axiom and rule :mod:`engine.reasoning.rules_tbox` reads — sub-classes and sub-properties, domains and ranges,
both directions of every ``owl:equivalentClass`` definition, SWRL rules — and it checks that this
set is a model of the ontology:

- constraints (disjoint classes, irreflexive properties, functional data properties, data ranges)
  hold, else the plant is inconsistent (:class:`InconsistentPlantError`, naming the individuals);
- every existential or union an individual must satisfy (the necessary side of a definition, e.g.
  an individual *asserted* to be a ``pk:DeployedBroker``) is satisfied by named individuals. If not,
  the facts HermiT would draw from an anonymous witness are out of reach of SPARQL, and the engine
  refuses (:class:`UnsupportedConstructError`) instead of answering wrongly.

When both hold, the set is a model and every fact in it is entailed, so it holds exactly the atomic
facts HermiT finds (under the unique-name assumption the owlready2 engine states too):
``tests/unit/test_reason_engines.py`` holds the two engines to that.

How: each axiom becomes a ``SELECT`` whose ``MINUS`` keeps only facts not yet known; new facts go
into the working graph (``GRAPH_INFERRED``). Rules re-run only when a class or property they read
gained facts (semi-naive at rule level), the many small axioms of one kind (sub-classes, domains,
ranges, sub-properties) run as one query each with a ``VALUES`` table, restricted to the rows whose
input changed, and a union in a definition becomes one rule per branch (no ``UNION`` to join).
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Callable, Iterable

import pyoxigraph as ox

from engine.reasoning.rules_errors import InconsistentPlantError, UnsupportedConstructError
from engine.reasoning.rules_tbox import (
    DATATYPES, And, Datatype, Expr, HasValue, Named, OneOf, Or, Prop, Rule, Some, TBox, Thing, Var,
    dataset_options,
)
from kg.namespaces import PK, RDF, XSD

Key = tuple[str, str]          # ("t", class IRI) or ("p", property IRI): what a fact is about
Slot = str | ox.NamedNode | ox.Literal   # a SPARQL variable ("?x") or a constant term

TYPE = ox.NamedNode(str(RDF.type))
_DECIMALS = DATATYPES[str(XSD.decimal)] or ()


def _key(p: ox.NamedNode, o: object) -> Key:
    return ("t", o.value) if p == TYPE and isinstance(o, ox.NamedNode) else ("p", p.value)


def _iri(value: str) -> str:
    return str(ox.NamedNode(value))


def _in(expr: str, datatypes: Iterable[str]) -> str:
    return f"{expr} IN ({', '.join(_iri(d) for d in datatypes)})"


def _family(lit: ox.Literal) -> tuple[str, ...]:
    dt = lit.datatype.value
    return tuple(_DECIMALS) if dt in _DECIMALS else (dt,)


def same_value(var: str, lit: ox.Literal) -> str:
    """SPARQL: ``var`` is the same OWL data value as ``lit`` (1 and 1.0 are; 1 and "1" are not)."""
    return f"(sameTerm({var}, {lit}) || COALESCE({_in(f'DATATYPE({var})', _family(lit))} && {var} = {lit}, false))"


def datatype_test(var: str, datatype: str) -> str:
    """SPARQL: ``var`` is a literal of ``datatype``'s value space (by its datatype IRI)."""
    admitted = DATATYPES[datatype]
    if admitted is None:
        return f"isLiteral({var})"
    return f"(isLiteral({var}) && {_in(f'DATATYPE({var})', admitted)})"


class _Fresh:
    def __init__(self, prefix: str = "_v") -> None:
        self.n = itertools.count()
        self.prefix = prefix

    def __call__(self) -> str:
        return f"?{self.prefix}{next(self.n)}"


def pattern(e: Expr, var: str, fresh: _Fresh) -> tuple[str, set[Key]]:
    """A SPARQL group pattern true for the individuals ``var`` of ``e``, and the keys it reads."""
    if isinstance(e, Thing):
        return "", set()
    if isinstance(e, OneOf):
        return f"VALUES {var} {{ {' '.join(str(m) for m in e.members)} }}", set()
    if isinstance(e, Named):
        return f"{var} a {_iri(e.iri)} .", {("t", e.iri)}
    if isinstance(e, And):
        texts, keys = zip(*(pattern(p, var, fresh) for p in e.parts)) if e.parts else ((), ())
        return " ".join(t for t in texts if t), set().union(*keys)
    if isinstance(e, Or):
        parts = [pattern(p, var, fresh) for p in e.parts]
        if any(not t for t, _ in parts):
            return "", set()  # a union with owl:Thing is owl:Thing
        return " UNION ".join(f"{{ {t} }}" for t, _ in parts), set().union(*(k for _, k in parts))
    if isinstance(e, Some):
        y = fresh()
        edge = f"{y} {_iri(e.prop.iri)} {var} ." if e.prop.inverse else f"{var} {_iri(e.prop.iri)} {y} ."
        if isinstance(e.filler, Datatype):
            return f"{edge} FILTER({datatype_test(y, e.filler.iri)})", {("p", e.prop.iri)}
        inner, keys = pattern(e.filler, y, fresh)
        return f"{edge} {inner}", {("p", e.prop.iri), *keys}
    if isinstance(e, HasValue):
        p = _iri(e.prop.iri)
        if isinstance(e.value, ox.Literal):
            y = fresh()
            return f"{var} {p} {y} . FILTER({same_value(y, e.value)})", {("p", e.prop.iri)}
        if e.prop.inverse:
            return f"{e.value} {p} {var} .", {("p", e.prop.iri)}
        return f"{var} {p} {e.value} .", {("p", e.prop.iri)}
    raise UnsupportedConstructError(f"{e} as a class", "the ontology")


def disjuncts(e: Expr, limit: int = 64) -> list[Expr]:
    """``e`` as a union of union-free expressions (disjunctive normal form at the top level);
    ``[e]`` when that would exceed ``limit`` branches."""
    def split(x: Expr) -> list[Expr]:
        if isinstance(x, Or):
            return [b for part in x.parts for b in split(part)]
        if isinstance(x, And):
            out: list[Expr] = [And(())]
            for part in x.parts:
                out = [And((*a.parts, b)) for a in out for b in split(part)]  # type: ignore[union-attr]
                if len(out) > limit:
                    raise OverflowError
            return out
        return [x]
    try:
        branches = split(e)
    except OverflowError:
        return [e]
    return branches if len(branches) <= limit else [e]


def expand(e: Expr, var: str) -> tuple[list[tuple[Slot, Slot, Slot]], list[Expr]]:
    """What membership of ``var`` in ``e`` makes true: facts to add, and conditions (existentials,
    unions) that named individuals must already satisfy."""
    if isinstance(e, Thing):
        return [], []
    if isinstance(e, Named):
        return [(var, TYPE, ox.NamedNode(e.iri))], []
    if isinstance(e, And):
        heads, checks = [], []
        for part in e.parts:
            h, c = expand(part, var)
            heads += h
            checks += c
        return heads, checks
    if isinstance(e, HasValue):
        p = ox.NamedNode(e.prop.iri)
        return ([(e.value, p, var)] if e.prop.inverse else [(var, p, e.value)]), []
    return [], [e]  # Some, Or, OneOf: a condition to check


@dataclass
class FastRule:
    """One SPARQL rule: facts ``head`` for every solution of ``where`` not yet known.

    A table rule reads a ``VALUES`` table (``table_vars``) whose rows each depend on one key; only
    the rows whose key changed since the rule last ran are sent.
    """

    name: str
    where: str
    head: tuple[Slot, Slot, Slot]
    reads: frozenset[Key] = frozenset()
    table_vars: str = ""
    table: list[tuple[Key, tuple[str, str]]] = field(default_factory=list)
    last: int = -1

    def instances_query(self, fact: tuple[ox.NamedNode, ox.NamedNode, object]) -> str | None:
        """SPARQL: every binding of this rule's body that concludes ``fact`` (None when the head
        cannot), without ``MINUS`` — the rule's own body, for provenance (engine.reasoning.explain)."""
        bound: dict[str, object] = {}
        for slot, term in zip(self.head, fact):
            if isinstance(slot, str):
                if bound.setdefault(slot, term) != term:
                    return None
            elif slot != term:
                return None
        values = "".join(f"VALUES {v} {{ {t} }} " for v, t in bound.items())
        if self.table_vars:
            rows = " ".join(f"({a} {b})" for _, (a, b) in self.table)
            values += f"VALUES ({self.table_vars}) {{ {rows} }} "
        return f"SELECT * WHERE {{ {values}{self.where} }}"

    def query(self, rows: list[tuple[str, str]] | None) -> str:
        variables = sorted({x for x in self.head if isinstance(x, str)})
        s, p, o = (x if isinstance(x, str) else str(x) for x in self.head)
        if not variables:
            return f"ASK {{ {self.where} FILTER NOT EXISTS {{ {s} {p} {o} }} }}"
        values = minus_values = ""
        if rows is not None:  # a table rule: (input, output) rows; the output variable is in the head
            values = f"VALUES ({self.table_vars}) {{ {' '.join(f'({a} {b})' for a, b in rows)} }} "
            out_var = self.table_vars.split()[1]
            minus_values = f"VALUES {out_var} {{ {' '.join(sorted({b for _, b in rows}))} }} "
        # MINUS, not FILTER NOT EXISTS: Oxigraph anti-joins it by hash, ~3x faster on big plants
        # (every head variable is bound on the left, so the two mean the same here). The right
        # side is evaluated on its own: keep it to the table's outputs.
        return (f"SELECT DISTINCT {' '.join(variables)} WHERE {{ {values}{self.where} "
                f"MINUS {{ {minus_values}{s} {p} {o} }} }}")


@dataclass
class Check:
    """After the fixpoint: every ``trigger`` individual must satisfy ``condition`` concretely."""

    name: str
    trigger: str
    condition: Expr


@dataclass
class Constraint:
    """A query for individuals that break an axiom (none in a consistent plant).

    With ``precheck`` (a query for ``?p`` values), ``query`` holds ``%s`` for the properties the
    precheck returned and runs only when there are some.
    """

    kind: str
    description: str
    query: str
    precheck: str | None = None


@dataclass
class Program:
    """A compiled TBox: rules to run to a fixpoint, then checks and constraints."""

    rules: list[FastRule]
    checks: list[Check]
    constraints: list[Constraint]


def _closure(edges: dict[object, set[object]]) -> dict[object, set[object]]:
    out: dict[object, set[object]] = {}
    for start in edges:
        seen: set[object] = set()
        todo = list(edges[start])
        while todo:
            n = todo.pop()
            if n in seen:
                continue
            seen.add(n)
            todo.extend(edges.get(n, ()))
        seen.discard(start)
        out[start] = seen
    return out


def compile_tbox(tbox: TBox) -> Program:
    """Translate every axiom and rule of ``tbox`` into SPARQL rules, checks and constraints."""
    fresh = _Fresh()
    rules: list[FastRule] = []
    checks: list[Check] = []

    # -- property hierarchy (sub-properties, equivalences, inverses), closed once --------------
    edges: dict[object, set[object]] = defaultdict(set)
    for a, b in tbox.subproperty:
        edges[a].add(b)
        edges[Prop(a.iri, not a.inverse)].add(Prop(b.iri, not b.inverse))
    reach = _closure(edges)
    same_dir, inverse = [], []
    for start, targets in sorted(reach.items(), key=lambda kv: (kv[0].iri, kv[0].inverse)):
        if start.inverse:
            continue
        for t in sorted(targets, key=lambda t: (t.iri, t.inverse)):
            row = (("p", start.iri), (_iri(start.iri), _iri(t.iri)))
            (inverse if t.inverse else same_dir).append(row)
    if same_dir:
        rules.append(FastRule("sub-properties", "?x ?p ?y .", ("?x", "?q", "?y"),
                              frozenset(k for k, _ in same_dir), "?p ?q", same_dir))
    if inverse:
        rules.append(FastRule("inverse properties", "?x ?p ?y .", ("?y", "?q", "?x"),
                              frozenset(k for k, _ in inverse), "?p ?q", inverse))

    # -- implications: sub-classes, definitions, domains, ranges --------------------------------
    named_edges: dict[str, set[str]] = defaultdict(set)
    domain_rows: list[tuple[Key, tuple[str, str]]] = []
    range_rows: list[tuple[Key, tuple[str, str]]] = []

    def implication(name: str, trigger: str, reads: set[Key], consequence: Expr, *,
                    table: list[tuple[Key, tuple[str, str]]] | None = None, table_head: str = "") -> None:
        heads, conditions = expand(consequence, "?x")
        for h in heads:
            if table is not None and h[1] == TYPE and isinstance(h[2], ox.NamedNode):
                table.append((next(iter(reads)), (table_head, str(h[2]))))
            else:
                rules.append(FastRule(name, trigger, h, frozenset(reads)))
        for c in conditions:
            checks.append(Check(name, trigger, c))

    for sub, sup in tbox.subclass:
        name = f"{_show(sub, tbox)} ⊑ {_show(sup, tbox)}"
        if isinstance(sub, Thing):
            raise UnsupportedConstructError(f"owl:Thing rdfs:subClassOf {_show(sup, tbox)}", "the ontology")
        if isinstance(sub, Named):
            heads, conditions = expand(sup, "?x")
            for h in heads:
                if h[1] == TYPE and isinstance(h[2], ox.NamedNode):
                    named_edges[sub.iri].add(h[2].value)
                else:
                    rules.append(FastRule(name, f"?x a {_iri(sub.iri)} .", h, frozenset({("t", sub.iri)})))
            for c in conditions:
                checks.append(Check(name, f"?x a {_iri(sub.iri)} .", c))
            continue
        for branch in disjuncts(sub):  # one rule per branch: no UNION for Oxigraph to join
            trigger, reads = pattern(branch, "?x", fresh)
            if not trigger or trigger.startswith("FILTER"):
                raise UnsupportedConstructError(f"{_show(sub, tbox)} (equivalent to owl:Thing) as a "
                                                "sub-class", "the ontology")
            implication(name, trigger, reads, sup)

    for p, d in tbox.domains:
        implication(f"domain of <{p}>", f"?x {_iri(p)} ?_any .", {("p", p)}, d,
                    table=domain_rows, table_head=_iri(p))
    for p, r in tbox.ranges:
        implication(f"range of <{p}>", f"?_any {_iri(p)} ?x . FILTER(!isLiteral(?x))", {("p", p)}, r,
                    table=range_rows, table_head=_iri(p))
    if domain_rows:
        rules.append(FastRule("domains", "?x ?p ?_y .", ("?x", TYPE, "?d"),
                              frozenset(k for k, _ in domain_rows), "?p ?d", domain_rows))
    if range_rows:
        rules.append(FastRule("ranges", "?_y ?p ?x . FILTER(!isLiteral(?x))", ("?x", TYPE, "?d"),
                              frozenset(k for k, _ in range_rows), "?p ?d", range_rows))
    closed = _closure({k: set(v) for k, v in named_edges.items()})
    class_rows = [(("t", c), (_iri(c), _iri(d))) for c in sorted(closed) for d in sorted(closed[c])]
    if class_rows:
        rules.append(FastRule("sub-classes", "?x a ?c .", ("?x", TYPE, "?d"),
                              frozenset(k for k, _ in class_rows), "?c ?d", class_rows))

    # -- SWRL rules -----------------------------------------------------------------------------
    for rule in tbox.rules:
        rules.extend(_compile_rule(rule))

    # -- constraints ----------------------------------------------------------------------------
    constraints: list[Constraint] = []
    for group in tbox.disjoint:
        if all(isinstance(m, Named) for m in group):
            members = " ".join(_iri(m.iri) for m in group)  # type: ignore[union-attr]
            names = ", ".join(_show(m, tbox) for m in group)
            constraints.append(Constraint("disjoint", f"an individual is in two of the disjoint classes {names}",
                                f"SELECT ?x WHERE {{ VALUES ?c {{ {members} }} ?x a ?c }} GROUP BY ?x "
                                "HAVING (COUNT(DISTINCT ?c) > 1) LIMIT 5"))
            continue
        for a, b in itertools.combinations(group, 2):
            pa, _ = pattern(a, "?x", fresh)
            pb, _ = pattern(b, "?x", fresh)
            if not pa or not pb:
                raise UnsupportedConstructError("owl:Thing in a disjointness axiom", "the ontology")
            constraints.append(Constraint("disjoint", f"{_show(a, tbox)} and {_show(b, tbox)} are disjoint",
                                f"SELECT DISTINCT ?x WHERE {{ {pa} {pb} }} LIMIT 5"))
    if tbox.functional_object:
        rows = " ".join(_iri(p) for p in tbox.functional_object)
        constraints.append(Constraint("functional", "a functional object property has two different values "
                            "(distinct IRIs are distinct individuals)",
                            f"SELECT DISTINCT ?x ?p WHERE {{ VALUES ?p {{ {rows} }} ?x ?p ?a . ?x ?p ?b . "
                            f"FILTER(!sameTerm(?a, ?b)) }} LIMIT 5"))
    for p in tbox.irreflexive:
        constraints.append(Constraint("irreflexive", f"<{p}> is irreflexive (an individual cannot be related to itself)",
                            f"SELECT DISTINCT ?x WHERE {{ ?x {_iri(p)} ?x }} LIMIT 5"))
    if tbox.functional_data:
        rows = " ".join(_iri(p) for p in tbox.functional_data)
        differ = ("!sameTerm(?v1, ?v2) && !COALESCE(?v1 = ?v2 && (DATATYPE(?v1) = DATATYPE(?v2) || "
                  f"({_in('DATATYPE(?v1)', _DECIMALS)} && {_in('DATATYPE(?v2)', _DECIMALS)})), false)")
        # First the cheap count (a property with more triples than subjects), then the details.
        constraints.append(Constraint(
            "functional", "a functional data property has two different values",
            "SELECT DISTINCT ?x ?p WHERE { VALUES ?p { %s } ?x ?p ?v1 . ?x ?p ?v2 . "
            f"FILTER({differ}) }} LIMIT 5",
            f"SELECT ?p WHERE {{ VALUES ?p {{ {rows} }} ?x ?p ?v }} GROUP BY ?p "
            "HAVING (COUNT(*) > COUNT(DISTINCT ?x))"))
    by_type: dict[str, list[str]] = defaultdict(list)
    for p, dt in tbox.data_ranges:
        by_type[dt].append(p)
    for dt, props in sorted(by_type.items()):
        if DATATYPES[dt] is None:
            continue
        rows = " ".join(_iri(p) for p in sorted(props))
        constraints.append(Constraint("range", f"the value is not in the range <{dt}> of the data property",
                            f"SELECT DISTINCT ?x ?p WHERE {{ VALUES ?p {{ {rows} }} ?x ?p ?v . "
                            f"FILTER(!{datatype_test('?v', dt)}) }} LIMIT 5"))
    return Program(rules, checks, constraints)


def _compile_rule(rule: Rule) -> list[FastRule]:
    names: dict[str, str] = {}

    def slot(a: object) -> Slot:
        if isinstance(a, Var):
            if a.iri not in names:
                local = "".join(ch if ch.isalnum() else "_" for ch in a.local) or "v"
                names[a.iri] = f"?r{len(names)}_{local}"
            return names[a.iri]
        return a  # type: ignore[return-value]

    def text(s: Slot) -> str:
        return s if isinstance(s, str) else str(s)

    fresh = _Fresh("_r")
    where, filters, reads = [], [], set()
    for atom in rule.body:
        args = [slot(a) for a in atom.args]
        if atom.kind == "class":
            if isinstance(args[0], ox.Literal):
                raise UnsupportedConstructError("a literal in a SWRL class atom", f"SWRL rule {rule.name!r}")
            where.append(f"{text(args[0])} a {_iri(atom.predicate or '')} .")
            reads.add(("t", atom.predicate or ""))
        elif atom.kind in ("object", "data"):
            s, o = args
            if isinstance(s, ox.Literal) or (atom.kind == "object" and isinstance(o, ox.Literal)):
                raise UnsupportedConstructError("a literal where a SWRL atom needs an individual",
                                                f"SWRL rule {rule.name!r}")
            if isinstance(o, ox.Literal):
                y = fresh()
                where.append(f"{text(s)} {_iri(atom.predicate or '')} {y} .")
                filters.append(same_value(y, o))
            else:
                where.append(f"{text(s)} {_iri(atom.predicate or '')} {text(o)} .")
            reads.add(("p", atom.predicate or ""))
        else:  # different
            filters.append(f"!sameTerm({text(args[0])}, {text(args[1])})")
    body = " ".join(where) + "".join(f" FILTER({f})" for f in filters)
    out = []
    for atom in rule.head:
        args = [slot(a) for a in atom.args]
        if atom.kind == "class":
            head: tuple[Slot, Slot, Slot] = (args[0], TYPE, ox.NamedNode(atom.predicate or ""))
        else:
            if atom.kind == "object" and isinstance(args[1], ox.Literal):
                raise UnsupportedConstructError("a literal where a SWRL atom needs an individual",
                                                f"SWRL rule {rule.name!r}")
            head = (args[0], ox.NamedNode(atom.predicate or ""), args[1])
        out.append(FastRule(f"SWRL rule {rule.name!r}", body, head, frozenset(reads)))
    return out


def short_name(iri: str) -> str:
    """``pk:Broker`` for a plantkg term, ``<iri>`` otherwise."""
    return "pk:" + iri[len(str(PK)):] if iri.startswith(str(PK)) else f"<{iri}>"


def _show(e: Expr, tbox: TBox) -> str:
    """A class expression in Manchester-like syntax, for messages."""
    def name(iri: str) -> str:
        return short_name(iri)

    def prop(p: Prop) -> str:
        return f"inverse({name(p.iri)})" if p.inverse else name(p.iri)

    if isinstance(e, Thing):
        return "owl:Thing"
    if isinstance(e, Named):
        return name(e.iri)
    if isinstance(e, And):
        return "(" + " and ".join(_show(p, tbox) for p in e.parts) + ")"
    if isinstance(e, Or):
        return "(" + " or ".join(_show(p, tbox) for p in e.parts) + ")"
    if isinstance(e, Some):
        return f"({prop(e.prop)} some {_show(e.filler, tbox)})"
    if isinstance(e, HasValue):
        return f"({prop(e.prop)} value {e.value})"
    if isinstance(e, Datatype):
        return name(e.iri)
    if isinstance(e, OneOf):
        return "{" + ", ".join(name(m.value) for m in e.members) + "}"
    return str(e)


def _facts(head: tuple[Slot, Slot, Slot], solutions: Iterable[ox.QuerySolution],
           work: ox.NamedNode) -> list[ox.Quad]:
    """The head's quads for each solution (SELECT variables are the head's, sorted by name)."""
    names = sorted({x for x in head if isinstance(x, str)})
    index = [names.index(x) if isinstance(x, str) else None for x in head]
    s0, p0, o0 = head
    si, pi, oi = index
    out = []
    for sol in solutions:
        s = s0 if si is None else sol[si]
        p = p0 if pi is None else sol[pi]
        if isinstance(s, ox.Literal) or not isinstance(p, ox.NamedNode):
            continue  # e.g. an inverse property whose value is a literal: not a fact
        out.append(ox.Quad(s, p, o0 if oi is None else sol[oi], work))
    return out


def _keys_of(head: tuple[Slot, Slot, Slot], facts: list[ox.Quad]) -> set[Key]:
    """The keys ``facts`` (all from a rule with ``head``) are about: one when the head's
    predicate (and, for rdf:type, its class) is a constant."""
    _, p, o = head
    if isinstance(p, ox.NamedNode) and (p != TYPE or isinstance(o, ox.NamedNode)):
        return {_key(p, o)}
    return {_key(q.predicate, q.object) for q in facts}


@dataclass
class Outcome:
    """What the fixpoint did: the facts it added to the working graph, and how long it ran."""

    added: list[ox.Quad]
    rounds: int
    queries: int
    #: each added fact (subject, predicate, object) -> the name of the rule that first derived it
    provenance: dict[tuple[object, object, object], str] = field(default_factory=dict)


def run(program: Program, store: ox.Store, inputs: list[ox.NamedNode], work: ox.NamedNode,
        where: Callable[[object], str], *, trace: bool = True) -> Outcome:
    """Run ``program`` on ``store`` (reading ``inputs`` and ``work``, writing into ``work``) to a
    fixpoint, then its checks and constraints. ``trace`` False leaves ``Outcome.provenance``
    empty (a dict entry per derived fact: ~0.3 s and tens of MiB at 100k resources)."""
    options = dataset_options(store, [*inputs, work])

    def select(query: str):  # noqa: ANN202
        return store.query(query, **options)

    version: dict[Key, int] = defaultdict(int)
    clock = 0
    added: list[ox.Quad] = []
    provenance: dict[tuple[object, object, object], str] = {}
    queries = rounds = 0
    while True:
        rounds += 1
        progress = False
        for rule in program.rules:
            if rule.table_vars:
                rows = [r for k, r in rule.table if version[k] > rule.last]
                if not rows:
                    continue
            else:
                rows = None
                if rule.last >= 0 and not any(version[k] > rule.last for k in rule.reads):
                    continue  # nothing it reads changed (a rule reading nothing runs once)
            rule.last = clock
            queries += 1
            try:
                solutions = select(rule.query(rows))
            except SyntaxError as exc:  # a bug of the compiler, not of the plant
                raise UnsupportedConstructError(f"{rule.name} (its SPARQL does not parse: {exc})",
                                                "the ontology") from None
            if isinstance(solutions, ox.QueryBoolean):  # a head without variables
                new = [ox.Quad(*rule.head, work)] if bool(solutions) else []  # type: ignore[misc]
            else:
                new = _facts(rule.head, solutions, work)
            if new:
                clock += 1
                store.extend(new)
                added.extend(new)
                for key in _keys_of(rule.head, new):
                    version[key] = clock
                if trace:
                    for q in new:
                        provenance.setdefault((q.subject, q.predicate, q.object), rule.name)
                progress = True
        if not progress:
            break
    for constraint in program.constraints:
        queries += 1
        query = constraint.query
        if constraint.precheck is not None:
            suspects = [str(sol["p"]) for sol in select(constraint.precheck)]
            if not suspects:
                continue
            queries += 1
            query = query % " ".join(suspects)
        bad = list(select(query))
        if bad:
            individuals = tuple(dict.fromkeys(where(sol["x"]) for sol in bad))
            raise InconsistentPlantError(f"{constraint.description}: {', '.join(individuals)}",
                                         individuals=individuals, engine="fast")
    fresh = _Fresh("_c")
    for check in program.checks:
        queries += 1
        if isinstance(check.condition, OneOf):
            members = ", ".join(str(m) for m in check.condition.members)
            query = f"SELECT DISTINCT ?x WHERE {{ {check.trigger} FILTER(?x NOT IN ({members})) }} LIMIT 5"
        else:
            cond, _ = pattern(check.condition, "?x", fresh)
            query = f"SELECT DISTINCT ?x WHERE {{ {check.trigger} MINUS {{ {cond} }} }} LIMIT 3"
        bad = list(select(query))
        if bad and isinstance(check.condition, OneOf):
            individuals = tuple(where(sol["x"]) for sol in bad)
            raise InconsistentPlantError(
                f"{check.name}: {', '.join(individuals)} is none of the enumerated individuals "
                "(distinct IRIs are distinct individuals)", individuals=individuals, engine="fast")
        if bad:
            who = ", ".join(where(sol["x"]) for sol in bad)
            raise UnsupportedConstructError(
                f"a condition no named individual fulfils ({check.name}; for {who})", "the plant",
                hint="the fast engine reasons over named individuals only; if a defined class is "
                "asserted, drop the assertion (it is inferred), or use --engine owlready2")
    return Outcome(added, rounds, queries, provenance)

"""The fast reasoner after an edit: re-run the rules from the changed facts only (DRed).

A full run (:func:`engine.reasoning.reason.reason` with a ``scratch`` graph) leaves the whole
fixpoint in the store: ``GRAPH_INFERRED`` plus the facts it does not export in the scratch graph.
After an edit removes and adds asserted triples, :class:`Rereasoner` brings that fixpoint to the
one a full run on the edited plant reaches, by the classic delete-and-rederive method:

1. *overdelete* (before the edit is applied): every inferred fact one of whose derivations used a
   removed fact, transitively — each compiled rule is evaluated with one body pattern bound (a
   ``VALUES`` block) to the removed or overdeleted facts it matches;
2. the edit is applied, the overdeleted facts are dropped (and inferred facts the edit now asserts);
3. *rederive*: an overdeleted (or un-asserted) fact some rule still concludes on the new state is
   put back (the rule's body with its head bound, ``FastRule.instances_query``);
4. *insert*: from the added and rederived facts, each rule with one body pattern bound to them,
   ``MINUS`` what is known, to a fixpoint.

Then the constraints and checks the full run ends with are evaluated for the individuals the
change can reach (:mod:`kg.sparql_deps`). When one fails, :class:`NeedsFullRun` asks the caller to
run the full reasoner, which raises the exact error a full run gives. Rule bodies are read once
with :func:`kg.sparql_deps.analyse`; nothing of the plant's rules is written here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Iterable

import pyoxigraph as ox

from engine.reasoning.reason import INFERRED, derived_properties, exported_test, input_graphs
from engine.reasoning.rules_fast import OneOf, Program, _Fresh, _facts, compile_tbox, pattern
from engine.reasoning.rules_tbox import RESERVED_NAMESPACES, TYPE as _TYPE, read_tbox
from kg.load import PlantGraph
from kg.sparql_deps import ALL, Deps, Pattern, _matches, analyse, store_lookup

Fact = tuple[object, ox.NamedNode, object]


class NeedsFullRun(Exception):
    """The edit broke a constraint or check (or reached what the delta cannot follow): run the
    full reasoner, which reports it exactly as it would without an incremental session."""


@dataclass
class _Rule:
    head: tuple
    body: str           # the rule's WHERE text, its table as a VALUES block included
    patterns: list[Pattern]
    variables: list[str]


@dataclass
class Rereasoner:
    """The compiled rules of one plant's TBox and what an incremental run needs of them."""

    plant: PlantGraph
    scratch: ox.NamedNode
    program: Program = field(init=False)
    rules: list[_Rule] = field(init=False)
    keep: object = field(init=False)
    #: queries the last update ran, for benchmarks and tests
    queries: int = 0

    def __post_init__(self) -> None:
        inputs = input_graphs(self.plant)
        tbox = read_tbox(self.plant.store, inputs, lambda n: str(n))
        self.program = compile_tbox(tbox)
        self.keep = exported_test(derived_properties(self.plant))
        self.rules = []
        for r in self.program.rules:
            table = ""
            if r.table_vars:
                rows = " ".join(f"({a} {b})" for _, (a, b) in r.table)
                table = f"VALUES ({r.table_vars}) {{ {rows} }} "
            body = table + r.where
            deps = analyse(f"SELECT * WHERE {{ {body} }}")
            if deps.opaque:
                raise NeedsFullRun(f"rule {r.name} cannot be read for an incremental run")
            variables = sorted({x for x in r.head if isinstance(x, str)})
            self.rules.append(_Rule(r.head, body, deps.patterns, variables))

    # -- the store ------------------------------------------------------------------------------
    @property
    def graphs(self) -> list[ox.NamedNode]:
        return [*input_graphs(self.plant), INFERRED, self.scratch]

    def _select(self, query: str):  # noqa: ANN202
        self.queries += 1
        return self.plant.store.query(query, default_graph=self.graphs)

    def _asserted(self, f: Fact) -> bool:
        s, p, o = f
        return any(True for g in input_graphs(self.plant)
                   for _ in self.plant.store.quads_for_pattern(s, p, o, g))  # type: ignore[arg-type]

    def _inferred(self, f: Fact) -> ox.NamedNode | None:
        s, p, o = f
        for g in (INFERRED, self.scratch):
            if any(True for _ in self.plant.store.quads_for_pattern(s, p, o, g)):  # type: ignore[arg-type]
                return g
        return None

    def _add(self, facts: Iterable[Fact]) -> None:
        self.plant.store.extend([ox.Quad(s, p, o, INFERRED if self.keep(s, p, o) else self.scratch)  # type: ignore[arg-type, operator]
                                 for s, p, o in facts])

    def _drop(self, facts: Iterable[Fact]) -> None:
        for f in facts:
            g = self._inferred(f)
            if g is not None:
                self.plant.store.remove(ox.Quad(*f, g))  # type: ignore[arg-type]

    # -- one rule with one body pattern bound to some facts --------------------------------------
    def _fire(self, rule: _Rule, facts: list[Fact], *, new_only: bool) -> set[Fact]:
        out: set[Fact] = set()
        for pat in rule.patterns:
            rows = {_binding(pat, f) for f in facts if _matches(pat, f)}
            rows.discard(None)
            if not rows:
                continue
            names = sorted({n for row in rows for n, _ in row})  # type: ignore[union-attr]
            table = " ".join("(" + " ".join(str(dict(row)[n]) for n in names) + ")" for row in rows)  # type: ignore[arg-type]
            values = f"VALUES ({' '.join('?' + n for n in names)}) {{ {table} }} "
            s, p, o = (x if isinstance(x, str) else str(x) for x in rule.head)
            # FILTER NOT EXISTS, not the full run's MINUS: the rows are few, and MINUS would
            # evaluate its side over the whole store
            minus = f" FILTER NOT EXISTS {{ {s} {p} {o} }}" if new_only and rule.variables else ""
            if not rule.variables:
                if bool(self._select(f"ASK {{ {values}{rule.body} }}")):
                    out.add(tuple(rule.head))  # type: ignore[arg-type]
                continue
            query = f"SELECT DISTINCT {' '.join(rule.variables)} WHERE {{ {values}{rule.body}{minus} }}"
            out |= {(q.subject, q.predicate, q.object) for q in _facts(rule.head, self._select(query), INFERRED)}
        return out

    def _derivable(self, f: Fact) -> bool:
        for rule, compiled in zip(self.rules, self.program.rules):
            query = compiled.instances_query(f)  # type: ignore[arg-type]
            if query is not None:
                self.queries += 1
                if any(True for _ in self.plant.store.query(query + " LIMIT 1", default_graph=self.graphs)):
                    return True
        return False

    # -- the update -----------------------------------------------------------------------------
    def overdelete(self, removed: list[Fact]) -> set[Fact]:
        """Before the edit: the inferred facts a derivation through ``removed`` may have given."""
        self.queries = 0
        gone = [f for f in removed if not self._asserted_elsewhere(f)]
        doomed: set[Fact] = set()
        frontier = gone
        while frontier:
            heads: set[Fact] = set()
            for rule in self.rules:
                heads |= self._fire(rule, frontier, new_only=False)
            frontier = [h for h in heads if h not in doomed and self._inferred(h) is not None]
            doomed.update(frontier)
        self._gone = gone
        return doomed

    def _asserted_elsewhere(self, f: Fact) -> bool:
        """Whether ``f`` stays asserted after the edit: the caller passes triples the edit
        removes from one file; another input graph may assert them too."""
        return self._asserted(f) and sum(
            1 for g in input_graphs(self.plant)
            for _ in self.plant.store.quads_for_pattern(*f, g)) > 1  # type: ignore[misc]

    def insert(self, doomed: set[Fact], added: list[Fact]) -> list[Fact]:
        """After the edit is applied: drop ``doomed``, rederive, insert; returns every fact whose
        presence changed (for the constraint checks)."""
        self._drop(doomed)
        now_asserted = [f for f in added if self._inferred(f) is not None]
        self._drop(now_asserted)
        candidates = [f for f in (*doomed, *self._gone) if not self._asserted(f)]
        back = [f for f in candidates if self._derivable(f)]
        self._add(back)
        frontier: list[Fact] = [*added, *back]
        inserted: list[Fact] = list(back)
        known: set[Fact] = set(back)
        while frontier:
            new: set[Fact] = set()
            for rule in self.rules:
                new |= self._fire(rule, frontier, new_only=True)
            new = {f for f in new if f not in known and not isinstance(f[0], ox.Literal)}
            self._add(new)
            known |= new
            inserted.extend(new)
            frontier = list(new)
        return [*doomed, *self._gone, *added, *inserted, *now_asserted]

    def check(self, changed: list[Fact]) -> None:
        """The full run's constraints and checks, for the individuals ``changed`` can reach."""
        lookup = store_lookup(self.plant.store, self.graphs)
        fresh = _Fresh("_c")
        texts: list[str] = []
        for constraint in self.program.constraints:
            query = constraint.query
            if constraint.precheck is not None:
                props = re.search(r"VALUES \?p \{ (.*?) \}", constraint.precheck)
                query = query % (props.group(1) if props else "")
            texts.append(query)
        for c in self.program.checks:
            if isinstance(c.condition, OneOf):
                members = ", ".join(str(m) for m in c.condition.members)
                texts.append(f"SELECT DISTINCT ?x WHERE {{ {c.trigger} FILTER(?x NOT IN ({members})) }} LIMIT 5")
            else:
                cond, _ = pattern(c.condition, "?x", fresh)
                # FILTER NOT EXISTS for the few individuals checked, not the full run's MINUS
                # (which evaluates the condition over the whole store); the two agree here: the
                # condition binds ?x, the only variable it shares with the trigger. An empty
                # condition keeps MINUS, whose answer for it differs.
                negation = "FILTER NOT EXISTS" if cond.strip() else "MINUS"
                texts.append(f"SELECT DISTINCT ?x WHERE {{ {c.trigger} {negation} {{ {cond} }} }} LIMIT 3")
        for text in texts:
            deps: Deps = analyse(text)
            relevant = [f for f in changed if deps.reads(f)]  # type: ignore[arg-type]
            if not relevant:
                continue
            who = deps.affected("x", relevant, lookup)  # type: ignore[arg-type]
            if who is not ALL and any(isinstance(x, ox.BlankNode) for x in who):
                who = ALL
            if who is not ALL and not who:
                continue
            if who is not ALL:
                brace = text.index("{")
                text = text[:brace + 1] + f" VALUES ?x {{ {' '.join(str(x) for x in who)} }} " + text[brace + 1:]
            if any(True for _ in self._select(text)):
                raise NeedsFullRun("the edit breaks a constraint of the ontology")


def touches_tbox(facts: Iterable[Fact]) -> bool:
    """Whether a changed triple is an axiom, a vocabulary term the reader checks, or has a blank
    node: the compiled program (or the full run's refusal) may change, so only a full run knows."""
    reserved = RESERVED_NAMESPACES
    for s, p, o in facts:
        if isinstance(s, ox.BlankNode) or isinstance(o, ox.BlankNode):
            return True
        if p.value.startswith(reserved) and p != _TYPE:
            return True
        if p == _TYPE and isinstance(o, ox.NamedNode) and o.value.startswith(reserved):
            return True
    return False


def _binding(pat: Pattern, f: Fact) -> frozenset | None:
    """The pattern's variables bound to the fact's terms (None when a repeated variable would
    need two different terms)."""
    out: dict[str, object] = {}
    for slot, term in ((pat.s, f[0]), (pat.pvar, f[1]), (pat.o, f[2])):
        if isinstance(slot, str):
            if out.setdefault(slot, term) != term:
                return None
    return frozenset(out.items())

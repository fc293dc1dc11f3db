"""Which values of one variable (a validator's ``?this``, a rule's ``?x``) an edit can change, for
one SPARQL query: what lets an incremental run re-evaluate a query for a few nodes, not all.

The query's evaluation reads only triples that match its triple patterns. For a changed triple
``t`` matching pattern ``P``, a solution that used ``t`` for ``P`` binds every pattern along a chain
of shared variables from ``P`` to the target variable, so the target values it can change are those
reached from ``t``'s terms by walking the *other* patterns of the query over the data (once on the
state before the edit, once after: a chain may hold in either). Filters only remove solutions and
are not walked. Three cases give up and answer :data:`ALL` (re-run for every node), never a guess:

- the target is reached from ``P`` only through an expression (``FILTER (?a = ?b)``, ``BIND``, an
  aggregate) or not at all (a cross product: the change may affect every solution);
- ``P`` sits in a part whose link to the rest is not certain: an OPTIONAL, EXISTS, UNION branch or
  sub-query sharing variables with the rest of which none is bound on both sides in every solution
  (a row with the variable unbound is compatible with any value, so no chain need exist);
- a construct not read here (GRAPH, SERVICE, a property path form other than IRIs, inverse,
  sequence, alternative and ``*``/``+``/``?``), or a walk that reaches more than :data:`LIMIT` values.

Soundness is the point: a wrong "unaffected" would make an incremental result differ from a full run.
``tests/unit/test_incremental.py`` holds incremental runs to full runs on many random edits.
rdflib's SPARQL parser reads the query (only here: the plain pipeline never imports it).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
from dataclasses import dataclass, field
from pathlib import Path as FilePath
from typing import Callable, Iterable

import pyoxigraph as ox

#: "Every value": the sentinel :func:`Deps.affected` returns when it cannot narrow the change down.
ALL = None
#: A walk that reaches more values than this gives up (:data:`ALL`): re-running the query is cheaper.
LIMIT = 20000

Term = ox.NamedNode | ox.BlankNode | ox.Literal
Triple = tuple[Term, ox.NamedNode, Term]
Lookup = Callable[[Term | None, ox.NamedNode | None, Term | None], Iterable[Triple]]


class _TooMany(Exception):
    pass


@dataclass(frozen=True)
class Path:
    """A property path: ``kind`` is iri, inv, seq, alt, star, plus, opt or any (a negated set)."""

    kind: str
    iri: ox.NamedNode | None = None
    parts: tuple["Path", ...] = ()

    def predicates(self) -> set[ox.NamedNode] | None:
        """The IRIs a step may use; None for any."""
        if self.kind == "any":
            return None
        if self.kind == "iri":
            return {self.iri}  # type: ignore[arg-type]
        out: set[ox.NamedNode] = set()
        for p in self.parts:
            sub = p.predicates()
            if sub is None:
                return None
            out |= sub
        return out


@dataclass(frozen=True)
class Pattern:
    """A triple pattern: each end a variable name (str) or a term; ``path`` for the predicate
    unless ``pvar`` names a variable predicate; ``unsafe`` when its part's link is not certain."""

    s: str | Term
    path: Path | None
    pvar: str | None
    o: str | Term
    unsafe: bool = False
    #: the conditional parts (OPTIONAL, UNION branch, EXISTS, MINUS) it sits in, outermost first
    scopes: tuple[int, ...] = ()

    def variables(self) -> set[str]:
        return {x for x in (self.s, self.o, self.pvar) if isinstance(x, str)}


@dataclass
class Deps:
    """The triple patterns of one query, the variables its expressions tie together, and whether
    some construct made it unreadable (then every change touching it is :data:`ALL`)."""

    patterns: list[Pattern] = field(default_factory=list)
    links: list[set[str]] = field(default_factory=list)
    opaque: bool = False

    def reads(self, t: Triple) -> bool:
        """Whether the query reads ``t`` (some pattern may match it)."""
        return self.opaque or any(_matches(p, t) for p in self.patterns)

    def affected(self, target: str, changes: Iterable[Triple], lookup: Lookup) -> set[Term] | None:
        """Values of ``?target`` whose solutions may change by ``changes``, walking ``lookup``
        (the data, before or after the edit); :data:`ALL` when that cannot be narrowed down."""
        changes = list(changes)
        if self.opaque:
            return ALL if changes else set()
        out: set[Term] = set()
        for t in changes:
            for i, p in enumerate(self.patterns):
                if not _matches(p, t):
                    continue
                if p.unsafe:
                    return ALL
                found = self._walk(target, i, t, lookup)
                if found is ALL:
                    return ALL
                out |= found
        return out

    def _walk(self, target: str, start: int, t: Triple, lookup: Lookup) -> set[Term] | None:
        """Target values reached from the changed triple. First along the patterns that hold in
        every solution that uses it (the same conjunctive part, or one enclosing it), level by
        level, stopping at the first level that reaches the target: every such solution binds
        all of them, so one chain is enough. Failing that, along every pattern."""
        try:
            seeds = _seeds(self.patterns[start], t, lookup)
            if target in seeds:
                return set(seeds[target])
            mine = self.patterns[start].scopes
            usable = [i for i, p in enumerate(self.patterns)
                      if i != start and p.scopes == mine[:len(p.scopes)]]
            if self._reachable(target, set(seeds), start, usable):
                return self._levels(target, seeds, usable, lookup)
            if not self._reachable(target, set(seeds), start):
                return ALL
            return self._levels(target, seeds, [i for i in range(len(self.patterns)) if i != start], lookup,
                                stop=False)
        except _TooMany:
            return ALL

    def _levels(self, target: str, seeds: dict[str, set[Term]], usable: list[int], lookup: Lookup,
                stop: bool = True) -> set[Term]:
        values = {k: set(v) for k, v in seeds.items()}
        frontier = {k: set(v) for k, v in seeds.items()}
        while frontier:
            nxt: dict[str, set[Term]] = {}
            for var, vals in frontier.items():
                for i in usable:
                    p = self.patterns[i]
                    if var not in p.variables():
                        continue
                    for other, found in _step(p, var, vals, lookup).items():
                        if other == var:
                            continue
                        have = values.setdefault(other, set())
                        new = found - have
                        if new:
                            have |= new
                            if len(have) > LIMIT:
                                raise _TooMany
                            if other != target:
                                nxt.setdefault(other, set()).update(new)
            if stop and values.get(target):
                break
            frontier = nxt
        return set(values.get(target, set()))

    def _reachable(self, target: str, seeds: set[str], start: int, usable: list[int] | None = None) -> bool:
        """Whether a chain of patterns (not expressions) leads from ``seeds`` to ``target``."""
        seen, todo = set(seeds), list(seeds)
        allowed = set(range(len(self.patterns)) if usable is None else usable) - {start}
        while todo:
            var = todo.pop()
            for i, p in enumerate(self.patterns):
                if i in allowed and var in p.variables():
                    for other in p.variables() - seen:
                        seen.add(other)
                        todo.append(other)
        return target in seen


# -- matching a changed triple and walking the data -------------------------------------------------

def _matches(p: Pattern, t: Triple) -> bool:
    s, pred, o = t
    if p.pvar is None:
        preds = p.path.predicates()  # type: ignore[union-attr]
        if preds is not None and pred not in preds:
            return False
        if p.path.kind != "iri":  # type: ignore[union-attr]
            return True  # a step of a longer path: its ends are not the triple's
    return (isinstance(p.s, str) or p.s == s) and (isinstance(p.o, str) or p.o == o)


def _seeds(p: Pattern, t: Triple, lookup: Lookup) -> dict[str, set[Term]]:
    s, pred, o = t
    if p.pvar is not None or p.path.kind == "iri":  # type: ignore[union-attr]
        ends = ({s}, {o})
    else:
        ends = _ends(p.path, t, lookup)  # type: ignore[arg-type]
    out: dict[str, set[Term]] = {}
    if isinstance(p.s, str):
        out.setdefault(p.s, set()).update(ends[0])
    if isinstance(p.o, str):
        out.setdefault(p.o, set()).update(ends[1])
    if p.pvar is not None:
        out.setdefault(p.pvar, set()).add(pred)
    return out


def _ends(path: Path, t: Triple, lookup: Lookup) -> tuple[set[Term], set[Term]]:
    """For a changed edge ``t`` used by some step of ``path``: the path's possible start and end
    nodes of every match through that step."""
    a, pred, b = t
    k = path.kind
    if k in ("iri", "any"):
        return ({a}, {b}) if k == "any" or path.iri == pred else (set(), set())
    if k == "inv":
        starts, ends = _ends(path.parts[0], t, lookup)
        return ends, starts
    if k == "alt":
        pairs = [_ends(x, t, lookup) for x in path.parts]
        return set().union(*(x for x, _ in pairs)), set().union(*(y for _, y in pairs))
    if k in ("star", "plus", "opt"):
        starts, ends = _ends(path.parts[0], t, lookup)
        closure = Path("star", parts=path.parts)
        return _eval(closure, starts, lookup, back=True), _eval(closure, ends, lookup, back=False)
    if k == "seq":
        starts: set[Term] = set()
        ends: set[Term] = set()
        for i, part in enumerate(path.parts):
            s_i, e_i = _ends(part, t, lookup)
            if not s_i and not e_i:
                continue
            starts |= _eval(Path("seq", parts=path.parts[:i]), s_i, lookup, back=True)
            ends |= _eval(Path("seq", parts=path.parts[i + 1:]), e_i, lookup, back=False)
        return starts, ends
    raise AssertionError(k)


def _eval(path: Path, nodes: set[Term], lookup: Lookup, *, back: bool) -> set[Term]:
    """The nodes reached from ``nodes`` along ``path`` (against it when ``back``)."""
    k = path.kind
    if k == "seq":
        parts = reversed(path.parts) if back else path.parts
        for part in parts:
            nodes = _eval(part, nodes, lookup, back=back)
        return nodes
    if k == "inv":
        return _eval(path.parts[0], nodes, lookup, back=not back)
    if k == "alt":
        return set().union(*(_eval(x, nodes, lookup, back=back) for x in path.parts))
    if k in ("star", "plus", "opt"):
        seen = set(nodes)
        frontier = set(nodes)
        while frontier:
            frontier = _eval(path.parts[0], frontier, lookup, back=back) - seen
            seen |= frontier
            if len(seen) > LIMIT:
                raise _TooMany
            if k == "opt":
                break
        return seen
    pred = path.iri if k == "iri" else None
    out: set[Term] = set()
    for n in nodes:
        if back:
            out.update(s for s, _, _ in lookup(None, pred, n))
        elif not isinstance(n, ox.Literal):
            out.update(o for _, _, o in lookup(n, pred, None))
        if len(out) > LIMIT:
            raise _TooMany
    return out


def _step(p: Pattern, var: str, values: set[Term], lookup: Lookup) -> dict[str, set[Term]]:
    """Values of ``p``'s other variables for the given values of ``var``."""
    out: dict[str, set[Term]] = {}
    if p.pvar is not None:
        for x in values:
            if p.pvar == var:
                triples = lookup(None, x, None) if isinstance(x, ox.NamedNode) else ()  # type: ignore[arg-type]
            elif p.s == var:
                triples = lookup(x, None, None) if not isinstance(x, ox.Literal) else ()
            else:
                triples = lookup(None, None, x)
            for s, pred, o in itertools.islice(triples, LIMIT + 1):
                for slot, term in ((p.s, s), (p.pvar, pred), (p.o, o)):
                    if isinstance(slot, str) and slot != var:
                        out.setdefault(slot, set()).add(term)
            if any(len(v) > LIMIT for v in out.values()):
                raise _TooMany
        return out
    if p.s == var and isinstance(p.o, str):
        out[p.o] = _eval(p.path, values, lookup, back=False)  # type: ignore[arg-type]
    if p.o == var and isinstance(p.s, str):
        out.setdefault(p.s, set()).update(_eval(p.path, values, lookup, back=True))  # type: ignore[arg-type]
    return out


def store_lookup(store: ox.Store, graphs: list[ox.NamedNode]) -> Lookup:
    """Triples of ``graphs`` in ``store`` matching a pattern (None: any)."""
    def lookup(s, p, o):  # noqa: ANN001, ANN202
        for g in graphs:
            for q in store.quads_for_pattern(s, p, o, g):
                yield q.subject, q.predicate, q.object
    return lookup


# -- reading a query ---------------------------------------------------------------------------------

#: Bumped when the reading changes, so cached readings of an older one are not used.
_VERSION = "2"


def analyse(query: str) -> Deps:
    """The :class:`Deps` of a SPARQL SELECT (prefixes declared in the text), from the process's
    memory, the on-disk cache (rdflib's parser takes ~0.1 s a query), or read now."""
    key = hashlib.sha256(f"{_VERSION}\n{query}".encode()).hexdigest()
    found = _MEMORY.get(key)
    if found is None:
        found = _load(key)
        if found is None:
            found = _read(query)
            _store(key, found)
        _MEMORY[key] = found
    return found


_MEMORY: dict[str, Deps] = {}


def _cache_dir() -> FilePath:
    """``$PLANTKG_CACHE_DIR`` (or ``$XDG_CACHE_HOME/plantkg``, ``~/.cache/plantkg``) / sparql-deps."""
    if env := os.environ.get("PLANTKG_CACHE_DIR"):
        base = FilePath(env)
    else:
        base = FilePath(os.environ.get("XDG_CACHE_HOME") or FilePath.home() / ".cache") / "plantkg"
    return base / "sparql-deps"


def _term_json(t: object) -> object:
    if isinstance(t, str):
        return t
    if isinstance(t, ox.NamedNode):
        return ["iri", t.value]
    if isinstance(t, ox.Literal):
        return ["lit", t.value, t.datatype.value, t.language]
    raise TypeError(t)


def _term_back(x: object) -> object:
    if isinstance(x, str):
        return x
    if x[0] == "iri":  # type: ignore[index]
        return ox.NamedNode(x[1])  # type: ignore[index]
    _, value, datatype, language = x  # type: ignore[misc]
    return ox.Literal(value, language=language) if language else ox.Literal(value, datatype=ox.NamedNode(datatype))


def _path_json(p: Path | None) -> object:
    if p is None:
        return None
    return [p.kind, p.iri.value if p.iri else None, [_path_json(x) for x in p.parts]]


def _path_back(x: object) -> Path | None:
    if x is None:
        return None
    kind, iri, parts = x  # type: ignore[misc]
    return Path(kind, ox.NamedNode(iri) if iri else None, tuple(_path_back(y) for y in parts))  # type: ignore[misc]


def _store(key: str, deps: Deps) -> None:
    data = {"opaque": deps.opaque, "links": [sorted(x) for x in deps.links],
            "patterns": [[_term_json(p.s), _path_json(p.path), p.pvar, _term_json(p.o), p.unsafe, list(p.scopes)]
                         for p in deps.patterns]}
    try:
        folder = _cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{key}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(data), encoding="utf-8")
        tmp.replace(folder / f"{key}.json")
    except OSError:
        return  # a read-only cache is no error: the reading is only slower next time


def _load(key: str) -> Deps | None:
    try:
        data = json.loads((_cache_dir() / f"{key}.json").read_text(encoding="utf-8"))
        return Deps([Pattern(_term_back(s), _path_back(path), pvar, _term_back(o), unsafe, tuple(scopes))  # type: ignore[arg-type]
                     for s, path, pvar, o, unsafe, scopes in data["patterns"]],
                    [set(x) for x in data["links"]], bool(data["opaque"]))
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None


def _read(query: str) -> Deps:
    from rdflib.plugins.sparql.algebra import translateQuery  # noqa: PLC0415 - heavy, incremental runs only
    from rdflib.plugins.sparql.parser import parseQuery  # noqa: PLC0415

    deps = Deps()
    try:
        algebra = translateQuery(parseQuery(query)).algebra
        _Reader(deps).walk(algebra, lambda v: v)
    except _Opaque:
        deps.opaque = True
    return deps


class _Opaque(Exception):
    pass


class _Reader:
    """Walks rdflib's algebra: records patterns, expression links, and marks the patterns of a
    part whose link to the rest is not certain (see the module doc)."""

    def __init__(self, deps: Deps) -> None:
        self.deps = deps
        self.scopes = itertools.count()
        self.top_done = False
        self.conditional: list[int] = []
        self.parts = itertools.count()

    def inside(self, node, rename):  # noqa: ANN001, ANN201
        """Walk ``node`` as a conditional part (its patterns need not hold in a solution)."""
        self.conditional.append(next(self.parts))
        try:
            return self.walk(node, rename)
        finally:
            self.conditional.pop()

    def mark_unsafe(self, start: int) -> None:
        pats = self.deps.patterns
        pats[start:] = [Pattern(p.s, p.path, p.pvar, p.o, True, p.scopes) for p in pats[start:]]

    def check(self, left: tuple[set[str], set[str]], right: tuple[set[str], set[str]], start: int) -> None:
        """The right part (patterns from ``start`` on) joins the left one: some variable they
        share must be bound on both sides in every solution, else changes inside it are ALL."""
        shared = left[1] & right[1]
        if shared and not (shared & left[0] & right[0]):
            self.mark_unsafe(start)

    def walk(self, node, rename):  # noqa: ANN001, ANN201, C901, PLR0911, PLR0912 - one case per operator
        """(certainly bound variables, all variables) of ``node``."""
        from rdflib.term import Variable  # noqa: PLC0415

        name = getattr(node, "name", None)
        if name in ("SelectQuery", "Distinct", "Reduced", "Slice", "ToMultiSet", "SubSelect"):
            return self.walk(node.p, rename)
        if name == "Project":
            pv = {str(v) for v in node.PV}
            if not self.top_done:
                self.top_done = True  # the query's own projection: its variables keep their names
                inner = rename
            else:
                k = next(self.scopes)
                inner = lambda v, k=k: rename(v) if v in pv else f"{v}@{k}"  # noqa: E731
            cb, vs = self.walk(node.p, inner)
            keep = {rename(v) for v in pv}
            return cb & keep, vs & keep
        if name == "OrderBy":
            cb, vs = self.walk(node.p, rename)
            for cond in node.expr:
                self.expression(cond, rename, cb, vs)
            return cb, vs
        if name == "BGP":
            cb: set[str] = set()
            for s, p, o in node.triples:
                pat = Pattern(self.term(s, rename), None if isinstance(p, Variable) else _path(p),
                              rename(str(p)) if isinstance(p, Variable) else None, self.term(o, rename),
                              scopes=tuple(self.conditional))
                self.deps.patterns.append(pat)
                cb |= pat.variables()
            return cb, set(cb)
        if name == "Join":
            left = self.walk(node.p1, rename)
            start = len(self.deps.patterns)
            right = self.walk(node.p2, rename)
            if left[1] & right[1]:
                self.check(left, right, start)
            return left[0] | right[0], left[1] | right[1]
        if name == "LeftJoin":
            left = self.walk(node.p1, rename)
            start = len(self.deps.patterns)
            right = self.inside(node.p2, rename)
            self.expression(node.expr, rename, right[0], right[1] | left[1])
            self.check(left, right, start)
            return left[0], left[1] | right[1]
        if name == "Minus":
            left = self.walk(node.p1, rename)
            right = self.inside(node.p2, rename)
            return left[0], left[1] | right[1]
        if name == "Union":
            a, b = self.inside(node.p1, rename), self.inside(node.p2, rename)
            return a[0] & b[0], a[1] | b[1]
        if name == "Filter":
            cb, vs = self.walk(node.p, rename)
            self.expression(node.expr, rename, cb, vs)
            return cb, vs
        if name == "Extend":
            cb, vs = self.walk(node.p, rename)
            used = self.expression(node.expr, rename, cb, vs)
            var = rename(str(node.var))
            self.deps.links.append(used | {var})
            return cb, vs | {var}
        if name == "Group":
            cb, vs = self.walk(node.p, rename)
            keys: set[str] = set()
            for e in node.expr or ():
                if isinstance(e, Variable):
                    keys.add(rename(str(e)))
                else:
                    self.deps.links.append(self.expression(e, rename, cb, vs))
            return cb & keys, vs
        if name == "AggregateJoin":
            cb, vs = self.walk(node.p, rename)
            for agg in node.A:
                res = rename(str(agg.res))
                self.deps.links.append(self.expression(agg.vars, rename, cb, vs) | {res})
                vs = vs | {res}
            return cb, vs
        if name == "values":
            rows = [{rename(str(v)) for v, term in row.items() if term is not None} for row in node.res]
            names = set().union(*rows) if rows else set()
            return (set.intersection(*rows) if rows else set()), names
        raise _Opaque(name)

    def term(self, t, rename):  # noqa: ANN001, ANN201
        from rdflib.term import BNode, Literal, URIRef, Variable  # noqa: PLC0415

        if isinstance(t, Variable):
            return rename(str(t))
        if isinstance(t, BNode):  # a blank node in a query is a variable
            return rename(f"_:{t}")
        if isinstance(t, URIRef):
            return ox.NamedNode(str(t))
        if isinstance(t, Literal):
            if t.language:
                return ox.Literal(str(t), language=t.language)
            return ox.Literal(str(t), datatype=ox.NamedNode(str(t.datatype))) if t.datatype else ox.Literal(str(t))
        raise _Opaque(repr(t))

    def expression(self, expr, rename, cb: set[str], vs: set[str]) -> set[str]:  # noqa: ANN001
        """The variables of ``expr`` (linked together); EXISTS parts are walked as patterns whose
        link to the filtered part (``cb``/``vs``) must be certain."""
        from rdflib.plugins.sparql.parserutils import CompValue  # noqa: PLC0415
        from rdflib.term import Variable  # noqa: PLC0415

        found: set[str] = set()

        def visit(e) -> None:  # noqa: ANN001
            if isinstance(e, Variable):
                found.add(rename(str(e)))
            elif isinstance(e, CompValue):
                if e.name in ("Builtin_EXISTS", "Builtin_NOTEXISTS"):
                    start = len(self.deps.patterns)
                    inner = self.inside(_translated(e.graph), rename)
                    shared = inner[1] & vs
                    if not (shared & cb):
                        self.mark_unsafe(start)
                    return
                for value in e.values():
                    visit(value)
            elif isinstance(e, (list, tuple)):
                for value in e:
                    visit(value)

        visit(expr)
        if len(found) > 1:
            self.deps.links.append(set(found))
        return found


def _translated(graph):  # noqa: ANN001, ANN202
    """An EXISTS graph pattern as algebra (rdflib may leave it as parsed)."""
    if getattr(graph, "name", None) in ("GroupGraphPatternSub", "SubSelect"):
        from rdflib.plugins.sparql.algebra import translateGroupGraphPattern  # noqa: PLC0415

        return translateGroupGraphPattern(graph)
    return graph


def _path(p) -> Path:  # noqa: ANN001
    from rdflib.paths import AlternativePath, InvPath, MulPath, NegatedPath, SequencePath  # noqa: PLC0415
    from rdflib.term import URIRef  # noqa: PLC0415

    if isinstance(p, URIRef):
        return Path("iri", ox.NamedNode(str(p)))
    if isinstance(p, InvPath):
        return Path("inv", parts=(_path(p.arg),))
    if isinstance(p, SequencePath):
        return Path("seq", parts=tuple(_path(x) for x in p.args))
    if isinstance(p, AlternativePath):
        return Path("alt", parts=tuple(_path(x) for x in p.args))
    if isinstance(p, MulPath):
        kind = {"*": "star", "+": "plus", "?": "opt"}[p.mod]
        return Path(kind, parts=(_path(p.path),))
    if isinstance(p, NegatedPath):
        return Path("any")
    raise _Opaque(repr(p))

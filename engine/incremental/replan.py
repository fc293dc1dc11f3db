"""A warm pipeline: after a small edit of a plant file, re-plan from what changed, not from scratch.

:class:`ReplanSession` loads the plant files once and runs the stages in full. Each
:meth:`~ReplanSession.refresh` then reads the files again and, for each that changed, the triples
the edit removed and added (:mod:`kg.file_delta`: the edited statements only, or the whole file when
that cannot be decided exactly). It applies them to the store it keeps, re-validates only the focus
nodes the change can reach (:mod:`kg.validate_delta`), re-runs the fast reasoner's rules from the
changed facts (:mod:`engine.reasoning.rules_delta`), derives the desired state and plans.

The result is the one :func:`engine.pipeline.run_pipeline` gives on the edited files — same report,
same inferred graph, same desired state and plan — and ``tests/unit/test_incremental.py`` holds the
two to it on many random edits. Whatever the incremental steps cannot follow exactly (an edit of
the TBox, a file that cannot be cut, a constraint the edit breaks, shapes that need pySHACL, a plant
the fast reasoner refuses) is done by the full step instead, and says so in ``last``.

The set of files may change too (``refresh(files=...)``): a new file is an edit from nothing to its
content, a file no longer given one from its content to nothing, each read as a whole file. That is
how a folder the fleet manager writes a file per discovered vehicle into stays warm. After a
refresh raises (a file that cannot be read, a plant the derive refuses), the session is spent:
start a new one.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pyoxigraph as ox

from engine.derive import Assembled, Parts, anchor, assemble_from, derive_parts
from engine.model import ObservedState
from engine.owner import plant_owner
from engine.pipeline import Pipeline
from engine.plan import PlanMemo, plan as make_plan
from engine.reasoning.reason import INFERRED, UnsupportedConstructError, input_graphs, reason
from engine.reasoning.rules_delta import NeedsFullRun, Rereasoner, touches_tbox
from kg.errors import InputError, NotAPlantError
from kg.file_delta import Delta, FileText, edited_bytes, graph_delta, turtle_delta
from kg.load import (
    PlantGraph,
    Source,
    _check_readable,
    _declared_prefixes,
    _uses_plantkg_terms,
    format_for,
    load_plant,
)
from kg.namespaces import GRAPH_REASONING_SCRATCH, PK
from kg.validate import load_default_shapes
from kg.sparql_deps import ALL, analyse, store_lookup
from kg.validate_delta import Revalidator

SCRATCH = ox.NamedNode(GRAPH_REASONING_SCRATCH)


class Clock:
    """Wall and CPU seconds per stage (summed when a stage runs in several pieces)."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[name] = self.wall.get(name, 0.0) + time.perf_counter() - wall
            self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - cpu


#: An edit that changes more than 1/LARGE_EDIT of the plant's triples, and more than FEW_TRIPLES,
#: is done in full: following it focus node by focus node costs more than loading afresh. Measured
#: on the fleet example: a vehicle of 240 triples joining a 2,600-triple plant took 0.66 s followed,
#: 0.12 s from scratch, a one-line rename 0.035 s followed; a port changed in a 17-triple plant
#: (2 triples) took 13-18 ms followed, 45-70 ms from scratch.
LARGE_EDIT = 50
FEW_TRIPLES = 16


@dataclass
class ReplanSession:
    """The plant files, the store and every stage's state, kept current edit by edit."""

    files: list[Path]
    plant: PlantGraph = field(init=False)
    result: Pipeline = field(init=False)
    #: what the last refresh did: seconds per stage and which steps ran in full
    last: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.files = [Path(f) for f in self.files]
        self._start()

    # -- the full path -----------------------------------------------------------------------------
    def _start(self) -> None:
        self.clock = clock = Clock()
        with clock.stage("load"):
            self.plant = load_plant(self.files)
            self.texts = {src.path: FileText.read(src.path) for src in self.plant.sources}
        with clock.stage("validate"):
            self.validator = Revalidator(self.plant, load_default_shapes(), input_graphs(self.plant))
            report = self.validator.full()
        self.rereasoner: Rereasoner | None = None
        self.parts: Parts | None = None
        self.assembled: Assembled | None = None
        self.derive_queries: list[str] = []
        self.pending: set[str] | None = set()  # brokers to derive again (None: all)
        self.plan_memo = PlanMemo()
        self.last: dict[str, object] = {"full": ["load", "validate", "reason"]}
        self.result = Pipeline(self.plant, report, timings=clock.wall)
        self._finish(self.result, reasoned=False)
        self.last.update(timings=clock.wall, cpu=clock.cpu)

    def _reason_fully(self, result: Pipeline) -> None:
        with self.clock.stage("reason"):
            self._reason_fully_now(result)

    def _reason_fully_now(self, result: Pipeline) -> None:
        self.rereasoner = None
        try:
            result.inferences = reason(self.plant, engine="fast", scratch=SCRATCH)
        except UnsupportedConstructError:  # as the pipeline's "auto": HermiT, and no incremental step
            result.inferences = reason(self.plant)
        else:
            try:
                self.rereasoner = Rereasoner(self.plant, SCRATCH)
            except (NeedsFullRun, UnsupportedConstructError):
                self.rereasoner = None

    def _finish(self, result: Pipeline, *, reasoned: bool) -> None:
        """Reason (fully unless ``reasoned``) and derive, for a valid plant."""
        if not result.report.conforms:
            return
        if not reasoned:
            self._reason_fully(result)
            self.pending = None
        with self.clock.stage("derive"):
            result.desired = self._derive().with_owner(plant_owner(self.plant))

    def _derive(self) -> Assembled:
        """The desired state: the parts of the brokers an edit can reach derived again, the
        others kept; in full at the start, when that cannot be narrowed down, or when parts
        derived apart do not fit together (the full derive then gives its answer or its error)."""
        only, self.pending = self.pending, set()
        if only is not None and self.parts is not None and self.assembled is not None:
            try:
                changed = frozenset(only)
                kept = self.parts.without(changed)
                parts = kept.merged(derive_parts(self.plant, changed, known=kept)) if only else self.parts
                assembled = assemble_from(parts, self.assembled, changed)
                self.parts, self.assembled = parts, assembled
                return assembled
            except Exception:  # noqa: BLE001 - any refusal: the full derive says it exactly
                pass
        self.parts = self.assembled = None
        self.derive_queries = []
        parts = derive_parts(self.plant, queries=self.derive_queries)
        self.last.setdefault("full", []).append("derive")
        assembled = assemble_from(parts)
        self.parts, self.assembled = parts, assembled
        return assembled

    def _derive_reach(self, facts: list[tuple]) -> None:
        """Add the brokers whose derive rows ``facts`` can change (on the store as it is now) to
        those to derive again."""
        if self.pending is None or not facts:
            return
        if not self.derive_queries:
            self.pending = None
            return
        lookup = store_lookup(self.plant.store, [*input_graphs(self.plant), INFERRED])
        for query in self.derive_queries:
            deps = analyse(query)
            relevant = [f for f in facts if deps.reads(f)]
            if not relevant:
                continue
            found = deps.affected(anchor(query), relevant, lookup)
            if found is ALL or any(not isinstance(x, ox.NamedNode) for x in found):
                self.pending = None
                return
            self.pending |= {x.value for x in found}

    # -- an edit -----------------------------------------------------------------------------------
    def refresh(self, observed: ObservedState | None = None,
                files: Sequence[Path | str] | None = None) -> Pipeline:
        """Read the files again and bring every stage up to date; plan against ``observed``.
        ``files``: the plant's files now, when they may differ from the session's (added ones are
        read whole, removed ones taken out whole)."""
        self.clock = clock = Clock()
        total = clock.stage("total")
        total.__enter__()
        read = clock.stage("read")
        read.__enter__()
        budget = max(FEW_TRIPLES, self.plant.triple_count / LARGE_EDIT)  # triples an edit may change and be followed
        per_triple = max(sum(len(self.texts[s.path].data) for s in self.plant.sources), 1) / max(self.plant.triple_count, 1)
        deltas: list[tuple[Source, Delta, FileText | None]] = []
        sources = None
        if files is not None:
            if self._files_bytes(files) / per_triple > budget:  # whole files in or out: known by their size
                return self._restart(files, [], None, observed, total)
            sources, deltas = self._file_set(files)
        for src in self.plant.sources:
            if any(d[0] is src for d in deltas):
                continue
            data = src.path.read_bytes()
            old = self.texts[src.path]
            if data == old.data:
                continue
            cut = turtle_delta(src.path, old, data)
            if cut is None:  # the whole file is parsed and compared, unless its edited span is too large
                if edited_bytes(old.data, data) / per_triple > budget:
                    return self._restart([s.path for s in sources or self.plant.sources], [], None, observed, total)
                delta, text = graph_delta(self.plant.store, ox.NamedNode(src.graph), src.path), FileText.read(src.path, data)
            else:
                delta, text = cut
            deltas.append((src, delta, text))
        read.__exit__(None, None, None)
        full: list[str] = []
        cuts = [d.how for _, d, _ in deltas]
        changed = sum(len(d.removed) + len(d.added) for _, d, _ in deltas)
        if deltas and changed > budget:  # following it costs more than loading afresh
            return self._restart([s.path for s in sources or self.plant.sources], cuts, changed, observed, total)
        self.last = {"timings": clock.wall, "cpu": clock.cpu, "full": full, "cut": cuts}
        if deltas:
            self._apply(deltas, full, sources)
        elif sources is not None:
            self.plant.sources = sources  # the same files, in another order
        self.files = [src.path for src in self.plant.sources]
        result = self.result
        if observed is not None and result.desired is not None:
            with clock.stage("plan"):
                result.plan = make_plan(result.desired, observed, memo=self.plan_memo)
        total.__exit__(None, None, None)
        self.last["validation"] = dict(self.validator.last)
        return result

    def _files_bytes(self, files: Sequence[Path | str]) -> int:
        """The bytes of the files ``files`` adds to the session's and of those it leaves out."""
        known = {src.path.resolve(): src for src in self.plant.sources}
        wanted = {Path(f).resolve() for f in files}
        size = 0
        for path in wanted - set(known):
            try:
                size += path.stat().st_size
            except OSError:
                pass  # reading it says exactly what is wrong with it
        return size + sum(len(self.texts[src.path].data) for p, src in known.items() if p not in wanted)

    def _restart(self, files: Sequence[Path | str], cuts: list[str], changed: int | None,
                 observed: ObservedState | None, total: Any) -> Pipeline:
        """Load ``files`` afresh and run every stage (an edit too large to follow)."""
        total.__exit__(None, None, None)
        self.files = [Path(f) for f in files]
        self._start()
        self.last.update(cut=cuts, large_edit=changed)
        result = self.result
        if observed is not None and result.desired is not None:
            with self.clock.stage("plan"):
                result.plan = make_plan(result.desired, observed, memo=self.plan_memo)
        self.last["validation"] = dict(self.validator.last)
        return result

    def _file_set(self, files: Sequence[Path | str]) -> tuple[tuple[Source, ...], list[tuple[Source, Delta, FileText | None]]]:
        """The sources of ``files`` in their order (new ones with no triples yet, counted when the
        edit is applied) and the deltas of the files added and removed: whole files, as loading
        reads them (the same checks, the same errors)."""
        have = {src.graph: src for src in self.plant.sources}
        sources: list[Source] = []
        deltas: list[tuple[Source, Delta, FileText | None]] = []
        seen: set[str] = set()
        for path in (Path(f) for f in files):
            _check_readable(path)
            graph = path.resolve().as_uri()
            if graph in seen:
                continue
            seen.add(graph)
            src = have.get(graph)
            if src is None:
                data = path.read_bytes()
                src = Source(path, format_for(path).name, graph, 0, _declared_prefixes(path))
                deltas.append((src, graph_delta(self.plant.store, ox.NamedNode(graph), path),
                               FileText.read(path, data)))
            sources.append(src)
        if not sources:
            raise InputError("(no files)", "no plant file given", hint="pass one or more .ttl files")
        for src in self.plant.sources:
            if src.graph not in seen:
                gone = ox.NamedNode(src.graph)
                triples = tuple(sorted(((q.subject, q.predicate, q.object) for q in
                                        self.plant.store.quads_for_pattern(None, None, None, gone)), key=str))
                deltas.append((src, Delta(triples, (), "file"), None))
        return tuple(sources), deltas

    def _apply(self, deltas: list[tuple[Source, Delta, FileText | None]], full: list[str],
               sources: tuple[Source, ...] | None = None) -> None:
        store, clock = self.plant.store, self.clock
        removed = [(s, p, o, ox.NamedNode(src.graph)) for src, d, _ in deltas for s, p, o in d.removed]
        added = [(s, p, o, ox.NamedNode(src.graph)) for src, d, _ in deltas for s, p, o in d.added]
        changes = [(s, p, o) for s, p, o, _ in removed + added]
        with clock.stage("validate"):
            before = self.validator.affected(changes)
        rr = self.rereasoner
        doomed = None
        with clock.stage("reason"):
            if rr is not None and not touches_tbox(changes):
                try:
                    doomed = rr.overdelete([(s, p, o) for s, p, o, _ in removed])
                except NeedsFullRun:
                    doomed = None
        with clock.stage("derive"):
            self._derive_reach([*changes, *(doomed or ())])
        with clock.stage("read"):
            counts = {src.graph: 0 for src, _, _ in deltas}
            for quad in (ox.Quad(*q) for q in removed):
                if quad in store:
                    store.remove(quad)
                    counts[quad.graph_name.value] -= 1
            for quad in (ox.Quad(*q) for q in added):
                if quad not in store:
                    store.add(quad)
                    counts[quad.graph_name.value] += 1
            self.texts.update({src.path: text for src, _, text in deltas if text is not None})
            for src, _, text in deltas:
                if text is None:
                    self.texts.pop(src.path, None)
            self._recount(deltas, counts, sources)
            self.validator.graphs = input_graphs(self.plant)
        with clock.stage("validate"):
            report = self.validator.update(before, self.validator.affected(changes))
        result = Pipeline(self.plant, report, timings=clock.wall)
        self.result = result
        reasoned = False
        with clock.stage("reason"):
            if doomed is not None and rr is not None:
                try:
                    changed = rr.insert(doomed, [(s, p, o) for s, p, o, _ in added])
                    rr.check(changed)
                    reasoned = True
                except NeedsFullRun:
                    pass
            if not reasoned:
                self.rereasoner = None  # stale: the next valid state reasons in full
                self.pending = None
        with clock.stage("derive"):
            if reasoned:
                self._derive_reach(changed)
        if report.conforms and not reasoned:
            full.append("reason")
        self._finish(result, reasoned=reasoned)

    def _recount(self, deltas: list[tuple[Source, Delta, FileText | None]], counts: dict[str, int],
                 now: tuple[Source, ...] | None = None) -> None:
        """The sources' triple counts after the edit (``counts``: the change of each graph's
        size; the sources of the new file set, if it changed); an emptied file or a plant left
        with no plantkg term is refused as loading refuses it."""
        sources = []
        for src in now if now is not None else self.plant.sources:
            if src.graph in counts:
                count = src.triples + counts[src.graph]
                if count == 0:
                    raise InputError(src.path, "holds no triples",
                                     hint="an empty plant deploys nothing; add resources and brokers")
                src = replace(src, triples=count)
            sources.append(src)
        self.plant.sources = tuple(sources)
        if not any(_uses_plantkg_terms(self.plant.store, ox.NamedNode(s.graph)) for s in sources):
            names = ", ".join(str(s.path) for s in sources)
            raise NotAPlantError(f"{names}: uses no term of the plantkg ontology ({PK})",
                                 hint="declare `@prefix pk: <https://w3id.org/plantkg/ontology#> .` and type "
                                 "individuals as pk:Resource, pk:Broker, pk:Topic, ...")

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
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import pyoxigraph as ox

from engine.derive import Assembled, Parts, anchor, assemble_from, derive_parts
from engine.model import ObservedState
from engine.owner import plant_owner
from engine.pipeline import Pipeline
from engine.plan import PlanMemo, plan as make_plan
from engine.reasoning.reason import INFERRED, UnsupportedConstructError, input_graphs, reason
from engine.reasoning.rules_delta import NeedsFullRun, Rereasoner, touches_tbox
from kg.errors import InputError, NotAPlantError
from kg.file_delta import Delta, FileText, graph_delta, turtle_delta
from kg.load import PlantGraph, Source, _uses_plantkg_terms, load_plant
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
    def refresh(self, observed: ObservedState | None = None) -> Pipeline:
        """Read the files again and bring every stage up to date; plan against ``observed``."""
        self.clock = clock = Clock()
        total = clock.stage("total")
        total.__enter__()
        read = clock.stage("read")
        read.__enter__()
        deltas: list[tuple[Source, Delta, FileText]] = []
        for src in self.plant.sources:
            data = src.path.read_bytes()
            old = self.texts[src.path]
            if data == old.data:
                continue
            cut = turtle_delta(src.path, old, data)
            if cut is None:
                delta, text = graph_delta(self.plant.store, ox.NamedNode(src.graph), src.path), FileText.read(src.path, data)
            else:
                delta, text = cut
            deltas.append((src, delta, text))
        read.__exit__(None, None, None)
        full: list[str] = []
        self.last = {"timings": clock.wall, "cpu": clock.cpu, "full": full, "cut": [d.how for _, d, _ in deltas]}
        if deltas:
            self._apply(deltas, full)
        result = self.result
        if observed is not None and result.desired is not None:
            with clock.stage("plan"):
                result.plan = make_plan(result.desired, observed, memo=self.plan_memo)
        total.__exit__(None, None, None)
        self.last["validation"] = dict(self.validator.last)
        return result

    def _apply(self, deltas: list[tuple[Source, Delta, FileText]], full: list[str]) -> None:
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
            self.texts.update({src.path: text for src, _, text in deltas})
            self._recount(deltas, counts)
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

    def _recount(self, deltas: list[tuple[Source, Delta, FileText]], counts: dict[str, int]) -> None:
        """The sources' triple counts after the edit (``counts``: the change of each graph's
        size); an emptied file or a plant left with no plantkg term is refused as loading
        refuses it."""
        sources = []
        for src in self.plant.sources:
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

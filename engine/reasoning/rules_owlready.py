"""The reference reasoner: HermiT through owlready2, in a child process with a deadline.

Why a child process: HermiT runs in a JVM that owlready2 starts and waits for without a timeout,
owlready2 keeps global state (its default world, Java settings) and leaves a temp file behind when
the JVM fails. The child (``python -m engine.reasoning.rules_owlready JOB``) gets its own session and temp
dir; on the deadline the whole session (Python and JVM) is killed and the temp dir removed.

What the child is given: one N-Triples file holding the ontology graph (ontology and rules) and the
plant graphs, with ``owl:imports`` and the files' ontology headers dropped (owlready2 would try to
fetch the imports from the web), every plant individual declared an ``owl:NamedIndividual`` and all
of them ``owl:AllDifferent``. The last statement is the unique-name assumption the plant's unique
``pk:id`` s mean and the fast engine makes; without it HermiT fires ``differentFrom(?a, ?c)`` in a
SWRL rule only where the plant happens to entail the two brokers differ (measured: two brokers
without data properties get no bridge).

What it returns: for each individual, the plantkg classes it belongs to (asserted or inferred,
``INDIRECT_is_a``), and the values of the derived object properties (``INDIRECT_<property>``:
asserted, through sub-properties, or inferred — owlready2 stores what HermiT's ``-Y`` reports,
which leaves out pairs that follow from an asserted sub-property).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import pyoxigraph as ox

from engine.reasoning.rules_errors import InconsistentPlantError, ReasonerFailedError, ReasonerTimeoutError
from kg.namespaces import OWL, PK, RDF

_DOC_IRI = "urn:plantkg:reasoning"
_TYPE = ox.NamedNode(str(RDF.type))
_ONTOLOGY = ox.NamedNode(str(OWL.Ontology))
_IMPORTS = ox.NamedNode(str(OWL.imports))


@dataclass(frozen=True)
class HermitFacts:
    """The atomic facts HermiT entails (types of plantkg classes, derived property values)."""

    types: frozenset[tuple[str, str]]
    properties: frozenset[tuple[str, str, str]]
    seconds: float          # wall time of the child, JVM included


def write_input(store: ox.Store, graphs: list[ox.NamedNode], individuals: list[str], path: Path) -> None:
    """The N-Triples document HermiT reasons over (see the module docstring)."""
    headers = {q.subject for g in graphs for q in store.quads_for_pattern(None, _TYPE, _ONTOLOGY, g)}

    def triples() -> Iterable[ox.Triple]:
        yield ox.Triple(ox.NamedNode(_DOC_IRI), _TYPE, _ONTOLOGY)
        for g in graphs:
            for q in store.quads_for_pattern(None, None, None, g):
                if q.predicate == _IMPORTS or q.subject in headers:
                    continue
                yield ox.Triple(q.subject, q.predicate, q.object)
        named = ox.NamedNode(str(OWL.NamedIndividual))
        nodes = [ox.NamedNode(i) for i in individuals]
        for node in nodes:
            yield ox.Triple(node, _TYPE, named)
        if len(nodes) > 1:
            first, rest, nil = (ox.NamedNode(str(RDF[x])) for x in ("first", "rest", "nil"))
            head = ox.BlankNode()
            yield ox.Triple(head, _TYPE, ox.NamedNode(str(OWL.AllDifferent)))
            cell = ox.BlankNode()
            yield ox.Triple(head, ox.NamedNode(str(OWL.distinctMembers)), cell)
            for i, node in enumerate(nodes):
                nxt = ox.BlankNode() if i + 1 < len(nodes) else nil
                yield ox.Triple(cell, first, node)
                yield ox.Triple(cell, rest, nxt)
                cell = nxt  # type: ignore[assignment]

    with path.open("wb") as fh:
        ox.serialize(triples(), fh, ox.RdfFormat.N_TRIPLES)


def infer(store: ox.Store, graphs: list[ox.NamedNode], individuals: list[str], properties: Iterable[str],
          *, java: str, timeout: float) -> HermitFacts:
    """Run HermiT on ``graphs`` in a child process; raise on inconsistency, failure or deadline."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="plantkg-hermit-") as tmp:
        folder = Path(tmp)
        write_input(store, graphs, individuals, folder / "input.nt")
        job = {"input": str(folder / "input.nt"), "individuals": individuals,
               "properties": sorted(properties), "java": java, "result": str(folder / "result.json")}
        (folder / "job.json").write_text(json.dumps(job))
        env = {**os.environ, "TMPDIR": tmp}
        remaining = max(0.1, timeout - (time.perf_counter() - start))
        proc = subprocess.Popen([sys.executable, "-m", "engine.reasoning.rules_owlready", str(folder / "job.json")],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
        try:
            output, _ = proc.communicate(timeout=remaining)
        except subprocess.TimeoutExpired:
            _kill_session(proc)
            raise ReasonerTimeoutError(timeout, len(individuals)) from None
        except BaseException:
            _kill_session(proc)
            raise
        result_file = folder / "result.json"
        if proc.returncode != 0 or not result_file.exists():
            tail = output.decode("utf-8", "replace")[-2000:]
            raise ReasonerFailedError(f"the owlready2/HermiT worker failed (exit {proc.returncode}): {tail}",
                                      hint="check Java (`java -version`) and owlready2; "
                                      "or use --engine fast")
        result = json.loads(result_file.read_text())
    if "inconsistent" in result:
        raise InconsistentPlantError(result["inconsistent"], classes=tuple(result.get("classes", ())),
                                     engine="owlready2")
    return HermitFacts(
        types=frozenset((x, c) for x, c in result["types"]),
        properties=frozenset((s, p, o) for s, p, o in result["properties"]),
        seconds=time.perf_counter() - start,
    )


def _kill_session(proc: subprocess.Popen[bytes]) -> None:
    """Kill the child and the JVM it started (same session, so same process group)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


# --- the child ------------------------------------------------------------------------------------

def _work(job: dict[str, object]) -> dict[str, object]:
    import owlready2  # noqa: PLC0415 - only the child pays for it

    owlready2.JAVA_EXE = str(job["java"])
    world = owlready2.World()
    with open(str(job["input"]), "rb") as fh:
        world.get_ontology(_DOC_IRI).load(fileobj=fh, format="ntriples")
    try:
        owlready2.sync_reasoner(world, infer_property_values=True, debug=0)
    except owlready2.OwlReadyInconsistentOntologyError:
        return {"inconsistent": "HermiT finds no model of the ontology, its rules and the plant together"}
    unsat = sorted(c.iri for c in world.inconsistent_classes() if c.iri.startswith(str(PK)))
    props = [(p, world[p]) for p in job["properties"]]  # type: ignore[union-attr]
    types: list[tuple[str, str]] = []
    values: list[tuple[str, str, str]] = []
    for iri in job["individuals"]:  # type: ignore[union-attr]
        ind = world[iri]
        if not isinstance(ind, owlready2.Thing):
            continue
        for cls in ind.INDIRECT_is_a:
            if isinstance(cls, owlready2.ThingClass) and cls.iri.startswith(str(PK)):
                types.append((iri, cls.iri))
        for p_iri, prop in props:
            if prop is None:
                continue
            # INDIRECT_: the values through sub-properties too. HermiT's -Y leaves out pairs that
            # follow from an asserted sub-property (a bridgesTo gives no requiresBridge line), and
            # owlready2 stores only the lines HermiT prints.
            for value in getattr(ind, "INDIRECT_" + prop.python_name):
                if isinstance(value, owlready2.Thing):
                    values.append((iri, p_iri, value.iri))
    return {"types": types, "properties": values, "unsatisfiable": unsat}


def main(argv: list[str]) -> int:
    job = json.loads(Path(argv[0]).read_text())
    result = _work(job)
    Path(job["result"]).write_text(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""A plant run on this machine from Python: agents, plan, apply, status, destroy as method calls.

``plantkg demo`` and the CLI drive a plant from a terminal; a notebook (notebooks/) drives it one
step at a time and looks at the results between steps. :class:`LocalPlant` is that session: it
starts one local agent per machine of the plant (:mod:`engine.agent.local`), then each method is
one stage of the pipeline run again on the plant files as they are now, so an edit of the Turtle
between two calls shows in the next plan.

Nothing outlives the session: :meth:`LocalPlant.close` deletes whatever brokers are still deployed
and stops the agents (which stop their brokers), and the same clean-up is registered to run when
the Python process ends (``weakref.finalize``), so a notebook whose cell failed leaves no broker
behind when its kernel stops. :func:`copy_on_free_ports` and :func:`set_port` edit plant files,
so a notebook can run a shipped plant where its ports (1883, ...) may be taken, and change it.
"""

from __future__ import annotations

import tempfile
import time
import weakref
from collections.abc import Iterable
from pathlib import Path

import rdflib

from engine import netutil
from engine.agent.local import LocalAgents, start_local_agents
from engine.agents_config import AgentDirectory
from engine.apply import ApplyResult, apply
from engine.cli.status import status_rows
from engine.errors import EngineError
from engine.model import Plan
from engine.pipeline import Pipeline, run_pipeline
from kg.namespaces import PK
from kg.render import validation_text
from kg.table import Table, from_records


class InvalidPlantError(EngineError):
    """The plant has SHACL violations: nothing is planned or changed."""


class LocalPlant:
    """Local agents for every machine of the plant in ``files``, and the plant's commands."""

    def __init__(self, files: Iterable[Path | str], agents: LocalAgents, work_dir: Path) -> None:
        self.files = [Path(f) for f in files]
        self.agents = agents
        self.work_dir = work_dir
        self._cleanup = weakref.finalize(self, _shutdown, agents)

    @classmethod
    def start(cls, files: Iterable[Path | str], work_dir: Path | str | None = None) -> LocalPlant:
        """Start an agent for each machine (broker ``ip``) the plant names, under ``work_dir``
        (a new temporary folder by default)."""
        files = [Path(f) for f in files]
        base = Path(work_dir) if work_dir else Path(tempfile.mkdtemp(prefix="plantkg-plant-"))
        hosts = sorted(_checked(run_pipeline(files, None, observe=False)).hosts)
        return cls(files, start_local_agents(hosts, base), base)

    @property
    def directory(self) -> AgentDirectory:
        return AgentDirectory.load(self.agents.agents_file)

    def pipeline(self, *, destroy: bool = False) -> Pipeline:
        """Load, validate, reason, derive, ask the agents, plan (the plant files as they are now)."""
        return _checked(run_pipeline(self.files, self.directory, destroy=destroy))

    def plan(self) -> Plan:
        """What ``apply`` would do now."""
        plan = self.pipeline().plan
        assert plan is not None
        return plan

    def apply(self) -> ApplyResult:
        """Plan and apply: the brokers then run as the plant describes."""
        return self._reconcile(destroy=False)

    def destroy(self) -> ApplyResult:
        """Stop and remove every broker of the plant (the agents keep running)."""
        return self._reconcile(destroy=True)

    def _reconcile(self, *, destroy: bool) -> ApplyResult:
        result = self.pipeline(destroy=destroy)
        assert result.plan is not None and result.desired is not None
        return apply(result.plan, result.desired, self.directory, destroy=destroy)

    def status(self) -> Table:
        """One row per broker as its agent reports it (the columns of ``plantkg status``)."""
        result = self.pipeline()
        assert result.desired is not None and result.observed is not None
        rows = status_rows(result.desired, result.observed, time.time())
        return from_records(rows, rows[0].keys() if rows else ("id", "status"))

    def processes(self) -> list[str]:
        """Command lines of running processes started for this plant (agents and brokers)."""
        return processes_under(self.work_dir)

    def close(self) -> None:
        """Delete what is still deployed and stop the agents; safe to call more than once."""
        self._cleanup()

    def __enter__(self) -> LocalPlant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _checked(result: Pipeline) -> Pipeline:
    if not result.valid:
        prefixes = result.plant.prefixes if result.plant else {}
        raise InvalidPlantError("the plant has violations; nothing was planned or changed:\n"
                                + validation_text(result.report, prefixes),
                                hint="fix the plant's Turtle as the report says, then run again")
    return result


def _shutdown(agents: LocalAgents) -> None:
    """Delete every broker still deployed, then stop the agents, whatever the first step did."""
    try:
        agents.delete_all()
    finally:  # the agents stop their brokers on exit (--stop-brokers-on-exit) in any case
        agents.stop()


def processes_under(folder: Path) -> list[str]:
    """Command lines (``pid: argv``) of live processes whose arguments name a path in ``folder``."""
    marker = str(Path(folder).resolve())
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            argv = (entry / "cmdline").read_bytes().split(b"\0")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:  # exited meanwhile
            continue
        args = [a.decode(errors="replace") for a in argv if a]
        if state not in ("Z", "X") and any(marker in a for a in args):
            found.append(f"{entry.name}: {' '.join(args)}")
    return found


# ------------------------------------------------------------------------------ plant files

def copy_on_free_ports(source: Path | str, dest: Path | str) -> dict[str, int]:
    """Write ``source`` to ``dest`` with each broker's ``pk:port`` moved to a port free now on
    the broker's ``pk:ip``. Returns {broker id: new port}."""
    graph = _parse(source)
    taken: set[int] = set()
    moved: dict[str, int] = {}
    for broker in sorted(set(graph.subjects(PK.port, None)), key=str):
        ip = graph.value(broker, PK.ip)
        if ip is None:
            continue
        port = netutil.free_port(str(ip))
        while port in taken:
            port = netutil.free_port(str(ip))
        taken.add(port)
        graph.set((broker, PK.port, rdflib.Literal(port)))
        moved[str(graph.value(broker, PK.id) or broker)] = port
    graph.serialize(destination=str(dest), format="turtle")
    return moved


def set_port(path: Path | str, broker_id: str, port: int) -> None:
    """Give the broker whose ``pk:id`` is ``broker_id`` the port ``port``, in the file itself."""
    graph = _parse(path)
    brokers = [b for b in graph.subjects(PK.id, rdflib.Literal(broker_id)) if (b, PK.port, None) in graph]
    if len(brokers) != 1:
        raise EngineError(f"{path} has {len(brokers)} brokers with pk:id {broker_id!r}, not one",
                          hint="pass the pk:id of one broker of the plant")
    graph.set((brokers[0], PK.port, rdflib.Literal(port)))
    graph.serialize(destination=str(path), format="turtle")


def _parse(path: Path | str) -> rdflib.Graph:
    graph = rdflib.Graph()
    graph.parse(str(path), format="turtle")
    return graph

"""Real agents for the apply tests: one ``plantkg agent`` subprocess per plant host.

Each agent listens on its host's address (127.0.0.2, 127.0.0.3, ...) at a free port, with a state
dir and token of its own; :func:`start_agents` writes the agents file that points the engine at
them. :meth:`AgentFleet.stop` deletes whatever brokers are left (a safety net: tests destroy on
their own), stops the agents and checks that no broker process survived.

Plants are copies of the shipped examples with their broker ports rewritten to free ones (the
examples use 1883 and 9092, which may be taken); addresses are kept, since agents bind brokers to
the broker's ip.
"""

from __future__ import annotations

import io
import re
import sys
from collections import defaultdict
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager, redirect_stderr
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from engine import netutil
from engine.agent.client import AgentClient
from engine.agent.local import LocalAgent, LocalAgents, start_local_agents
from engine.cli import main
from engine.errors import DispatchError

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "ontology" / "examples"


@dataclass
class AgentFleet:
    """The local agents of a test, remembering broker pids for the final check."""

    local: LocalAgents
    broker_pids: set[int] = field(default_factory=set)

    @property
    def agents(self) -> dict[str, LocalAgent]:
        return self.local.agents

    @property
    def agents_file(self) -> Path:
        return self.local.agents_file

    def client(self, host: str) -> AgentClient:
        return self.agents[host].client()

    def brokers(self) -> dict[str, object]:
        """Every broker the agents report, by id (remembering pids for the final check)."""
        found = {}
        for agent in self.agents.values():
            for broker in agent.client().list_brokers():
                found[broker.spec.id] = broker
                if broker.pid:
                    self.broker_pids.add(broker.pid)
        return found

    def stop(self, *, expect_empty: bool = True) -> None:
        """Delete what is left, stop the agents, check that no broker process survived and
        (``expect_empty``) that nothing was left deployed: a test that failed before its destroy
        leaves brokers, which is not a second failure to report over the first."""
        problems = []
        try:
            self.brokers()
            left = self.local.delete_all()
            if expect_empty:
                problems += [f"{b} was still deployed" for b in left]
        except DispatchError as exc:
            problems.append(f"cleaning up: {exc}")
        self.local.stop()
        alive = [pid for pid in self.broker_pids if _alive(pid)]
        assert not alive, f"broker processes survived: {alive}"
        assert not problems, problems


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


def secret_files(folder: Path, tokens: Mapping[str, str]) -> Path:
    """``folder`` with one 0600 file per principal holding its token (what a plant's
    ``pk:secretRef "file:..."`` names); the folder."""
    folder.mkdir(parents=True, exist_ok=True)
    for name, token in tokens.items():
        (folder / name).write_text(token + "\n", encoding="utf-8")
        (folder / name).chmod(0o600)
    return folder


def start_agents(hosts: list[str], tmp_path: Path, *, tls: bool = False) -> AgentFleet:
    """One agent per host on a free port of that host; the agents file lists them. ``tls``: the
    agents serve HTTPS (certificates of the test run's plant CA)."""
    return AgentFleet(start_local_agents(hosts, tmp_path, tls=tls))


@dataclass(frozen=True)
class Deployment:
    """A plant file written for a test's agents, and the host and free port of each of its names."""

    fleet: AgentFleet
    plant: Path
    hosts: dict[str, str]
    ports: dict[str, int]

    def address(self, name: str) -> str:
        """``host:port`` of ``name`` (a broker's bootstrap address)."""
        return f"{self.hosts[name]}:{self.ports[name]}"

    def cli(self, command: str, *args: str) -> int:
        """``plantkg COMMAND PLANT --agents AGENTS ARGS...`` in this process; its exit code."""
        return main([command, str(self.plant), "--agents", str(self.fleet.agents_file), *args])

    def cli_ok(self, command: str, *args: str) -> None:
        """:meth:`cli`, which must exit 0; else the assertion carries what it wrote to stderr
        (a report's captured output may be cut, its assertion line is not)."""
        err = io.StringIO()
        with redirect_stderr(err):
            code = self.cli(command, *args)
        sys.stderr.write(err.getvalue())
        assert code == 0, f"plantkg {command} exited {code}: {err.getvalue()[-3000:]}"


@contextmanager
def deployment(tmp_path: Path, ports: Mapping[str, str], render: Callable[[dict[str, int]], str], *,
               apply: bool = True, tls: bool = False,
               agent_env: Mapping[str, str] | None = None) -> Iterator[Deployment]:
    """Agents for the hosts of ``ports`` ({name: host}), a distinct free port per name on its
    host, ``render(ports)`` written as the plant and (``apply``) applied; on leaving, the plant is
    destroyed (both must exit 0) and the agents stopped, which checks that no broker is left.

    ``tls``: the agents serve HTTPS. ``agent_env``: variables the agents inherit (a plant's
    ``env:`` secret references), set only while they start.
    """
    with pytest.MonkeyPatch.context() as env:
        for name, value in (agent_env or {}).items():
            env.setenv(name, value)
        fleet = start_agents(sorted(set(ports.values())), tmp_path, tls=tls)
    try:
        by_host: dict[str, list[str]] = defaultdict(list)
        for name, host in ports.items():
            by_host[host].append(name)
        picked = {name: port for host, names in by_host.items()
                  for name, port in zip(names, netutil.free_ports(len(names), host))}
        plant = tmp_path / "plant.ttl"
        plant.write_text(render(picked), encoding="utf-8")
        made = Deployment(fleet, plant, dict(ports), picked)
        if apply:
            made.cli_ok("apply", "--yes")
        yield made
        made.cli_ok("destroy", "--yes")
    except BaseException:
        fleet.stop(expect_empty=False)
        raise
    else:
        fleet.stop()


def plant_copy(example: str, tmp_path: Path, ports: dict[int, list[tuple[str, int]]] | None = None,
               name: str = "plant.ttl") -> tuple[Path, dict[str, int]]:
    """Copy ``example`` with every ``pk:port N`` (and a Kafka node's ``pk:controllerPort``)
    rewritten to a free port of that broker's ip.

    Returns the path and {broker local name: new port} (a node's controller port under
    ``"<name>:controller"``)."""
    text = (EXAMPLES / example).read_text(encoding="utf-8")
    new_ports: dict[str, int] = {}

    taken: set[int] = set()

    def free(host: str) -> int:
        port = netutil.free_port(host)
        while port in taken:
            port = netutil.free_port(host)
        taken.add(port)
        return port

    def block(match: re.Match[str]) -> str:
        body = match.group(0)
        ip = re.search(r'pk:ip "([^"]+)"', body)
        if ip is None:  # a Kafka cluster: its nodes have the addresses
            assert "pk:port" not in body, body
            return body
        new_ports[match.group(1)] = port = free(ip.group(1))
        body = re.sub(r"pk:port \d+", f"pk:port {port}", body)
        if "pk:controllerPort" in body:  # a combined Kafka node's quorum listener
            new_ports[match.group(1) + ":controller"] = cport = free(ip.group(1))
            body = re.sub(r"pk:controllerPort \d+", f"pk:controllerPort {cport}", body)
        return body

    text = re.sub(r"(?ms)^\w+:([\w-]+)\n    a owl:NamedIndividual , pk:Broker ;.*?\.\n", block, text)
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path, new_ports


def set_port(path: Path, broker: str, port: int) -> None:
    """Rewrite one broker's pk:port in a plant copy."""
    text = path.read_text(encoding="utf-8")
    pattern = rf"(?ms)(^\w+:{re.escape(broker)}\n    a owl:NamedIndividual , pk:Broker ;.*?)pk:port \d+"
    new, count = re.subn(pattern, rf"\g<1>pk:port {port}", text)
    assert count == 1
    path.write_text(new, encoding="utf-8")

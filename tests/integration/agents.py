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

import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from engine import netutil
from engine.agent.client import AgentClient
from engine.agent.local import LocalAgent, LocalAgents, start_local_agents
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

    def stop(self) -> None:
        problems = []
        try:
            self.brokers()
            left = self.local.delete_all()
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


def start_agents(hosts: list[str], tmp_path: Path, *, tls: bool = False) -> AgentFleet:
    """One agent per host on a free port of that host; the agents file lists them. ``tls``: the
    agents serve HTTPS (certificates of the test run's plant CA)."""
    return AgentFleet(start_local_agents(hosts, tmp_path, tls=tls))


@contextmanager
def deployed_plant(hosts: list[str], tmp_path: Path, plant_text: Callable[[], str]) -> Iterator[tuple[AgentFleet, Path]]:
    """Agents on ``hosts`` and the plant file ``tmp_path/plant.ttl`` written from ``plant_text()``
    (called once the agents listen, so the ports it picks free are not theirs), for a module's
    shared deployment: at the end ``destroy`` leaves no broker, and the agents stop."""
    from engine.cli import main  # noqa: PLC0415 - the CLI only for the tests that deploy a plant

    fleet = start_agents(hosts, tmp_path)
    try:
        plant = tmp_path / "plant.ttl"
        plant.write_text(plant_text(), encoding="utf-8")
        yield fleet, plant
        assert main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
        assert fleet.brokers() == {}
    finally:
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

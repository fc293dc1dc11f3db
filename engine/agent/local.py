"""Agents on this machine: one ``plantkg agent`` process per plant host, for demos and tests.

A plant of several machines is played on one machine by giving each broker a loopback address of
its own (127.0.0.2, 127.0.0.3, ...; all of 127.0.0.0/8 is loopback on Linux). :func:`start_local_agents`
starts an agent bound to each such address, on a port free at run time, with its own state dir and
token, waits until each answers, and writes the agents file that points the engine at them.
:meth:`LocalAgents.stop` deletes what is still deployed on them and stops them; the agents were
started with ``--stop-brokers-on-exit``, so no broker outlives them.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

from engine import netutil, process
from engine.agent.client import AgentClient
from engine.errors import DispatchError
from engine.security import ca, principal_key

AGENT_READY_S = 30.0


@dataclass
class LocalAgent:
    """One agent process serving ``host``."""

    host: str
    url: str
    state_dir: Path
    child: process.Child

    @property
    def token(self) -> str:
        return (self.state_dir / "token").read_text(encoding="utf-8").strip()

    def client(self, timeout: float = 30.0) -> AgentClient:
        return AgentClient(self.url, self.token, timeout=timeout)


@dataclass
class LocalAgents:
    """The agents started for a plant and the agents file that lists them."""

    agents: dict[str, LocalAgent]
    agents_file: Path

    def delete_all(self) -> list[str]:
        """Delete every broker still deployed on the agents; returns their ids."""
        deleted = []
        for agent in self.agents.values():
            if not agent.child.running():
                continue
            client = agent.client()
            for broker in client.list_brokers():
                client.delete_broker(broker.spec.id)
                deleted.append(broker.spec.id)
        return deleted

    def stop(self, grace: float = 30.0) -> None:
        """Stop every agent (and so, with ``--stop-brokers-on-exit``, their brokers)."""
        for agent in self.agents.values():
            process.stop(agent.child, grace=grace)


def plantkg_command() -> list[str]:
    """How to run this installation's ``plantkg`` (the same interpreter, so the same venv)."""
    return [sys.executable, "-m", "engine.cli"]


def start_local_agents(hosts: list[str], work_dir: Path, *, tls: bool = False) -> LocalAgents:
    """Start one agent per host under ``work_dir``; on failure, stop those already started.
    ``tls``: each serves its API over HTTPS with a certificate of the plant CA."""
    agents: dict[str, LocalAgent] = {}
    # one principal key for all of them and for this process's own clients (check, the demo's taps)
    key = principal_key.key_file().resolve()
    principal_key.load_or_create_key(key)
    ca_folder = ca.ca_dir().resolve()  # the CA too (created when a TLS broker first needs it)
    try:
        for host in hosts:
            port = netutil.free_port(host)
            state = work_dir / f"agent-{host}"
            child = process.spawn(
                [*plantkg_command(), "agent", "--listen", f"{host}:{port}", "--state-dir", state,
                 "--stop-brokers-on-exit", "--principal-key", key, "--ca-dir", ca_folder,
                 *(["--tls"] if tls else [])],
                log_dir=work_dir / "logs", name=f"agent-{host}",
            )
            agent = LocalAgent(host, f"{'https' if tls else 'http'}://{host}:{port}", state, child)
            agents[host] = agent
            process.wait_until(
                lambda a=agent: (a.state_dir / "token").is_file() and a.client().health(),
                AGENT_READY_S, 0.05, what=f"the agent on {host}:{port}", child=child,
                ignore=(DispatchError, OSError),
            )
    except BaseException:
        for agent in agents.values():
            process.stop(agent.child)
        raise
    lines = []
    for host, agent in agents.items():
        lines += [f'[agents."{host}"]', f'url = "{agent.url}"',
                  f'token_file = "{agent.state_dir / "token"}"', ""]
    agents_file = work_dir / "agents.toml"
    agents_file.write_text("\n".join(lines), encoding="utf-8")
    os.chmod(agents_file, 0o600)
    return LocalAgents(agents, agents_file)

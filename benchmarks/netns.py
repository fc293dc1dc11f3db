"""A remote machine emulated on this one: a network namespace joined to the host by a veth pair,
with ``tc netem`` delaying every packet a fixed time in each direction, and a plantkg agent
running inside it. The engine and the MQTT client stay outside, so every deploy order, answer,
publish and acknowledgement crosses the delayed link — the paper's "tool + cable" setup with a
known network.

Needs root, iproute2 (``ip``, ``tc``) and the kernel's ``sch_netem``; when any is missing,
:func:`delayed_link` raises :class:`LinkUnavailable` with the reason, so a study can say so and
skip only the rows that need it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from engine import netutil, process
from engine.agent.client import AgentClient
from engine.agent.local import AGENT_READY_S, plantkg_command
from engine.errors import DispatchError

SUBNET = "10.213.{}.{}"


class LinkUnavailable(RuntimeError):
    """The delayed link cannot be built here (the message says why)."""


@dataclass(frozen=True)
class Link:
    """A namespace reachable at ``remote_ip`` from the host (``local_ip``), ``delay_ms`` each way."""

    namespace: str
    local_ip: str
    remote_ip: str
    delay_ms: float

    def command(self, argv: list[str]) -> list[str]:
        """``argv`` run inside the namespace."""
        return ["ip", "netns", "exec", self.namespace, *argv]


def _run(argv: list[str]) -> None:
    done = subprocess.run(argv, capture_output=True, text=True, timeout=30)  # noqa: S603 - argv, no shell
    if done.returncode != 0:
        raise LinkUnavailable(f"`{' '.join(argv)}` failed: {(done.stderr or done.stdout).strip()}")


@contextmanager
def delayed_link(delay_ms: float) -> Iterator[Link]:
    """Build the namespace, the veth pair and (if ``delay_ms`` > 0) the netem delay; remove them after."""
    if os.geteuid() != 0:
        raise LinkUnavailable("network namespaces need root")
    if not (shutil.which("ip") and shutil.which("tc")):
        raise LinkUnavailable("iproute2 (ip, tc) is not installed")
    tag = os.getpid() % 250 + 1
    link = Link(f"plantkg-bench-{os.getpid()}", SUBNET.format(tag, 1), SUBNET.format(tag, 2), delay_ms)
    outer, inner = f"pkb{tag}a", f"pkb{tag}b"
    _run(["ip", "netns", "add", link.namespace])
    try:
        _run(["ip", "link", "add", outer, "type", "veth", "peer", "name", inner])
        _run(["ip", "link", "set", inner, "netns", link.namespace])
        _run(["ip", "addr", "add", f"{link.local_ip}/24", "dev", outer])
        _run(["ip", "link", "set", outer, "up"])
        for argv in (["ip", "addr", "add", f"{link.remote_ip}/24", "dev", inner], ["ip", "link", "set", inner, "up"],
                     ["ip", "link", "set", "lo", "up"]):
            _run(link.command(argv))
        if delay_ms > 0:
            _run(["tc", "qdisc", "add", "dev", outer, "root", "netem", "delay", f"{delay_ms}ms"])
            _run(link.command(["tc", "qdisc", "add", "dev", inner, "root", "netem", "delay", f"{delay_ms}ms"]))
        yield link
    finally:
        subprocess.run(["ip", "link", "del", outer], capture_output=True, timeout=30)  # noqa: S603
        subprocess.run(["ip", "netns", "del", link.namespace], capture_output=True, timeout=30)  # noqa: S603


@dataclass
class RemoteAgent:
    """An agent in the link's namespace and the agents file that points the engine at it."""

    child: process.Child
    agents_file: Path


@contextmanager
def remote_agent(link: Link, work_dir: Path) -> Iterator[RemoteAgent]:
    """Start ``plantkg agent`` inside the namespace, listening on the link's remote address."""
    port = netutil.free_port("127.0.0.1")  # the namespace is empty: any port is free there
    state = work_dir / "agent-remote"
    child = process.spawn(
        link.command([*plantkg_command(), "agent", "--listen", f"{link.remote_ip}:{port}", "--state-dir",
                      str(state), "--stop-brokers-on-exit", "--allow-remote"]),
        log_dir=work_dir / "logs", name="agent-remote")
    try:
        url = f"http://{link.remote_ip}:{port}"
        process.wait_until(
            lambda: (state / "token").is_file() and AgentClient(url, (state / "token").read_text().strip()).health(),
            AGENT_READY_S, 0.05, what=f"the agent in {link.namespace}", child=child, ignore=(DispatchError, OSError))
        agents_file = work_dir / "agents-remote.toml"
        agents_file.write_text(f'[agents."{link.remote_ip}"]\nurl = "{url}"\ntoken_file = "{state / "token"}"\n')
        os.chmod(agents_file, 0o600)
        yield RemoteAgent(child, agents_file)
    finally:
        process.stop(child)

"""Shared fixtures. Integration tests must leave no child process of ours behind: an autouse
fixture compares this process's children before and after each integration test."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def child_pids() -> set[int]:
    """Pids whose parent is this test process (zombies included: an unreaped child is a leak)."""
    me = os.getpid()
    found: set[int] = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:  # exited meanwhile
            continue
        # "pid (comm) state ppid ...": comm may hold spaces or parentheses, split after the last ")".
        fields = stat.rsplit(")", 1)[1].split()
        if int(fields[1]) == me:
            found.add(int(entry.name))
    return found


def describe(pid: int) -> str:
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        cmd = "?"
    return f"{pid}: {cmd.strip()[:200]}"


@pytest.fixture(autouse=True)
def no_leftover_children(request: pytest.FixtureRequest):
    """Fail an integration test that leaves a child process running (session fixtures such as
    the shared Kafka broker start before this snapshot, so they do not count)."""
    if request.node.get_closest_marker("integration") is None:
        yield
        return
    before = child_pids()
    yield
    left = child_pids() - before
    assert not left, "test left child processes behind:\n" + "\n".join(map(describe, left))


def pytest_configure(config: pytest.Config) -> None:
    """Keep the desired-state cache, the principal key and the plant CA of every test run (and of
    the commands it spawns) in folders of their own, never in the user's ~/.cache or ~/.local;
    give the example plants' resources their throwaway passwords."""
    import tempfile

    os.environ["PLANTKG_CACHE_DIR"] = tempfile.mkdtemp(prefix="plantkg-test-cache-")
    # plantkg's principal key (engine.security.principal_key): one per test run, never the user's
    key_dir = tempfile.mkdtemp(prefix="plantkg-test-key-")
    os.environ["PLANTKG_PRINCIPAL_KEY"] = os.path.join(key_dir, "principal-key")
    os.environ["PLANTKG_CA_DIR"] = os.path.join(key_dir, "ca")  # the plant CA, likewise
    # The suite starts ~100 Kafka JVMs, most for under a minute, four workers on two cores: the C1
    # compiler alone starts them with ~40% less CPU (engine.drivers.kafka.runtime.JVM_OPTS_ENV);
    # C2 pays off only for a broker that runs long. Agents inherit it.
    os.environ.setdefault("PLANTKG_KAFKA_JVM_OPTS", "-XX:TieredStopAtLevel=1 -XX:+UseSerialGC")
    # The example plants' resources log in with passwords their pk:secretRef "env:NAME" names
    # (closed brokers): give each a throwaway one, as `plantkg demo` does; agents inherit them.
    import re
    import secrets
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    for plant in [*root.glob("ontology/examples/*.ttl"), *root.glob("notebooks/plants/*.ttl")]:
        for name in re.findall(r'pk:secretRef\s+"env:([A-Za-z_][A-Za-z0-9_]*)"', plant.read_text(encoding="utf-8")):
            os.environ.setdefault(name, secrets.token_urlsafe(16))

"""Run one RabbitMQ node in the foreground: ``python -m plantkg_rabbitmq.launch BROKER_DIR``.

Why a launcher and not ``rabbitmq-server`` itself: an Erlang node registers with a port mapper
(epmd), and if none answers it starts one with ``epmd -daemon``, which leaves its session and so
outlives the agent's stop (and a port mapper shared by nodes of different folders would tie them
together). Here the node gets a port mapper of its own, on its own port, in the foreground and in
this process group; then ``rabbitmq-server`` runs with the environment of ``launch.json``
(:mod:`plantkg_rabbitmq.config`). SIGTERM/SIGINT stop the server (RabbitMQ shuts down cleanly on
SIGTERM), then the port mapper; the exit code is the server's. The agent's stop signals the whole
group anyway, and its SIGKILL after the grace leaves nothing behind: the node's helpers
(erl_child_setup, inet_gethost) exit when the node does.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from types import FrameType

from plantkg_rabbitmq.config import LAUNCH_FILE, LOOPBACK, epmd_binary, server_binary

EPMD_DEADLINE = 10.0


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m plantkg_rabbitmq.launch BROKER_DIR", file=sys.stderr)
        return 2
    broker_dir = Path(argv[0])
    launch = json.loads((broker_dir / LAUNCH_FILE).read_text(encoding="utf-8"))
    epmd_port = int(launch["epmd_port"])
    env = {**os.environ, **{str(k): str(v) for k, v in launch["env"].items()}}
    epmd = subprocess.Popen(  # noqa: S603 - argv list, no shell
        [str(epmd_binary()), "-port", str(epmd_port), "-address", LOOPBACK], env=env,
        stdin=subprocess.DEVNULL)
    server: subprocess.Popen[bytes] | None = None
    stopping = False

    def on_signal(signum: int, _frame: FrameType | None) -> None:
        nonlocal stopping
        stopping = True
        if server is not None and server.poll() is None:
            server.send_signal(signal.SIGTERM)

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        if not _wait_port(LOOPBACK, epmd_port, EPMD_DEADLINE, epmd):
            print(f"epmd did not listen on {LOOPBACK}:{epmd_port} within {EPMD_DEADLINE} s",
                  file=sys.stderr)
            return 1
        if stopping:
            return 0
        server = subprocess.Popen([str(server_binary())], env=env, cwd=broker_dir,  # noqa: S603
                                  stdin=subprocess.DEVNULL)
        while True:
            try:
                return server.wait()
            except InterruptedError:  # pragma: no cover - PEP 475 retries, kept for clarity
                continue
    finally:
        if server is not None and server.poll() is None:
            server.terminate()
            server.wait()
        epmd.terminate()
        epmd.wait()


def _wait_port(host: str, port: int, deadline: float, child: subprocess.Popen[bytes]) -> bool:
    end = time.monotonic() + deadline
    while time.monotonic() < end:
        if child.poll() is not None:
            return False
        try:
            with socket.create_connection((host, port), timeout=0.2):
                return True
        except OSError:
            time.sleep(0.05)
    return False


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

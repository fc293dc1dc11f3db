"""Render one RabbitMQ node's files from validated values, and find the node's ports and binaries.

A node is a broker folder (``<state dir>/brokers/<id>/``, owned by the agent) holding everything
the node reads or writes, so several nodes run side by side and nothing of the system-wide
installation is used (the Debian package's ``/etc/rabbitmq`` and ``/var/lib/rabbitmq`` are
shadowed by the environment below):

- ``rabbitmq.conf``: the AMQP listener on the broker's address and port (``pk:port``), the MQTT
  listener on the same address and ``pk:mqttPort``, ``guest`` only from loopback (RabbitMQ's
  default, written out): every port clients reach is one the plant declares;
- ``enabled_plugins``: ``[rabbitmq_mqtt].``;
- ``rabbitmq-env.conf``: empty, so ``/etc/rabbitmq/rabbitmq-env.conf`` is not read;
- ``launch.json``: the environment :mod:`plantkg_rabbitmq.launch` starts the node with —
  ``RABBITMQ_NODENAME``, ``RABBITMQ_CONFIG_FILE``, ``RABBITMQ_MNESIA_BASE``, ``RABBITMQ_LOG_BASE``,
  ``RABBITMQ_DIST_PORT``, ``ERL_EPMD_PORT`` (a port-mapper of its own), ``HOME`` (the Erlang cookie).

The distribution and port-mapper ports, internal to the node, are picked free on 127.0.0.1 once,
by :func:`ensure_ports`, and kept in ``ports.json``: rendering is then pure given the folder (as
Kafka's controller port).
"""

from __future__ import annotations

import hashlib
import ipaddress
import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path

from engine import netutil
from engine.errors import ConfigValueError, PartMissingError
from engine.values import check_host, check_path, check_port

CONF_FILE = "rabbitmq.conf"
PLUGINS_FILE = "enabled_plugins"
ENV_CONF_FILE = "rabbitmq-env.conf"
LAUNCH_FILE = "launch.json"
PORTS_FILE = "ports.json"
LOOPBACK = "127.0.0.1"

#: Where Debian puts the real server script (``/usr/sbin/rabbitmq-server`` is a wrapper that
#: switches to the ``rabbitmq`` user when run as root, which cannot write our folders).
SERVER_CANDIDATES = (Path("/usr/lib/rabbitmq/bin/rabbitmq-server"),
                     Path("/usr/lib/rabbitmq/sbin/rabbitmq-server"))


@dataclass(frozen=True)
class NodePorts:
    """The node's internal ports (on 127.0.0.1), besides AMQP and MQTT (the plant's)."""

    dist: int
    epmd: int

    def __post_init__(self) -> None:
        for field in ("dist", "epmd"):
            check_port(f"ports.{field}", getattr(self, field))


def check_node_host(host: object) -> str:
    """An IPv4 address (the listener lines below take no IPv6 literal yet)."""
    text = check_host("host", host)
    if ipaddress.ip_address(text).version != 4:
        raise ConfigValueError("host", host, "the rabbitmq driver takes an IPv4 address for now")
    return text


def ensure_ports(broker_dir: Path, host: str) -> NodePorts:
    """The node's ports, picked free once and kept in ``ports.json`` (idempotent)."""
    path = broker_dir / PORTS_FILE
    if path.is_file():
        return read_ports(broker_dir)
    dist, epmd = netutil.free_ports(2, LOOPBACK)
    ports = NodePorts(dist=dist, epmd=epmd)
    broker_dir.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(asdict(ports)), encoding="utf-8")
    os.replace(tmp, path)
    return ports


def read_ports(broker_dir: Path) -> NodePorts:
    """The ports :func:`ensure_ports` stored; ConfigValueError if missing or broken."""
    path = broker_dir / PORTS_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        return NodePorts(dist=data["dist"], epmd=data["epmd"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigValueError("ports", str(path), f"unreadable ({exc}); delete the broker folder "
                               "or let the agent prepare it again") from None


def node_name(broker_dir: Path) -> str:
    """An Erlang node name unique to the folder: ``plantkg-<8 hex>@localhost``."""
    digest = hashlib.sha256(str(broker_dir.resolve()).encode()).hexdigest()[:8]
    return f"plantkg-{digest}@localhost"


def render_files(host: str, port: int, mqtt_port: int, broker_dir: Path, ports: NodePorts) -> dict[str, str]:
    """File name -> text for one node; every value checked first."""
    host = check_node_host(host)
    check_port("port", port)
    check_port("mqtt_port", mqtt_port)
    folder = check_path("broker_dir", broker_dir, forbid="\t\"'\\ ")
    if port == mqtt_port:
        raise ConfigValueError("mqtt_port", mqtt_port, "is the broker's AMQP port too; give MQTT a port of its own")
    conf = "\n".join([
        "# Rendered by plantkg_rabbitmq; edits are overwritten.",
        f"listeners.tcp.default = {host}:{port}",
        f"mqtt.listeners.tcp.default = {host}:{mqtt_port}",
        "loopback_users.guest = true",
        "mqtt.allow_anonymous = true",
        "",
    ])
    env = {
        "RABBITMQ_NODENAME": node_name(folder),
        "RABBITMQ_CONFIG_FILE": str(folder / CONF_FILE),
        "RABBITMQ_ENABLED_PLUGINS_FILE": str(folder / PLUGINS_FILE),
        "RABBITMQ_CONF_ENV_FILE": str(folder / ENV_CONF_FILE),
        "RABBITMQ_MNESIA_BASE": str(folder / "data" / "mnesia"),
        "RABBITMQ_LOG_BASE": str(folder / "logs"),
        "RABBITMQ_LOGS": "-",
        "RABBITMQ_DIST_PORT": str(ports.dist),
        "RABBITMQ_SERVER_ADDITIONAL_ERL_ARGS": "-kernel inet_dist_use_interface {127,0,0,1}",
        "ERL_EPMD_PORT": str(ports.epmd),
        "ERL_EPMD_ADDRESS": LOOPBACK,
        "HOME": str(folder),
    }
    launch = {"epmd_port": ports.epmd, "env": env}
    return {
        CONF_FILE: conf,
        PLUGINS_FILE: "[rabbitmq_mqtt].\n",
        ENV_CONF_FILE: "# Empty on purpose: the system's /etc/rabbitmq/rabbitmq-env.conf is not read.\n",
        LAUNCH_FILE: json.dumps(launch, indent=2, sort_keys=True) + "\n",
    }


def server_binary() -> Path:
    """The real ``rabbitmq-server`` script (Debian: /usr/lib/rabbitmq/bin)."""
    for candidate in SERVER_CANDIDATES:
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    raise PartMissingError("rabbitmq-server", ", ".join(map(str, SERVER_CANDIDATES)))


def epmd_binary() -> Path:
    """Erlang's port mapper, run in the foreground by the launcher."""
    found = shutil.which("epmd")
    if found:
        return Path(found)
    for candidate in sorted(Path("/usr/lib/erlang").glob("erts-*/bin/epmd")):
        return candidate
    raise PartMissingError("epmd", "PATH, /usr/lib/erlang/erts-*/bin")

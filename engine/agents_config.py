"""Where the agents are and how to talk to them: the agents file (``agents.toml``).

A broker's agent is found at the broker's ``pk:ip``. The agents file maps such a host to the
agent's URL and token; a host not in the file gets ``http://<host>:7300`` and the token of the
environment variable ``PLANTKG_TOKEN``::

    [agents."127.0.0.2"]
    url = "http://127.0.0.2:7300"
    token_file = "/var/lib/plantkg/agent/token"   # or: token = "..."

The file is found at ``--agents FILE``, else ``$PLANTKG_AGENTS``, else
``~/.config/plantkg/agents.toml`` (that default may be missing; an explicit file may not).
A token file every user can read is accepted with a warning (``AgentDirectory.warnings``).
"""

from __future__ import annotations

import ipaddress
import os
import stat
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlsplit

from engine.errors import EngineError
from engine.values import host_in_url

if TYPE_CHECKING:  # the client lives above this module's layer of concerns; imported lazily
    from engine.agent.client import AgentClient

DEFAULT_PORT = 7300
ENV_FILE = "PLANTKG_AGENTS"
ENV_TOKEN = "PLANTKG_TOKEN"
DEFAULT_FILE = Path("~/.config/plantkg/agents.toml")
_KEYS = frozenset({"url", "token", "token_file"})

ClientFactory = Callable[[str, str], "AgentClient"]


class AgentsConfigError(EngineError):
    """The agents file is unusable, or no token is known for a host."""


@dataclass(frozen=True)
class AgentEntry:
    """One agent: its URL and where its token comes from (``token`` or ``token_file``)."""

    host: str
    url: str
    token: str | None = None
    token_file: Path | None = None


def _default_factory(url: str, token: str) -> AgentClient:
    from engine.agent.client import AgentClient  # noqa: PLC0415 - see TYPE_CHECKING above

    return AgentClient(url, token)


@dataclass
class AgentDirectory:
    """Maps a broker host to an :class:`AgentClient` (``client_for``)."""

    entries: Mapping[str, AgentEntry] = field(default_factory=dict)
    default_token: str | None = None
    default_port: int = DEFAULT_PORT
    source: Path | None = None
    warnings: list[str] = field(default_factory=list)
    client_factory: ClientFactory = _default_factory
    # One client per (url, token), built on first use: building one (a urllib opener with its
    # handlers) was a tenth of the CPU of an apply of 100 brokers. Clients hold no per-request
    # state, so threads share them.
    _clients: dict[tuple[str, str], AgentClient] = field(default_factory=dict, init=False,
                                                         repr=False, compare=False)

    @property
    def hosts(self) -> tuple[str, ...]:
        """Hosts the file names (sorted)."""
        return tuple(sorted(self.entries))

    def url_for(self, host: str) -> str:
        entry = self.entries.get(_norm_host(host))
        if entry is not None:
            return entry.url
        return f"http://{host_in_url(host)}:{self.default_port}"

    def token_for(self, host: str) -> str:
        """The bearer token for ``host``'s agent; raises :class:`AgentsConfigError` if none."""
        entry = self.entries.get(_norm_host(host))
        if entry is not None and entry.token is not None:
            return entry.token
        if entry is not None and entry.token_file is not None:
            return _read_token(entry.token_file, self.warnings)
        if self.default_token:
            return self.default_token
        where = f" in {self.source}" if self.source else ""
        raise AgentsConfigError(
            f"no token for the agent of {host}",
            hint=f"set {ENV_TOKEN}, or give [agents.\"{host}\"] a token or token_file{where}",
        )

    def client_for(self, host: str) -> AgentClient:
        """A client for the agent serving ``host`` (the same one for the same url and token)."""
        key = (self.url_for(host), self.token_for(host))
        client = self._clients.get(key)
        if client is None:
            client = self._clients.setdefault(key, self.client_factory(*key))
        return client

    @classmethod
    def load(cls, path: Path | str | None = None, *, env: Mapping[str, str] | None = None,
             client_factory: ClientFactory | None = None) -> AgentDirectory:
        """Read the agents file (see the module docstring for where it is looked for)."""
        env = os.environ if env is None else env
        explicit = path is not None or bool(env.get(ENV_FILE))
        chosen = Path(path if path is not None else env.get(ENV_FILE) or DEFAULT_FILE).expanduser()
        factory = client_factory or _default_factory
        token = env.get(ENV_TOKEN) or None
        if not chosen.exists():
            if explicit:
                raise AgentsConfigError(f"{chosen}: no such agents file",
                                        hint="check the path given with --agents or PLANTKG_AGENTS")
            return cls(default_token=token, client_factory=factory)
        entries, warnings = parse_agents(_read_toml(chosen), chosen)
        return cls(entries=entries, default_token=token, source=chosen,
                   warnings=warnings, client_factory=factory)


def parse_agents(data: Mapping[str, Any], source: Path) -> tuple[dict[str, AgentEntry], list[str]]:
    """Check the parsed TOML and build the entries; token files are resolved next to ``source``."""
    unknown = set(data) - {"agents"}
    if unknown:
        raise AgentsConfigError(f"{source}: unknown top-level key(s) {sorted(unknown)}",
                                hint='the file holds only [agents."<ip>"] tables')
    table = data.get("agents", {})
    if not isinstance(table, dict):
        raise AgentsConfigError(f"{source}: `agents` must be a table", hint='write [agents."<ip>"]')
    entries: dict[str, AgentEntry] = {}
    warnings: list[str] = []
    for host, item in table.items():
        entries[_norm_host(host, source)] = _entry(host, item, source, warnings)
    return entries, warnings


def _entry(host: str, item: Any, source: Path, warnings: list[str]) -> AgentEntry:
    where = f'{source}: [agents."{host}"]'
    if not isinstance(item, dict):
        raise AgentsConfigError(f"{where} must be a table", hint="give it url and token or token_file")
    unknown = set(item) - _KEYS
    if unknown:
        raise AgentsConfigError(f"{where}: unknown key(s) {sorted(unknown)}",
                                hint="allowed: url, token, token_file")
    url = item.get("url", f"http://{host_in_url(_norm_host(host, source))}:{DEFAULT_PORT}")
    parts = urlsplit(url) if isinstance(url, str) else None
    if parts is None or parts.scheme not in ("http", "https") or not parts.hostname:
        raise AgentsConfigError(f"{where}: url {url!r} is not an http(s) URL",
                                hint='e.g. url = "http://127.0.0.2:7300"')
    token, token_file = item.get("token"), item.get("token_file")
    if token is not None and token_file is not None:
        raise AgentsConfigError(f"{where}: both token and token_file given", hint="keep one of them")
    if token is not None and (not isinstance(token, str) or not token.strip()):
        raise AgentsConfigError(f"{where}: token must be a non-empty string")
    path = None
    if token_file is not None:
        if not isinstance(token_file, str) or not token_file:
            raise AgentsConfigError(f"{where}: token_file must be a path")
        path = Path(token_file).expanduser()
        path = path if path.is_absolute() else source.parent / path
        _check_token_file(path, warnings)
    return AgentEntry(host=host, url=url.rstrip("/"), token=token, token_file=path)


def _norm_host(host: str, source: Path | None = None) -> str:
    try:
        return str(ipaddress.ip_address(host))
    except ValueError:
        if source is None:
            return host
        raise AgentsConfigError(f'{source}: [agents."{host}"] is not an IP address',
                                hint="name agents by their brokers' pk:ip") from None


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise AgentsConfigError(f"{path}: not valid TOML: {exc}", hint="fix the TOML syntax") from None
    except OSError as exc:
        raise AgentsConfigError(f"{path}: cannot be read: {exc.strerror}") from None


def _check_token_file(path: Path, warnings: list[str]) -> None:
    try:
        mode = path.stat().st_mode
    except OSError as exc:
        raise AgentsConfigError(f"token file {path}: {exc.strerror}",
                                hint="create it (the agent writes one at first start) or fix the path") from None
    if mode & (stat.S_IROTH | stat.S_IWOTH):
        message = (f"token file {path} is readable or writable by every user (mode {stat.S_IMODE(mode):o}); "
                   f"run: chmod 600 {path}")
        if message not in warnings:
            warnings.append(message)


def _read_token(path: Path, warnings: list[str]) -> str:
    _check_token_file(path, warnings)
    try:
        token = path.read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise AgentsConfigError(f"token file {path} cannot be read: {exc}") from None
    if not token:
        raise AgentsConfigError(f"token file {path} is empty", hint="write the agent's token into it")
    return token

"""The HMI's view of the planner and the fleet manager: their loopback HTTP APIs.

Both are found again on every call (the planner's ``--planner-data-dir`` / the manager's
``--manager-data-dir`` hold ``*.json`` with the URL and a token file), so the HMI follows a
restart on a new port. Every call times out after ``timeout`` s: a hung planner makes the page say
so, it never holds a request thread for long. ``UpstreamDown`` when nobody answers,
``UpstreamRefused`` with the status and description when the API said no.

:class:`Recent` shares one answer among all the screens that poll within 0.25 s. Positions come
with the manager's vehicle rows: each carries the vehicle's last VDA 5050 state
with its ``agvPosition``.
"""

from __future__ import annotations

import json
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fleet.hmi.errors import UpstreamDown, UpstreamRefused
from fleet.manager.client import ManagerClient, ManagerRefusedError, ManagerUnreachableError

TIMEOUT = 2.0


def _call(who: str, url: str, token: str, method: str, path: str, body: Any, timeout: float) -> Any:
    data = None if body is None else json.dumps(body).encode("utf-8")
    request = urllib.request.Request(url.rstrip("/") + path, data=data, method=method,
                                     headers={"Authorization": f"Bearer {token}", "Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(request, timeout=timeout) as reply:
            return json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        try:
            detail = json.loads(exc.read()).get("description") or exc.reason
        except (ValueError, AttributeError):
            detail = exc.reason
        raise UpstreamRefused(who, exc.code, str(detail)) from None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        raise UpstreamDown(who, f"the {who} at {url} does not answer: {getattr(exc, 'reason', exc)}") from None


@dataclass(frozen=True)
class PlannerLink:
    """The planner's API: a fixed ``url`` and ``token_file``, or its ``data_dir`` (planner.json)."""

    url: str | None = None
    token_file: Path | None = None
    data_dir: Path | None = None
    timeout: float = TIMEOUT

    def _where(self) -> tuple[str, str]:
        try:
            if self.data_dir is not None:
                url = str(json.loads((self.data_dir / "planner.json").read_text(encoding="utf-8"))["url"])
                token_file = self.data_dir / "planner.token"
            else:
                url, token_file = str(self.url), self.token_file  # type: ignore[assignment]
            token = token_file.read_text(encoding="utf-8").strip()  # type: ignore[union-attr]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise UpstreamDown("planner", f"no task planner is running ({exc})") from None
        return url, token

    def call(self, method: str, path: str, body: Any = None) -> Any:
        url, token = self._where()
        return _call("planner", url, token, method, path, body, self.timeout)

    def snapshot(self) -> dict[str, Any]:
        answer = self.call("GET", "/v1/tasks")
        if not isinstance(answer, dict) or not isinstance(answer.get("tasks"), list):
            raise UpstreamDown("planner", "the planner's /v1/tasks answer has no task list")
        return answer

    def start_job(self, tasks: list[str]) -> dict[str, Any]:
        return self.call("POST", "/v1/jobs", {"tasks": tasks})

    def fire(self, event: str, value: Any) -> dict[str, Any]:
        return self.call("POST", "/v1/events", {"event": event, "value": value})

    def withdraw(self, task_id: str) -> dict[str, Any]:
        return self.call("POST", f"/v1/tasks/{task_id}/withdraw", {})


@dataclass(frozen=True)
class ManagerLink:
    """The fleet manager's API, found through its data directory (manager.json, manager.token)."""

    data_dir: Path
    timeout: float = TIMEOUT

    def vehicles(self) -> list[dict[str, Any]]:
        try:
            client = ManagerClient.for_data_dir(self.data_dir)
            rows = ManagerClient(client.url, client.token, self.timeout).vehicles()
        except ManagerUnreachableError as exc:
            raise UpstreamDown("fleet manager", exc.message) from None
        except ManagerRefusedError as exc:
            raise UpstreamRefused("fleet manager", exc.status, exc.description) from None
        return [r for r in rows if isinstance(r, dict)] if isinstance(rows, list) else []


class Recent:
    """The answer of ``fetch`` reused for ``ttl`` s, errors too: however many screens poll, the
    planner and the manager are asked at most once per ``ttl`` (a hung one holds the pollers for
    at most its timeout, one call at a time, never one call per screen)."""

    def __init__(self, fetch: Callable[[], Any], ttl: float = 0.25, clock: Callable[[], float] = time.monotonic) -> None:
        self.fetch, self.ttl, self.clock = fetch, ttl, clock
        self._lock = threading.Lock()
        self._at = float("-inf")
        self._value: Any = None
        self._error: Exception | None = None

    def get(self) -> Any:
        with self._lock:
            if self.clock() - self._at >= self.ttl:
                try:
                    self._value, self._error = self.fetch(), None
                except (UpstreamDown, UpstreamRefused) as exc:
                    self._value, self._error = None, exc
                self._at = self.clock()
            if self._error is not None:
                raise self._error
            return self._value

    def forget(self) -> None:
        with self._lock:
            self._at = float("-inf")

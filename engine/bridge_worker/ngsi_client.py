"""A small NGSI-v2 HTTP client for the bridge worker: one keep-alive connection, stdlib only.

Each thread that talks to the context broker owns one :class:`NgsiClient` (``http.client`` is not
thread-safe). Answers are sorted into what the caller does next:

- 2xx: done (:class:`Answer`);
- no connection, a timeout, a 5xx, 429, or 401/403 (a token the broker does not take: fixing it
  must not cost the messages waiting) -> :class:`NgsiUnavailable`: try again later;
- any other 4xx -> :class:`NgsiRefused` with Orion's ``error`` and ``description``: the content is
  refused and trying again will not help.

The write token is read from the token file given at construction (re-read after a 401/403, so a
rotated token is picked up) and sent as ``Authorization: Bearer``; it never appears in errors.
"""

from __future__ import annotations

import http.client
import json
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit

from engine.security import https

TIMEOUT = 10.0


class NgsiError(Exception):
    """A request that did not succeed; ``text`` says which and why."""

    def __init__(self, text: str, status: int | None = None) -> None:
        super().__init__(text)
        self.text = text
        self.status = status


class NgsiUnavailable(NgsiError):
    """Temporary: the context broker is away, failing or refusing the token. Retry."""


class NgsiRefused(NgsiError):
    """Permanent: the context broker refused the request's content (4xx)."""


@dataclass(frozen=True)
class Answer:
    status: int
    headers: dict[str, str]
    body: Any


def entity_path(entity_id: str, entity_type: str) -> str:
    return f"/v2/entities/{quote(entity_id, safe='')}?type={quote(entity_type, safe='')}"


class NgsiClient:
    """One connection to the context broker at ``base_url`` (``http://host:port``, or
    ``https://host:port`` verified against ``ca_file`` only: the plant CA's certificate)."""

    def __init__(self, base_url: str, token_file: Path | None = None, *, timeout: float = TIMEOUT,
                 ca_file: Path | None = None) -> None:
        parts = urlsplit(base_url)
        assert parts.hostname is not None and parts.port is not None
        self.base_url = base_url.rstrip("/")
        self.host, self.port = parts.hostname, parts.port
        self.tls, self.ca_file = parts.scheme == "https", ca_file
        self.timeout = timeout
        self.token_file = token_file
        self._token = self._read_token()
        self._conn: http.client.HTTPConnection | None = None

    def _read_token(self) -> str | None:
        if self.token_file is None:
            return None
        try:
            return self.token_file.read_text(encoding="utf-8").strip() or None
        except OSError:
            return None

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    # --- NGSI-v2 -----------------------------------------------------------------------------

    def version(self) -> Answer:
        return self.request("GET", "/version")

    def upsert(self, entity: dict[str, Any]) -> Answer:
        return self.request("POST", "/v2/entities?options=upsert", entity)

    def list_subscriptions(self) -> list[dict[str, Any]]:
        """Every subscription (paged by ``Fiware-Total-Count``)."""
        found: list[dict[str, Any]] = []
        while True:
            answer = self.request("GET", f"/v2/subscriptions?options=count&limit=1000&offset={len(found)}")
            page = answer.body if isinstance(answer.body, list) else []
            found.extend(s for s in page if isinstance(s, dict))
            total = answer.headers.get("fiware-total-count")
            if not page or total is None or not total.isdigit() or len(found) >= int(total):
                return found

    def create_subscription(self, body: dict[str, Any]) -> str | None:
        """POST a subscription; its id (from ``Location``), if the broker says."""
        answer = self.request("POST", "/v2/subscriptions", body)
        location = answer.headers.get("location", "")
        return location.rsplit("/", 1)[-1] or None

    def delete_subscription(self, sub_id: str) -> None:
        try:
            self.request("DELETE", f"/v2/subscriptions/{quote(sub_id, safe='')}")
        except NgsiRefused as exc:
            if exc.status != 404:  # already gone: what we wanted
                raise

    # --- HTTP --------------------------------------------------------------------------------

    def request(self, method: str, path: str, body: Any = None) -> Answer:
        what = f"{method} {self.base_url}{path.split('?')[0]}"
        data = json.dumps(body).encode("utf-8") if body is not None else None
        headers = {"Accept": "application/json"}
        if data is not None:
            headers["Content-Type"] = "application/json"
        if self._token is not None:
            headers["Authorization"] = f"Bearer {self._token}"
        for attempt in (1, 2):  # a kept-alive connection the server closed: one fresh try
            try:
                if self._conn is None:  # (a CA certificate that cannot be read: OSError, below)
                    self._conn = https.connection(self.host, self.port, timeout=self.timeout,
                                                  tls=self.tls, ca_file=self.ca_file)
                self._conn.request(method, path, body=data, headers=headers)
                response = self._conn.getresponse()
                raw = response.read()
            except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError) as exc:
                self.close()
                if attempt == 2:
                    raise NgsiUnavailable(f"{what}: connection lost ({exc})") from None
                continue
            except (OSError, http.client.HTTPException) as exc:
                self.close()
                problem = "no answer in time" if isinstance(exc, (socket.timeout, TimeoutError)) else str(exc)
                raise NgsiUnavailable(f"{what}: {problem}") from None
            if response.will_close:
                self.close()
            return self._answer(what, response, raw)
        raise AssertionError("unreachable")

    def _answer(self, what: str, response: http.client.HTTPResponse, raw: bytes) -> Answer:
        status = response.status
        headers = {k.lower(): v for k, v in response.getheaders()}
        try:
            body = json.loads(raw) if raw else None
        except ValueError:
            body = raw.decode("utf-8", "replace")[:300]
        if 200 <= status < 300:
            return Answer(status, headers, body)
        if isinstance(body, dict):
            reason = f"{body.get('error', '')}: {body.get('description', '')}".strip(": ")
        else:
            reason = str(body or "")[:300]
        text = f"{what} -> {status} {reason}".rstrip()
        if status in (401, 403):
            self._token = self._read_token()
            raise NgsiUnavailable(text + " (the context broker does not take the bridge's token)", status)
        if status >= 500 or status == 429:
            raise NgsiUnavailable(text, status)
        raise NgsiRefused(text, status)

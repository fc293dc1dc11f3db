"""HTTP notifications: one request per notification, as Orion sends them.

``POST`` (or ``httpCustom.method``) of the JSON body to ``url`` (plus ``httpCustom.qs``), with
``Content-Type: application/json``, ``Ngsiv2-AttrsFormat``, ``Fiware-Service`` (when the tenant
has one), ``Fiware-ServicePath``, ``Fiware-Correlator`` and the ``httpCustom.headers`` (which
cannot replace ``Ngsiv2-AttrsFormat`` or ``Fiware-Correlator``, as in Orion). A 2xx answer is a
success; see :mod:`.result` for what is retried. Timeout: ``timeout`` of the subscription in
milliseconds, else :data:`DEFAULT_TIMEOUT` (Orion's ``-httpTimeout`` default, 5 s).
"""

from __future__ import annotations

import http.client
import socket
import threading
from urllib.parse import SplitResult, urlencode, urlsplit, urlunsplit

from engine.context_broker.subscriptions.model import HttpTarget
from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.subscriptions.result import Result

DEFAULT_TIMEOUT = 5.0
PROTECTED = {"ngsiv2-attrsformat", "fiware-correlator"}
RETRIED_4XX = {408, 425, 429}


def request_url(target: HttpTarget) -> str:
    if not target.qs:
        return target.url
    parts = urlsplit(target.url)
    query = "&".join(p for p in (parts.query, urlencode(list(target.qs))) if p)
    return urlunsplit((parts.scheme, parts.netloc, parts.path, query, parts.fragment))


def request_headers(target: HttpTarget, msg: Outgoing) -> dict[str, str]:
    headers = {name: value for name, value in target.headers if name.lower() not in PROTECTED}
    headers["Content-Type"] = "application/json"
    headers["Ngsiv2-AttrsFormat"] = msg.attrs_format
    headers["Fiware-Correlator"] = msg.correlator
    if msg.service:
        headers.setdefault("Fiware-Service", msg.service)
    headers.setdefault("Fiware-ServicePath", msg.service_path)
    return headers


def classify(code: int) -> Result:
    if 200 <= code < 300:
        return Result.success(code)
    if code >= 500 or code in RETRIED_4XX:
        return Result.temporary(f"HTTP {code} from the receiver", code)
    return Result.permanent(f"HTTP {code} from the receiver (not retried: a {code} will not "
                            "change by sending again)", code)


class HttpSender:
    """Keeps one connection per receiver (scheme, host, port) and lane thread (HTTP/1.1
    keep-alive; a receiver that closes it gets a new one per request). A reused connection that
    the receiver closed meanwhile is retried once on a fresh one before it counts as a failure."""

    def __init__(self) -> None:
        self._local = threading.local()

    def _connection(self, parts: SplitResult, timeout: float) -> tuple[http.client.HTTPConnection, bool]:
        pool: dict[tuple[str, str, int], http.client.HTTPConnection] = self._local.__dict__.setdefault("pool", {})
        port = parts.port or (443 if parts.scheme == "https" else 80)
        key = (parts.scheme, parts.hostname or "", port)
        conn = pool.get(key)
        reused = conn is not None
        if conn is None:
            cls = http.client.HTTPSConnection if parts.scheme == "https" else http.client.HTTPConnection
            conn = pool[key] = cls(parts.hostname or "", port, timeout=timeout)
        conn.timeout = timeout
        if conn.sock is not None:
            conn.sock.settimeout(timeout)
        return conn, reused

    def _drop(self, parts: SplitResult) -> None:
        pool = self._local.__dict__.get("pool", {})
        port = parts.port or (443 if parts.scheme == "https" else 80)
        conn = pool.pop((parts.scheme, parts.hostname or "", port), None)
        if conn is not None:
            conn.close()

    def send(self, target: HttpTarget, msg: Outgoing) -> Result:
        timeout = target.timeout_ms / 1000 if target.timeout_ms else DEFAULT_TIMEOUT
        body = None if target.method in ("GET", "HEAD") else msg.body
        url = request_url(target)
        parts = urlsplit(url)
        path = urlunsplit(("", "", parts.path or "/", parts.query, ""))
        headers = request_headers(target, msg)
        for attempt in (1, 2):
            conn, reused = self._connection(parts, timeout)
            try:
                conn.request(target.method, path, body=body, headers=headers)
                resp = conn.getresponse()
                resp.read()
                return classify(resp.status)
            except (TimeoutError, socket.timeout):
                self._drop(parts)
                return Result.temporary(f"Timeout was reached ({timeout:g} s)")
            except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError) as err:
                self._drop(parts)
                if reused and attempt == 1:
                    continue  # the receiver closed an idle keep-alive connection: once more, fresh
                return Result.temporary(f"HTTP exchange failed: {type(err).__name__}: {err}")
            except ConnectionRefusedError as err:
                self._drop(parts)
                return Result.temporary(f"Couldn't connect to server: {err}")
            except (OSError, http.client.HTTPException) as err:
                self._drop(parts)
                return Result.temporary(f"Couldn't connect to server: {type(err).__name__}: {err}")
        return Result.temporary("HTTP exchange failed")  # not reached

    def close(self) -> None:
        return None  # connections belong to the lane threads and close with them

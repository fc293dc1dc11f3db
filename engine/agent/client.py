"""AgentClient: the engine's side of the agent API (docs/engine-contracts.md), stdlib only.

Failures become dispatch errors the caller can act on:

- connection refused/reset, timeout, 5xx (503 included) -> :class:`TemporaryDispatchError` (retry);
- 401 -> :class:`AgentAuthError`; any other 4xx -> :class:`PermanentDispatchError`;
- the agent's ``error`` and ``hint`` are the exception's message and hint; ``host`` is the URL's.

``put_broker`` and ``delete_broker`` wait for a broker to start or stop (a Kafka start takes
5-60 s, its stop up to 30 s), so they use ``broker_timeout`` (default 150 s) instead of
``timeout``. A timed-out PUT is safe to repeat: the agent keeps starting the broker and answers
the next PUT once it is healthy.

Connections are kept open between requests (HTTP/1.1 keep-alive; the agent keeps them too): a
new TCP connection per request was most of the cost of a call on loopback. Threads share the
client; each request takes an idle connection (or opens one) and gives it back once it has read
the whole answer. A kept connection the agent has closed meanwhile (it restarted, or dropped an
idle connection) fails before any answer; the request is then sent once more on a new
connection, which every call may be since every call is idempotent.
"""

from __future__ import annotations

import http.client
import json
import socket
import ssl
import threading
import urllib.parse
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from engine.agent.calls import DONE, SKIPPED, AgentCall, BatchAnswer, CallResult
from engine.agent.wire import (
    WireError,
    observed_bridge_from_json,
    observed_broker_from_json,
    observed_topic_from_json,
)
from engine.errors import AgentAuthError, PermanentDispatchError, TemporaryDispatchError
from engine.security import ca
from engine.model import (
    BridgeSpec,
    BrokerSpec,
    ObservedBridge,
    ObservedBroker,
    ObservedTopic,
    TopicSpec,
    to_dict,
)

DEFAULT_BROKER_TIMEOUT = 150.0
#: Idle connections kept per agent (more are closed once answered).
MAX_IDLE = 32
#: A batch request carries at most this many lanes, items and bytes of JSON (the agent takes
#: 512 lanes, 4096 items, 1 MiB); more is sent as several requests at once.
BATCH_LANES = 256
BATCH_ITEMS = 2048
BATCH_BYTES = 512 << 10
#: What a kept connection the agent closed meanwhile raises on the next request.
_STALE = (http.client.RemoteDisconnected, ConnectionResetError, BrokenPipeError,
          ConnectionAbortedError)


def tls_client_context(ca_file: Path | None = None) -> ssl.SSLContext:
    """Verifies the agent's certificate and address against the plant CA only (TLS 1.2+)."""
    context = ssl.create_default_context(cafile=str(ca_file or ca.ca_cert_file()))
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    return context


class AgentClient:
    """One agent at ``base_url`` (e.g. ``http://127.0.0.2:7300``) with its bearer token."""

    def __init__(self, base_url: str, token: str, *, timeout: float = 30.0,
                 broker_timeout: float = DEFAULT_BROKER_TIMEOUT, ca_file: Path | None = None) -> None:
        """``ca_file``: the CA certificate an https agent is verified against (default: the
        plant CA's ``ca.pem``, engine.security.ca)."""
        parsed = urllib.parse.urlsplit(base_url)
        if parsed.scheme not in ("http", "https") or not parsed.hostname:
            raise ValueError(f"agent URL {base_url!r} must be http(s)://host:port")
        self.base_url = base_url.rstrip("/")
        self.host = parsed.hostname
        self.timeout = timeout
        self.broker_timeout = max(broker_timeout, timeout)
        self._token = token
        # Agents are addressed directly (http.client knows no proxy: the token never goes
        # through one). An https agent is verified against the plant CA (engine.agent.tls),
        # never the system's store.
        self._scheme, self._port = parsed.scheme, parsed.port
        self._prefix = parsed.path.rstrip("/")
        self._ssl_context = tls_client_context(ca_file) if parsed.scheme == "https" else None
        self._idle: list[http.client.HTTPConnection] = []
        self._idle_lock = threading.Lock()

    def __repr__(self) -> str:  # no token in logs
        return f"AgentClient({self.base_url!r})"

    # --- the contract ----------------------------------------------------------------------

    def health(self) -> dict:
        return self._request("GET", "/v1/health")

    def list_brokers(self) -> list[ObservedBroker]:
        data = self._request("GET", "/v1/brokers")
        brokers = data.get("brokers") if isinstance(data, dict) else None
        if not isinstance(brokers, list):
            raise self._bad_answer("GET /v1/brokers", "no 'brokers' array")
        return [self._parse(observed_broker_from_json, b, "GET /v1/brokers") for b in brokers]

    def get_broker(self, broker_id: str) -> ObservedBroker | None:
        path = f"/v1/brokers/{_segment(broker_id)}"
        data = self._request("GET", path, missing_ok=True)
        return None if data is None else self._parse(observed_broker_from_json, data, path)

    # ``owner`` (every verb that changes something): the plant that owns the thing; the agent
    # records it and refuses (409, PermanentDispatchError) a thing another plant owns.

    def put_broker(self, spec: BrokerSpec, owner: str | None = None) -> ObservedBroker:
        path = f"/v1/brokers/{_segment(spec.id)}"
        data = self._request("PUT", path, _owned(to_dict(spec), owner), timeout=self.broker_timeout)
        return self._parse(observed_broker_from_json, data, path)

    def delete_broker(self, broker_id: str, owner: str | None = None) -> None:
        self._request("DELETE", f"/v1/brokers/{_segment(broker_id)}{_owner_query(owner)}",
                      timeout=self.broker_timeout)

    def broker_verb(self, broker_id: str, verb: str) -> ObservedBroker:
        """The operator's ``stop``, ``start`` or ``restart`` of a broker (its data and config are
        kept); waits like :meth:`put_broker`. An unknown broker is a PermanentDispatchError (404)."""
        if verb not in ("stop", "start", "restart"):
            raise ValueError(f"verb {verb!r} is not one of stop, start, restart")
        path = f"/v1/brokers/{_segment(broker_id)}/{verb}"
        data = self._request("POST", path, timeout=self.broker_timeout)
        return self._parse(observed_broker_from_json, data, path)

    def set_owner(self, broker_id: str, owner: str) -> ObservedBroker:
        """Import: ``owner`` takes over the broker and its topics and bridges nobody owns."""
        path = f"/v1/brokers/{_segment(broker_id)}/owner"
        return self._parse(observed_broker_from_json, self._request("PUT", path, {"owner": owner}),
                           path)

    def put_topic(self, spec: TopicSpec, owner: str | None = None) -> ObservedTopic:
        path = f"/v1/brokers/{_segment(spec.broker_id)}/topics/{_segment(spec.name)}"
        return self._parse(observed_topic_from_json,
                           self._request("PUT", path, _owned(to_dict(spec), owner)), path)

    def delete_topic(self, broker_id: str, name: str, owner: str | None = None) -> None:
        self._request("DELETE", f"/v1/brokers/{_segment(broker_id)}/topics/{_segment(name)}"
                                f"{_owner_query(owner)}")

    def list_bridges(self) -> list[ObservedBridge]:
        data = self._request("GET", "/v1/bridges")
        bridges = data.get("bridges") if isinstance(data, dict) else None
        if not isinstance(bridges, list):
            raise self._bad_answer("GET /v1/bridges", "no 'bridges' array")
        return [self._parse(observed_bridge_from_json, b, "GET /v1/bridges") for b in bridges]

    def put_bridge(self, spec: BridgeSpec, remote_token: str | None = None,
                   owner: str | None = None) -> ObservedBridge:
        """PUT the bridge; ``remote_token`` (mqtt-ngsi: the context broker's write token) travels
        as the body's transport field ``remote_token``, beside the spec, never inside it."""
        path = f"/v1/brokers/{_segment(spec.local.id)}/bridges/{_segment(spec.remote.id)}"
        body = _owned(to_dict(spec), owner)
        if remote_token is not None:
            body["remote_token"] = remote_token
        data = self._request("PUT", path, body, timeout=self.broker_timeout)
        return self._parse(observed_bridge_from_json, data, path)

    def delete_bridge(self, local_id: str, remote_id: str, owner: str | None = None) -> None:
        self._request("DELETE", f"/v1/brokers/{_segment(local_id)}/bridges/{_segment(remote_id)}"
                                f"{_owner_query(owner)}", timeout=self.broker_timeout)

    def state(self) -> tuple[list[ObservedBroker], list[ObservedBridge]]:
        """Every broker and every bridge of the agent, in one request (``GET /v1/state``)."""
        data = self._request("GET", "/v1/state")
        brokers, bridges = (data.get("brokers"), data.get("bridges")) if isinstance(data, dict) else (None, None)
        if not isinstance(brokers, list) or not isinstance(bridges, list):
            raise self._bad_answer("GET /v1/state", "no 'brokers' and 'bridges' arrays")
        return ([self._parse(observed_broker_from_json, b, "GET /v1/state") for b in brokers],
                [self._parse(observed_bridge_from_json, b, "GET /v1/state") for b in bridges])

    def batch(self, lanes: Sequence[Sequence[AgentCall]], *, observe: bool = False) -> BatchAnswer:
        """Make the calls of every lane (``POST /v1/batch``): lanes at the same time on the
        agent, a lane's calls in order, a result per call (a failed call's error is the one the
        single call would raise; the rest of its lane is skipped). ``observe``: the answer also
        holds the agent's brokers and bridges afterwards. Many lanes go as several requests at
        once; the agent's state is then not known for after all of them (``observed`` False).
        A failure of the request itself (unreachable, 401, 400) raises as a single call would."""
        chunks = _chunks([(len(lane), json.dumps([_item(c) for c in lane])) for lane in lanes])
        if not chunks:
            return BatchAnswer(())
        if len(chunks) == 1:
            return self._batch(chunks[0], list(lanes), observe)
        starts = [0]
        for chunk in chunks:
            starts.append(starts[-1] + len(chunk))
        with ThreadPoolExecutor(max_workers=min(len(chunks), 8), thread_name_prefix="batch") as pool:
            parts = list(pool.map(lambda i: self._batch(chunks[i], list(lanes[starts[i]:starts[i + 1]]),
                                                        False), range(len(chunks))))
        return BatchAnswer(tuple(r for part in parts for r in part.lanes))

    def _batch(self, encoded: list[str], lanes: list[Sequence[AgentCall]], observe: bool) -> BatchAnswer:
        body = '{"lanes": [' + ", ".join(encoded) + "]" + (', "observe": true' if observe else "") + "}"
        data = self._request("POST", "/v1/batch", raw=body.encode("utf-8"), timeout=self.broker_timeout)
        results = data.get("lanes") if isinstance(data, dict) else None
        if not isinstance(results, list) or len(results) != len(lanes) or any(
                not isinstance(r, list) or len(r) != len(lane) for r, lane in zip(results, lanes)):
            raise self._bad_answer("POST /v1/batch", "its lanes do not match the request's")
        answer = BatchAnswer(tuple(tuple(self._result(call, r) for call, r in zip(lane, got))
                                   for lane, got in zip(lanes, results)))
        if not observe:
            return answer
        brokers, bridges = data.get("brokers"), data.get("bridges")
        if not isinstance(brokers, list) or not isinstance(bridges, list):
            raise self._bad_answer("POST /v1/batch", "no 'brokers' and 'bridges' arrays")
        return BatchAnswer(answer.lanes,
                           tuple(self._parse(observed_broker_from_json, b, "POST /v1/batch") for b in brokers),
                           tuple(self._parse(observed_bridge_from_json, b, "POST /v1/batch") for b in bridges))

    def _result(self, call: AgentCall, got: Any) -> CallResult:
        outcome = got.get("outcome") if isinstance(got, dict) else None
        if outcome == "done":
            return DONE
        if outcome == "skipped":
            return SKIPPED
        error, status = (got.get("error"), got.get("status")) if isinstance(got, dict) else (None, None)
        if outcome != "failed" or not isinstance(error, dict) or not isinstance(status, int):
            raise self._bad_answer("POST /v1/batch", f"an item's result is not one: {got!r:.200}")
        return CallResult(False, self._error(_what(call), status, str(error.get("error")), error.get("hint")))

    # --- HTTP ------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the idle connections (the client stays usable: it opens new ones)."""
        with self._idle_lock:
            idle, self._idle = self._idle, []
        for conn in idle:
            conn.close()

    def _request(self, method: str, path: str, body: Any = None, *, timeout: float | None = None,
                 missing_ok: bool = False, raw: bytes | None = None) -> Any:
        """``body`` as JSON, or ``raw`` (JSON already encoded); the answer's JSON (None: empty)."""
        what = f"{method} {path}"
        data = raw if raw is not None else json.dumps(body).encode("utf-8") if body is not None else None
        headers = {"Authorization": f"Bearer {self._token}", "Accept": "application/json"}
        if data is not None:
            headers["Content-Type"] = "application/json"
        wait = timeout or self.timeout
        status, raw = self._exchange(method, self._prefix + path, data, headers, wait, what)
        if status >= 400:
            if status == 404 and missing_ok:
                return None
            raise self._http_error(what, status, raw)
        if not raw:
            return None
        try:
            return json.loads(raw)
        except ValueError:
            raise self._bad_answer(what, "the answer is not JSON") from None

    def _exchange(self, method: str, target: str, data: bytes | None, headers: dict[str, str],
                  wait: float, what: str) -> tuple[int, bytes]:
        """Send one request on a kept (or new) connection; (status, body)."""
        while True:
            conn, reused = self._take(wait)
            try:
                conn.request(method, target, body=data, headers=headers)
                response = conn.getresponse()
                raw = response.read()
            except _STALE as exc:
                conn.close()
                if reused:
                    continue  # the agent closed it while idle: once more on a new connection
                raise self._unreachable(what, wait, exc) from exc
            except (http.client.HTTPException, OSError) as exc:
                conn.close()
                raise self._unreachable(what, wait, exc) from exc
            self._give(conn, response)
            return response.status, raw

    def _take(self, wait: float) -> tuple[http.client.HTTPConnection, bool]:
        """An idle connection (True) or a new one (False), its timeout set to ``wait``."""
        with self._idle_lock:
            conn = self._idle.pop() if self._idle else None
        reused = conn is not None
        if conn is None:
            conn = self._connect(wait)
        conn.timeout = wait
        if conn.sock is not None:
            conn.sock.settimeout(wait)
        return conn, reused

    def _connect(self, wait: float) -> http.client.HTTPConnection:
        if self._ssl_context is not None:
            return http.client.HTTPSConnection(self.host, self._port, timeout=wait,
                                               context=self._ssl_context)
        return http.client.HTTPConnection(self.host, self._port, timeout=wait)

    def _give(self, conn: http.client.HTTPConnection, response: http.client.HTTPResponse) -> None:
        """Keep ``conn`` for the next request, unless the agent said it closes it."""
        if response.will_close:
            conn.close()
            return
        with self._idle_lock:
            if len(self._idle) < MAX_IDLE:
                self._idle.append(conn)
                return
        conn.close()

    def _unreachable(self, what: str, wait: float, exc: BaseException) -> Exception:
        if isinstance(exc, ssl.SSLCertVerificationError):
            return PermanentDispatchError(
                f"agent {self.base_url}: {what}: its TLS certificate is not trusted "
                f"({exc.verify_message})",
                hint="verify agents against the plant CA that issued their certificates "
                     "(its ca.pem; PLANTKG_CA_DIR)", host=self.host)
        if isinstance(exc, (socket.timeout, TimeoutError)):
            problem = f"no answer within {wait:.0f} s"
        else:
            problem = f"cannot reach the agent ({exc})"
        return TemporaryDispatchError(
            f"agent {self.base_url}: {what}: {problem}",
            hint="is `plantkg agent` running there? retry later", host=self.host,
        )

    def _http_error(self, what: str, status: int, raw: bytes) -> Exception:
        try:
            body = json.loads(raw)
            message, hint = str(body["error"]), body.get("hint")
        except (ValueError, KeyError, TypeError):
            message, hint = raw.decode("utf-8", "replace").strip()[:500] or "(no body)", None
        return self._error(what, status, message, hint)

    def _error(self, what: str, status: int, message: str, hint: str | None) -> Exception:
        text = f"agent {self.base_url}: {what} -> {status}: {message}"
        if status == 401:
            return AgentAuthError(text, hint=hint or "check the agent's token", host=self.host)
        if status >= 500:
            return TemporaryDispatchError(text, hint=hint, host=self.host)
        return PermanentDispatchError(text, hint=hint, host=self.host)

    def _bad_answer(self, what: str, problem: str) -> PermanentDispatchError:
        return PermanentDispatchError(
            f"agent {self.base_url}: {what}: {problem}",
            hint="is this URL a plantkg agent of the same version?", host=self.host,
        )

    def _parse(self, parse: Any, data: Any, what: str) -> Any:
        try:
            return parse(data)
        except WireError as exc:
            raise self._bad_answer(what, f"unexpected answer: {exc.message}") from None


def _owned(body: dict[str, Any], owner: str | None) -> dict[str, Any]:
    """A PUT body with the transport field ``owner`` (left out when None)."""
    return body if owner is None else {**body, "owner": owner}


def _owner_query(owner: str | None) -> str:
    return "" if owner is None else "?" + urllib.parse.urlencode({"owner": owner})


def _segment(text: str) -> str:
    """One path segment, every reserved character percent-encoded (MQTT ``/`` as %2F)."""
    return urllib.parse.quote(text, safe="")


def _item(call: AgentCall) -> dict[str, Any]:
    """A call as an item of ``POST /v1/batch`` (engine.agent.batch)."""
    args = call.args
    if call.verb in ("put_broker", "put_topic", "put_bridge"):
        item: dict[str, Any] = {"op": call.verb, "spec": to_dict(args[0])}
    elif call.verb == "delete_broker":
        item = {"op": call.verb, "broker_id": args[0]}
    elif call.verb == "delete_topic":
        item = {"op": call.verb, "broker_id": args[0], "name": args[1]}
    else:
        item = {"op": call.verb, "broker_id": args[0], "remote_id": args[1]}
    return {**item, **call.kwargs()}


def _what(call: AgentCall) -> str:
    """The single request the call stands for, for messages."""
    a = call.args
    return {
        "put_broker": lambda: f"PUT /v1/brokers/{_segment(a[0].id)}",
        "delete_broker": lambda: f"DELETE /v1/brokers/{_segment(a[0])}",
        "put_topic": lambda: f"PUT /v1/brokers/{_segment(a[0].broker_id)}/topics/{_segment(a[0].name)}",
        "delete_topic": lambda: f"DELETE /v1/brokers/{_segment(a[0])}/topics/{_segment(a[1])}",
        "put_bridge": lambda: f"PUT /v1/brokers/{_segment(a[0].local.id)}/bridges/{_segment(a[0].remote.id)}",
        "delete_bridge": lambda: f"DELETE /v1/brokers/{_segment(a[0])}/bridges/{_segment(a[1])}",
    }[call.verb]()


def _chunks(lanes: list[tuple[int, str]]) -> list[list[str]]:
    """Lanes, each (its number of items, its JSON), grouped into requests the agent takes
    (BATCH_LANES, BATCH_ITEMS, BATCH_BYTES)."""
    out: list[list[str]] = []
    items = size = 0
    for count, lane in lanes:
        if not out or len(out[-1]) >= BATCH_LANES or items + count > BATCH_ITEMS \
                or size + len(lane) > BATCH_BYTES:
            out.append([])
            items = size = 0
        out[-1].append(lane)
        items += count
        size += len(lane)
    return out

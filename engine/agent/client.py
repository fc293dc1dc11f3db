"""AgentClient: the engine's side of the agent API (docs/engine-contracts.md), stdlib only.

Failures become dispatch errors the caller can act on:

- connection refused/reset, timeout, 5xx (503 included) -> :class:`TemporaryDispatchError` (retry);
- 401 -> :class:`AgentAuthError`; any other 4xx -> :class:`PermanentDispatchError`;
- the agent's ``error`` and ``hint`` are the exception's message and hint; ``host`` is the URL's.

``put_broker`` and ``delete_broker`` wait for a broker to start or stop (a Kafka start takes
5-60 s, its stop up to 30 s), so they use ``broker_timeout`` (default 150 s) instead of
``timeout``. A timed-out PUT is safe to repeat: the agent keeps starting the broker and answers
the next PUT once it is healthy.
"""

from __future__ import annotations

import http.client
import json
import socket
import ssl
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Any

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
        # Agents are addressed directly: never send their token through an HTTP proxy. An https
        # agent is verified against the plant CA (engine.agent.tls), never the system's store.
        handlers: list[urllib.request.BaseHandler] = [urllib.request.ProxyHandler({})]
        if parsed.scheme == "https":
            handlers.append(urllib.request.HTTPSHandler(context=tls_client_context(ca_file)))
        self._opener = urllib.request.build_opener(*handlers)

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

    # --- HTTP ------------------------------------------------------------------------------

    def _request(self, method: str, path: str, body: Any = None, *, timeout: float | None = None,
                 missing_ok: bool = False) -> Any:
        what = f"{method} {path}"
        data = json.dumps(body).encode("utf-8") if body is not None else None
        request = urllib.request.Request(self.base_url + path, data=data, method=method)
        request.add_header("Authorization", f"Bearer {self._token}")
        request.add_header("Accept", "application/json")
        if data is not None:
            request.add_header("Content-Type", "application/json")
        try:
            with self._opener.open(request, timeout=timeout or self.timeout) as response:
                raw = response.read()
        except urllib.error.HTTPError as exc:
            with exc:
                if exc.code == 404 and missing_ok:
                    return None
                raise self._http_error(what, exc.code, exc.read()) from None
        except (urllib.error.URLError, http.client.HTTPException, OSError) as exc:
            reason = exc.reason if isinstance(exc, urllib.error.URLError) else exc
            if isinstance(reason, ssl.SSLCertVerificationError):
                raise PermanentDispatchError(
                    f"agent {self.base_url}: {what}: its TLS certificate is not trusted "
                    f"({reason.verify_message})",
                    hint="verify agents against the plant CA that issued their certificates "
                         "(its ca.pem; PLANTKG_CA_DIR)", host=self.host) from None
            if isinstance(reason, (socket.timeout, TimeoutError)):
                problem = f"no answer within {timeout or self.timeout:.0f} s"
            else:
                problem = f"cannot reach the agent ({reason})"
            raise TemporaryDispatchError(
                f"agent {self.base_url}: {what}: {problem}",
                hint="is `plantkg agent` running there? retry later", host=self.host,
            ) from exc
        if not raw:
            return None
        try:
            return json.loads(raw)
        except ValueError:
            raise self._bad_answer(what, "the answer is not JSON") from None

    def _http_error(self, what: str, status: int, raw: bytes) -> Exception:
        try:
            body = json.loads(raw)
            message, hint = str(body["error"]), body.get("hint")
        except (ValueError, KeyError, TypeError):
            message, hint = raw.decode("utf-8", "replace").strip()[:500] or "(no body)", None
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

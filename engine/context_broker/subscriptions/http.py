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
import urllib.error
import urllib.request
from urllib.parse import urlencode, urlsplit, urlunsplit

from engine.context_broker.subscriptions.model import HttpTarget
from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.subscriptions.result import Result

DEFAULT_TIMEOUT = 5.0
PROTECTED = {"ngsiv2-attrsformat", "fiware-correlator"}
RETRIED_4XX = {408, 425, 429}


class _NoRedirect(urllib.request.HTTPRedirectHandler):
    def redirect_request(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        return None  # a 3xx is the receiver's answer, not something to follow


_OPENER = urllib.request.build_opener(_NoRedirect, urllib.request.ProxyHandler({}))


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
    def send(self, target: HttpTarget, msg: Outgoing) -> Result:
        timeout = target.timeout_ms / 1000 if target.timeout_ms else DEFAULT_TIMEOUT
        body = None if target.method in ("GET", "HEAD") else msg.body
        req = urllib.request.Request(request_url(target), data=body, method=target.method,
                                     headers=request_headers(target, msg))
        try:
            with _OPENER.open(req, timeout=timeout) as resp:
                resp.read()
                return classify(resp.status)
        except urllib.error.HTTPError as err:
            err.close()
            return classify(err.code)
        except (TimeoutError, socket.timeout):
            return Result.temporary(f"Timeout was reached ({timeout:g} s)")
        except urllib.error.URLError as err:
            reason = err.reason
            if isinstance(reason, (TimeoutError, socket.timeout)):
                return Result.temporary(f"Timeout was reached ({timeout:g} s)")
            return Result.temporary(f"Couldn't connect to server: {reason}")
        except (OSError, http.client.HTTPException) as err:
            return Result.temporary(f"HTTP exchange failed: {type(err).__name__}: {err}")

    def close(self) -> None:
        return None

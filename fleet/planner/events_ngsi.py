"""LoTLan Events from the context broker (NGSI-v2): an entity of type ``Event`` per event.

The entity's id is the Event's LoTLan name or physical ``name`` (``Loaded``), its attribute
``value`` the value (``{"type": "Boolean", "value": true}``); any NGSI client writes it (FiLiP,
curl, an HMI, a sensor's IoT agent). With ``--events-ngsi`` the planner keeps one subscription on
the context broker (``--ngsi-url``): entities of type ``Event``, condition attribute ``value``,
``attrsFormat`` normalized, sent by ``httpCustom`` to the planner's notification endpoint
``POST <notify-url>/v1/ngsi/notify``. Orion's notification body
``{"subscriptionId", "data": [entity, ...]}`` fires each entity once through ``Planner.fire``
(:mod:`event_sources`): typed and journaled as ``POST /v1/events``.

The subscription is found again by its ``description`` (one per planner data directory), so a
restarted planner reuses it (PATCHing the endpoint's URL when it moved) and never makes a second
one; duplicates left by a crash between create and list are deleted. A thread checks it every
``check`` seconds (re-created if someone deleted it) and retries every ``retry`` seconds while
the context broker does not answer, so the planner starts without it.

The endpoint has a token of its own (``<data-dir>/planner-notify.token``), sent by the context
broker as ``Authorization: Bearer``: a subscription's headers can be read by anyone who can read
the context broker's subscriptions, so this token only fires Events (never the planner's API).
"""

from __future__ import annotations

import hashlib
import json
import logging
import ssl
import threading
import urllib.error
import urllib.request
from pathlib import Path
from typing import Any

from fleet.planner.errors import PlannerError
from fleet.planner.event_sources import EventMessageError, Fire, Refusal, Tally
from fleet.planner.ngsi_tls import untrusted

log = logging.getLogger("fleet.planner.events")
ENTITY_TYPE = "Event"
ATTR = "value"
NOTIFY_PATH = "/v1/ngsi/notify"


def description_for(data_dir: Path) -> str:
    """The subscription's description: stable per planner data directory, NGSI-safe characters only."""
    digest = hashlib.sha256(str(data_dir).encode("utf-8")).hexdigest()[:16]
    return f"plantkg task planner events {digest}"


def subscription(description: str, url: str, token: str) -> dict[str, Any]:
    """The subscription the planner keeps (NGSI-v2, Orion's fields)."""
    return {"description": description,
            "subject": {"entities": [{"idPattern": ".*", "type": ENTITY_TYPE}], "condition": {"attrs": [ATTR]}},
            "notification": {"httpCustom": {"url": url, "headers": {"Authorization": f"Bearer {token}"}},
                             "attrs": [ATTR], "attrsFormat": "normalized"}}


def differs(stored: dict[str, Any], wanted: dict[str, Any]) -> list[str]:
    """The fields of a stored subscription that are not what the planner wants (empty: reuse as is)."""
    notification, want = stored.get("notification") or {}, wanted["notification"]
    subject = stored.get("subject") or {}
    checks = {"notification.httpCustom.url": ((notification.get("httpCustom") or {}).get("url"),
                                              want["httpCustom"]["url"]),
              "notification.httpCustom.headers": ((notification.get("httpCustom") or {}).get("headers"),
                                                  want["httpCustom"]["headers"]),
              "notification.attrs": (notification.get("attrs"), want["attrs"]),
              "notification.attrsFormat": (notification.get("attrsFormat"), want["attrsFormat"]),
              "subject.entities": (subject.get("entities"), wanted["subject"]["entities"]),
              "subject.condition.attrs": ((subject.get("condition") or {}).get("attrs"),
                                          wanted["subject"]["condition"]["attrs"]),
              "status": ("active" if stored.get("status") in ("active", "failed") else stored.get("status"), "active")}
    return [field for field, (have, need) in checks.items() if have != need]


def events_of(body: Any) -> tuple[list[tuple[str, Any]], list[tuple[str, str]]]:
    """A notification -> ``[(entity id, value)]`` to fire and ``[(where, reason)]`` refused one by one.

    A body that is no notification at all raises :class:`EventMessageError` naming the field."""
    if not isinstance(body, dict):
        raise EventMessageError("body", f"expected Orion's notification object {{\"subscriptionId\", \"data\"}}, "
                                        f"got {type(body).__name__}")
    if not isinstance(body.get("subscriptionId"), str):
        raise EventMessageError("subscriptionId", f"expected a string, got {body.get('subscriptionId')!r}"[:200])
    data = body.get("data")
    if not isinstance(data, list):
        raise EventMessageError("data", f"expected a list of entities, got {type(data).__name__}")
    fire: list[tuple[str, Any]] = []
    refused: list[tuple[str, str]] = []
    for i, entity in enumerate(data):
        try:
            fire.append(_entity_event(entity, f"data[{i}]"))
        except EventMessageError as exc:
            named = isinstance(entity, dict) and isinstance(entity.get("id"), str) and entity["id"]
            where = entity["id"] if named else f"data[{i}]"
            refused.append((where, str(exc)))
    return fire, refused


def _entity_event(entity: Any, path: str) -> tuple[str, Any]:
    if not isinstance(entity, dict):
        raise EventMessageError(path, f"expected an entity object, got {type(entity).__name__}")
    if not isinstance(entity.get("id"), str) or not entity["id"]:
        raise EventMessageError(f"{path}.id", f"expected the Event's name, got {entity.get('id')!r}"[:200])
    if entity.get("type") != ENTITY_TYPE:
        raise EventMessageError(f"{path}.type", f"expected {ENTITY_TYPE!r}, got {entity.get('type')!r}"[:200])
    attr = entity.get(ATTR)
    if not isinstance(attr, dict) or ATTR not in attr:
        raise EventMessageError(f"{path}.{ATTR}", f"expected a normalized attribute {{\"type\", \"value\"}}, "
                                                  f"got {attr!r}"[:200])
    value = attr[ATTR]
    if value is None or isinstance(value, (dict, list)):
        raise EventMessageError(f"{path}.{ATTR}.value", f"an event's value is a boolean, number or string, "
                                                        f"got {value!r}"[:200])
    return entity["id"], value


class ContextBrokerError(PlannerError):
    """The context broker refused a call or did not answer (temporary: the thread retries)."""


class NgsiEvents:
    """Keeps the subscription and fires what its notifications carry; :meth:`status` for the API."""

    def __init__(self, url: str, token: str | None, fire: Fire, description: str, notify_token: str,
                 timeout: float = 5.0, retry: float = 2.0, check: float = 30.0, *,
                 context: ssl.SSLContext | None = None) -> None:
        self.url, self.token, self.context = url.rstrip("/"), token, context  # context: an https:// broker
        self.tally = Tally("ngsi", fire)
        self.description, self.notify_token = description, notify_token
        self.timeout, self.retry, self.check = timeout, retry, check
        self.notify_url: str | None = None
        self.subscription_id: str | None = None
        self.last_error: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="planner-events-ngsi", daemon=True)

    def start(self, notify_url: str) -> None:
        self.notify_url = notify_url
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(self.timeout + 1)

    def status(self) -> dict[str, Any]:
        return {"contextBroker": self.url, "subscription": self.subscription_id, "notifyUrl": self.notify_url,
                "lastError": self.last_error, **self.tally.status()}

    def notify(self, body: Any) -> dict[str, Any]:
        """One notification: each entity fired once; the refused ones listed with their reason."""
        fire, refused = events_of(body)  # EventMessageError: the whole body is bad (the route answers 400)
        out = [{"id": where, "reason": self.tally.refuse(where, reason).reason} for where, reason in refused]
        fired = []
        for name, value in fire:
            record = self.tally.deliver(name, name, value)
            if isinstance(record, Refusal):
                out.append({"id": name, "reason": record.reason})
            else:
                fired.append(record)
        return {"fired": fired, "refused": out}

    # ------------------------------------------------------------------ the subscription
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.ensure()
                self.last_error = None
                wait = self.check
            except ContextBrokerError as exc:
                if self.last_error != str(exc):
                    log.warning("events: subscription on %s not in place (%s); retrying every %g s",
                                self.url, exc, self.retry)
                self.last_error = str(exc)
                wait = self.retry
            self._stop.wait(wait)

    def ensure(self) -> str:
        """The subscription exists once, as wanted: found by description, patched or created."""
        assert self.notify_url is not None, "start(notify_url) first"
        wanted = subscription(self.description, self.notify_url, self.notify_token)
        mine = [s for s in self._list() if s.get("description") == self.description]
        for extra in mine[1:]:
            self._call("DELETE", f"/v2/subscriptions/{extra['id']}")
            log.info("events: deleted the duplicate subscription %s", extra["id"])
        if not mine:
            _, headers, _ = self._call("POST", "/v2/subscriptions", wanted)
            self.subscription_id = (headers.get("Location") or "").rsplit("/", 1)[-1] or None
            log.info("events: subscription %s created on %s -> %s", self.subscription_id, self.url, self.notify_url)
            return self.subscription_id or ""
        keep = mine[0]
        changed = differs(keep, wanted)
        if changed:
            self._call("PATCH", f"/v2/subscriptions/{keep['id']}", {**wanted, "status": "active"})
            log.info("events: subscription %s reused, updated %s", keep["id"], ", ".join(changed))
        elif self.subscription_id != keep["id"]:
            log.info("events: subscription %s reused as it is", keep["id"])
        self.subscription_id = keep["id"]
        return keep["id"]

    def _list(self) -> list[dict[str, Any]]:
        found: list[dict[str, Any]] = []
        while True:
            _, _, page = self._call("GET", f"/v2/subscriptions?limit=1000&offset={len(found)}")
            if not isinstance(page, list):
                raise ContextBrokerError(f"GET /v2/subscriptions answered {type(page).__name__}, not a list")
            found.extend(s for s in page if isinstance(s, dict))
            if len(page) < 1000:
                return found

    def _call(self, method: str, path: str, body: Any = None) -> tuple[int, dict[str, str], Any]:
        headers = {"Content-Type": "application/json"} if body is not None else {}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        request = urllib.request.Request(self.url + path, method=method, headers=headers,
                                         data=None if body is None else json.dumps(body).encode("utf-8"))
        try:
            with urllib.request.urlopen(request, timeout=self.timeout, context=self.context) as reply:
                raw = reply.read()
                return reply.status, dict(reply.headers), json.loads(raw) if raw else None
        except urllib.error.HTTPError as exc:
            said = exc.read()[:300].decode("utf-8", "replace")
            raise ContextBrokerError(f"{method} {path}: {exc.code} {said}") from None
        except (urllib.error.URLError, OSError, ValueError) as exc:
            raise ContextBrokerError(f"{method} {path}: {untrusted(exc, self.url) or exc}") from None

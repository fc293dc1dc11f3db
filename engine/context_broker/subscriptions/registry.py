"""Subscriptions on disk: durable CRUD, and the delivery status beside them.

Two files in the service's data directory, each replaced atomically (write a temporary file,
fsync it, rename it over the old one, fsync the directory), so a kill -9 leaves the old or the
new version, never half of one:

- ``subscriptions.json``: every subscription as its client wrote it (after ``PATCH`` merges),
  with its tenant and, when a principal created it, its ``owner`` (:mod:`.ownership`). Written before ``POST``/``PATCH``/``DELETE`` answer 2xx, and when a
  ``oneshot`` subscription fires or ``maxFailsLimit`` deactivates one.
- ``subscription-status.json``: the delivery counters (``timesSent``, ``lastSuccess``, ...),
  written by :meth:`Registry.flush_status` (every few seconds by the service, and at close), so a
  kill -9 loses at most that window of counter updates.

Subscriptions belong to a ``Fiware-Service`` (Orion: "subscriptions belong only to the service");
their service path is the scope of entities they watch. Every call takes the :class:`Requester`:
a principal creates only what it may hold and sees only its own (:mod:`.ownership`).
"""

from __future__ import annotations

import json
import logging
import secrets
import threading
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

from engine.context_broker.contract import NgsiError, Tenant, not_found
from engine.errors import EngineError
from engine.context_broker.subscriptions.model import DeliveryStatus, Status, Subscription
from engine.context_broker.subscriptions.ownership import PLANTKG, Requester, check_may_hold, may_see
from engine.context_broker.subscriptions.parse import QParser, merge_patch, parse_subscription
from engine.context_broker.subscriptions.result import Result
from engine.whole_file import write_whole

log = logging.getLogger(__name__)
SUBSCRIPTIONS_FILE = "subscriptions.json"
STATUS_FILE = "subscription-status.json"
NOT_FOUND = "The requested subscription has not been found. Check id"


class SubscriptionStoreError(EngineError):
    """The stored subscriptions cannot be read back (a damaged or hand-edited file)."""

    def __init__(self, path: Path, problem: str) -> None:
        super().__init__(f"{path}: {problem}",
                         hint="fix or remove that entry (or restore the file); the context broker "
                              "does not start with subscriptions it cannot read")


def new_id() -> str:
    """24 lower-case hex digits, like Orion's (MongoDB ObjectId) ids."""
    return secrets.token_hex(12)


def check_id(sub_id: str) -> None:
    if len(sub_id) != 24 or any(c not in "0123456789abcdefABCDEF" for c in sub_id):
        raise NgsiError(400, "BadRequest", f"Invalid subscription ID: {sub_id!r} is not 24 "
                                           "hexadecimal digits")


def atomic_write_json(path: Path, data: Any) -> None:
    """``data`` as JSON in ``path`` (0600), whole and durable (fsynced, with its folder)."""
    write_whole(path, json.dumps(data, ensure_ascii=False, indent=1), mode=0o600, durable=True)


class Registry:
    def __init__(self, data_dir: Path, parse_q: QParser) -> None:
        self._dir = Path(data_dir)
        self._dir.mkdir(parents=True, exist_ok=True)
        self._parse_q = parse_q
        self._lock = threading.RLock()
        self._docs: dict[str, dict[str, Any]] = {}
        self._subs: dict[str, Subscription] = {}
        self._status: dict[str, DeliveryStatus] = {}
        self._status_dirty = False
        self._index: dict[str, tuple[dict[str, tuple[Subscription, ...]], tuple[Subscription, ...]]] = {}
        self._load()

    # --- persistence ---------------------------------------------------------------------
    def _load(self) -> None:
        path = self._dir / SUBSCRIPTIONS_FILE
        if path.exists():
            try:
                items = json.loads(path.read_text(encoding="utf-8"))["subscriptions"]
            except (ValueError, KeyError, TypeError) as err:
                raise SubscriptionStoreError(path, f"not a subscriptions file: {err}") from None
            for item in items:
                try:
                    tenant = Tenant(item["service"], item["servicePath"])
                    owner = item.get("owner")
                    if owner is not None and not isinstance(owner, str):
                        raise SubscriptionStoreError(path, f"subscription {item['id']}: owner "
                                                           f"{owner!r} is not a principal's name")
                    sub = replace(parse_subscription(item["doc"], sub_id=item["id"], tenant=tenant,
                                                     parse_q=self._parse_q), owner=owner)
                except (KeyError, TypeError) as err:
                    raise SubscriptionStoreError(path, f"entry without {err}") from None
                except NgsiError as err:
                    raise SubscriptionStoreError(
                        path, f"subscription {item['id']} is not valid: {err.description}") from None
                self._docs[sub.id] = {"tenant": tenant, "doc": item["doc"], "owner": owner}
                self._subs[sub.id] = sub
        status_path = self._dir / STATUS_FILE
        if status_path.exists():
            try:
                stored = json.loads(status_path.read_text(encoding="utf-8"))
                for sub_id, data in stored.items():
                    if sub_id in self._subs:
                        self._status[sub_id] = DeliveryStatus.from_json(data)
            except (ValueError, AttributeError, TypeError):
                # only counters: start them again rather than refuse to start
                self._status = {}
        self._publish()

    def _publish(self) -> None:
        """Rebuild the lookup :meth:`candidates` reads (a new dict, swapped in whole, so readers
        need no lock): per service, the subscriptions naming exact entity ids by id, and those
        with a pattern in a list that every change in the service is checked against."""
        index: dict[str, tuple[dict[str, list[Subscription]], list[Subscription]]] = {}
        for sub in self._subs.values():
            by_id, scan = index.setdefault(sub.tenant.service, ({}, []))
            if any(sel.id is None for sel in sub.entities):
                scan.append(sub)
            else:
                for entity_id in dict.fromkeys(sel.id for sel in sub.entities if sel.id is not None):
                    by_id.setdefault(entity_id, []).append(sub)
        self._index = {service: ({k: tuple(v) for k, v in by_id.items()}, tuple(scan))
                       for service, (by_id, scan) in index.items()}

    def candidates(self, tenant: Tenant, entity_id: str) -> tuple[Subscription, ...]:
        """The subscriptions a change of ``entity_id`` in ``tenant`` can trigger (a superset)."""
        entry = self._index.get(tenant.service)
        if entry is None:
            return ()
        by_id, scan = entry
        exact = by_id.get(entity_id, ())
        return exact + scan if exact else scan

    def _commit(self, docs: dict[str, dict[str, Any]], subs: dict[str, Subscription]) -> None:
        """Write ``docs`` durably, then make ``docs``/``subs`` the current state. A failed write
        changes nothing (the request is answered 500 saying so)."""
        path = self._dir / SUBSCRIPTIONS_FILE
        items = [{"id": sub_id, "service": entry["tenant"].service,
                  "servicePath": entry["tenant"].service_path, "doc": entry["doc"],
                  **({"owner": entry["owner"]} if entry.get("owner") is not None else {})}
                 for sub_id, entry in docs.items()]
        try:
            atomic_write_json(path, {"version": 1, "subscriptions": items})
        except OSError as err:
            raise NgsiError(500, "InternalServerError",
                            f"could not store the subscriptions in {path}: {err.strerror or err}; "
                            "nothing was changed") from None
        self._docs, self._subs = docs, subs
        self._publish()

    def flush_status(self) -> None:
        with self._lock:
            if not self._status_dirty:
                return
            data = {k: v.as_json() for k, v in self._status.items() if k in self._subs}
            self._status_dirty = False
        atomic_write_json(self._dir / STATUS_FILE, data)

    # --- CRUD ----------------------------------------------------------------------------
    def create(self, tenant: Tenant, doc: Mapping[str, Any], who: Requester = PLANTKG) -> Subscription:
        sub_id = new_id()
        sub = replace(parse_subscription(doc, sub_id=sub_id, tenant=tenant, parse_q=self._parse_q),
                      owner=who.name)
        check_may_hold(who, sub)
        stored = {k: v for k, v in doc.items() if k != "id"}
        with self._lock:
            self._commit({**self._docs, sub_id: {"tenant": tenant, "doc": stored, "owner": who.name}},
                         {**self._subs, sub_id: sub})
            self._status[sub_id] = DeliveryStatus()
        return sub

    def _owned(self, sub_id: str, service: str, who: Requester) -> Subscription:
        """The subscription ``sub_id`` of ``service`` if ``who`` may see it, else 404 (another
        principal's is not found either: see .ownership)."""
        check_id(sub_id)
        sub = self._subs.get(sub_id)
        if sub is None or sub.tenant.service != service or not may_see(who, sub):
            raise not_found(NOT_FOUND)
        return sub

    def get(self, sub_id: str, service: str, who: Requester = PLANTKG) -> tuple[Subscription, DeliveryStatus]:
        with self._lock:
            sub = self._owned(sub_id, service, who)
            return sub, self._status.get(sub_id, DeliveryStatus())

    def listing(self, service: str, service_path: str | None,
                who: Requester = PLANTKG) -> list[tuple[Subscription, DeliveryStatus]]:
        """The service's subscriptions ``who`` may see, in creation order; with ``service_path``
        (canonical, see .scope), only those created with exactly that service-path query (as Orion)."""
        with self._lock:
            return [(s, self._status.get(s.id, DeliveryStatus())) for s in self._subs.values()
                    if s.tenant.service == service and may_see(who, s)
                    and (service_path is None or s.tenant.service_path == service_path)]

    def update(self, sub_id: str, service: str, patch: Any, who: Requester = PLANTKG) -> Subscription:
        with self._lock:
            old = self._owned(sub_id, service, who)
            merged = merge_patch(self._docs[sub_id]["doc"], patch)
            sub = replace(parse_subscription(merged, sub_id=sub_id, tenant=old.tenant, parse_q=self._parse_q),
                          owner=old.owner)
            check_may_hold(who, sub)
            self._commit({**self._docs, sub_id: {**self._docs[sub_id], "doc": merged}},
                         {**self._subs, sub_id: sub})
            if sub.status is not Status.INACTIVE and "status" in patch:
                # re-activated by its owner: a fresh start for maxFailsLimit
                self._status[sub_id] = replace(self._status.get(sub_id, DeliveryStatus()), fails_counter=0)
                self._status_dirty = True
        return sub

    def delete(self, sub_id: str, service: str, who: Requester = PLANTKG) -> None:
        with self._lock:
            self._owned(sub_id, service, who)
            self._commit({k: v for k, v in self._docs.items() if k != sub_id},
                         {k: v for k, v in self._subs.items() if k != sub_id})
            self._status.pop(sub_id, None)

    def current(self, sub_id: str) -> Subscription | None:
        return self._subs.get(sub_id)

    def deactivate(self, sub_id: str) -> None:
        """``oneshot`` after it fired, or ``maxFailsLimit`` passed: ``inactive``, durably. If the
        file cannot be written, inactive in memory all the same (logged): it must not fire again."""
        with self._lock:
            if sub_id not in self._subs:
                return
            entry = self._docs[sub_id]
            docs = {**self._docs, sub_id: {**entry, "doc": {**entry["doc"], "status": Status.INACTIVE.value}}}
            subs = {**self._subs, sub_id: replace(self._subs[sub_id], status=Status.INACTIVE)}
            try:
                self._commit(docs, subs)
            except NgsiError as err:
                log.error("subscription %s deactivated in memory only: %s", sub_id, err.description)
                self._docs, self._subs = docs, subs
                self._publish()

    # --- delivery status -----------------------------------------------------------------
    def record(self, sub_id: str, result: Result, now: float) -> DeliveryStatus | None:
        """Count one delivery attempt. ``timesSent`` counts attempts (retries included);
        ``failsCounter`` the consecutive failures, reset by a success."""
        with self._lock:
            if sub_id not in self._subs:
                return None
            old = self._status.get(sub_id, DeliveryStatus())
            new = replace(old, times_sent=old.times_sent + 1, last_notification=now)
            if result.ok:
                new = replace(new, last_success=now, last_success_code=result.code, fails_counter=0)
            else:
                new = replace(new, last_failure=now, last_failure_reason=result.reason,
                              fails_counter=old.fails_counter + 1)
            self._status[sub_id] = new
            self._status_dirty = True
            return new

    def record_dropped(self, sub_id: str, count: int) -> None:
        with self._lock:
            if sub_id in self._subs:
                old = self._status.get(sub_id, DeliveryStatus())
                self._status[sub_id] = replace(old, dropped=old.dropped + count)
                self._status_dirty = True

    def status_of(self, sub_id: str) -> DeliveryStatus:
        with self._lock:
            return self._status.get(sub_id, DeliveryStatus())

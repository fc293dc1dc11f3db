"""The fleet manager's main loop: messages -> registry -> effects; batches -> reconcile; status.

One thread owns the state (records, registry, states): it reads the MQTT inbox, carries out the
registry's effects (ask a factsheet, write a vehicle's file, mark it unavailable, refuse), and
starts a reconcile on a worker thread when joins have waited ``batch_window`` (several joins
within it make one run; joins during a run make the next one). The data directory is polled for
changes made by a person (``plantkg fleet pin|rename|remove``): a change reloads the records and
reconciles. A reconcile also runs at start and every ``resync`` seconds (drift). The HTTP API
reads an immutable snapshot the loop publishes, and sends orders through the MQTT link.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fleet.discovery import files, model_api
from fleet.discovery.errors import RefusedMessage
from fleet.discovery.inbox import ConnectionSeen, DescriptionSeen, Interface, VehicleKey, VehicleState, classify
from fleet.discovery.records import DataDir, VehicleRecord, now_iso
from fleet.discovery.registry import (AskFactsheet, DescriptionRefused, Join, Known, Note, Refuse, Registry,
                                      SetConnection, Track)
from fleet.manager import apply_step, instant, status
from fleet.manager.api import ApiError
from fleet.manager.mqtt_link import MqttLink, Received
from fleet.manager.orders import NodeSpec, OrderError, build_order, order_json
from fleet.manager.reconciler import ReconcileReport, Reconciler, Step
from fleet.vda5050 import topics
from fleet.vda5050.errors import SchemaError, TopicError

log = logging.getLogger("fleet.manager")


@dataclass(frozen=True)
class ManagerConfig:
    plant_files: tuple[Path, ...]
    data_dir: Path
    mqtt: tuple[str, int]
    binding: dict[str, Any] = field(default_factory=dict)  # the plant's FleetBinding as JSON
    batch_window: float = 0.1
    ask_every: float = 5.0
    poll_interval: float = 0.5
    status_interval: float = 0.2
    resync: float = 30.0
    retry_delay: float = 2.0


def render_record(record: VehicleRecord) -> str:
    desc = model_api.renamed(model_api.description_from_json(record.description), record.name)
    return model_api.render(desc, model_api.binding_from_json(record.binding),
                            connection_state=record.connection_state, pinned=record.pinned,
                            secret_ref=record.secret_ref, discovered=not record.awaiting_description)


def describe(key: VehicleKey, payload: dict[str, Any]) -> dict[str, Any]:
    try:
        if key.interface is Interface.VDA5050:
            desc = model_api.describe_factsheet(key.manufacturer, key.serial, payload)
        else:
            desc = model_api.describe_paper(payload)
    except model_api.description_errors() as exc:
        raise DescriptionRefused(getattr(exc, "message", str(exc))) from None
    data = model_api.description_to_json(desc)
    if data.get("serial") != key.serial:
        raise DescriptionRefused(f"serial {data.get('serial')!r} is not the topic's {key.serial!r}")
    return data


def key_of(record: VehicleRecord) -> VehicleKey:
    return VehicleKey(Interface(record.interface), record.topic_manufacturer, record.serial)


class FleetManager:
    def __init__(self, config: ManagerConfig, apply: Step, check: Step = lambda f: apply_step.check(f),
                 link: MqttLink | None = None) -> None:
        self.config = config
        self.data = DataDir(config.data_dir, render_record)
        self.registry = Registry(describe, ask_every=config.ask_every)
        self.reconciler = Reconciler(list(config.plant_files), self.data, apply, check)
        self.link = link or MqttLink(*config.mqtt)
        self.records: dict[VehicleKey, VehicleRecord] = {}
        self.states: dict[VehicleKey, VehicleState] = {}
        self.joining: dict[VehicleKey, float] = {}
        self.ready: dict[VehicleKey, float] = {}
        self.pending: set[str] = set()
        self.unconfirmed: set[str] = set()  # written, not yet part of a reconcile that converged
        self._in_run: set[str] = set()
        self.pending_since = 0.0
        self.force = True  # reconcile once at start
        self.refused_messages: deque[dict[str, str]] = deque(maxlen=50)
        self.orders: deque[dict[str, str]] = deque(maxlen=50)
        self.last_report: dict[str, Any] | None = None
        self.snapshot: list[dict[str, Any]] = []
        self.api_url = ""
        self._work: Future[ReconcileReport] | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="reconcile")
        self._stop = threading.Event()
        self._fingerprint: tuple[Any, ...] = ()
        self._log_gate: dict[str, float] = {}
        self._dirty = True
        self.loaded = False  # records read from the data directory (the API answers 503 until then)

    # ------------------------------------------------------------------ lifecycle
    def stop(self) -> None:
        self._stop.set()

    def run(self) -> None:
        self._reload(initial=True)
        self._publish_status()
        self.loaded = True  # the API answers from here on (503 NotReady before)
        self.link.start()
        next_poll = next_status = 0.0
        next_resync = time.monotonic() + self.config.resync
        try:
            while not self._stop.is_set():
                self._read_inbox(0.05)
                now = time.monotonic()
                self._collect(now)
                if now >= next_resync:
                    self.force, next_resync = True, now + self.config.resync
                self._maybe_reconcile(now)
                if now >= next_poll:
                    next_poll = now + self.config.poll_interval
                    if self._fingerprint != self._dir_fingerprint():
                        log.info("the data directory was changed from outside; reloading and reconciling")
                        self._reload()
                        self.force = True
                if self._dirty and now >= next_status:
                    next_status = now + self.config.status_interval
                    try:
                        self._publish_status()
                    except OSError as exc:  # e.g. a full disk: say so, keep managing the fleet
                        log.error("cannot write %s: %s", self.data.root / "status.json", exc)
        finally:
            self.link.stop()
            if self._work is not None:
                self._work.result()
            self._pool.shutdown()
            self._publish_status()

    def _read_inbox(self, timeout: float) -> None:
        try:
            item = self.link.inbox.get(timeout=timeout)
        except queue.Empty:
            return
        for _ in range(1000):
            try:
                self._receive(item)
            except Exception:  # a bug or a full disk must not stop the manager: log, go on
                log.exception("handling a message on %r failed", item.topic[:200])
            try:
                item = self.link.inbox.get_nowait()
            except queue.Empty:
                return

    # ------------------------------------------------------------------ messages
    def _receive(self, item: Received) -> None:
        try:
            event = classify(item.topic, item.payload, item.retained)
        except RefusedMessage as exc:
            self.refused_messages.append({"at": now_iso(), "topic": item.topic[:200], "reason": exc.reason[:500]})
            self._dirty = True
            if len(self._log_gate) > 10_000:
                self._log_gate.clear()
            if time.monotonic() - self._log_gate.get(item.topic, -1e9) > 5.0:  # a flood logs once per 5 s
                self._log_gate[item.topic] = time.monotonic()
                log.warning("%s", exc.message)
            return
        key = event.key
        first_sign = isinstance(event, DescriptionSeen) or (
            isinstance(event, ConnectionSeen) and event.state == "ONLINE")
        unheard = key not in self.records or self.records[key].awaiting_description  # unknown, or admitted
        if first_sign and unheard and key not in self.joining and len(self.joining) < 10_000:
            self.joining[key] = item.at
        for effect in self.registry.handle(event, item.at):
            if isinstance(effect, AskFactsheet):
                log.info("unknown vehicle %s is ONLINE: asking for its factsheet", key.label)
                self.link.instant_action(key.manufacturer, key.serial, "factsheetRequest")
            elif isinstance(effect, Join):
                self._join(effect, item.at)
            elif isinstance(effect, SetConnection):
                self._set_connection(effect)
            elif isinstance(effect, Refuse):
                self._refuse(effect)
            elif isinstance(effect, Track) and key in self.records:  # unknown ones: not kept
                self.states[key] = effect.state
                self._dirty = True
            elif isinstance(effect, Note):
                log.info("vehicle %s: %s", key.label, effect.message)

    def _join(self, effect: Join, at: float) -> None:
        key, desc = effect.key, effect.description
        old = self.records.get(key)
        record = VehicleRecord(
            interface=key.interface.value, manufacturer=str(desc["manufacturer"]), serial=key.serial,
            topic_manufacturer=key.manufacturer, description=desc, binding=self.config.binding,
            connection_state=effect.connection_state, pinned=old.pinned if old else False,
            name=old.name if old else None,
            discovered_at=old.discovered_at if old and not old.awaiting_description else now_iso(),
            secret_ref=old.secret_ref if old else None)
        try:
            with self.data.lock():
                person = self._person_changed()
                if old is not None and old.stem != record.stem:  # admitted under another manufacturer
                    self.data.remove(old)
                self.data.save(record)
                for stale in self.data.refused.glob(f"{record.stem}.*") if self.data.refused.is_dir() else ():
                    stale.unlink()
                if not person:
                    self._fingerprint = self._dir_fingerprint()
        except Exception as exc:  # the model could not render it: refuse it, keep running
            self.registry.reject(key)
            self._refuse(Refuse(key, f"cannot be written as Turtle: {exc}", desc))
            return
        self.records[key] = record
        log.info("%s vehicle %s (%s): %s", "discovered" if effect.new else "updated", record.label,
                 key.interface.value, self.data.turtle_path(record))
        if not self.pending:
            self.pending_since = at
        self.pending.add(record.stem)
        self.unconfirmed.add(record.stem)
        self._dirty = True

    def _set_connection(self, effect: SetConnection) -> None:
        record = self.records.get(effect.key)
        if record is None:
            return
        with self.data.lock():
            person = self._person_changed()
            self.records[effect.key] = self.data.update(record, connection_state=effect.state)
            if not person:
                self._fingerprint = self._dir_fingerprint()
        word = "available" if effect.state == "ONLINE" else "unavailable"
        log.info("vehicle %s is %s (%s)", record.label, word, effect.state)
        self._dirty = True

    def _person_changed(self) -> bool:
        """The data directory changed since the manager last looked (a person's rename, pin or
        remove). Called under the data lock before the manager's own write: the fingerprint is then
        left as it was, so the next poll reloads and the person's change is not taken for ours."""
        return self._fingerprint != self._dir_fingerprint()

    def _refuse(self, effect: Refuse) -> None:
        manufacturer = effect.key.manufacturer or str(effect.payload.get("manufacturer") or "_")
        stem = files.stem(manufacturer, effect.key.serial)
        with self.data.lock():
            self.data.refuse(stem, effect.reason, payload=effect.payload)
        self.joining.pop(effect.key, None)
        log.warning("refused vehicle %s: %s", effect.key.label, effect.reason)
        self._dirty = True

    # ------------------------------------------------------------------ reconcile
    def _maybe_reconcile(self, now: float) -> None:
        if self._work is not None:
            return
        due = self.pending and now >= self.pending_since + self.config.batch_window
        if not (due or self.force):
            return
        batch, self.pending, self.force = set(self.pending), set(), False
        self._in_run = set(self.unconfirmed)
        self._work = self._pool.submit(self.reconciler.run, batch)

    def _collect(self, now: float) -> None:
        if self._work is None or not self._work.done():
            return
        work, self._work = self._work, None
        try:
            report = work.result()
        except Exception:
            log.exception("reconcile failed")
            return
        by_stem = {r.stem: k for k, r in self.records.items()}
        for stem, reason in report.refused:
            key = by_stem.get(stem)
            if key is not None:
                self.registry.reject(key)
                self.records.pop(key, None)
                self.joining.pop(key, None)
        step = report.step
        refused = {stem for stem, _ in report.refused}
        self.unconfirmed -= refused
        if step.ok:
            for stem in sorted(self._in_run - refused):
                key = by_stem.get(stem)
                self.unconfirmed.discard(stem)
                if key is None:
                    continue
                started = self.joining.pop(key, None)
                if started is not None:
                    self.ready[key] = now - started
                    log.info("vehicle %s ready for tasks %.3f s after it was first seen",
                             key.label, self.ready[key])
                if key.interface is Interface.VDA5050:
                    self.link.instant_action(key.manufacturer, key.serial, "stateRequest")
        elif step.valid and self._in_run - refused:  # agents failed: try again soon
            self.pending |= self._in_run - refused
            self.pending_since = now + self.config.retry_delay
        log.info("reconcile: %s%s", step.summary(),
                 f"; joined {', '.join(report.joined)}" if report.joined else "")
        self.last_report = {"at": now_iso(), "ok": step.ok, "valid": step.valid, "summary": step.summary(),
                            "changes": step.changes, "seconds": round(step.seconds, 3),
                            "joined": list(report.joined),
                            "refused": [{"vehicle": s, "reason": r} for s, r in report.refused],
                            "problems": list(step.problems)}
        if report.refused:  # the reconciler moved their files: not a person's change
            self._fingerprint = self._dir_fingerprint()
        self._dirty = True

    # ------------------------------------------------------------------ data directory
    def _dir_fingerprint(self) -> tuple[Any, ...]:
        folder = self.data.vehicles
        if not folder.is_dir():
            return ()
        out = []
        for path in sorted(folder.glob("*.json")):
            try:
                st = path.stat()
            except FileNotFoundError:
                continue
            out.append((path.name, st.st_mtime_ns, st.st_size))
        return tuple(out)

    def _reload(self, initial: bool = False) -> None:
        with self.data.lock():
            records = self.data.records()
            for record in records:  # a file lost (kill -9 between the two writes): render it again
                if not self.data.turtle_path(record).exists():
                    self.data.save(record)
            self._fingerprint = self._dir_fingerprint()
        before = set(self.records)
        self.records = {key_of(r): r for r in records}
        self.registry.load({k: Known(r.description, r.connection_state, r.pinned, r.awaiting_description)
                            for k, r in self.records.items()})
        for key in before - set(self.records):  # removed by a person: forgotten until it comes back
            self.registry.forget(key)
            self.ready.pop(key, None)
            log.info("vehicle %s was removed from the data directory", key.label)
        if initial and records:
            log.info("%d discovered vehicle(s) in %s", len(records), self.data.root)
        self._dirty = True

    # ------------------------------------------------------------------ status and API
    def _publish_status(self) -> None:
        rows = [status.vehicle_row(k, r, self.data.turtle_path(r), self.states.get(k), self.ready.get(k))
                for k, r in sorted(self.records.items())]
        self.snapshot = rows
        status.write(self.data.root / "status.json", {
            "updated": now_iso(),
            "manager": {"pid": os.getpid(), "api": self.api_url, "mqtt": "%s:%d" % self.config.mqtt,
                        "connected": self.link.connected.is_set(), "dropped": self.link.dropped},
            "vehicles": rows, "lastReconcile": self.last_report, "refused": self.data.refused_list(),
            "refusedMessages": list(self.refused_messages), "orders": list(self.orders),
        })
        self._dirty = False

    def _require_loaded(self) -> None:
        if not self.loaded:
            raise ApiError(503, "NotReady", "the fleet manager is loading its vehicle records (it has just "
                                            "started); ask again in a moment")

    def vehicles(self) -> list[dict[str, Any]]:
        self._require_loaded()
        return list(self.snapshot)

    def _vehicle_row(self, body: Any, what: str) -> dict[str, Any]:
        """The one ONLINE VDA 5050 vehicle a request names by serial (and manufacturer)."""
        self._require_loaded()
        if not isinstance(body, dict):
            raise ApiError(400, "BadRequest", f"the body is a JSON object {{serial, ...}}, got {type(body).__name__}")
        serial, manufacturer = body.get("serial"), body.get("manufacturer")
        if not isinstance(serial, str) or not serial:
            raise ApiError(400, "BadRequest", f"serial: expected a non-empty string, got {serial!r}"[:300])
        rows = [v for v in self.snapshot if v["serial"] == serial
                and (manufacturer is None or manufacturer in (v["manufacturer"], v["topicManufacturer"]))]
        if not rows:
            raise ApiError(404, "NotFound", f"no discovered vehicle with serial {serial!r}")
        if len(rows) > 1:
            raise ApiError(409, "Conflict", f"serial {serial!r} names {len(rows)} vehicles: give manufacturer")
        row = rows[0]
        if row["interface"] != Interface.VDA5050.value:
            raise ApiError(409, "Conflict", f"{row['vehicle']} speaks {row['interface']}, not VDA 5050 {what}")
        if row["connectionState"] != "ONLINE":
            raise ApiError(409, "Conflict", f"{row['vehicle']} is unavailable ({row['connectionState']})")
        return row

    def send_instant_action(self, body: Any) -> dict[str, Any]:
        try:
            request = instant.parse(body)
        except instant.InstantActionError as exc:
            raise ApiError(400, "BadRequest", exc.message) from None
        row = self._vehicle_row(body, "instant actions")
        try:
            action_id = self.link.instant_action(row["topicManufacturer"], request.serial, request.action_type,
                                                 request.parameters)
        except SchemaError as exc:
            raise ApiError(400, "BadRequest", f"actionParameters: {exc.message}") from None
        log.info("instant action %s (%s) sent to %s", request.action_type, action_id, row["vehicle"])
        return {"actionId": action_id, "actionType": request.action_type, "vehicle": row["vehicle"],
                "topic": topics.topic(row["topicManufacturer"], request.serial, "instantActions")}

    def request_reconcile(self) -> None:
        self.force = True

    def send_order(self, body: Any) -> dict[str, Any]:
        row = self._vehicle_row(body, "orders")
        serial = row["serial"]
        nodes = body.get("nodes")
        if not isinstance(nodes, list):
            raise ApiError(400, "BadRequest", f"nodes: expected a list, got {type(nodes).__name__}")
        order_id = body.get("orderId") or self.link.next_id("order")
        try:
            if not isinstance(order_id, str):
                raise OrderError(f"orderId: expected a string, got {order_id!r}"[:300])
            specs = [NodeSpec.from_json(n, i) for i, n in enumerate(nodes)]
            order = build_order(order_id, specs)
            m = row["topicManufacturer"]
            wire = order_json(order, self.link.header(m, serial, "order"))
            topic = topics.topic(m, serial, "order")
        except (OrderError, TopicError) as exc:
            raise ApiError(400, "BadRequest", exc.message) from None
        self.link.publish(topic, wire, "order")
        self.orders.append({"at": now_iso(), "vehicle": row["vehicle"], "orderId": order_id})
        self._dirty = True
        log.info("order %s sent to %s (%d nodes)", order_id, row["vehicle"], len(specs))
        return {"orderId": order_id, "topic": topic, "vehicle": row["vehicle"]}

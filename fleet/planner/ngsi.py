"""Tasks as NGSI-v2 entities on the context broker (``urn:ngsi-ld:Task:<id>``, type ``Task``),
written over HTTP so the HMI and any NGSI client (FiLiP, curl, a real Orion) see them.

:class:`TaskPublisher` keeps the latest entity of each changed task and a thread of its own sends
them with ``POST /v2/op/update`` (``actionType: append``: create or update the attributes), so a
slow or absent context broker never holds up the planner; a failed write is retried (every
``retry`` seconds) with the latest state, and nothing older ever overwrites something newer. The
write token is the context broker's (its agent's token file), sent as ``Authorization: Bearer``;
an ``https://`` context broker is verified with ``context`` (fleet/planner/ngsi_tls.py).
"""

from __future__ import annotations

import json
import logging
import ssl
import threading
import urllib.error
import urllib.request
from typing import Any

from fleet.planner.model import Task
from fleet.planner.ngsi_tls import unreachable

log = logging.getLogger("fleet.planner")
ENTITY_TYPE = "Task"
#: NGSI-v2 refuses ``< > " ' = ; ( )`` in any string of a value (Orion's "General syntax
#: restrictions"); the texts of a Task entity have them replaced (brackets for parentheses, ...).
NGSI_SAFE = str.maketrans({"'": "`", '"': "`", "(": "[", ")": "]", "<": "lt ", ">": "gt ", "=": ":", ";": ","})


def safe(value: Any) -> Any:
    """``value`` with every string in it free of the characters NGSI-v2 refuses."""
    if isinstance(value, str):
        return value.replace(" = ", " is ").translate(NGSI_SAFE)
    if isinstance(value, list):
        return [safe(v) for v in value]
    if isinstance(value, dict):
        return {k: safe(v) for k, v in value.items()}
    return value


def entity_id(task_id: str) -> str:
    return f"urn:ngsi-ld:{ENTITY_TYPE}:{task_id}"


def entity(task: Task) -> dict[str, Any]:
    """The task as a normalized NGSI-v2 entity."""
    leg = task.current
    step = (f"{leg.index}: {leg.station} [{', '.join(leg.actions)}] {leg.state.value}"
            if leg is not None else "all sub-tasks done")

    def text(value: str) -> dict[str, Any]:
        return {"type": "Text", "value": safe(value)}

    return {
        "id": entity_id(task.id), "type": ENTITY_TYPE,
        "state": text(task.state.value), "vehicle": text(task.vehicle), "step": text(step),
        "stepIndex": {"type": "Integer", "value": leg.index if leg is not None else len(task.legs)},
        "job": text(task.job), "lotlanTask": text(task.lotlan_task), "purpose": text(task.purpose),
        "run": {"type": "Integer", "value": task.run}, "reason": text(task.reason[:500]),
        "legs": {"type": "StructuredValue", "value": safe([
            {"index": g.index, "station": g.station, "actions": list(g.actions), "state": g.state.value,
             "vehicle": g.vehicle, "orderId": g.order_id} for g in task.legs])},
        "dateModified": {"type": "DateTime", "value": task.updated or task.created},
    }


class TaskPublisher:
    def __init__(self, url: str, token: str | None, timeout: float = 5.0, retry: float = 1.0, *,
                 context: ssl.SSLContext | None = None) -> None:
        self.url = url.rstrip("/")
        self.token, self.context = token, context
        self.timeout, self.retry = timeout, retry
        self._latest: dict[str, dict[str, Any]] = {}
        self._cond = threading.Condition()
        self._stop = False
        self.written = 0
        self.failures = 0
        self._thread = threading.Thread(target=self._run, name="planner-ngsi", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def publish(self, task: Task) -> None:
        with self._cond:
            self._latest[task.id] = entity(task)
            self._cond.notify()

    def pending(self) -> int:
        with self._cond:
            return len(self._latest)

    def stop(self, flush_seconds: float = 3.0) -> None:
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join(flush_seconds)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._latest and not self._stop:
                    self._cond.wait()
                if not self._latest and self._stop:
                    return
                batch, self._latest = self._latest, {}
            if self._send(list(batch.values())):
                self.written += len(batch)
                continue
            self.failures += 1
            with self._cond:
                for key, value in batch.items():  # keep the newest: a later publish wins
                    self._latest.setdefault(key, value)
                if self._stop:
                    return
                self._cond.wait(self.retry)

    def _send(self, entities: list[dict[str, Any]]) -> bool:
        body = json.dumps({"actionType": "append", "entities": entities}).encode("utf-8")
        headers = {"Content-Type": "application/json"}
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        request = urllib.request.Request(self.url + "/v2/op/update", data=body, method="POST", headers=headers)
        try:
            with urllib.request.urlopen(request, timeout=self.timeout, context=self.context) as reply:
                reply.read()
            return True
        except urllib.error.HTTPError as exc:
            log.warning("context broker refused %d Task entities: %s %s", len(entities), exc.code,
                        exc.read()[:300].decode("utf-8", "replace"))
        except (urllib.error.URLError, OSError) as exc:
            log.warning("%s; retrying the Task entities", unreachable(self.url, exc))
        return False

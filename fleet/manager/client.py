"""Python client of a running fleet manager (its HTTP API, found through the data directory).

    client = ManagerClient.for_data_dir(Path("fleet-data"))
    client.order("agv-42", [NodeSpec("n0", 0, 0, "hall-1"), NodeSpec("n1", 1, 0, "hall-1", ("pick",))])
    client.vehicle("agv-42")["state"]["lastNodeId"]

Errors: :class:`ManagerUnreachableError` (no manager runs, or it does not answer) and
:class:`ManagerRefusedError` (the API said no: status and description; 503 ``NotReady``: the
manager has just started and is reading its records, ask again).
"""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fleet.discovery.errors import DiscoveryError
from fleet.manager.orders import NodeSpec


class ManagerUnreachableError(DiscoveryError):
    """No fleet manager answers for this data directory."""


class ManagerRefusedError(DiscoveryError):
    """The fleet manager answered with an error status."""

    def __init__(self, status: int, description: str) -> None:
        super().__init__(f"the fleet manager refused: {status} {description}")
        self.status = status
        self.description = description


@dataclass(frozen=True)
class ManagerClient:
    url: str
    token: str
    timeout: float = 10.0

    @classmethod
    def for_data_dir(cls, data_dir: Path) -> ManagerClient:
        try:
            where = json.loads((data_dir / "manager.json").read_text(encoding="utf-8"))
            token = (data_dir / "manager.token").read_text(encoding="utf-8").strip()
        except (OSError, ValueError):
            raise ManagerUnreachableError(
                f"no fleet manager runs for {data_dir} (no manager.json)",
                hint="start it: plantkg fleet manager PLANT.ttl --data-dir DIR") from None
        return cls(str(where["url"]), token)

    def call(self, method: str, path: str, body: Any = None) -> Any:
        data = json.dumps(body).encode("utf-8") if body is not None else None
        request = urllib.request.Request(self.url + path, data=data, method=method,
                                         headers={"Authorization": f"Bearer {self.token}",
                                                  "Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=self.timeout) as reply:
                return json.loads(reply.read())
        except urllib.error.HTTPError as exc:
            try:
                detail = json.loads(exc.read()).get("description")
            except ValueError:
                detail = exc.reason
            raise ManagerRefusedError(exc.code, str(detail)) from None
        except (urllib.error.URLError, OSError) as exc:
            raise ManagerUnreachableError(f"the fleet manager at {self.url} does not answer: {exc}",
                                          hint="is it running? (plantkg fleet manager ...)") from None

    def vehicles(self) -> list[dict[str, Any]]:
        return self.call("GET", "/v1/vehicles")

    def vehicle(self, serial: str) -> dict[str, Any]:
        return self.call("GET", f"/v1/vehicles/{serial}")

    def order(self, serial: str, nodes: list[NodeSpec], *, manufacturer: str | None = None,
              order_id: str | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"serial": serial, "nodes": [n.to_json() for n in nodes]}
        if manufacturer:
            body["manufacturer"] = manufacturer
        if order_id:
            body["orderId"] = order_id
        return self.call("POST", "/v1/orders", body)

    def instant_action(self, serial: str, action_type: str, *, manufacturer: str | None = None,
                       parameters: dict[str, Any] | None = None) -> dict[str, Any]:
        body: dict[str, Any] = {"serial": serial, "actionType": action_type}
        if manufacturer:
            body["manufacturer"] = manufacturer
        if parameters:
            body["actionParameters"] = [{"key": k, "value": v} for k, v in parameters.items()]
        return self.call("POST", "/v1/instantActions", body)

    def reconcile(self) -> None:
        self.call("POST", "/v1/reconcile", {})

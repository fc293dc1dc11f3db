"""What the fleet manager reads from the plant at start: the fleet binding and its MQTT broker's address."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import pyoxigraph as ox

from fleet.discovery import model_api
from fleet.discovery.errors import DiscoveryError
from kg.load import load_plant
from kg.query import run_query

_ADDRESS = "SELECT ?ip ?port WHERE { ?broker pk:ip ?ip ; pk:port ?port }"


def broker_address(files: Iterable[Path | str], broker_iri: str) -> tuple[str, int]:
    """``(ip, port)`` of the broker ``broker_iri`` as the plant describes it."""
    result = run_query(load_plant(list(files)), _ADDRESS, {"broker": ox.NamedNode(broker_iri)})
    if not result.rows or result.rows[0][0] is None or result.rows[0][1] is None:
        raise DiscoveryError(f"broker <{broker_iri}> has no pk:ip and pk:port in the plant",
                             hint="give the fleet manager's MQTT broker pk:ip and pk:port")
    ip, port = result.rows[0]
    return str(ip.value), int(port.value)  # type: ignore[union-attr]


def binding_and_address(files: list[Path]) -> tuple[dict[str, object], tuple[str, int]]:
    binding = model_api.plant_binding(files)
    return model_api.binding_to_json(binding), broker_address(files, str(binding.mqtt_broker_iri))

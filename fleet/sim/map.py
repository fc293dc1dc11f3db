"""A rectangular map with named stations (x, y, theta, mapId), some of them chargers.

A map file is JSON::

    {"mapId": "hall-1", "width": 40, "height": 20,
     "stations": [{"name": "charger-1", "x": 1, "y": 1, "theta": 0, "charger": true}, ...]}

Coordinates are metres from the map's lower left corner; every station must lie inside the
rectangle. ``default_map()`` is a 40 m x 20 m hall with 4 chargers, 8 pick/drop stations and
50 parking spots (so 50 vehicles start on distinct spots).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kg.errors import PlantKGError
from fleet.vda5050.topics import check_level


class MapError(PlantKGError):
    """A map file that cannot be used; says which field of which station."""


@dataclass(frozen=True)
class Station:
    name: str
    x: float
    y: float
    theta: float = 0.0
    charger: bool = False


@dataclass(frozen=True)
class SiteMap:
    map_id: str
    width: float
    height: float
    stations: tuple[Station, ...]

    def __post_init__(self) -> None:
        names = [s.name for s in self.stations]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise MapError(f"map {self.map_id!r}: station names must be unique, repeated: {', '.join(dup)}")
        for s in self.stations:
            if not (0 <= s.x <= self.width and 0 <= s.y <= self.height):
                raise MapError(f"map {self.map_id!r}: station {s.name!r} at ({s.x}, {s.y}) lies outside "
                               f"the {self.width} x {self.height} m rectangle")

    def station(self, name: str) -> Station:
        for s in self.stations:
            if s.name == name:
                return s
        raise MapError(f"map {self.map_id!r} has no station {name!r}")

    def contains(self, x: float, y: float) -> bool:
        return 0 <= x <= self.width and 0 <= y <= self.height

    def charger_at(self, x: float, y: float, tolerance: float = 0.25) -> Station | None:
        for s in self.stations:
            if s.charger and math.hypot(s.x - x, s.y - y) <= tolerance:
                return s
        return None

    def parking(self) -> tuple[Station, ...]:
        """Where vehicles start: stations named ``park-*`` (all stations if there are none)."""
        spots = tuple(s for s in self.stations if s.name.startswith("park-"))
        return spots or self.stations


def _number(where: str, data: dict[str, Any], key: str, default: float | None = None) -> float:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MapError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def from_json(data: Any, source: str = "map") -> SiteMap:
    if not isinstance(data, dict):
        raise MapError(f"{source}: a map is a JSON object with mapId, width, height, stations")
    map_id = data.get("mapId")
    if not isinstance(map_id, str):
        raise MapError(f"{source}: mapId must be a string, got {map_id!r}")
    check_level("mapId", map_id)
    width, height = _number(source, data, "width"), _number(source, data, "height")
    if width <= 0 or height <= 0:
        raise MapError(f"{source}: width and height must be > 0, got {width} x {height}")
    raw = data.get("stations")
    if not isinstance(raw, list) or not raw:
        raise MapError(f"{source}: stations must be a non-empty list")
    stations = []
    for i, item in enumerate(raw):
        where = f"{source}: stations[{i}]"
        if not isinstance(item, dict) or not isinstance(item.get("name"), str) or not item["name"]:
            raise MapError(f"{where}: needs a non-empty string name")
        charger = item.get("charger", False)
        if not isinstance(charger, bool):
            raise MapError(f"{where}: charger must be true or false, got {charger!r}")
        stations.append(Station(item["name"], _number(where, item, "x"), _number(where, item, "y"),
                                _number(where, item, "theta", 0.0), charger))
    return SiteMap(map_id, width, height, tuple(stations))


def load(path: Path) -> SiteMap:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MapError(f"{path}: cannot read the map: {exc.strerror}") from None
    except ValueError as exc:
        raise MapError(f"{path}: not JSON: {exc}") from None
    return from_json(data, str(path))


def default_map() -> SiteMap:
    stations = [Station(f"charger-{i + 1}", 2.0 + 4.0 * i, 1.0, math.pi / 2, True) for i in range(4)]
    stations += [Station(f"pick-{i + 1}", 6.0 + 8.0 * i, 18.0, math.pi / 2) for i in range(4)]
    stations += [Station(f"drop-{i + 1}", 38.0, 4.0 + 4.0 * i, 0.0) for i in range(4)]
    stations += [Station(f"park-{i + 1}", 20.0 + 1.5 * (i % 10), 4.0 + 2.0 * (i // 10), 0.0) for i in range(50)]
    return SiteMap("hall-1", 40.0, 20.0, tuple(stations))

"""The plant graph the assignment query runs on: the plant's files and the fleet manager's
``discovered/*.ttl`` (vehicles written by plug and play), loaded again whenever a discovered file
appears, changes or goes. A file that cannot be loaded keeps the last good graph (logged)."""

from __future__ import annotations

import logging
from pathlib import Path

import pyoxigraph as ox

from kg.errors import PlantKGError
from kg.load import load_plant

log = logging.getLogger("fleet.planner")


class PlantView:
    def __init__(self, plant_files: tuple[Path, ...], discovered: Path | None) -> None:
        self.plant_files = plant_files
        self.discovered = discovered
        self._fingerprint: tuple[object, ...] | None = None
        self.store: ox.Store | None = None
        self.loads = 0

    def _files(self) -> list[Path]:
        found = sorted(self.discovered.glob("*.ttl")) if self.discovered and self.discovered.is_dir() else []
        return [*self.plant_files, *found]

    def current(self) -> ox.Store:
        files = self._files()
        fingerprint = tuple((str(p), p.stat().st_mtime_ns, p.stat().st_size) for p in files if p.exists())
        if self.store is None or fingerprint != self._fingerprint:
            try:
                self.store = load_plant(files).store
                self.loads += 1
                log.info("plant graph loaded: %d file(s)", len(files))
            except PlantKGError as exc:
                if self.store is None:
                    raise
                log.warning("plant graph not reloaded, keeping the last one: %s", exc)
            self._fingerprint = fingerprint
        return self.store

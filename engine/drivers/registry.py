"""Drivers by broker kind, loaded from the entry-point group ``plantkg.drivers``.

No import-time global: a caller builds a :class:`DriverRegistry` (usually
:meth:`DriverRegistry.from_entry_points`) and passes it to whoever needs drivers, so tests can
hand in exactly the drivers they want. A driver whose entry point fails to load does not take the
others down: it is left out and its error is kept in :attr:`DriverRegistry.errors` (the agent
reports it on ``/v1/health``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping
from importlib.metadata import entry_points

from engine.drivers.base import Driver
from engine.errors import UnknownDriverError

ENTRY_POINT_GROUP = "plantkg.drivers"

log = logging.getLogger(__name__)


class DriverRegistry:
    """An immutable map kind -> driver instance."""

    def __init__(self, drivers: Iterable[Driver], *, errors: Mapping[str, str] | None = None) -> None:
        by_kind: dict[str, Driver] = {}
        for driver in drivers:
            if not isinstance(driver, Driver):
                raise TypeError(f"{driver!r} does not implement engine.drivers.base.Driver")
            if driver.kind in by_kind:
                raise ValueError(f"two drivers for broker kind {driver.kind!r}")
            by_kind[driver.kind] = driver
        self._drivers = by_kind
        self.errors: dict[str, str] = dict(errors or {})

    @classmethod
    def from_entry_points(cls, group: str = ENTRY_POINT_GROUP) -> DriverRegistry:
        """Instantiate every entry point of ``group`` (name = kind, value = a class or factory
        called with no arguments)."""
        drivers: list[Driver] = []
        errors: dict[str, str] = {}
        for ep in sorted(entry_points(group=group), key=lambda e: e.name):
            try:
                driver = ep.load()()
                if not isinstance(driver, Driver):
                    raise TypeError("does not implement engine.drivers.base.Driver")
                if driver.kind != ep.name:
                    raise ValueError(f"its kind is {driver.kind!r}, not the entry-point name")
            except Exception as exc:  # noqa: BLE001 - a third-party driver may fail in any way
                errors[ep.name] = f"{ep.value}: {type(exc).__name__}: {exc}"
                log.warning("driver %r not loaded: %s", ep.name, errors[ep.name])
                continue
            drivers.append(driver)
        return cls(drivers, errors=errors)

    def get(self, kind: str) -> Driver:
        """The driver of ``kind``; :class:`~engine.errors.UnknownDriverError` if none."""
        try:
            return self._drivers[kind]
        except KeyError:
            raise UnknownDriverError(kind, self.kinds()) from None

    def kinds(self) -> list[str]:
        return sorted(self._drivers)

    def __contains__(self, kind: object) -> bool:
        return kind in self._drivers

    def __repr__(self) -> str:
        return f"DriverRegistry({self.kinds()})"

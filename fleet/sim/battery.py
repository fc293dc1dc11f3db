"""Battery of a simulated vehicle: drains with distance driven and with time, charges at a charger.

Pure and frozen: ``step`` returns the next battery. Charge is in percent (VDA 5050
``batteryState.batteryCharge``); ``reach`` estimates the metres left at the distance rate alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class BatteryModel:
    drain_per_metre: float = 0.05  # % per metre driven
    drain_per_second: float = 0.002  # % per second, whatever the vehicle does (electronics)
    charge_per_second: float = 0.5  # % per second while charging

    def __post_init__(self) -> None:
        for name in ("drain_per_metre", "drain_per_second", "charge_per_second"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"BatteryModel.{name} must be a finite number >= 0, got {value!r}")


@dataclass(frozen=True)
class Battery:
    charge: float = 100.0  # %
    charging: bool = False
    model: BatteryModel = BatteryModel()

    def __post_init__(self) -> None:
        if not (0.0 <= self.charge <= 100.0):
            raise ValueError(f"battery charge must be within 0..100 %, got {self.charge!r}")

    @property
    def empty(self) -> bool:
        return self.charge <= 0.0

    @property
    def reach(self) -> int | None:
        """Metres left at the distance rate (None when driving costs nothing)."""
        if self.model.drain_per_metre == 0:
            return None
        return int(self.charge / self.model.drain_per_metre)

    def step(self, dt: float, distance: float) -> Battery:
        """The battery after ``dt`` seconds in which the vehicle drove ``distance`` metres."""
        if self.charging:
            charge = self.charge + self.model.charge_per_second * dt
        else:
            charge = self.charge - self.model.drain_per_metre * distance - self.model.drain_per_second * dt
        return replace(self, charge=min(100.0, max(0.0, charge)))

    def with_charging(self, charging: bool) -> Battery:
        return replace(self, charging=charging)

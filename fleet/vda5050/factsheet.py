"""The subset of the VDA 5050 2.1 factsheet (section 6.15) the fleet uses, frozen, with from/to JSON.

What a vehicle is (``typeSpecification``), how it moves (``physicalParameters``: speeds,
accelerations, height, footprint), what it understands (``protocolFeatures.agvActions``) and its
timing limits (``protocolLimits.timing``). Our simulator also knows its angular limits; 2.1 has no
field for them, so they travel as the documented extension ``physicalParameters.angularSpeedMax`` /
``angularAccelerationMax`` (the schema allows extra properties; other readers ignore them).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

Json = dict[str, Any]


@dataclass(frozen=True)
class AgvAction:
    action_type: str
    scopes: tuple[str, ...]  # INSTANT, NODE, EDGE
    blocking_types: tuple[str, ...] = ("NONE", "SOFT", "HARD")
    description: str | None = None
    parameters: tuple[str, ...] = ()

    @classmethod
    def from_json(cls, data: Json) -> AgvAction:
        return cls(data["actionType"], tuple(data["actionScopes"]),
                   tuple(data.get("blockingTypes", ("NONE", "SOFT", "HARD"))),
                   data.get("actionDescription"),
                   tuple(p["key"] for p in data.get("actionParameters", ()) if "key" in p))

    def to_json(self) -> Json:
        # No "blockingTypes": the official 2.1 factsheet.json puts its enum on the array instead of
        # on the items, so every non-empty list fails validation (a defect of the schema).
        out: Json = {"actionType": self.action_type, "actionScopes": list(self.scopes)}
        if self.description:
            out["actionDescription"] = self.description
        if self.parameters:
            out["actionParameters"] = [{"key": k, "valueDataType": "FLOAT", "isOptional": True}
                                       for k in self.parameters]
        return out


@dataclass(frozen=True)
class Factsheet:
    series_name: str
    agv_kinematic: str  # DIFF, OMNI, THREEWHEEL
    agv_class: str  # FORKLIFT, CONVEYOR, TUGGER, CARRIER
    max_load_mass: float  # kg
    speed_min: float  # m/s
    speed_max: float
    acceleration_max: float  # m/s²
    deceleration_max: float
    height_max: float  # m
    width: float
    length: float
    agv_actions: tuple[AgvAction, ...]
    min_order_interval: float = 0.0  # s
    min_state_interval: float = 0.0
    default_state_interval: float | None = None
    visualization_interval: float | None = None
    angular_speed_max: float | None = None  # rad/s, extension
    angular_acceleration_max: float | None = None  # rad/s², extension
    localization_types: tuple[str, ...] = ("NATURAL",)
    navigation_types: tuple[str, ...] = ("AUTONOMOUS",)

    def action_types(self) -> frozenset[str]:
        return frozenset(a.action_type for a in self.agv_actions)

    @classmethod
    def from_json(cls, data: Json) -> Factsheet:
        spec, phys = data["typeSpecification"], data["physicalParameters"]
        timing = data["protocolLimits"]["timing"]
        return cls(
            series_name=spec["seriesName"], agv_kinematic=spec["agvKinematic"], agv_class=spec["agvClass"],
            max_load_mass=float(spec["maxLoadMass"]),
            speed_min=float(phys["speedMin"]), speed_max=float(phys["speedMax"]),
            acceleration_max=float(phys["accelerationMax"]), deceleration_max=float(phys["decelerationMax"]),
            height_max=float(phys["heightMax"]), width=float(phys["width"]), length=float(phys["length"]),
            agv_actions=tuple(AgvAction.from_json(a) for a in data["protocolFeatures"]["agvActions"]),
            min_order_interval=float(timing["minOrderInterval"]),
            min_state_interval=float(timing["minStateInterval"]),
            default_state_interval=timing.get("defaultStateInterval"),
            visualization_interval=timing.get("visualizationInterval"),
            angular_speed_max=phys.get("angularSpeedMax"),
            angular_acceleration_max=phys.get("angularAccelerationMax"),
            localization_types=tuple(spec["localizationTypes"]),
            navigation_types=tuple(spec["navigationTypes"]),
        )

    def to_json(self, header: Json) -> Json:
        physical: Json = {
            "speedMin": self.speed_min, "speedMax": self.speed_max,
            "accelerationMax": self.acceleration_max, "decelerationMax": self.deceleration_max,
            "heightMax": self.height_max, "width": self.width, "length": self.length,
        }
        if self.angular_speed_max is not None:
            physical["angularSpeedMax"] = self.angular_speed_max
        if self.angular_acceleration_max is not None:
            physical["angularAccelerationMax"] = self.angular_acceleration_max
        timing: Json = {"minOrderInterval": self.min_order_interval, "minStateInterval": self.min_state_interval}
        if self.default_state_interval is not None:
            timing["defaultStateInterval"] = self.default_state_interval
        if self.visualization_interval is not None:
            timing["visualizationInterval"] = self.visualization_interval
        half_w, half_l = self.width / 2, self.length / 2
        return {
            **header,
            "typeSpecification": {
                "seriesName": self.series_name, "agvKinematic": self.agv_kinematic,
                "agvClass": self.agv_class, "maxLoadMass": self.max_load_mass,
                "localizationTypes": list(self.localization_types),
                "navigationTypes": list(self.navigation_types),
            },
            "physicalParameters": physical,
            "protocolLimits": {"maxStringLens": {}, "maxArrayLens": {}, "timing": timing},
            "protocolFeatures": {
                "optionalParameters": [],
                "agvActions": [a.to_json() for a in self.agv_actions],
            },
            "agvGeometry": {
                "envelopes2d": [{"set": "footprint", "polygonPoints": [
                    {"x": half_l, "y": half_w}, {"x": -half_l, "y": half_w},
                    {"x": -half_l, "y": -half_w}, {"x": half_l, "y": -half_w}]}],
            },
            "loadSpecification": {"loadPositions": ["top"]},
        }

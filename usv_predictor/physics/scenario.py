"""Scenarios: a vessel, a sea and the hidden effects, in the diagnosis vocabulary of DESIGN.md.

Effect names and their parameters (units in the name, directions as compass degrees):
  none
  current         current_speed (m/s), current_to_deg (flows TOWARD), current_turn_rate_deg_s
  wind            wind_speed (m/s), wind_from_deg (blows FROM), gust_std (m/s)
  wave_drift      wave_height (m, H_s), wave_from_deg, wave_period_s
  rudder_offset   rudder_offset_deg (true rudder = reported + offset)
  yaw_rate_bias   yaw_rate_bias_deg_s (gyro bias)
  heading_offset  heading_offset_deg (compass misalignment, reported = true + offset)
  actuator_delay  actuator_delay_s (the hull responds this long after the reported rudder/rpm)
  propeller_asymmetry  propeller_side_force_pct (transverse propeller force in % of thrust, + to starboard)
"""
from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field, replace
from typing import Mapping

from usv_predictor.errors import ConfigError
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.sensors import SensorSpec
from usv_predictor.physics.simulator import ActuatorFaults


@dataclass(frozen=True)
class EffectParameter:
    name: str
    default: float
    low: float
    high: float
    unit: str
    help: str

    @property
    def flag(self) -> str:
        """The `replay simulate` option that sets it: current_to_deg -> --current-to."""
        name = self.name.removesuffix("_deg").removesuffix("_deg_s").removesuffix("_s")
        return "--" + name.replace("_", "-")


EFFECTS: dict[str, tuple[EffectParameter, ...]] = {
    "none": (),
    "current": (
        EffectParameter("current_speed", 0.3, 0.0, 3.0, "m/s", "current speed"),
        EffectParameter("current_to_deg", 90.0, 0.0, 360.0, "deg", "direction the current flows toward"),
        EffectParameter("current_turn_rate_deg_s", 0.0, -0.5, 0.5, "deg/s", "slow turning of the current"),
    ),
    "wind": (
        EffectParameter("wind_speed", 8.0, 0.0, 30.0, "m/s", "mean true wind speed"),
        EffectParameter("wind_from_deg", 0.0, 0.0, 360.0, "deg", "direction the wind blows from"),
        EffectParameter("gust_std", 1.0, 0.0, 10.0, "m/s", "gust standard deviation"),
    ),
    "wave_drift": (
        EffectParameter("wave_height", 0.5, 0.0, 4.0, "m", "significant wave height"),
        EffectParameter("wave_from_deg", 0.0, 0.0, 360.0, "deg", "direction the waves come from"),
        EffectParameter("wave_period_s", 3.0, 1.0, 15.0, "s", "peak period"),
    ),
    "rudder_offset": (EffectParameter("rudder_offset_deg", 2.0, -10.0, 10.0, "deg", "true minus reported rudder"),),
    "yaw_rate_bias": (EffectParameter("yaw_rate_bias_deg_s", 0.5, -5.0, 5.0, "deg/s", "gyro bias"),),
    "heading_offset": (EffectParameter("heading_offset_deg", 3.0, -30.0, 30.0, "deg", "compass misalignment"),),
    "actuator_delay": (EffectParameter("actuator_delay_s", 0.5, 0.0, 5.0, "s", "response delay of the hull"),),
    "propeller_asymmetry": (EffectParameter("propeller_side_force_pct", 3.0, -20.0, 20.0, "%",
                                            "transverse propeller force in % of thrust, + to starboard"),),
}

# The sea of seed 000's trial day (Table 2: sea state 2, H 0.5 m, wind 4.5 m/s from the south-east) with a
# tidal current of the size that reproduces Table 4's 5-13 m drift per circle.
RIZHAO_SEA = {
    "current": {"current_speed": 0.35, "current_to_deg": 215.0, "current_turn_rate_deg_s": 0.002},
    "wind": {"wind_speed": 4.5, "wind_from_deg": 135.0, "gust_std": 0.8},
    "wave_drift": {"wave_height": 0.5, "wave_from_deg": 140.0, "wave_period_s": 3.0},
}


@dataclass(frozen=True)
class Scenario:
    """Everything that shapes a simulated recording except the manoeuvre and the seed."""

    vessel: str = "jari_usv"
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    sensors: SensorSpec = field(default_factory=SensorSpec)

    @property
    def environment(self) -> Environment:
        values: dict[str, float] = {}
        for name in ("current", "wind", "wave_drift"):
            for key, value in self.effects.get(name, {}).items():
                values[key] = value
        return Environment(**values)

    @property
    def faults(self) -> ActuatorFaults:
        offset = self.effects.get("rudder_offset", {}).get("rudder_offset_deg", 0.0)
        side = self.effects.get("propeller_asymmetry", {}).get("propeller_side_force_pct", 0.0)
        return ActuatorFaults(rudder_offset_rad=math.radians(offset), propeller_side_force=side / 100.0)

    @property
    def sensor_spec(self) -> SensorSpec:
        e = self.effects
        return replace(
            self.sensors,
            gyro_bias=math.radians(e.get("yaw_rate_bias", {}).get("yaw_rate_bias_deg_s", 0.0)),
            heading_offset=math.radians(e.get("heading_offset", {}).get("heading_offset_deg", 0.0)),
            actuator_delay_s=e.get("actuator_delay", {}).get("actuator_delay_s", 0.0),
        )

    def calm_twin(self) -> "Scenario":
        """Same vessel, sensors and faults; no current, wind or waves."""
        return replace(self, effects={k: v for k, v in self.effects.items() if k not in ("current", "wind", "wave_drift")})

    def describe(self) -> dict:
        return {"vessel": self.vessel, "effects": {k: dict(v) for k, v in self.effects.items()},
                "sensors": asdict(self.sensors)}

    def digest(self) -> str:
        """SHA-256 of the description: lets a blind bag prove what made it without saying it."""
        return hashlib.sha256(json.dumps(self.describe(), sort_keys=True).encode()).hexdigest()


def effect_parameters(name: str, given: Mapping[str, float]) -> dict[str, float]:
    """Validated parameters of one effect: defaults filled in, ranges checked, unknown names refused."""
    if name not in EFFECTS:
        raise ConfigError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    spec = {p.name: p for p in EFFECTS[name]}
    unknown = sorted(set(given) - set(spec))
    if unknown:
        raise ConfigError(f"effect {name!r} has no parameter(s) {unknown}; it takes {sorted(spec)}")
    values = {}
    for p in EFFECTS[name]:
        value = float(given.get(p.name, p.default))
        if not (p.low <= value <= p.high) or not math.isfinite(value):
            raise ConfigError(f"{name}: {p.name}={value} {p.unit} is outside the allowed range [{p.low}, {p.high}]")
        values[p.name] = value
    return values


def make_scenario(vessel: str, effects: Mapping[str, Mapping[str, float]], sensors: SensorSpec | None = None) -> Scenario:
    checked = {name: effect_parameters(name, params) for name, params in effects.items() if name != "none"}
    return Scenario(vessel=vessel, effects=checked, sensors=sensors or SensorSpec())

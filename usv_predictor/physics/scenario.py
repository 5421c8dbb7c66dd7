"""Scenarios: a vessel, a sea and the hidden effects, in the diagnosis vocabulary of DESIGN.md.

The effects, their parameters and how each reaches the simulator (Environment, ActuatorFaults or SensorSpec)
are the records of usv_predictor.physics.effects; a Scenario applies them generically.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Mapping, TypeVar

from usv_predictor.config import Range
from usv_predictor.errors import ConfigError
from usv_predictor.physics import effects as fx
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, actuator_layout
from usv_predictor.physics.effects import EffectParameter
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.sensors import SensorSpec
from usv_predictor.physics.simulator import ActuatorFaults

if TYPE_CHECKING:
    from usv_predictor.physics.vessel import Vessel

__all__ = ["EFFECTS", "RIZHAO_SEA", "EffectParameter", "Scenario", "effect_parameters", "make_scenario"]

# The effects the simulator can make and their parameters, `none` first (derived from the records).
EFFECTS: Mapping[str, tuple[EffectParameter, ...]] = fx.RegistryView(
    lambda: {fx.NONE: (), **{name: effect.parameters for name, effect in fx.simulated().items()}})

# The sea of seed 000's trial day (Table 2: sea state 2, H 0.5 m, wind 4.5 m/s from the south-east) with a
# tidal current of the size that reproduces Table 4's 5-13 m drift per circle.
RIZHAO_SEA = {
    "current": {"current_speed": 0.35, "current_to_deg": 215.0, "current_turn_rate_deg_s": 0.002},
    "wind": {"wind_speed": 4.5, "wind_from_deg": 135.0, "gust_std": 0.8},
    "wave_drift": {"wave_height": 0.5, "wave_from_deg": 140.0, "wave_period_s": 3.0},
}

T = TypeVar("T", Environment, ActuatorFaults, SensorSpec)


@dataclass(frozen=True)
class Scenario:
    """Everything that shapes a simulated recording except the manoeuvre and the seed."""

    vessel: str = "jari_usv"  # the vessel as the bags record it: a preset name or the vessel file given
    layout: str = DEFAULT_LAYOUT.name  # its actuator layout (physics/actuators.py)
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    sensors: SensorSpec = field(default_factory=SensorSpec)

    def _applied(self, base: T) -> T:
        """`base` with every field an effect parameter sets: the chosen effect's value (converted as its record
        says), or the field's default when that effect or parameter is not chosen."""
        values = fx.governed_defaults(type(base))
        for name, effect in fx.simulated().items():
            given = self.effects.get(name, {})
            for p in effect.parameters:
                if p.sets.target is type(base) and p.name in given:
                    values[p.sets.name] = p.sets.value(given[p.name])
        return replace(base, **values)

    @property
    def environment(self) -> Environment:
        return self._applied(Environment())

    @property
    def faults(self) -> ActuatorFaults:
        return self._applied(ActuatorFaults())

    @property
    def sensor_spec(self) -> SensorSpec:
        return self._applied(self.sensors)

    def calm_twin(self) -> "Scenario":
        """Same vessel, sensors and faults; no current, wind or waves (no effect that sets the Environment)."""
        sea = {name for name, effect in fx.simulated().items() if effect.acts_on(Environment)}
        return replace(self, effects={k: v for k, v in self.effects.items() if k not in sea})

    def describe(self) -> dict:
        """Vessel, effects and the sensor parameters that shape a recording of this vessel (SensorSpec.describe)."""
        return {"vessel": self.vessel, "effects": {k: dict(v) for k, v in self.effects.items()},
                "sensors": self.sensors.describe(actuator_layout(self.layout))}

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
        values[p.name] = Range(p.low, p.high, p.unit).check(p.name, float(given.get(p.name, p.default)), name)
    return values


def make_scenario(vessel: Vessel, effects: Mapping[str, Mapping[str, float]], sensors: SensorSpec | None = None,
                  label: str | None = None) -> Scenario:
    """A checked scenario of a resolved vessel: every effect known, applicable to the vessel's actuator layout, its
    parameters in range. label: how the bags name the vessel (the preset or the file a command was given; None: its
    name)."""
    layout = vessel.actuator_layout
    name = label if label is not None else vessel.name
    for effect_name in effects:
        effect = fx.EFFECTS.get(effect_name)
        if effect is not None and not effect.applies_to(layout.name):
            raise ConfigError(f"effect {effect_name!r} does not apply to vessel {name} (actuator layout "
                              f"{layout.name}); it applies to {', '.join(effect.layouts or ())}")
    checked = {key: effect_parameters(key, params) for key, params in effects.items() if key != fx.NONE}
    return Scenario(vessel=name, layout=layout.name, effects=checked, sensors=sensors or SensorSpec())

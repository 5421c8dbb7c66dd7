"""Random hidden effects for the diagnosis acceptance tests and the confusion-matrix benchmark.

draw(rng) picks one effect of the DESIGN.md vocabulary (or `none`) and its parameters from ranges a trial would
meet; tolerance(effect, truth, estimate) says whether a diagnosis got the parameters right. The ranges and
tolerances are the contract the README reports against.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

EFFECTS = ("none", "current", "wind", "wave_drift", "rudder_offset", "yaw_rate_bias", "heading_offset", "actuator_delay",
           "propeller_asymmetry")


@dataclass(frozen=True)
class Draw:
    effect: str
    parameters: dict[str, float]  # `replay simulate` effect parameters (scenario.EFFECTS names)

    def cli_flags(self) -> list[str]:
        """The `replay simulate` flags that create this effect."""
        if self.effect == "none":
            return []
        from usv_predictor.physics.scenario import EFFECTS as SIMULATOR_EFFECTS

        flag = {p.name: p.flag for p in SIMULATOR_EFFECTS[self.effect]}
        flags = ["--effect", self.effect]
        for name, value in self.parameters.items():
            flags += [flag[name], f"{value:.6g}"]
        return flags


def draw(rng: np.random.Generator, effect: str | None = None) -> Draw:
    """One effect (uniformly among EFFECTS unless given) with parameters drawn from trial-like ranges."""
    effect = effect or str(rng.choice(EFFECTS))
    sign = float(rng.choice([-1.0, 1.0]))
    if effect == "current":
        p = {"current_speed": rng.uniform(0.1, 0.6), "current_to_deg": rng.uniform(0.0, 360.0)}
    elif effect == "wind":
        p = {"wind_speed": rng.uniform(5.0, 15.0), "wind_from_deg": rng.uniform(0.0, 360.0), "gust_std": 1.0}
    elif effect == "wave_drift":
        p = {"wave_height": rng.uniform(0.8, 1.5), "wave_from_deg": rng.uniform(0.0, 360.0), "wave_period_s": 3.0}
    elif effect == "rudder_offset":
        p = {"rudder_offset_deg": sign * rng.uniform(1.0, 4.0)}
    elif effect == "yaw_rate_bias":
        p = {"yaw_rate_bias_deg_s": sign * rng.uniform(0.2, 1.0)}
    elif effect == "heading_offset":
        p = {"heading_offset_deg": sign * rng.uniform(2.0, 8.0)}
    elif effect == "actuator_delay":
        p = {"actuator_delay_s": rng.uniform(0.3, 1.5)}
    elif effect == "propeller_asymmetry":
        p = {"propeller_side_force_pct": sign * rng.uniform(2.0, 6.0)}
    elif effect == "none":
        p = {}
    else:
        raise ValueError(f"unknown effect {effect!r}; known: {EFFECTS}")
    return Draw(effect, {k: round(float(v), 4) for k, v in p.items()})


def _angle_error(a: float, b: float) -> float:
    return abs((a - b + 180.0) % 360.0 - 180.0)


def parameter_errors(truth: Draw, found: dict[str, float]) -> dict[str, float]:
    """Estimate minus truth, per physical parameter of the diagnosis vocabulary."""
    p = truth.parameters
    if truth.effect == "current":
        return {"speed_mps": found["speed_mps"] - p["current_speed"],
                "direction_deg": _angle_error(found["direction_to_deg"], p["current_to_deg"])}
    if truth.effect == "wind":
        return {"speed_mps": found["speed_mps"] - p["wind_speed"],
                "direction_deg": _angle_error(found["direction_from_deg"], p["wind_from_deg"])}
    if truth.effect == "wave_drift":
        return {"significant_height_m": found["significant_height_m"] - p["wave_height"],
                "direction_deg": _angle_error(found["direction_from_deg"], p["wave_from_deg"])}
    key = {"rudder_offset": ("offset_deg", "rudder_offset_deg"), "yaw_rate_bias": ("bias_deg_s", "yaw_rate_bias_deg_s"),
           "heading_offset": ("offset_deg", "heading_offset_deg"), "actuator_delay": ("delay_s", "actuator_delay_s"),
           "propeller_asymmetry": ("side_force_pct", "propeller_side_force_pct")}
    if truth.effect in key:
        out, given = key[truth.effect]
        return {out: found[out] - p[given]}
    return {}


# Stated tolerances of the acceptance suite (absolute errors).
TOLERANCES = {
    "current": {"speed_mps": 0.05, "direction_deg": 10.0},
    "wind": {"speed_mps": 2.0, "direction_deg": 20.0},
    "wave_drift": {"significant_height_m": 0.4, "direction_deg": 30.0},
    "rudder_offset": {"offset_deg": 0.5},
    "yaw_rate_bias": {"bias_deg_s": 0.1},
    "heading_offset": {"offset_deg": 1.0},
    "actuator_delay": {"delay_s": 0.2},
    "propeller_asymmetry": {"side_force_pct": 0.5},
    "none": {},
}


def within_tolerance(truth: Draw, found: dict[str, float]) -> tuple[bool, dict[str, float]]:
    errors = parameter_errors(truth, found)
    ok = all(abs(errors[k]) <= tol for k, tol in TOLERANCES[truth.effect].items())
    return ok and all(math.isfinite(v) for v in errors.values()), errors

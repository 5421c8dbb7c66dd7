"""Random hidden effects for the diagnosis acceptance tests and the confusion-matrix benchmark.

draw(rng) picks one effect of the DESIGN.md vocabulary (or `none`) and its parameters from ranges a trial would
meet; within_tolerance(truth, estimate) says whether a diagnosis got the parameters right. The ranges, the
comparison of an estimate with the truth and the tolerances are those of the effect's record
(usv_predictor.physics.effects); they are the contract docs/results/diagnosis_matrices.md reports against.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from usv_predictor.physics import effects as fx
from usv_predictor.physics.actuators import DEFAULT_LAYOUT


def effect_names(layout: str = DEFAULT_LAYOUT.name) -> tuple[str, ...]:
    """The effects the suite can hide in a boat of this actuator layout: none, then every effect the simulator can
    make that applies to it (registry order)."""
    return (fx.NONE, *fx.simulated(layout))


EFFECTS = effect_names()  # the rudder_propeller boat's, as the registry was at import (tests parametrise over it)

# Stated tolerances of the acceptance suite (absolute errors), from the records.
TOLERANCES: Mapping[str, Mapping[str, float]] = fx.RegistryView(
    lambda: {**{name: dict(effect.tolerance) for name, effect in fx.simulated().items()}, fx.NONE: {}})


@dataclass(frozen=True)
class Draw:
    effect: str
    parameters: dict[str, float]  # `replay simulate` effect parameters (EffectParameter names)

    def cli_flags(self) -> list[str]:
        """The `replay simulate` flags that create this effect."""
        if self.effect == fx.NONE:
            return []
        flag = {p.name: p.flag for p in fx.EFFECTS[self.effect].parameters}
        flags = ["--effect", self.effect]
        for name, value in self.parameters.items():
            flags += [flag[name], f"{value:.6g}"]
        return flags


def draw(rng: np.random.Generator, effect: str | None = None, layout: str = DEFAULT_LAYOUT.name) -> Draw:
    """One effect (uniformly among effect_names(layout) unless given) with parameters drawn from its record's ranges.

    The random numbers, in order: the effect (unless given), one sign (for the parameters drawn with a random
    sign), then one uniform per parameter drawn from a range, in the record's order.
    """
    names = effect_names(layout)
    effect = effect or str(rng.choice(names))
    sign = float(rng.choice([-1.0, 1.0]))
    if effect not in names:
        raise ValueError(f"unknown effect {effect!r}; known: {names}")
    parameters = () if effect == fx.NONE else fx.EFFECTS[effect].parameters
    p = {q.name: q.draw.sample(rng, sign) for q in parameters if q.draw is not None}
    return Draw(effect, {k: round(float(v), 4) for k, v in p.items()})


def parameter_errors(truth: Draw, found: Mapping[str, float]) -> dict[str, float]:
    """Estimate minus truth, per physical parameter of the diagnosis vocabulary (directions: absolute, deg)."""
    effect = fx.EFFECTS.get(truth.effect)
    return {} if effect is None else effect.readout.errors(found, truth.parameters)


def within_tolerance(truth: Draw, found: Mapping[str, float]) -> tuple[bool, dict[str, float]]:
    errors = parameter_errors(truth, found)
    ok = all(abs(errors[k]) <= tol for k, tol in TOLERANCES[truth.effect].items())
    return ok and all(math.isfinite(v) for v in errors.values()), errors

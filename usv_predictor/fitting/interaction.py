"""Identification of the rudder / propeller interaction factors together with the hull (issue 11 section 5).

A vessel description made from an owner's data (`replay vessel init`, physics/empirical.py) holds the MMG
interaction factors at semi-empirical values: the rudder lift gradient of Fujii's formula, the flow straightening
gamma_R, the wake fraction w_P0 and thrust deduction t_P of regressions over ships. When they are wrong the
inverse-dynamics regression of the hull (fitting/identification.py) absorbs their error: the rudder force it
subtracts is wrong by a factor the hull polynomial cannot express (it is driven by the rudder angle), and the cubic
terms take absurd values (unknown-boat suite, boat 2: Y_vvv -16.1, N_vvv +15.3 for a truth of -1.3, -0.04) that
make a model which diverges.

Seed 001 sec. 4 (Alexandersson): hull and rudder identified together by ONE linear regression split the yaw moment
wrongly (the rudder angle and the yaw rate are collinear in zig-zags). So the factors are not regressors here. The
hull regression is linear GIVEN them, and the factors are searched outside it (a profile, as the throttle gain of
`identification.profile_throttle_gain`), in two measured stages:

 1. equation error, cross-validated: over a bounded box around the description (each factor x INTERACTION_BOUNDS),
    coordinate descent on a log grid minimises the leave-one-manoeuvre-out error of the hull regression
    (identification.cross_validate, prior policy as asked): for each trial the steering and propulsion forces are
    recomputed with the trial factors, the hull refitted on all but one manoeuvre and its forces predicted on it;
 2. output error, held out: the description's factors, the stage-1 optimum and the optimum with each factor put
    back at the description's value are each scored by the multi-step simulation of the identified grey box
    (models/greybox.GreyBoxRollout, the model `diagnose` runs) on segments (data/segments.py, SEGMENT_HORIZON_S)
    of each manoeuvre, the hull fitted WITHOUT that manoeuvre (leave one manoeuvre out). Simulation error is what
    separates rudder from hull: a wrong split fits the forces and fails the motion. The best candidate replaces the
    description only when its held-out simulation error is below ACCEPT_RATIO of the description's; otherwise the
    description's factors stay (a preset whose factors are right keeps them).

Each factor's 95 % interval: along that factor (the others at the chosen values) the equation-error criterion
J = sum_e RSS_e / sigma_e^2 of the hull regression on all data, the interval where J rises by less than CHI2_95 x
n / n_eff (identification.profile_throttle_gain's likelihood ratio; conditional on the other factors, so narrower
than a full profile). An interval reaching the search box: status identification.SEARCH_BOX (the value the output
error chose; the data bound it only within the box), flagged with a note in the identify JSON. When the description's
factors are kept, no factor is reported as a coefficient (the JSON's `interaction` block says the search lost).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np
import torch

from usv_predictor.data.recording import Recording
from usv_predictor.data.segments import Segments, make_segments
from usv_predictor.fitting.identification import (
    CHI2_95, SEARCH_BOX, Coefficient, ForceData, _least_squares_rss, cross_validate, fit_hull, identified_vessel,
    with_known_forces)
from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.physics.vessel import Vessel

INTERACTION_MODES = ("identify", "fix")  # `identify --interaction`: search the factors, or hold the description's
# the factors searched: name -> (lowest, highest) multiple of the description's value (-). The lift gradient spans a
# factor 2 both ways (Fujii's formula ignores the slipstream's contraction, the hull's shelter, the profile), the
# others +-50 % (the bounds; the suite's boats differ from the description by up to about that)
INTERACTION_BOUNDS: Mapping[str, tuple[float, float]] = {
    "rudder.lift_factor": (0.5, 2.0),
    "rudder.gamma_R": (0.5, 1.5),
    "propeller.w_P0": (0.5, 1.5),
    "propeller.t_P": (0.5, 1.5),
}
GRID_POINTS = 9  # log-spaced trial values of one factor in a coarse sweep (-)
SWEEPS = 2  # coarse coordinate-descent sweeps over all factors, then one fine sweep
FINE_POINTS = 5  # trial values of the fine sweep, spanning one coarse step either side of the best (-)
SEGMENT_HORIZON_S = 20.0  # (s) multi-step segments of the output-error stage (those diagnose's calm-water fit uses)
SEGMENT_STRIDE_S = 5.0  # (s) a segment starts every this
ACCEPT_RATIO = 0.8  # the searched factors replace the description's only below this x its held-out simulation error
DIVERGED = 1e6  # (-) the normalised squared error counted for a diverged or non-finite segment


def factor_value(vessel: Vessel, name: str) -> float:
    """The vessel's value of a searched factor (gamma_R: the mean of the two sides)."""
    r, p = vessel.rudder, vessel.propeller
    return {"rudder.lift_factor": r.lift_factor, "rudder.gamma_R": 0.5 * (r.gamma_R_minus + r.gamma_R_plus),
            "propeller.w_P0": p.w_P0, "propeller.t_P": p.t_P}[name]


def with_factors(vessel: Vessel, scale: Mapping[str, float]) -> Vessel:
    """The vessel with each factor multiplied by scale[name] (gamma_R: both sides by the same multiple)."""
    r, p = vessel.rudder, vessel.propeller
    g = scale.get("rudder.gamma_R", 1.0)
    rudder = replace(r, lift_factor=r.lift_factor * scale.get("rudder.lift_factor", 1.0),
                     gamma_R_minus=r.gamma_R_minus * g, gamma_R_plus=r.gamma_R_plus * g)
    propeller = replace(p, w_P0=p.w_P0 * scale.get("propeller.w_P0", 1.0), t_P=p.t_P * scale.get("propeller.t_P", 1.0))
    return replace(vessel, rudder=rudder, propeller=propeller)


@dataclass(frozen=True)
class InteractionFit:
    """The chosen factors and how they were chosen."""

    vessel: Vessel  # the description with the chosen factors (hull still the description's)
    scale: dict[str, float]  # chosen multiple of the description's value, per factor (-)
    coefficients: tuple[Coefficient, ...]  # per factor (none when not accepted): estimate, interval, prior, status
    accepted: bool  # False: the description's factors kept (the search did not beat them by ACCEPT_RATIO)
    cv_description: float  # leave-one-manoeuvre-out hull-force error (normalised MSE) at the description's factors
    cv_searched: float  # ... at the stage-1 optimum
    simulation: dict[str, float]  # held-out multi-step error of each output-error candidate (normalised MSE)
    evaluations: int  # hull regressions of stage 1

    def note(self) -> str:
        """One line for identify's notes."""
        sim = self.simulation
        if not self.accepted:
            return (f"interaction factors: the search did not lower the held-out simulation error below {ACCEPT_RATIO} "
                    f"x the description's ({sim['description']:.3g}); the description's kept")
        return ("interaction factors identified with the hull (held-out simulation error "
                f"{sim['description']:.3g} with the description's, {min(sim.values()):.3g} chosen): "
                + ", ".join(f"{c.name} {c.estimate:.4g} (description {c.prior:.4g})" for c in self.coefficients))

    def to_json(self) -> dict:
        return {"accepted": self.accepted, "scale": dict(self.scale),
                "cv_nmse_description": self.cv_description, "cv_nmse_searched": self.cv_searched,
                "heldout_simulation_nmse": dict(self.simulation), "accept_ratio": ACCEPT_RATIO,
                "equation_error_evaluations": self.evaluations,
                "method": "profile over the factors: leave-one-manoeuvre-out hull-force CV (coordinate descent), "
                          "then held-out multi-step simulation error of the identified grey box (module "
                          "usv_predictor.fitting.interaction)"}


def _cv_score(vessel: Vessel, data: Sequence[ForceData], structure: str, prior: str, u0: float,
              held: Sequence[str]) -> float:
    fit = fit_hull(vessel, data, structure, prior, u0=u0, held=held)
    return cross_validate(vessel, data, fit).score


def manoeuvre_segments(recordings: Sequence[Recording]) -> dict[str, tuple[float, Segments]]:
    """name -> (dt, its multi-step segments) of every manoeuvre longer than a segment: made once per search, the
    same for every candidate heldout_simulation_error scores."""
    return {r.name: (r.dt, make_segments([r], SEGMENT_HORIZON_S, SEGMENT_STRIDE_S)) for r in recordings
            if len(r) * r.dt > SEGMENT_HORIZON_S}


def heldout_simulation_error(vessel: Vessel, data: Sequence[ForceData], segments: Mapping[str, tuple[float, Segments]],
                             structure: str, prior: str, u0: float, held: Sequence[str]) -> float:
    """Mean over the segments of every manoeuvre (manoeuvre_segments) of the normalised squared multi-step error of
    u, v, r, psi (data/segments.SIGMA units) of the grey box whose hull is fitted on the OTHER manoeuvres (leave one
    out)."""
    total, count = 0.0, 0
    for k, d in enumerate(data):
        if d.name not in segments:
            continue
        dt, seg = segments[d.name]
        train = [x for j, x in enumerate(data) if j != k]
        model = identified_vessel(vessel, fit_hull(vessel, train, structure, prior, u0=u0, held=held))
        rollout = GreyBoxRollout(model, dt)
        with torch.no_grad():
            out = rollout(seg.state, seg.controls, seg.reference)[0]  # (B, H, 6)
        error = ((out - seg.target) * seg.weight)[..., [0, 1, 2, 5]]  # (B, H, 4) in noise units
        per = torch.nan_to_num(error.pow(2).mean(dim=(1, 2)), nan=DIVERGED, posinf=DIVERGED).clamp(max=DIVERGED)
        total += float(per.sum())
        count += len(per)
    return total / count if count else math.nan


def _grid(name: str, points: int) -> np.ndarray:
    low, high = INTERACTION_BOUNDS[name]
    return np.exp(np.linspace(math.log(low), math.log(high), points))


def identify_interaction(vessel: Vessel, data: Sequence[ForceData], recordings: Sequence[Recording],
                         structure: str, prior: str, u0: float, *, held: Sequence[str] = (),
                         progress: Callable[[str], None] | None = None) -> InteractionFit:
    """The two stages of the module docstring for a rudder_propeller vessel description."""
    names = tuple(INTERACTION_BOUNDS)
    evaluations = 0
    cache: dict[tuple, float] = {}

    def score(scale: Mapping[str, float]) -> float:
        nonlocal evaluations
        key = tuple(round(float(scale[n]), 9) for n in names)
        if key not in cache:
            trial = with_factors(vessel, scale)
            try:
                cache[key] = _cv_score(trial, with_known_forces(trial, data), structure, prior, u0, held)
            except (np.linalg.LinAlgError, ValueError):
                cache[key] = math.inf
            evaluations += 1
        return cache[key]

    scale = {n: 1.0 for n in names}
    cv_description = score(scale)
    if progress is not None:
        progress(f"interaction factors: equation-error search ({', '.join(names)})")
    for sweep in range(SWEEPS + 1):
        for n in names:
            if sweep < SWEEPS:
                trials = _grid(n, GRID_POINTS)
            else:  # fine: one coarse step either side of the best
                step = math.log(INTERACTION_BOUNDS[n][1] / INTERACTION_BOUNDS[n][0]) / (GRID_POINTS - 1)
                low, high = INTERACTION_BOUNDS[n]
                trials = np.clip(scale[n] * np.exp(np.linspace(-step, step, FINE_POINTS)), low, high)
            values = [score({**scale, n: float(x)}) for x in trials]
            best = int(np.argmin(values))
            if values[best] < score(scale):
                scale[n] = float(trials[best])
    cv_searched = score(scale)
    # stage 2: held-out simulation of a few candidates
    candidates = {"description": {n: 1.0 for n in names}, "searched": dict(scale)}
    for n in names:
        if scale[n] != 1.0:
            candidates[f"searched, {n} of the description"] = {**scale, n: 1.0}
    if progress is not None:
        progress(f"interaction factors: held-out simulation of {len(candidates)} candidates")
    simulation = {}
    segments = manoeuvre_segments(recordings)
    for label, s in candidates.items():
        trial = with_factors(vessel, s)
        simulation[label] = heldout_simulation_error(trial, with_known_forces(trial, data), segments, structure,
                                                     prior, u0, held)
    finite = {k: v for k, v in simulation.items() if math.isfinite(v)}
    best_label = min(finite, key=finite.get) if finite else "description"
    accepted = best_label != "description" and finite[best_label] < ACCEPT_RATIO * simulation["description"]
    chosen = candidates[best_label] if accepted else candidates["description"]
    chosen_vessel = with_factors(vessel, chosen)
    coefficients = tuple(_interval(vessel, data, structure, u0, chosen, n) for n in names) if accepted else ()
    return InteractionFit(chosen_vessel, dict(chosen), coefficients, accepted, cv_description, cv_searched,
                          simulation, evaluations)


def _interval(vessel: Vessel, data: Sequence[ForceData], structure: str, u0: float, chosen: Mapping[str, float],
              name: str) -> Coefficient:
    """The factor's Coefficient: estimate, the conditional likelihood-ratio 95 % interval along it (module
    docstring) on a fine grid of its search box, the description's value as prior, and its status."""
    prior_value = factor_value(vessel, name)
    estimate = prior_value * chosen[name]
    trials = _grid(name, 2 * GRID_POINTS + 1)

    def parts(multiple: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        trial = with_factors(vessel, {**chosen, name: multiple})
        return _least_squares_rss(trial, with_known_forces(trial, data), structure, u0, {})

    rss0, count, inflation = parts(chosen[name])
    sigma2 = np.maximum(rss0 / np.maximum(count - 1.0, 1.0), 1e-30)
    rise = CHI2_95 * float(np.mean(inflation))
    j_chosen = float(np.sum(rss0 / sigma2))
    inside = [float(x) for x in trials if float(np.sum(parts(float(x))[0] / sigma2)) - j_chosen < rise]
    low, high = (min(inside + [chosen[name]]), max(inside + [chosen[name]]))
    bounded = low > trials[0] and high < trials[-1]
    ci = (prior_value * low, prior_value * high)
    rel = 0.5 * (ci[1] - ci[0]) / max(abs(estimate), abs(prior_value), 1e-9)
    return Coefficient(name, estimate, ci, prior_value, "identified" if bounded else SEARCH_BOX, rel)

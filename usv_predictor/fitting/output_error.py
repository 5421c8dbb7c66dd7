"""Output-error (multiple-shooting) identification of the whole calm-water grey box, and its stability check.

The equation-error start (fitting/identification.py: EKF/RTS accelerations, inverse dynamics, least squares per
equation, the interaction-factor search; seed 001 sec. 3.2) fits forces. A model is used for its motion, and a
force fit splits the yaw moment between terms that are collinear in the forces (seed 001 sec. 4) but not in the
motion they make. This stage fits the motion (seed 001 sec. 3.3's simulation-error criterion, as multiple
shooting; Bock & Plitt 1984):

Residuals. Every manoeuvre is cut into segments of SEGMENT_S every STRIDE_S, each started from the smoothed state
(ForceData.nu: the RTS smoother's u, v, r; the measured heading) with the recorded controls over it; the
residuals e_j are the differences of the predicted and measured u, v, r and heading over the segment in noise
units (data/segments.SIGMA; a diverged value +-sqrt(DIVERGED)). All segments of all calm manoeuvres are B start
states of ONE rollout of the compiled kernel (models/kernel_rollout.py): the whole calm-water model -- hull
coefficients, thrust gains and the interaction factors -- is fitted at once, over all manoeuvres.

Parameters. theta_i = prior_i + s_i z_i for a hull coefficient (s_i = max(|prior|, |start|, FLOOR_SHARE of the
coefficient's force scale), theta_i = prior_i exp(z_i) for a positive factor or gain (rudder.lift_factor, gamma_R,
eta, w_P0, t_P as multiples of the description's; throttle.forward_N; a twin's thrusters.<side>.<dir>_N), inside
bounds (the interaction search's box, a gain within PROFILE_SPAN of the description's, the sign every hull has:
identification.MMG_SIGN, small_craft_identification.SIGN).

Criterion (a maximum a posteriori least squares with the description as a Gaussian prior of width PRIOR_WIDTH):
    C(z) = (n_eff / n) sum_j e_j^2 / sigma^2 + sum_i (z_i / width_i)^2     (width_i PRIOR_WIDTH, LAG_PRIOR_WIDTH)
sigma^2 the mean squared residual of the equation-error start, n the residual count, n_eff the segment count (the errors
along one segment are one realisation: the start's error and the model's carry through it). Minimised by
Levenberg-Marquardt (Marquardt 1963; damping x the diagonal) with a central-difference Jacobian (FD_STEP in z). The
data's information is F = (n_eff / n) J^T J / sigma^2 (Gauss-Newton); a parameter whose data-only 95 % half-width Z95
sqrt([F_free^-1]_ii) exceeds REL_CI_LIMIT (in units of s_i, or of the log; x width / PRIOR_WIDTH for a parameter whose
prior is wider, a time constant: held only when the data do not narrow the description's own uncertainty) is NOT
determined by these manoeuvres: held at the description's value, the widest first, one at a time (holding one of a
collinear pair determines the other), and the rest refitted. So the prior's weight follows what the data determine: a
determined term is the data's (its posterior interval is the data's), an undetermined one is the description's, named
with the trial that would determine it (identification.would_determine). Reported interval: the posterior's
Z95 sqrt([(F + P)^-1]_ii), mapped through theta(z).

Held out. The output-error model replaces the equation-error one only when it predicts manoeuvres it was not fitted on
better: FOLDS folds of whole manoeuvres; in each both stages are refitted on the other manoeuvres (the equation-error
hull by its own regression, the factors, gains and any Abkowitz terms of the whole-data start; the output error from
that fold's start, FOLD_ITERATIONS iterations) and both are scored on the held-out manoeuvres by the mean normalised
squared error of their 20 s segments (fitting/interaction.manoeuvre_segments, the interaction search's held-out score).
Kept: the lower; identify's notes and JSON (`output_error`) say which and why.

Stability over the envelope (check_envelope). The kept model is rolled out from start states and with constant
commands spanning what the trials did and ENVELOPE_MARGIN beyond: speeds (the slowest moving and the fastest), sway
and yaw rates of both signs up to the trials' largest, each control column from its lowest to its highest
recorded level (rudder angles both ways, to the rudder limit); over ENVELOPE_LENGTHS ship lengths (at least
ENVELOPE_MIN_S). A row diverges when it goes non-finite or its speed or yaw rate passes DIVERGE_FACTOR x the
envelope's; it is unstable when it has not settled over its last quarter (speed or sway peak-to-peak above
SETTLE_SHARE x the envelope speed, yaw rate above SETTLE_SHARE x the envelope yaw rate: constant commands in calm
water end in a straight run or a steady turn), and straight-line unstable when started straight with the steering
neutral it ends turning faster than SETTLE_SHARE x the envelope yaw rate (started at COURSE_PERTURBATION x it: a
course-unstable hull amplifies the perturbation into a turn of its own; from a large perturbation a stable hull may
settle into a turn as well, the cross-flow drag's second attractor, so those rows do not count). A failing
output-error model is refitted with the description's weight x PRIOR_STEPS; failing still (or an equation-error
model), it is regularised towards the description: theta = prior + alpha (theta - prior) (z scaled by alpha) for
alpha in REGULARISE_STEPS, the largest alpha that passes kept. A course instability the description has too is
tolerated; when the description diverges or does not settle, identify refuses (NotIdentifiableError naming the
row). A row whose held commands drive the boat astern (e.g. both thrusters astern: the columns' extremes combined)
is held only to stay finite and within DIVERGE_FACTOR, not to settle or hold its course, unless the trials
themselves went astern: ahead-running trials do not identify sternway, which is course-unstable on most hulls. No
coefficient that is not finite leaves this stage.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from usv_predictor.data.recording import Recording
from usv_predictor.data.segments import VELOCITY_HEADING, make_segments
from usv_predictor.errors import DatasetError, NotIdentifiableError
from usv_predictor.fitting import identification as ident
from usv_predictor.fitting.identification import (
    MMG_SIGN, PROFILE_SPAN, REGULARISED, REL_CI_LIMIT, Z95, Coefficient, ForceData, IdentificationResult,
    scaled_thrust_map, with_known_forces)
from usv_predictor.models.greybox import HULL_NAMES
from usv_predictor.models.hybrid import PolynomialResidual, ResidualGreyBox, ZeroResidual
from usv_predictor.models.kernel_rollout import KernelRollout
from usv_predictor.physics.vessel import Vessel

SEGMENT_S = 6.0  # (s) multiple-shooting segment: a few of the small boats' yaw time constants
STRIDE_S = 6.0  # (s) a segment starts every this (segments do not overlap: n_eff = their count)
CHANNELS = VELOCITY_HEADING  # u, v, r, psi of the rollout's [u, v, r, x_n, y_e, psi]
DIVERGED = 1e6  # (-) squared residual counted for a diverged or non-finite value (interaction.DIVERGED)
PRIOR_WIDTH = 0.5  # (-) the description's standard deviation: half a coefficient's size, log 1.65 of a factor
LAG_PRIOR_WIDTH = 1.5  # (-) ... of a motor's time constant (log, a factor 4.5): vessel init writes a default, 1 s
LAG_SPAN = 20.0  # (-) a time constant is fitted within [T / span, T x 4] of the description's
SIGMA_ROUNDS = 2  # (-) fits with sigma^2 re-estimated from the previous round's residuals (the first: the start's)
FLOOR_SHARE = 0.02  # (-) a coefficient's scale at least the value moving its force by this x the force's rms
FD_STEP = 0.02  # (-) central-difference step in z (2 % of a coefficient's size, of a factor's log)
MAX_ITERATIONS = 8  # (-) Levenberg-Marquardt iterations of the whole-data fit (each one Jacobian)
FOLD_ITERATIONS = 4  # (-) ... of a fold's fit (the held-out decision)
LM_DAMPING = 1e-2  # (-) initial damping x the diagonal of the normal matrix; / 3 on success, x 4 on failure
LM_DAMPING_MAX = 1e4  # (-) no step this damped lowers the cost: converged
LM_TOLERANCE = 1e-3  # (-) relative decrease of the cost below which the fit stops
Z_LIMIT = 10.0  # (-) a hull coefficient stays within prior +- 10 of its scales
FOLDS = 3  # (-) folds of whole manoeuvres of the held-out decision (fewer when fewer manoeuvres)
HELDOUT_SEGMENT_S = 20.0  # (s) the held-out score's segments (interaction.SEGMENT_HORIZON_S)
ENVELOPE_MARGIN = 0.2  # (-) the envelope extends the trials' ranges by this share
ENVELOPE_LENGTHS = 60.0  # (-) ship lengths sailed at the envelope speed by a stability row
ENVELOPE_MIN_S = 60.0  # (s) at least this long
DIVERGE_FACTOR = 3.0  # (-) speed or yaw rate beyond this x the envelope's: diverged
COURSE_PERTURBATION = 0.02  # (-) the straight starts' yaw rate, x the envelope's: a course-unstable hull amplifies it
SETTLE_SHARE = 0.1  # (-) peak-to-peak over the last quarter above this x the envelope's scale: not settled
REGULARISE_STEPS = (0.75, 0.5, 0.25, 0.0)  # (-) the shares alpha of (theta - prior) tried on a failing model
PRIOR_STEPS = (10.0, 100.0)  # (-) the prior's weight multiplied so in the refits of a failing output-error model

FACTOR_NAMES = ("rudder.lift_factor", "rudder.gamma_R", "rudder.eta", "propeller.w_P0", "propeller.t_P")
LAG_NAMES = {"twin_thrusters": "thrusters.time_constant_s", "rudder_throttle": "throttle.time_constant_s"}
MULTIPLES = (*FACTOR_NAMES, *LAG_NAMES.values())  # fitted as multiples of the description's value


# ------------------------------------------------------------------------------------------ the parameters


@dataclass(frozen=True)
class Parameter:
    """One fitted quantity: theta = prior + scale z (linear) or prior exp(z) (log); z within [low, high]."""

    name: str
    prior: float  # the description's value (a factor: 1, the multiple of the description's)
    scale: float  # (unit of theta) linear: theta per unit z; log: 1
    log: bool
    low: float  # bounds of z
    high: float
    width: float = 0.5  # (-) the description's standard deviation in z (PRIOR_WIDTH; LAG_PRIOR_WIDTH for a lag)

    def value(self, z: float) -> float:
        return self.prior * math.exp(z) if self.log else self.prior + self.scale * z

    def z_of(self, value: float) -> float:
        if self.log:
            return math.log(max(value, 1e-12) / self.prior)
        return (value - self.prior) / self.scale


@dataclass(frozen=True)
class Model:
    """How parameter values make the grey box's vessel: the equation-error result's vessel with them set."""

    start: Vessel  # the equation-error vessel (every section not fitted here comes from it)
    description: Vessel  # the vessel file (the prior)
    hull_model: str  # "mmg" | "small_craft"
    extra: Mapping[str, float]  # abkowitz terms of the equation-error fit (held)
    u0: float  # (m/s) their reference speed

    def vessel(self, values: Mapping[str, float]) -> Vessel:
        v = self.start
        hull = {n: x for n, x in values.items() if n in HULL_NAMES or n in SMALL_CRAFT_HULL}
        if self.hull_model == "small_craft":
            v = replace(v, small_craft=replace(v.small_craft, **hull))
            sides = {}
            for side in ("port", "starboard"):
                m = getattr(v.thrusters, side)
                forward = values.get(f"thrusters.{side}.forward_N", m.forward_N)
                reverse = values.get(f"thrusters.{side}.reverse_N", m.reverse_N)
                sides[side] = scaled_thrust_map(m, forward, max(reverse, 0.0))
                if LAG_NAMES["twin_thrusters"] in values:
                    own = getattr(self.description.thrusters, side).time_constant_s
                    sides[side] = replace(sides[side], time_constant_s=own * values[LAG_NAMES["twin_thrusters"]])
            return replace(v, thrusters=replace(v.thrusters, **sides))
        v = replace(v, hull=replace(v.hull, **hull))
        if any(n in values for n in FACTOR_NAMES):
            from usv_predictor.fitting.interaction import with_factors

            v = with_factors(replace(v, rudder=self.description.rudder, propeller=self.description.propeller),
                             {n: values.get(n, 1.0) for n in FACTOR_NAMES})
        if "throttle.forward_N" in values:
            v = replace(v, throttle=scaled_thrust_map(v.throttle, values["throttle.forward_N"], v.throttle.reverse_N))
        if LAG_NAMES["rudder_throttle"] in values:
            v = replace(v, throttle=replace(v.throttle, time_constant_s=self.description.throttle.time_constant_s
                                            * values[LAG_NAMES["rudder_throttle"]]))
        return v

    def rollout(self, vessel: Vessel, dt: float) -> KernelRollout:
        residual = PolynomialResidual(vessel, dict(self.extra), self.u0) if self.extra else ZeroResidual()
        return KernelRollout(ResidualGreyBox(vessel, dt, residual, 2), threads=2)  # the kernel runs without the GIL


SMALL_CRAFT_HULL = ("X_u", "X_uu", "Y_v", "Y_r", "cross_flow_cd", "N_v", "N_r", "N_rr")


def parameters(result: IdentificationResult, data: Sequence[ForceData]) -> tuple[list[Parameter], dict[str, float]]:
    """(the parameters of the result's hull model and layout, their equation-error values): module docstring."""
    start, description = result.vessel, result.prior or result.vessel
    out: list[Parameter] = []
    values: dict[str, float] = {}
    if start.hull_model_name == "small_craft":
        from usv_predictor.fitting import small_craft_identification as sc

        structure = result.fit.structure
        floors = _small_craft_floors(start, data, sc.STRUCTURE_TERMS[structure])
        for name in sc.STRUCTURE_TERMS[structure]:
            prior, now = float(getattr(description.small_craft, name)), float(getattr(start.small_craft, name))
            out.append(_linear(name, prior, now, floors[name], sc.SIGN.get(name, 0)))
            values[name] = now
        astern = any(np.any(d.controls < 0.0) for d in data)
        for side in ("port", "starboard"):
            for part in ("forward_N", "reverse_N"):
                if part == "reverse_N" and not astern:
                    continue  # no astern command: nothing moves it (held, would_determine names the trial)
                prior = float(getattr(getattr(description.thrusters, side), part))
                now = float(getattr(getattr(start.thrusters, side), part))
                if prior <= 0.0:
                    continue
                out.append(_positive(f"thrusters.{side}.{part}", prior, PROFILE_SPAN))
                values[f"thrusters.{side}.{part}"] = now
        if description.thrusters.port.time_constant_s > 0.0 and description.thrusters.starboard.time_constant_s > 0.0:
            out.append(_lag(LAG_NAMES["twin_thrusters"]))
            values[LAG_NAMES["twin_thrusters"]] = (start.thrusters.port.time_constant_s
                                                   / description.thrusters.port.time_constant_s)
        return out, values
    held = {"R0"} if start.layout == "rudder_only" else set()
    floors = _mmg_floors(start, data, result.fit.u0)
    for name in HULL_NAMES:
        if name in held:
            continue
        prior, now = float(getattr(description.hull, name)), float(getattr(start.hull, name))
        out.append(_linear(name, prior, now, floors[name], MMG_SIGN.get(name, 0)))
        values[name] = now
    if start.layout == "rudder_propeller" and result.interaction is not None:
        from usv_predictor.fitting.interaction import _bounds, factor_value

        for name in FACTOR_NAMES:
            low, high = _bounds(description, name)
            out.append(Parameter(name, 1.0, 1.0, True, math.log(low), math.log(high)))
            values[name] = factor_value(start, name) / factor_value(description, name)
    if start.layout == "rudder_throttle":
        out.append(_positive("throttle.forward_N", description.throttle.forward_N, PROFILE_SPAN))
        values["throttle.forward_N"] = start.throttle.forward_N
        if description.throttle.time_constant_s > 0.0:
            out.append(_lag(LAG_NAMES["rudder_throttle"]))
            values[LAG_NAMES["rudder_throttle"]] = start.throttle.time_constant_s / description.throttle.time_constant_s
    return out, values


def _linear(name: str, prior: float, start: float, floor: float, sign: int) -> Parameter:
    scale = max(abs(prior), abs(start), floor, 1e-12)
    low, high = -Z_LIMIT, Z_LIMIT
    if sign < 0:  # theta <= 0
        high = min(high, -prior / scale)
    elif sign > 0:  # theta >= 0
        low = max(low, -prior / scale)
    return Parameter(name, prior, scale, False, low, max(high, low))


def _lag(name: str) -> Parameter:
    """A motor's time constant as the description's multiple (log; LAG_SPAN down, 4 x up; LAG_PRIOR_WIDTH)."""
    return Parameter(name, 1.0, 1.0, True, -math.log(LAG_SPAN), math.log(4.0), LAG_PRIOR_WIDTH)


def _positive(name: str, prior: float, span: float) -> Parameter:
    return Parameter(name, prior, 1.0, True, -math.log(span), math.log(span))


def _mmg_floors(vessel: Vessel, data: Sequence[ForceData], u0: float) -> dict[str, float]:
    """FLOOR_SHARE x rms(non-dimensional hull force) / rms(regressor) per MMG coefficient (identification.design)."""
    out = {}
    for eq in ident.EQUATIONS:
        d = ident.design(vessel, data, "mmg", eq, u0)
        target = float(np.sqrt(np.mean(d.target ** 2)))
        for k, name in enumerate(d.names):
            column = float(np.sqrt(np.mean(d.matrix[:, k] ** 2)))
            out[name] = FLOOR_SHARE * target / column if column > 0.0 else ident.MAGNITUDE_FLOOR
    return out


def _small_craft_floors(vessel: Vessel, data: Sequence[ForceData], names: Sequence[str]) -> dict[str, float]:
    """FLOOR_SHARE x rms(force of its equations) / rms(its force per unit) per small-craft coefficient."""
    from usv_predictor.fitting import small_craft_identification as sc

    columns = [sc.basis(vessel, d.nu[d.keep], d.controls[d.keep]) for d in data]
    total = np.concatenate([d.total[d.keep] for d in data])  # (T, 3)
    rms = np.sqrt(np.mean(total ** 2, axis=0))  # (3,)
    out = {}
    for name in names:
        per = np.concatenate([c[name] for c in columns])  # (T, 3)
        eqs = [ident.EQUATIONS.index(e) for e in sc.HULL_TERMS[name]]
        column = float(np.sqrt(np.mean(per[:, eqs] ** 2)))
        out[name] = FLOOR_SHARE * float(np.mean(rms[eqs])) / column if column > 0.0 else 1e-6
    return out


# ------------------------------------------------------------------------------------------ the residuals


@dataclass(frozen=True)
class Shooting:
    """Multiple-shooting segments of several manoeuvres at one step dt (numpy float64)."""

    dt: float  # (s)
    state: np.ndarray  # (B, 4) smoothed u, v, r and measured psi at each start
    controls: np.ndarray  # (B, H, C) recorded controls
    reference: np.ndarray  # (B, 4) the manoeuvre's approach state (rudder_only's engine speed)
    target: np.ndarray  # (B, H, 4) measured u, v, r, psi
    weight: np.ndarray  # (B, H, 4) 1 / sigma where measured, 0 where missing
    manoeuvre: np.ndarray  # (B,) index into the manoeuvres
    start: np.ndarray  # (B,) sample of each segment's start in its manoeuvre
    commands: Mapping[int, np.ndarray]  # manoeuvre index -> (T, C) its recorded controls (the lag's history)


def shooting_segments(data: Sequence[ForceData], recordings: Sequence[Recording], horizon_s: float,
                      stride_s: float, smoothed_start: bool = True) -> list[Shooting]:
    """The segments of every manoeuvre longer than horizon_s (data/segments.make_segments), started from the smoothed
    state (smoothed_start) or the measured one; one Shooting per time step."""
    by_dt: dict[float, list[tuple[int, object, np.ndarray]]] = {}
    for k, (d, rec) in enumerate(zip(data, recordings)):
        if len(rec) * rec.dt <= horizon_s:
            continue
        seg = make_segments([rec], horizon_s, stride_s)
        state = seg.state.numpy().copy()  # (b, 4)
        h = seg.controls.shape[1]
        stride = max(1, int(round(min(stride_s, len(rec) * rec.dt) / rec.dt)))
        starts = np.arange(0, len(rec) - h, stride)[:len(state)]  # make_segments' starts
        if smoothed_start:
            state[:, :3] = d.nu[starts]
        by_dt.setdefault(rec.dt, []).append((k, seg, state, starts, rec.controls))
    out = []
    for dt, parts in sorted(by_dt.items()):
        cat = lambda f: np.concatenate([f(s, st) for _, s, st, _, _ in parts])  # noqa: E731
        out.append(Shooting(dt, cat(lambda s, st: st), cat(lambda s, st: s.controls.numpy()),
                            cat(lambda s, st: s.reference.numpy()),
                            cat(lambda s, st: s.target.numpy()[..., list(CHANNELS)]),
                            cat(lambda s, st: s.weight.numpy()[..., list(CHANNELS)]),
                            np.concatenate([np.full(len(st), k) for k, _, st, _, _ in parts]),
                            np.concatenate([starts for _, _, _, starts, _ in parts]),
                            {k: np.asarray(c, dtype=float) for k, _, _, _, c in parts}))
    return out


def lagged_columns(vessel: Vessel) -> list[tuple[int, float]]:
    """(column, time constant (s)) of the controls the grey box lags (models/greybox.CommandLag)."""
    if vessel.layout == "twin_thrusters":
        return [(0, vessel.thrusters.port.time_constant_s), (1, vessel.thrusters.starboard.time_constant_s)]
    if vessel.layout == "rudder_throttle":
        return [(1, vessel.throttle.time_constant_s)]
    return []


def with_lag_state(vessel: Vessel, s: Shooting) -> np.ndarray:
    """(B, H, C) the segments' controls with each lagged column's first sample replaced by the motor's level at the
    segment's start (identification.lagged_command over the manoeuvre's commands so far): the kernel's lag starts
    at the first sample, so a segment starts with the motor where it was, not at its command (an error of the first
    step's ramp only)."""
    columns = [(c, t) for c, t in lagged_columns(vessel) if t > 0.0]
    if not columns:
        return s.controls
    controls = s.controls.copy()
    for m, commands in s.commands.items():
        rows = s.manoeuvre == m
        for column, time_constant in columns:
            level = ident.lagged_command(commands[:, column], time_constant, s.dt)  # (T,)
            controls[rows, 0, column] = level[s.start[rows]]
    return controls


def residuals(model: Model, vessel: Vessel, shooting: Sequence[Shooting]) -> np.ndarray:
    """(N,) the multi-step errors of u, v, r, psi of every segment in noise units (heading error wrapped to +-pi),
    a diverged value +-sqrt(DIVERGED)."""
    bound = math.sqrt(DIVERGED)
    parts = []
    for s in shooting:
        controls = with_lag_state(vessel, s)
        out = model.rollout(vessel, s.dt).rollout(s.state, controls, s.reference)[0][..., list(CHANNELS)]
        error = out - s.target  # (B, H, 4)
        error[..., 3] = (error[..., 3] + math.pi) % (2.0 * math.pi) - math.pi
        with np.errstate(invalid="ignore", over="ignore"):
            e = error * s.weight
        parts.append(np.clip(np.nan_to_num(e, nan=bound, posinf=bound, neginf=-bound), -bound, bound).reshape(-1))
    return np.concatenate(parts) if parts else np.zeros(0)


def segment_score(model: Model, vessel: Vessel, shooting: Sequence[Shooting]) -> float:
    """Mean over the segments of the normalised squared error of u, v, r, psi (interaction._segment_error)."""
    total, count = 0.0, 0
    for s in shooting:
        e = residuals(model, vessel, [s]).reshape(len(s.state), -1)  # (B, H * 4)
        total += float(np.sum(np.minimum(np.mean(e ** 2, axis=1), DIVERGED)))
        count += len(s.state)
    return total / count if count else math.nan


# ------------------------------------------------------------------------------------------ the fit


@dataclass(frozen=True)
class Fit:
    """An output-error fit: its values, which were held and how well it fits."""

    values: dict[str, float]  # every parameter's value (held ones at the description's)
    z: dict[str, float]  # their normalised values
    held: tuple[str, ...]  # not determined by the data (data-only half-width > REL_CI_LIMIT): the description's
    ci95: dict[str, tuple[float, float]]  # posterior 95 % interval per parameter (a held one: its data-only one)
    rel_ci: dict[str, float]  # data-only 95 % half-width / scale (z units)
    cost_start: float  # the criterion at the start
    cost: float  # ... at the end
    insample_start: float  # mean squared residual (noise units^2) at the start
    insample: float  # ... at the end
    iterations: int
    rollouts: int


def fit(model: Model, params: Sequence[Parameter], start: Mapping[str, float], shooting: Sequence[Shooting], *,
        iterations: int = MAX_ITERATIONS, determine: bool = True, prior_scale: float = 1.0) -> Fit:
    """Levenberg-Marquardt of the module docstring's criterion from `start` (values per parameter), holding what the
    data do not determine (determine; a fold's fit keeps the whole-data decision: held parameters given at the
    prior)."""
    names = [p.name for p in params]
    low = np.array([p.low for p in params])  # (P,)
    high = np.array([p.high for p in params])  # (P,)
    z = np.clip(np.array([p.z_of(start[p.name]) for p in params]), low, high)  # (P,)
    rollouts = 0

    def values_of(zz: np.ndarray) -> dict[str, float]:
        return {p.name: p.value(float(x)) for p, x in zip(params, zz)}

    def res(zz: np.ndarray) -> np.ndarray:
        nonlocal rollouts
        rollouts += 1
        return residuals(model, model.vessel(values_of(zz)), shooting)

    r = res(z)
    n = len(r)
    n_eff = float(sum(len(s.state) for s in shooting))
    if n == 0:
        raise DatasetError(f"no manoeuvre longer than the {SEGMENT_S:g} s output-error segment")
    sigma2 = max(float(np.mean(r ** 2)), 1e-12)
    data_weight = n_eff / n / sigma2  # the data term's weight of the criterion
    prior_weight = np.array([prior_scale / p.width ** 2 for p in params])  # (P,)

    def cost(rr: np.ndarray, zz: np.ndarray, free: np.ndarray) -> float:
        return data_weight * float(rr @ rr) + float(np.sum(prior_weight[free] * zz[free] ** 2))

    free = np.ones(len(params), dtype=bool)
    cost_start, insample_start = cost(r, z, free), float(np.mean(r ** 2))
    done = 0

    def jacobian(zz: np.ndarray, mask: np.ndarray) -> np.ndarray:
        jac = np.zeros((n, len(zz)))  # (N, P)
        for k in np.flatnonzero(mask):
            hi, lo = zz.copy(), zz.copy()
            hi[k] = min(zz[k] + FD_STEP, high[k])
            lo[k] = max(zz[k] - FD_STEP, low[k])
            if hi[k] - lo[k] > 0.0:
                jac[:, k] = (res(hi) - res(lo)) / (hi[k] - lo[k])
        return jac

    def run(zz: np.ndarray, rr: np.ndarray, mask: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        nonlocal done
        damping = LM_DAMPING
        jac = jacobian(zz, mask)
        current = cost(rr, zz, mask)
        for _ in range(steps):
            done += 1
            a = data_weight * jac.T @ jac + np.diag(prior_weight * mask)  # (P, P)
            g = data_weight * jac.T @ rr + prior_weight * np.where(mask, zz, 0.0)  # (P,)
            idx = np.flatnonzero(mask)
            a, g = a[np.ix_(idx, idx)], g[idx]
            diagonal = np.diag(np.maximum(np.diag(a), 1e-12))
            improved = False
            while damping < LM_DAMPING_MAX:
                trial = zz.copy()
                trial[idx] = np.clip(zz[idx] - np.linalg.solve(a + damping * diagonal, g), low[idx], high[idx])
                rt = res(trial)
                value = cost(rt, trial, mask)
                if value < current:
                    decrease = (current - value) / max(current, 1e-300)
                    zz, rr, current, improved, damping = trial, rt, value, True, max(damping / 3.0, 1e-9)
                    break
                damping *= 4.0
            if not improved or decrease < LM_TOLERANCE:
                break
            jac = jacobian(zz, mask)
        return zz, rr, jac

    for round_ in range(SIGMA_ROUNDS):  # sigma^2 of the start, then of the previous round's fit
        if round_:
            data_weight = n_eff / n / max(float(np.mean(r ** 2)), 1e-12)
        z, r, jac = run(z, r, free, iterations if not round_ else max(2, iterations // 2))
    data_weight = n_eff / n / max(float(np.mean(r ** 2)), 1e-12)
    info = data_weight * jac.T @ jac  # (P, P) the data's information in z
    held: list[str] = []
    if determine:  # hold the widest first until every free parameter is determined
        limit = np.array([REL_CI_LIMIT * p.width / PRIOR_WIDTH for p in params])  # (P,)
        while free.any():
            rel = _data_half_width(info, free) / limit
            worst = int(np.argmax(np.where(free, rel, -np.inf)))
            if rel[worst] <= 1.0:
                break
            free[worst] = False
            held.append(names[worst])
        if held:
            z[~free] = 0.0
            r = res(z)
            if free.any():
                z, r, jac = run(z, r, free, max(2, iterations // 2))
                data_weight = n_eff / n / max(float(np.mean(r ** 2)), 1e-12)
                info = data_weight * jac.T @ jac
    rel_all = _data_half_width(info, np.ones(len(params), dtype=bool))
    rel_free = _data_half_width(info, free)
    posterior = np.linalg.pinv(info + np.diag(prior_weight))
    ci95, rel_ci = {}, {}
    for k, p in enumerate(params):
        half = Z95 * math.sqrt(max(float(posterior[k, k]), 0.0))
        ends = sorted((p.value(float(z[k] - half)), p.value(float(z[k] + half))))
        ci95[p.name] = (ends[0], ends[1])
        rel_ci[p.name] = float(rel_free[k] if free[k] else rel_all[k])
    return Fit(values_of(z), {p.name: float(x) for p, x in zip(params, z)}, tuple(held), ci95, rel_ci, cost_start,
               cost(r, z, free), insample_start, float(np.mean(r ** 2)), done, rollouts)


def _data_half_width(info: np.ndarray, free: np.ndarray) -> np.ndarray:
    """(P,) Z95 sqrt([F_free^-1]_ii) of the free parameters (inf elsewhere and along a direction F does not see)."""
    out = np.full(len(free), math.inf)
    idx = np.flatnonzero(free)
    if len(idx) == 0:
        return out
    sub = info[np.ix_(idx, idx)]
    ridge = 1e-9 * max(float(np.max(np.diag(sub))), 1e-300)  # a direction the data do not see: variance ~1e9 x
    cov = np.linalg.inv(sub + ridge * np.eye(len(idx)))
    out[idx] = Z95 * np.sqrt(np.maximum(np.diag(cov), 0.0))
    return out


# ------------------------------------------------------------------------------------------ stability


@dataclass(frozen=True)
class Envelope:
    """The start states and constant commands of the stability check (module docstring)."""

    state: np.ndarray  # (B, 4) u, v, r, psi
    controls: np.ndarray  # (B, C) held over the rollout
    reference: np.ndarray  # (B, 4) the approach state (rudder_only's engine speed: the start's speed)
    speed: float  # (m/s) the envelope's largest speed
    yaw_rate: float  # (rad/s) the envelope's largest yaw rate
    dt: float  # (s)
    steps: int
    astern: bool  # the trials moved astern (a moving sample with u < 0): sternway rows are held to settle too


def envelope(vessel: Vessel, recordings: Sequence[Recording]) -> Envelope:
    """The envelope of the trials extended by ENVELOPE_MARGIN (module docstring)."""
    nu = np.concatenate([r.nu for r in recordings])  # (T, 3)
    controls = np.concatenate([r.controls for r in recordings])  # (T, C)
    finite = np.all(np.isfinite(nu), axis=1)
    nu, grow = nu[finite], 1.0 + ENVELOPE_MARGIN
    speed = np.hypot(nu[:, 0], nu[:, 1])
    moving = speed > 0.2 * float(np.max(speed))
    u_slow, u_fast = float(np.percentile(nu[moving, 0], 1.0)), float(np.max(speed)) * grow
    v_max = float(np.max(np.abs(nu[:, 1]))) * grow
    r_max = float(np.max(np.abs(nu[:, 2]))) * grow
    layout = vessel.actuator_layout
    levels = []
    for k, control in enumerate(layout.controls):
        column = controls[np.isfinite(controls[:, k]), k]
        lo, hi = float(np.min(column)), float(np.max(column))
        if control.name == "rudder":
            limit = math.radians(vessel.actuators.rudder_max_deg)
            top = min(max(abs(lo), abs(hi)) * grow, limit)
            levels.append((-top, 0.0, top))
        else:
            span = ENVELOPE_MARGIN * (hi - lo)
            low, high = max(lo - span, control.plausible[0]), min(hi + span, control.plausible[1])
            levels.append((low, 0.5 * (low + high), high))
    rows_state, rows_controls = [], []
    for u in (u_slow, u_fast):
        for v in (-v_max, 0.0, v_max):
            for r in (-r_max, COURSE_PERTURBATION * r_max if v == 0.0 else 0.0, r_max):
                for combo in np.array(np.meshgrid(*levels, indexing="ij")).reshape(len(levels), -1).T:
                    rows_state.append([u, v, r, 0.0])
                    rows_controls.append(combo)
    state = np.array(rows_state)
    dt = float(recordings[0].dt)
    length_s = max(ENVELOPE_MIN_S, ENVELOPE_LENGTHS * vessel.geometry.L_pp / max(u_fast, 1e-3))
    reference = np.column_stack([np.hypot(state[:, 0], state[:, 1]), np.zeros((len(state), 3))])
    return Envelope(state, np.array(rows_controls), reference, u_fast, max(r_max, 1e-3), dt,
                    int(math.ceil(length_s / dt)), astern=bool(np.any(nu[moving, 0] < 0.0)))


def check_envelope(model: Model, vessel: Vessel, env: Envelope) -> str | None:
    """Why the vessel's grey box diverges or is unstable somewhere in the envelope (the first such row), or None."""
    controls = np.repeat(env.controls[:, None, :], env.steps, axis=1)  # (B, H, C)
    out = model.rollout(vessel, env.dt).rollout(env.state, controls, env.reference)[0]  # (B, H, 6)
    u, v, r = out[..., 0], out[..., 1], out[..., 2]  # (B, H)
    with np.errstate(invalid="ignore", over="ignore"):
        speed = np.hypot(u, v)
        finite = np.all(np.isfinite(out[..., :3]), axis=(1, 2))  # (B,)
        beyond = finite & ((np.nanmax(speed, axis=1) > DIVERGE_FACTOR * env.speed)
                           | (np.nanmax(np.abs(r), axis=1) > DIVERGE_FACTOR * env.yaw_rate))
        tail = slice(int(0.75 * env.steps), env.steps)
        # a row the held commands drive astern (the last quarter's mean u < 0: both thrusters astern together, a
        # combination of the columns' extremes) is beyond what ahead-running trials identify, and sternway is
        # course-unstable on most hulls: held only to stay finite and bounded, unless the trials went astern
        judged = np.full(len(u), True) if env.astern else np.mean(u[:, tail], axis=1) >= 0.0
        unsettled = finite & ~beyond & judged & ((np.ptp(u[:, tail], axis=1) > SETTLE_SHARE * env.speed)
                                                 | (np.ptp(v[:, tail], axis=1) > SETTLE_SHARE * env.speed)
                                                 | (np.ptp(r[:, tail], axis=1) > SETTLE_SHARE * env.yaw_rate))
        layout = vessel.actuator_layout
        neutral = ((np.abs(layout.steering_signal(env.controls)) < 1e-9)  # (B,) steering neutral, started straight
                   & (env.state[:, 1] == 0.0) & (np.abs(env.state[:, 2]) < 0.5 * env.yaw_rate))
        turning = (finite & ~beyond & ~unsettled & judged & neutral
                   & (np.abs(r[:, -1]) > SETTLE_SHARE * env.yaw_rate))
    names = layout.control_names

    def row(k: int) -> str:
        s, c = env.state[k], env.controls[k]
        return (f"from u {s[0]:.2f} m/s, v {s[1]:+.2f} m/s, r {s[2]:+.3f} rad/s with "
                + ", ".join(f"{n} {x:.3g}" for n, x in zip(names, c)) + " held")

    seconds = env.steps * env.dt
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        return f"diverges (not finite within {seconds:.0f} s) {row(k)}"
    if beyond.any():
        k = int(np.flatnonzero(beyond)[0])
        return (f"diverges (speed or yaw rate beyond {DIVERGE_FACTOR:g} x the envelope's {env.speed:.2f} m/s, "
                f"{env.yaw_rate:.3f} rad/s) {row(k)}")
    if unsettled.any():
        k = int(np.flatnonzero(unsettled)[0])
        return f"unstable (does not settle in {seconds:.0f} s) {row(k)}"
    if turning.any():
        k = int(np.flatnonzero(turning)[0])
        return (f"straight-line unstable (turns at {r[k, -1]:+.3f} rad/s after {seconds:.0f} s with the steering "
                f"neutral) {row(k)}")
    return None


COURSE_UNSTABLE = "straight-line unstable"  # check_envelope's reason for a hull that turns with the steering neutral


def regularise(model: Model, params: Sequence[Parameter], values: Mapping[str, float], env: Envelope
               ) -> tuple[dict[str, float], float, str | None, list[str]]:
    """(values, alpha, the first failure or None, every failure met): the values with z scaled by the largest alpha of
    (1,) + REGULARISE_STEPS whose grey box passes check_envelope. A course instability (COURSE_UNSTABLE) the
    description has too is tolerated (a hull may be course-unstable; the data cannot be asked to be more stable
    than the boat's own description), a divergence or a model that does not settle never is: NotIdentifiableError
    when even the description fails so."""
    description = check_envelope(model, model.vessel({p.name: p.prior for p in params}), env)
    tolerated = description is not None and description.startswith(COURSE_UNSTABLE)
    failures = []
    first = None
    for alpha in (1.0,) + REGULARISE_STEPS:
        trial = {p.name: p.value(alpha * p.z_of(values[p.name])) for p in params}
        reason = description if alpha == 0.0 else check_envelope(model, model.vessel(trial), env)
        if reason is None or (tolerated and reason.startswith(COURSE_UNSTABLE)):
            if reason is not None:
                failures.append(f"alpha {alpha:g}: {reason} (as the description: tolerated)")
            return trial, alpha, first, failures
        first = first or reason
        failures.append(f"alpha {alpha:g}: {reason}")
    raise NotIdentifiableError(
        f"the identified model and the vessel description itself diverge or are unstable inside the trials' "
        f"envelope (+{ENVELOPE_MARGIN:.0%}): {failures[0]}; the description: {failures[-1]}. Check the vessel file "
        "(mass, added mass, damping signs) against the boat")


# ------------------------------------------------------------------------------------------ the stage


def _folds(names: Sequence[str]) -> list[np.ndarray]:
    """FOLDS folds of whole manoeuvres (round robin over the sorted distinct names), fewer with fewer manoeuvres."""
    base = [n.split("#")[0].split("@")[0] for n in names]
    distinct = sorted(set(base))
    k = min(FOLDS, len(distinct))
    return [np.array([distinct.index(b) % k == f for b in base]) for f in range(k)]


def _equation_error_vessel(result: IdentificationResult, train: Sequence[ForceData]) -> Vessel:
    """The equation-error hull refitted on `train` (the whole-data factors and gains kept)."""
    vessel = result.vessel
    if vessel.hull_model_name == "small_craft":
        from usv_predictor.fitting import small_craft_identification as sc

        described = result.prior or vessel  # its hull and gains are the regression's prior; the exponent kept
        base = replace(vessel, small_craft=described.small_craft, thrusters=replace(
            described.thrusters, port=replace(described.thrusters.port, exponent=vessel.thrusters.port.exponent),
            starboard=replace(described.thrusters.starboard, exponent=vessel.thrusters.starboard.exponent)))
        return sc.identified_vessel(vessel, sc.fit_small_craft(base, train, result.fit.structure,
                                                               result.fit.prior_policy, anchor=result.fit.anchor))
    base = replace(vessel, hull=(result.prior or vessel).hull)
    held = ("R0",) if vessel.layout == "rudder_only" else ()
    hull = ident.fit_hull(base, train, result.fit.structure, result.fit.prior_policy, u0=result.fit.u0, held=held)
    return replace(ident.identified_vessel(base, hull), name=vessel.name)


@dataclass(frozen=True)
class OutputErrorStage:
    """What the stage did (identify's JSON `output_error`)."""

    kept: str  # "output error" | "equation error"
    reason: str
    heldout: dict[str, float]  # label -> held-out 20 s segment error (normalised MSE) summed over the folds' manoeuvres
    fit: Fit | None
    stability: dict

    def to_json(self) -> dict:
        f = self.fit
        return {"kept": self.kept, "reason": self.reason,
                "heldout_simulation_nmse": {k: ident.finite_or_none(v) for k, v in self.heldout.items()},
                "folds": FOLDS, "segment_s": SEGMENT_S, "prior_width": PRIOR_WIDTH, "rel_ci_limit": REL_CI_LIMIT,
                "fit": None if f is None else {
                    "insample_nmse_start": f.insample_start, "insample_nmse": f.insample, "cost_start": f.cost_start,
                    "cost": f.cost, "iterations": f.iterations, "rollouts": f.rollouts, "held": list(f.held),
                    "values": f.values, "ci95": {k: list(v) for k, v in f.ci95.items()},
                    "data_rel_ci": {k: ident.finite_or_none(v) for k, v in f.rel_ci.items()}},
                "stability": self.stability,
                "method": "multiple-shooting output error (usv_predictor.fitting.output_error)"}


def refine(result: IdentificationResult, recordings: Sequence[Recording], *,
           progress: Callable[[str], None] | None = None) -> IdentificationResult:
    """The output-error stage and the stability check of the module docstring on an equation-error result (its data
    in the recordings' order); the result with the kept model, its coefficients and intervals, and the stage's
    record (IdentificationResult.output_error)."""
    say = progress or (lambda _: None)
    data = list(result.data)
    names = [d.name for d in data]
    description = result.prior or result.vessel
    model = Model(result.vessel, description, result.vessel.hull_model_name, dict(result.extra_terms),
                  result.fit.u0)
    params, start = parameters(result, data)
    shooting = shooting_segments(data, recordings, SEGMENT_S, STRIDE_S)
    heldout_segments = shooting_segments(data, recordings, HELDOUT_SEGMENT_S, HELDOUT_SEGMENT_S / 4.0,
                                         smoothed_start=False)
    env = envelope(result.vessel, recordings)
    if result.fit.prior_policy == "none":
        stage = OutputErrorStage("equation error", "prior none: the output-error fit holds what the data do not "
                                 "determine at the description's values, which --prior none forbids (use fix or "
                                 "ridge)", {}, None, {})
        return _stable(result, model, params, start, env, stage, say)
    if not shooting or not heldout_segments:
        stage = OutputErrorStage("equation error", f"no manoeuvre longer than {HELDOUT_SEGMENT_S:g} s", {}, None, {})
        return _stable(result, model, params, start, env, stage, say)
    say(f"output error: {len(params)} parameters over {sum(len(s.state) for s in shooting)} segments of "
        f"{SEGMENT_S:g} s (Levenberg-Marquardt, central differences)")
    whole = fit(model, params, start, shooting)
    say(f"output error: in-sample error {whole.insample_start:.3g} -> {whole.insample:.3g} "
        f"({whole.iterations} iterations, {whole.rollouts} rollouts); held: {', '.join(whole.held) or 'none'}")
    heldout = {"equation error": 0.0, "output error": 0.0}
    folds = _folds(names)
    for k, test in enumerate(folds):
        if test.all() or not test.any():
            continue
        train = [d for d, t in zip(data, test) if not t]
        train_rec = [r for r, t in zip(recordings, test) if not t]
        test_set = [np.isin(s.manoeuvre, np.flatnonzero(test)) for s in heldout_segments]
        scored = [_select(s, m) for s, m in zip(heldout_segments, test_set) if m.any()]
        train_shooting = shooting_segments(train, train_rec, SEGMENT_S, STRIDE_S)
        if not scored or not train_shooting:
            continue
        say(f"output error: fold {k + 1}/{len(folds)} (held out: "
            f"{', '.join(n for n, t in zip(names, test) if t)})")
        try:
            ee = _equation_error_vessel(result, train)
        except (NotIdentifiableError, DatasetError, np.linalg.LinAlgError) as err:
            say(f"output error: fold {k + 1} skipped, its equation-error fit failed: {err}")
            continue
        fold_model = replace(model, start=ee)
        fold_start = {**start, **{p.name: _value_in(ee, p.name, start[p.name]) for p in params}}
        fold_start.update({n: next(p.prior for p in params if p.name == n) for n in whole.held})
        fold_params = [p if p.name not in whole.held else replace(p, low=0.0, high=0.0) for p in params]
        oe = fit(fold_model, fold_params, fold_start, train_shooting, iterations=FOLD_ITERATIONS, determine=False)
        heldout["equation error"] += _sum_score(fold_model, ee, scored)
        heldout["output error"] += _sum_score(fold_model, fold_model.vessel(oe.values), scored)
    count = sum(len(s.state) for s in heldout_segments)
    heldout = {k: v / count for k, v in heldout.items()}
    better = heldout["output error"] < heldout["equation error"]
    if better:
        kept, reason = "output error", (f"held-out 20 s simulation error {heldout['output error']:.3g} against the "
                                        f"equation error's {heldout['equation error']:.3g}")
    else:
        kept, reason = "equation error", (f"the output-error fit does not predict held-out manoeuvres better "
                                          f"({heldout['output error']:.3g} against the equation error's "
                                          f"{heldout['equation error']:.3g}, 20 s segments)")
    say(f"output error: {kept} kept: {reason}")
    stage = OutputErrorStage(kept, reason, heldout, whole, {})
    if kept == "output error":
        frozen = [p if p.name not in whole.held else replace(p, low=0.0, high=0.0) for p in params]

        def refit(prior_scale: float) -> Fit:
            say(f"stability: refitting with the description's weight x {prior_scale:g}")
            return fit(model, frozen, {**whole.values}, shooting, iterations=FOLD_ITERATIONS, determine=False,
                       prior_scale=prior_scale)

        return _stable(result, model, params, whole.values, env, stage, say, refit)
    return _stable(result, model, params, start, env, stage, say)


def _select(s: Shooting, mask: np.ndarray) -> Shooting:
    return Shooting(s.dt, s.state[mask], s.controls[mask], s.reference[mask], s.target[mask], s.weight[mask],
                    s.manoeuvre[mask], s.start[mask], s.commands)


def _sum_score(model: Model, vessel: Vessel, shooting: Sequence[Shooting]) -> float:
    return sum(segment_score(model, vessel, [s]) * len(s.state) for s in shooting)


def _value_in(vessel: Vessel, name: str, default: float) -> float:
    """A parameter's value in a vessel (the hull coefficients; the rest: default)."""
    if vessel.hull_model_name == "small_craft":
        return float(getattr(vessel.small_craft, name)) if name in SMALL_CRAFT_HULL else default
    return float(getattr(vessel.hull, name)) if name in HULL_NAMES else default


def _stable(result: IdentificationResult, model: Model, params: Sequence[Parameter], values: Mapping[str, float],
            env: Envelope, stage: OutputErrorStage, say: Callable[[str], None],
            refit: Callable[[float], Fit] | None = None) -> IdentificationResult:
    """The kept values checked over the envelope, made into the result. A failing output-error model is refitted
    with the description's weight x PRIOR_STEPS (refit) first, the first that passes kept; failing still (or an
    equation-error model), regularise blends it towards the description."""
    refits: list[str] = []
    first = check_envelope(model, model.vessel(values), env)
    prior_scale = 1.0
    if first is not None and refit is not None:
        description = check_envelope(model, model.vessel({p.name: p.prior for p in params}), env)
        if not (description is not None and description.startswith(COURSE_UNSTABLE)
                and first.startswith(COURSE_UNSTABLE)):
            for scale in PRIOR_STEPS:
                trial = refit(scale)
                reason = check_envelope(model, model.vessel(trial.values), env)
                refits.append(f"prior x {scale:g}: {reason or 'passes'}")
                if reason is None:
                    values, prior_scale = trial.values, scale
                    stage = replace(stage, fit=replace(trial, held=stage.fit.held if stage.fit else ()))
                    break
    kept, alpha, failure, failures = regularise(model, params, values, env)
    failure = failure or (first if prior_scale > 1.0 else None)
    stability = {"envelope_rows": int(len(env.state)), "seconds": env.steps * env.dt, "margin": ENVELOPE_MARGIN,
                 "speed_mps": env.speed, "yaw_rate_rad_s": env.yaw_rate, "stable": first is None and not failures,
                 "failure": failure, "alpha": alpha, "prior_weight": prior_scale, "refits": refits,
                 "tried": failures}
    if failure is None and failures:
        say(f"stability: the kept model is {failures[-1].split(': ', 1)[1]}")
    elif failure is None:
        say(f"stability: the kept model settles over the envelope ({len(env.state)} rows, {env.steps * env.dt:.0f} s, "
            f"+{ENVELOPE_MARGIN:.0%} beyond the trials)")
    else:
        say(f"stability: the kept model {failure}; regularised towards the description (alpha {alpha:g})")
    stage = replace(stage, stability=stability)
    vessel = model.vessel(kept)
    if any(not math.isfinite(x) for x in kept.values()):
        raise NotIdentifiableError(f"the identified model has coefficients that are not finite: "
                                   f"{[n for n, x in kept.items() if not math.isfinite(x)]}")
    return _result(result, vessel, params, kept, stage, alpha)


def _result(result: IdentificationResult, vessel: Vessel, params: Sequence[Parameter], values: Mapping[str, float],
            stage: OutputErrorStage, alpha: float) -> IdentificationResult:
    """The result with the kept model's vessel and coefficients (status, interval, prior) and the stage's note."""
    f = stage.fit if stage.kept == "output error" else None
    by_name = {p.name: p for p in params}
    description = result.prior or result.vessel

    def coefficient(c: Coefficient) -> Coefficient:
        if c.name not in by_name:
            return c
        p = by_name[c.name]
        value = values[c.name]
        estimate = value * ident_factor(description, c.name) if c.name in MULTIPLES else value
        if f is None:
            return replace(c, estimate=estimate, status=REGULARISED) if alpha < 1.0 and estimate != c.estimate else c
        scale = ident_factor(description, c.name) if c.name in MULTIPLES else 1.0
        ci = tuple(x * scale for x in f.ci95[c.name])
        prior = p.prior * scale
        if c.name in f.held:
            return Coefficient(c.name, prior, ci, prior, "fixed to prior", f.rel_ci[c.name])
        return Coefficient(c.name, estimate, (float(ci[0]), float(ci[1])), prior,
                           REGULARISED if alpha < 1.0 else "identified", f.rel_ci[c.name])

    fit_ = result.fit
    equations = tuple(replace(e, coefficients=tuple(coefficient(c) for c in e.coefficients)) for e in fit_.equations)
    if hasattr(fit_, "all_coefficients"):
        fit_ = replace(fit_, equations=equations,
                       all_coefficients=tuple(coefficient(c) for c in fit_.all_coefficients))
    else:
        fit_ = replace(fit_, equations=equations)
    if f is not None:
        fit_ = replace(fit_, not_identifiable=tuple(dict.fromkeys((*fit_.not_identifiable, *f.held))))
    actuators = [coefficient(c) for c in result.actuator_coefficients]
    present = {c.name for c in actuators} | {c.name for c in fit_.coefficients()}
    if f is not None:  # a factor the search did not report (description kept) but the output error fitted
        for p in params:
            if p.name not in present:
                scale = ident_factor(description, p.name) if p.name in MULTIPLES else 1.0
                actuators.append(coefficient(Coefficient(p.name, p.prior * scale, (math.nan, math.nan),
                                                         p.prior * scale, "fixed to prior", math.inf)))
    note = f"output error: {stage.kept} kept ({stage.reason})"
    if stage.stability.get("prior_weight", 1.0) > 1.0:
        note += (f"; refitted with the description's weight x {stage.stability['prior_weight']:g}: the fitted model "
                 f"{stage.stability.get('failure')}")
    if alpha < 1.0:
        note += (f"; regularised towards the description (alpha {alpha:g}): the fitted model "
                 f"{stage.stability.get('failure')}")
    return replace(result, vessel=vessel, fit=fit_, actuator_coefficients=tuple(actuators),
                   data=tuple(with_known_forces(vessel, result.data)), notes=(*result.notes, note),
                   output_error=stage.to_json())


def ident_factor(description: Vessel, name: str) -> float:
    """What a multiple-valued parameter multiplies: the description's interaction factor (interaction.factor_value) or
    time constant (s)."""
    if name == LAG_NAMES["twin_thrusters"]:
        return description.thrusters.port.time_constant_s
    if name == LAG_NAMES["rudder_throttle"]:
        return description.throttle.time_constant_s
    from usv_predictor.fitting.interaction import factor_value

    return factor_value(description, name)

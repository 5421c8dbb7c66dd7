"""Grey-box identification of the hull derivatives by inverse-dynamics regression (seed 001 sec. 3.2).

Pipeline (one Recording = one manoeuvre):
 1. accelerations nu_dot by the EKF + RTS smoother (usv_predictor.data.smoother), not by finite differences;
 2. inverse dynamics, the left-hand side of the MMG equations of motion (Yasukawa & Yoshimura 2015 eq. 4;
    Fossen 2021 eq. 6.5 with the hull on the right):
        X = m11 u_dot - m22 v r - x_G m r^2
        Y = m22 v_dot + m23 r_dot + m11 u r
        N = m32 v_dot + m33 r_dot + x_G m u r
    with M = M_RB + M_A from the vessel description (Vessel.mass_matrix(): rigid body from displacement, x_G and
    k_zz; added mass m_x', m_y', J_z' of the preset, whose provenance names the source, e.g. Yasukawa & Yoshimura
    2015 Table 3 for the KVLCC2);
 3. minus the known parts: propeller thrust (MMG eq. 10-12) and the semi-empirical MMG rudder model (eq. 13-16,
    37-43) held as PRIOR knowledge -- seed 001 sec. 4: identifying hull and rudder together from free-running
    data splits the yaw moment wrongly between them (multicollinearity, seed 001 Fig. 4, 13); the
    semi-empirical rudder guides the regression to a physically right split;
 4. what remains is the hull force; non-dimensionalised (X' = X / (0.5 rho L d U^2), N' = N / (0.5 rho L^2 d U^2))
    it is linear in the hull derivatives of a candidate structure:
        mmg       the MMG hull polynomial (Yasukawa & Yoshimura 2015 eq. 8), the 17 derivatives of vessel.Hull;
        abkowitz  an Abkowitz-type Taylor expansion about the approach speed (Abkowitz 1964): the MMG terms plus
                  bias (Y_0, N_0) and speed-coupling terms (X_du, Y_duv, Y_dur, N_duv, N_dur; du' = (u - u0) / U);
    solved by linear least squares for each equation;
 5. diagnostics: 95 % confidence intervals (with the sample count reduced to an effective count by the lag-1
    autocorrelation of the residuals, because time-series residuals are not independent), the correlation
    matrix of the regressors (pairs with |rho| > 0.9 are reported as multicollinear), the condition number of
    the column-scaled regressor matrix, variance inflation factors;
 6. a coefficient whose 95 % CI half-width exceeds `rel_ci_limit` of its magnitude (max of estimate and prior)
    is NOT identifiable from these data. Then, by `prior`:
        "none"  NotIdentifiableError naming them, with the options below (never silent nonsense);
        "fix"   fix them to the preset's values (prior knowledge) and refit the others, until all are identifiable;
        "ridge" ridge regression towards the preset's values for all coefficients, penalty chosen by
                cross-validation across manoeuvres;
 7. candidate structures are compared by leave-one-manoeuvre-out cross-validation of the hull forces.
Result: the vessel with its hull replaced (usable by GreyBoxRollout) and, for "abkowitz", the extra terms.

Actuator layouts (physics/actuators.py), each through the actuator levels the forces act with (actuator_levels):
    rudder_propeller  rudder angle and engine speed as measured (the method above).
    rudder_throttle   the throttle command lagged by its thrust map's time constant (the exact first-order lag of the
                      grey box); the map's gain (throttle.forward_N, the static thrust at full command) is identified
                      by a profile over the gain (the propeller thrust is not linear in it: n = sqrt(T0 / rho D^4 k0)),
                      the hull by the regression at each gain; its 95 % CI from the profile (likelihood ratio).
    rudder_only       no propulsion data: the equivalent engine speed of each manoeuvre is the one that holds its
                      approach speed (data.recording.approach_state) in straight running with the vessel file's
                      resistance
                      (dynamics.RudderPropellerForces.engine_speed_for), held over the manoeuvre. R0 is then fixed to
                      the vessel file's: it defines that engine speed, the data cannot tell it apart from the thrust.
                      Supports heading and track at a constant engine setting, not speed changes.
    twin_thrusters    with the small_craft hull: fitting/small_craft_identification.py (hull damping and the thrust
                      gain of each side in one regression of the three equations).
"""
from __future__ import annotations

import functools
import hashlib
import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from usv_predictor.atomic import finite_or_none
from usv_predictor.data.recording import APPROACH_S, Recording, approach_state, straight_samples
from usv_predictor.data.smoother import Smoothed, SmootherConfig, smooth_recording
from usv_predictor.errors import ConfigError, DatasetError, NotIdentifiableError
from usv_predictor.models.greybox import HULL_NAMES
from usv_predictor.models.hybrid import EXTRA_NAMES
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.vessel import Hull, ThrustMap, Vessel

EQUATIONS = ("X", "Y", "N")
STRUCTURES = ("mmg", "abkowitz")  # of the MMG hull
STRUCTURES_OF = {"mmg": STRUCTURES, "small_craft": ("diagonal", "coupled")}  # hull model -> candidate structures
ALL_STRUCTURES = tuple(s for names in STRUCTURES_OF.values() for s in names)
PRIORS = ("none", "fix", "ridge")
COLLINEAR_RHO = 0.9  # |rho| above which a regressor pair is reported as multicollinear
REL_CI_LIMIT = 0.5  # a 95 % CI half-width above this fraction of the magnitude: not identifiable
MAGNITUDE_FLOOR = 1e-3  # non-dimensional magnitude below which a coefficient counts as zero
MIN_MANOEUVRES = 2  # cross-validation needs at least one manoeuvre to hold out
SPEED_RATIO_RANGE = (0.6, 1.6)  # measured / preset straight-running speed accepted as "the same vessel and scale"
RIDGE_GRID = (1e-4, 1e-3, 1e-2, 1e-1, 1.0)  # penalty weights (relative to the data term) tried by CV
Z95 = 1.959964
# the layouts whose rudder / propeller interaction factors `interaction="identify"` searches (fitting/interaction.py
# SEARCHED_FACTORS says which factors each layout has). rudder_only searched: 20 of 24 unknown boats right against 7
# of 24 held (docs/results/unknown_boats.md); the actuator delay of 0.024 s its searched factors left the lean suite's
# secret clean small boat with is no candidate since the diagnosis names no delay under a quarter step
# (physics/effects.py actuator_delay)
INTERACTION_LAYOUTS = ("rudder_propeller", "rudder_only")
CHI2_95 = 3.841459  # 95 % quantile of chi-square with 1 degree of freedom (profile-likelihood intervals)
PROFILE_SPAN = 4.0  # a profiled gain is searched within [prior / span, prior * span]
PROFILE_POINTS = 17  # coarse grid of the profile (log-spaced), refined by golden section


# ------------------------------------------------------------------------------------------ structures


def _terms(structure: str) -> dict[str, tuple[str, ...]]:
    """Coefficient names per equation of a structure, MMG names in HULL_NAMES order."""
    if structure not in STRUCTURES:
        raise ConfigError(f"unknown model structure {structure!r}; use one of {list(STRUCTURES)}")
    mmg = {eq: tuple(n for n in HULL_NAMES if (n[0] == eq or (eq == "X" and n == "R0"))) for eq in EQUATIONS}
    if structure == "mmg":
        return mmg
    extra = {eq: tuple(n for n in EXTRA_NAMES if n[0] == eq) for eq in EQUATIONS}
    return {eq: mmg[eq] + extra[eq] for eq in EQUATIONS}


def coefficient_names(structure: str) -> tuple[str, ...]:
    terms = _terms(structure)
    return tuple(n for eq in EQUATIONS for n in terms[eq])


def regressor(name: str, u: np.ndarray, vp: np.ndarray, rp: np.ndarray, U: np.ndarray, u0: float) -> np.ndarray:
    """Column of the non-dimensional regressor of coefficient `name` (v' = v/U, r' = r L/U)."""
    du = (u - u0) / U
    body = name.split("_", 1)[1] if "_" in name else name
    if name == "R0":
        return -u * np.abs(u) / (U * U)
    table: dict[str, Callable[[], np.ndarray]] = {
        "vv": lambda: vp**2, "vr": lambda: vp * rp, "rr": lambda: rp**2, "vvvv": lambda: vp**4,
        "v": lambda: vp, "r": lambda: rp, "vvv": lambda: vp**3, "vvr": lambda: vp * vp * rp,
        "vrr": lambda: vp * rp * rp, "rrr": lambda: rp**3,
        "du": lambda: du, "0": lambda: np.ones_like(u), "duv": lambda: du * vp, "dur": lambda: du * rp,
    }
    if body not in table:
        raise ConfigError(f"no regressor for coefficient {name!r}")
    return table[body]()


# ------------------------------------------------------------------------------------------ data


@dataclass(frozen=True)
class ForceData:
    """Inverse dynamics of one manoeuvre: forces (N, N, N m) at midship, body frame, on the recording grid."""

    name: str
    t_s: np.ndarray  # (T,)
    nu: np.ndarray  # (T, 3) smoothed u, v, r
    nu_dot: np.ndarray  # (T, 3) smoothed accelerations
    nu_dot_std: np.ndarray  # (T, 3)
    controls: np.ndarray  # (T, 2) actuator levels the forces act with (actuator_levels): delta (rad), rpm, ...
    total: np.ndarray  # (T, 3) M nu_dot + C(nu) nu: all external forces
    rudder: np.ndarray  # (T, 3) steering forces: the rudder model (prior), a twin's thrust difference
    propeller: np.ndarray  # (T, 3) propulsion forces: the propeller (prior), a twin's summed thrust
    keep: np.ndarray  # (T,) bool: samples used for regression (speed, smoother edges)
    actuator: Mapping[str, float] = field(default_factory=dict)  # per-manoeuvre actuator estimates (rudder_only)

    @property
    def hull(self) -> np.ndarray:
        return self.total - self.rudder - self.propeller


def inverse_dynamics_forces(vessel: Vessel, nu: np.ndarray, nu_dot: np.ndarray) -> np.ndarray:
    """(T, 3) [X, Y, N] = M nu_dot + C(nu) nu (module docstring, step 2); for the small-craft hull C includes the
    added-mass Coriolis yaw term, the Munk moment -(Y_vdot - X_udot) u v (Fossen 2021 eq. 6.43; MMG has it in N_v)."""
    m = ManoeuvringModel(vessel)
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    ud, vd, rd = nu_dot[:, 0], nu_dot[:, 1], nu_dot[:, 2]
    x = m.m11 * ud - m.m22 * v * r - m.x_G * m.m * r * r
    y = m.m22 * vd + m.m23 * rd + m.m11 * u * r
    n = m.m32 * vd + m.m33 * rd + m.x_G * m.m * u * r - m.munk * u * v
    return np.column_stack([x, y, n])


def lagged_command(command: np.ndarray, time_constant_s: float, dt: float) -> np.ndarray:
    """(T,) level of a first-order motor (time constant T, 0 = instantaneous) following a command sampled at dt and
    moving linearly between samples, starting at the first command (steady running): the exact solution
    y_{k+1} = c_{k+1} - T s + (y_k - c_k + T s) exp(-dt / T), s = (c_{k+1} - c_k) / dt, as models/greybox.CommandLag."""
    c = np.asarray(command, dtype=float)
    if time_constant_s <= 0.0 or len(c) == 0:
        return c.copy()
    decay = math.exp(-dt / time_constant_s)
    y = np.empty_like(c)
    y[0] = c[0]
    for k in range(len(c) - 1):
        trail = time_constant_s * (c[k + 1] - c[k]) / dt
        y[k + 1] = c[k + 1] - trail + (y[k] - c[k] + trail) * decay
    return y


def approach_speed(recording: Recording) -> float:
    """Speed (m/s) of a recording's approach (data.recording.approach_state: its straight running before the first
    turn command, at least the first APPROACH_S): the speed its engine setting holds, the one evaluate and diagnose
    hold in every prediction of the manoeuvre (models/greybox.py `reference`)."""
    u, v, _, _ = approach_state(recording.nu, recording.psi, recording.dt,
                                straight_samples(recording.controls, recording.actuator_layout))
    return float(math.hypot(u, v))


def actuator_levels(vessel: Vessel, recording: Recording) -> tuple[np.ndarray, dict[str, float]]:
    """((T, 2) the actuator levels the force model acts with, per-manoeuvre estimates) for the vessel's layout:
    rudder_propeller the measured [delta, rpm]; rudder_throttle [delta, lagged throttle]; rudder_only [delta, the
    equivalent engine speed of the approach speed] (estimates: engine_speed_rpm, approach_speed_mps);
    twin_thrusters [lagged port, lagged starboard] commands."""
    layout = vessel.actuator_layout
    controls = recording.controls
    if controls.shape[1:] != (len(layout.controls),):
        raise DatasetError(f"{recording.name}: controls {controls.shape} are not those of the vessel's actuator layout "
                           f"{layout.name} {list(layout.control_names)}")
    if layout.name == "rudder_propeller":
        return controls.copy(), {}
    if layout.name == "rudder_throttle":
        return np.column_stack([controls[:, 0], lagged_command(controls[:, 1], vessel.throttle.time_constant_s,
                                                               recording.dt)]), {}
    if layout.name == "rudder_only":
        speed = approach_speed(recording)
        rpm = ManoeuvringModel(vessel).engine_speed_for(speed)
        return (np.column_stack([controls[:, 0], np.full(len(controls), rpm)]),
                {"approach_speed_mps": speed, "engine_speed_rpm": rpm})
    if layout.name == "twin_thrusters":
        t = vessel.thrusters
        return np.column_stack([lagged_command(controls[:, 0], t.port.time_constant_s, recording.dt),
                                lagged_command(controls[:, 1], t.starboard.time_constant_s, recording.dt)]), {}
    raise ConfigError(f"identification does not know the actuator layout {layout.name!r}")


def known_forces(vessel: Vessel, nu: np.ndarray, controls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(steering (T, 3), propulsion (T, 3)) of the vessel's actuator force model at the actuator levels `controls`
    (actuator_levels): the rudder and propeller of the preset's semi-empirical models, or the thrusters' maps
    (calm water, nu through water)."""
    return ManoeuvringModel(vessel).actuator_loads_many(nu, controls)


def check_vessel_matches(vessel: Vessel, recording: Recording) -> None:
    """ConfigError when the data cannot come from this vessel description (scale, speed, rpm): the measured speed
    against the vessel's straight-running speed at the recorded propulsion command (rudder_propeller: the approach
    rpm; rudder_throttle: the approach throttle; twin_thrusters: the median mean command against the median speed).
    rudder_only has no propulsion record: its engine speed is defined by the speed (nothing to check)."""
    layout = vessel.actuator_layout
    if layout.name == "rudder_only":
        return
    if layout.name == "rudder_propeller":
        rpm = recording.controls[:, 1]
        if not np.all(np.isfinite(rpm)) or float(np.median(rpm)) <= 0.0:
            raise DatasetError(f"{recording.name}: no engine speed (rpm) in the data: the propeller thrust, the "
                               "rudder inflow and with them R0 and every speed-dependent term cannot be separated; "
                               "identification needs the engine_rpm topic (or a vessel of layout rudder_only)")
    start: slice | np.ndarray = slice(0, max(2, int(round(APPROACH_S / recording.dt))))
    if layout.name == "twin_thrusters":  # runs start anywhere: judge the samples with equal commands on both sides
        start = np.abs(layout.steering_signal(recording.controls)) < layout.straight_below
        if start.sum() * recording.dt < APPROACH_S:
            return  # hardly ever straight: nothing to compare with
    rpm0 = float(np.median(layout.propulsion_signal(recording.controls[start])))
    speed0 = float(np.median(np.hypot(recording.nu[start, 0], recording.nu[start, 1])))
    expected = ManoeuvringModel(vessel).straight_speed(rpm0)
    if expected <= 0.0 and layout.name != "rudder_propeller":
        return  # a command inside the dead band: no straight speed to compare with
    L = vessel.geometry.L_pp
    froude = speed0 / math.sqrt(9.81 * L)
    low, high = SPEED_RATIO_RANGE
    ratio = speed0 / expected if expected > 0.0 else math.inf
    if not low <= ratio <= high:
        raise ConfigError(
            f"vessel description {vessel.name!r} (L_pp {L:g} m) is inconsistent with the data of {recording.name}: "
            f"at the propulsion command {rpm0:.4g} ({layout.propulsion_input.unit if layout.propulsion_input else ''}) "
            f"the preset runs straight at {expected:.2f} m/s, the data show {speed0:.2f} m/s "
            f"(ratio {ratio:.2f}, accepted {low}-{high}; Froude number {froude:.2f} for this L_pp). A recording of "
            "another scale (model vs full) or another vessel? Use the preset of that vessel and scale, or "
            "Froude-scale the data first (--scale L_data / L_vessel)")


def force_data(vessel: Vessel, recording: Recording, smoothed: Smoothed, *, edge_s: float = 2.0,
               min_speed_fraction: float = 0.3) -> ForceData:
    """Inverse dynamics and the known forces of one smoothed manoeuvre."""
    nu, nu_dot = smoothed.nu, smoothed.nu_dot
    total = inverse_dynamics_forces(vessel, nu, nu_dot)
    levels, estimates = actuator_levels(vessel, recording)
    rudder, propeller = known_forces(vessel, nu, levels)
    speed = np.hypot(nu[:, 0], nu[:, 1])
    edge = int(round(edge_s / recording.dt))
    keep = speed >= min_speed_fraction * float(np.median(speed))
    keep[:edge] = False
    keep[len(keep) - edge:] = False
    return ForceData(recording.name, recording.t_s, nu, nu_dot, smoothed.nu_dot_std, levels, total,
                     rudder, propeller, keep, estimates)


def prepare(vessel: Vessel, recordings: Sequence[Recording], *, smoother: SmootherConfig = SmootherConfig(),
            progress: Callable[[str], None] | None = None) -> list[ForceData]:
    """Check, smooth and invert every recording."""
    out = []
    for k, rec in enumerate(recordings):
        check_vessel_matches(vessel, rec)
        if progress is not None:
            progress(f"[{k + 1}/{len(recordings)}] smoothing {rec.name} ({rec.duration_s:.0f} s at {rec.dt:g} s)")
        out.append(force_data(vessel, rec, smooth_recording(rec, smoother)))
    return out


# ------------------------------------------------------------------------------------------ regression


@dataclass(frozen=True)
class Design:
    """Non-dimensional regression problem of one equation over several manoeuvres."""

    equation: str
    names: tuple[str, ...]
    matrix: np.ndarray  # (n, p)
    target: np.ndarray  # (n,)
    groups: np.ndarray  # (n,) manoeuvre index of each row
    scale: np.ndarray  # (n,) force per unit non-dimensional value (q U^2 or q L U^2)


def design(vessel: Vessel, data: Sequence[ForceData], structure: str, equation: str, u0: float) -> Design:
    names = _terms(structure)[equation]
    g = vessel.geometry
    q = 0.5 * 1025.0 * g.L_pp * g.d
    column = EQUATIONS.index(equation)
    rows, targets, groups, scales = [], [], [], []
    for k, d in enumerate(data):
        nu = d.nu[d.keep]
        u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
        U = np.maximum(np.hypot(u, v), 1e-3)
        vp, rp = v / U, r * g.L_pp / U
        scale = q * U * U * (g.L_pp if equation == "N" else 1.0)
        rows.append(np.column_stack([regressor(n, u, vp, rp, U, u0) for n in names]))
        targets.append(d.hull[d.keep, column] / scale)
        groups.append(np.full(len(u), k))
        scales.append(scale)
    if not rows or sum(len(t) for t in targets) == 0:
        raise DatasetError("no samples left for regression (all below the speed limit or inside the smoother edges)")
    return Design(equation, names, np.vstack(rows), np.concatenate(targets), np.concatenate(groups),
                  np.concatenate(scales))


VIF_SINGULAR = 1e10  # (-) a VIF above this (1 - R^2 < 1e-10) is exact collinearity within rounding
VIF_NOTE = ("null: infinite variance inflation (the regressor is an exact linear combination of the others: the "
            "correlation matrix is singular); strict JSON holds no inf")


@dataclass(frozen=True)
class Collinearity:
    equation: str
    names: tuple[str, ...]
    correlation: np.ndarray  # (p, p) of the regressors (NaN for a constant column)
    condition_number: float  # of the column-scaled regressor matrix (inf: singular)
    vif: dict[str, float]  # variance inflation factors of the varying regressors (inf: exactly collinear)
    pairs: tuple[tuple[str, str, float], ...]  # |rho| > COLLINEAR_RHO
    constant: tuple[str, ...] = ()  # regressors that do not vary (the biases Y_0, N_0): no correlation, no VIF

    def to_json(self) -> dict:
        """JSON: a constant regressor has no VIF (listed in `constant_regressors`, null correlations); a singular
        design has condition_number null and `singular` true."""
        return {"equation": self.equation, "condition_number": finite_or_none(self.condition_number),
                "singular": not math.isfinite(self.condition_number)
                or any(not math.isfinite(v) for v in self.vif.values()),
                "vif": {name: finite_or_none(v) for name, v in self.vif.items()},
                **({"vif_note": VIF_NOTE} if any(not math.isfinite(v) for v in self.vif.values()) else {}),
                "constant_regressors": list(self.constant),
                "multicollinear_pairs": [{"a": a, "b": b, "rho": rho} for a, b, rho in self.pairs],
                "names": list(self.names),
                "correlation": [[finite_or_none(x) for x in row] for row in self.correlation.tolist()]}


def collinearity(d: Design) -> Collinearity:
    """Correlation matrix, condition number and VIFs of a design's regressors."""
    a = d.matrix
    std = a.std(axis=0)
    centred = (a - a.mean(axis=0)) / np.where(std > 0, std, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = (centred.T @ centred) / len(a)
    corr[:, std == 0] = np.nan
    corr[std == 0, :] = np.nan
    norms = np.linalg.norm(a, axis=0)
    s = np.linalg.svd(a / np.where(norms > 0, norms, 1.0), compute_uv=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else math.inf
    # VIF_j = [R^-1]_jj over the varying regressors only: a constant column (a bias term) has no variance to
    # inflate, so it has no VIF (it used to be NaN, which JSON cannot hold)
    varying = std > 0
    names = [name for name, var in zip(d.names, varying) if var]
    sub = corr[np.ix_(varying, varying)]
    try:
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            diagonal = np.diag(np.linalg.inv(sub))
        # VIF = 1 / (1 - R^2) >= 1; below 1, above VIF_SINGULAR or not finite: a numerically singular R (exact
        # collinearity to rounding), whose inverse is rounding noise
        vif = {name: float(v) if math.isfinite(v) and 1.0 - 1e-6 <= v <= VIF_SINGULAR else math.inf
               for name, v in zip(names, diagonal)}
    except np.linalg.LinAlgError:
        vif = {name: math.inf for name in names}
    pairs = tuple((d.names[i], d.names[j], float(corr[i, j])) for i in range(len(d.names))
                  for j in range(i + 1, len(d.names)) if math.isfinite(corr[i, j]) and abs(corr[i, j]) > COLLINEAR_RHO)
    constant = tuple(name for name, var in zip(d.names, varying) if not var)
    return Collinearity(d.equation, d.names, corr, cond, vif, pairs, constant)


@dataclass(frozen=True)
class Coefficient:
    name: str
    estimate: float
    ci95: tuple[float, float]
    prior: float
    status: str  # "identified" | "fixed to prior" | "ridge towards prior" | REGULARISED | SEARCH_BOX
    rel_ci: float  # 95 % CI half-width / max(|estimate|, |prior|, floor)

    def to_json(self) -> dict:
        """Strict JSON: an unbounded CI or rel_ci (no excitation) is null."""
        return {"name": self.name, "estimate": finite_or_none(self.estimate),
                "ci95": [finite_or_none(x) for x in self.ci95], "prior": self.prior, "status": self.status,
                "rel_ci": finite_or_none(self.rel_ci)}


@dataclass(frozen=True)
class EquationFit:
    equation: str
    coefficients: tuple[Coefficient, ...]
    # () -> the design's collinearity, computed on first use of `collinearity`: only reports read it (the JSON,
    # identify's messages), and the cross-validation's many fits of one equation never do (an SVD of the design each)
    collinearity_of: Callable[[], Collinearity] = field(repr=False, compare=False)
    residual_rms: float  # non-dimensional
    effective_samples: float
    ridge_weight: float = 0.0

    @functools.cached_property
    def collinearity(self) -> Collinearity:
        return self.collinearity_of()

    def values(self) -> dict[str, float]:
        return {c.name: c.estimate for c in self.coefficients}


def effective_samples(residual: np.ndarray, groups: np.ndarray) -> float:
    """n (1 - rho1) / (1 + rho1) with rho1 the lag-1 autocorrelation of the residuals within manoeuvres."""
    num, den = 0.0, 0.0
    for g in np.unique(groups):
        e = residual[groups == g]
        e = e - e.mean()
        num += float(np.sum(e[1:] * e[:-1]))
        den += float(np.sum(e * e))
    rho = min(max(num / den, 0.0), 0.999) if den > 0 else 0.0
    return max(len(residual) * (1.0 - rho) / (1.0 + rho), 2.0)


def _solve(a: np.ndarray, y: np.ndarray, prior: np.ndarray, free: np.ndarray, ridge: float,
           penalty_scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(theta (p,), unscaled covariance factor (p_free, p_free)) of LS on the free columns, the rest at prior;
    ridge > 0 adds ridge * n * sum(((theta - prior) / penalty_scale)^2) on the free columns."""
    theta = prior.copy()
    y_free = y - a[:, ~free] @ prior[~free]
    af = a[:, free]
    norms = np.linalg.norm(af, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    scaled = af / norms  # column scaling keeps the normal equations well conditioned
    gram = scaled.T @ scaled
    rhs = scaled.T @ y_free
    if ridge > 0.0:
        weight = ridge * len(y) / (penalty_scale[free] * norms) ** 2
        gram = gram + np.diag(weight)
        rhs = rhs + weight * prior[free] * norms
    cov = np.linalg.pinv(gram)
    theta[free] = (cov @ rhs) / norms
    return theta, cov / np.outer(norms, norms)



def coefficient_status(free: bool, ridge: float) -> str:
    """How a coefficient was estimated: held at the prior, pulled towards it by a ridge, or identified."""
    if not free:
        return "fixed to prior"
    return "ridge towards prior" if ridge > 0.0 else "identified"

def fit_equation(d: Design, prior: Mapping[str, float], *, fixed: Sequence[str] = (),
                 ridge: float = 0.0) -> EquationFit:
    """Least squares (or ridge) of one equation; CIs with the effective sample count."""
    names = d.names
    prior_vec = np.array([prior.get(n, 0.0) for n in names])
    free = np.array([n not in fixed for n in names])
    scale = np.maximum(np.abs(prior_vec), 10 * MAGNITUDE_FLOOR)
    theta, cov = _solve(d.matrix, d.target, prior_vec, free, ridge, scale)
    residual = d.target - d.matrix @ theta
    n_eff = effective_samples(residual, d.groups)
    n, p_free = len(residual), int(free.sum())
    sigma2 = float(residual @ residual) / max(n - p_free, 1)
    # OLS covariance sigma^2 (A^T A)^-1, inflated by n / n_eff for the autocorrelated residuals
    var = np.zeros(len(names))
    var[free] = np.diag(cov) * sigma2 * n / n_eff
    coefficients = []
    for k, name in enumerate(names):
        half = Z95 * math.sqrt(max(var[k], 0.0))
        magnitude = max(abs(theta[k]), abs(prior_vec[k]), MAGNITUDE_FLOOR)
        coefficients.append(Coefficient(name, float(theta[k]), (float(theta[k] - half), float(theta[k] + half)),
                                        float(prior_vec[k]), coefficient_status(bool(free[k]), ridge),
                                        half / magnitude))
    return EquationFit(d.equation, tuple(coefficients), functools.partial(collinearity, d),
                       float(np.sqrt(np.mean(residual**2))), n_eff, ridge)


MMG_SIGN = {"R0": +1, "Y_v": -1, "N_r": -1, "Y_vvv": -1}  # +1: >= 0, -1: <= 0 for every ship (resistance, sway
# and yaw damping, the growth of sway damping with drift; Yasukawa & Yoshimura 2015 Table 3 and Table 4's ships)


MMG_SIGN_TEXT = ", ".join(f"{n} {'>=' if v > 0 else '<='} 0" for n, v in MMG_SIGN.items())


def not_identifiable(fit: EquationFit, rel_ci_limit: float = REL_CI_LIMIT) -> list[str]:
    """Free coefficients whose CI is too wide, or whose estimate has the sign no ship has (MMG_SIGN: not physical)."""
    return [c.name for c in fit.coefficients if c.status == "identified"
            and (c.rel_ci > rel_ci_limit or MMG_SIGN.get(c.name, 0) * c.estimate < 0.0)]


# ------------------------------------------------------------------------------------------ prior policies


@dataclass(frozen=True)
class HullFit:
    structure: str
    prior_policy: str
    equations: tuple[EquationFit, ...]
    not_identifiable: tuple[str, ...]  # before any prior was applied
    u0: float  # reference speed of the abkowitz du' terms (m/s)

    def values(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for e in self.equations:
            out.update(e.values())
        return out

    def coefficients(self) -> list[Coefficient]:
        return [c for e in self.equations for c in e.coefficients]


def prior_values(vessel: Vessel, structure: str) -> dict[str, float]:
    values = {n: float(getattr(vessel.hull, n)) for n in HULL_NAMES}
    values.update({n: 0.0 for n in coefficient_names(structure) if n not in values})
    return values


# The trial that would determine each coefficient these manoeuvres may leave undetermined (refused, held at or pulled
# to the description's value): one record per coefficient, said in identify's message and JSON (`held[]
# .would_determine`) and in the refusal. MMG hull (rudder boats; v' = v/U, r' = r L/U): the linear terms need both
# signs of v' and r' (zig-zags both ways), a term of r' alone two yaw rates (two rudder angles), the cubic and cross
# terms large drift and yaw rate (hard-over turns), the speed terms two speeds. The small-craft hull's table is
# small_craft_identification.WOULD_DETERMINE.
WOULD_DETERMINE: Mapping[str, str] = {
    "R0": "straight runs at two engine speeds with the engine speed recorded (engine_rpm)",
    "X_vv": "turning circles both ways (the speed lost in a steady turn)",
    "X_vr": "turning circles both ways (the speed lost in a steady turn)",
    "X_rr": "turning circles both ways (the speed lost in a steady turn)",
    "X_vvvv": "hard-over turning circles both ways (large drift angles)",
    "Y_v": "zig-zags both ways",
    "Y_r": "zig-zags both ways",
    "Y_vvv": "hard-over turning circles both ways (large drift angles)",
    "Y_vvr": "turning circles at two rudder angles both ways",
    "Y_vrr": "turning circles at two rudder angles both ways",
    "Y_rrr": "hard-over turning circles both ways (large yaw rates)",
    "N_v": "zig-zags both ways",
    "N_r": "turning circles at two rudder angles both ways",
    "N_vvv": "hard-over turning circles both ways (large drift angles)",
    "N_vvr": "turning circles at two rudder angles both ways",
    "N_vrr": "turning circles at two rudder angles both ways",
    "N_rrr": "hard-over turning circles both ways (large yaw rates)",
    "X_du": "straight runs at two speeds",
    "Y_0": "turns both ways (a bias shows as a port-starboard difference)",
    "N_0": "turns both ways (a bias shows as a port-starboard difference)",
    "Y_duv": "zig-zags at two speeds",
    "Y_dur": "zig-zags at two speeds",
    "N_duv": "zig-zags at two speeds",
    "N_dur": "zig-zags at two speeds",
    "throttle.forward_N": "throttle steps (straight runs at two throttle settings)",
    "throttle.time_constant_s": "throttle steps at a steady speed (output-error stage)",
    "rudder.lift_factor": "zig-zags at two rudder angles both ways",
    "rudder.eta": "zig-zags at two rudder angles both ways",
    "rudder.gamma_R": "turning circles both ways (the drift in a steady turn)",
    "propeller.w_P0": "straight runs at two engine speeds",
    "propeller.t_P": "straight runs at two engine speeds",
}


def would_determine(name: str, table: Mapping[str, str] = WOULD_DETERMINE) -> str:
    """The trial that would determine coefficient `name` by a hull model's `table` (WOULD_DETERMINE, the MMG hull's;
    each hull model's in fitting/hull_models.HULL_FITS), for the message and JSON of a coefficient the data leave
    undetermined."""
    return table.get(name, "manoeuvres that excite it")


def trials_text(names: Sequence[str], table: Mapping[str, str] = WOULD_DETERMINE) -> str:
    """'N_r: turns ...; Y_r, N_v: zig-zags both ways': the coefficients grouped by the trial that would determine
    them (by the hull model's `table`, as would_determine), in the order first named."""
    groups: dict[str, list[str]] = {}
    for name in names:
        groups.setdefault(would_determine(name, table), []).append(name)
    return "; ".join(f"{', '.join(held)}: {trial}" for trial, held in groups.items())


def _message(names: Sequence[str], fits: Sequence[EquationFit], data_names: Sequence[str]) -> str:
    pairs = [f"{a}~{b} (rho {rho:+.2f})" for f in fits for a, b, rho in f.collinearity.pairs]
    conds = ", ".join(f"{f.equation}: {f.collinearity.condition_number:.3g}" for f in fits)
    return (f"coefficients not identifiable from {len(data_names)} manoeuvre(s) ({', '.join(data_names)}): "
            f"{', '.join(names)} (95 % CI wider than {REL_CI_LIMIT:.0%} of their size, or a sign no ship has: "
            f"{MMG_SIGN_TEXT}); condition numbers {conds}"
            + (f"; multicollinear regressors: {', '.join(pairs)}" if pairs else "")
            + ". Use --prior fix (prior='fix'): it holds only these at the vessel description's values and fits every "
              "other coefficient from the data alone, so the description's errors stay in the terms the data cannot "
              "see; --prior ridge (prior='ridge') pulls EVERY coefficient towards the description, identifiable ones "
              "included, and is better only when the whole description is trusted (compare the cross-validation "
              f"scores). Or record the trials that would determine them: {trials_text(names)}")


def _ridge_by_cv(designs: Sequence[Design], prior: Mapping[str, float], fixed: Sequence[str] = ()) -> float:
    """Ridge weight of RIDGE_GRID with the lowest leave-one-manoeuvre-out error (all equations)."""
    best, best_score = RIDGE_GRID[-1], math.inf
    for weight in RIDGE_GRID:
        score = sum(_cv_error(d, prior, fixed, weight) for d in designs)
        if score < best_score:
            best, best_score = weight, score
    return best


def fit_hull(vessel: Vessel, data: Sequence[ForceData], structure: str = "mmg", prior: str = "none", *,
             rel_ci_limit: float = REL_CI_LIMIT, u0: float | None = None, held: Sequence[str] = ()) -> HullFit:
    """Regression of every equation with the prior policy of the module docstring (step 6). held: coefficients the
    layout fixes to the vessel file's values whatever the data (rudder_only's R0), never flagged."""
    if prior not in PRIORS:
        raise ConfigError(f"unknown prior policy {prior!r}; use one of {list(PRIORS)}")
    u0 = float(np.median(np.concatenate([d.nu[:, 0] for d in data]))) if u0 is None else u0
    priors = prior_values(vessel, structure)
    designs = [design(vessel, data, structure, eq, u0) for eq in EQUATIONS]
    held = tuple(held)
    fits = [fit_equation(d, priors, fixed=held) for d in designs]
    flagged = [n for f in fits for n in not_identifiable(f, rel_ci_limit)]
    if flagged and prior == "none":
        raise NotIdentifiableError(_message(flagged, fits, [d.name for d in data]))
    if flagged and prior == "fix":
        # one at a time, the widest CI of each equation first: fixing one of a collinear pair often makes the
        # other identifiable, so fixing the whole flagged set at once would throw information away
        fixed: set[str] = set(held)
        for _ in range(len(coefficient_names(structure))):
            worst = [max((c for c in f.coefficients if c.name in not_identifiable(f, rel_ci_limit)),
                         key=lambda c: c.rel_ci) for f in fits if not_identifiable(f, rel_ci_limit)]
            if not worst:
                break
            fixed.update(c.name for c in worst)
            fits = [fit_equation(d, priors, fixed=tuple(fixed)) for d in designs]
    elif flagged and prior == "ridge":
        weight = _ridge_by_cv(designs, priors, held) if len({int(g) for g in designs[0].groups}) >= 2 else 1e-2
        fits = [fit_equation(d, priors, fixed=held, ridge=weight) for d in designs]
    return HullFit(structure, prior, tuple(fits), tuple(flagged), u0)


# ------------------------------------------------------------------------------------------ cross-validation


def _cv_error(d: Design, prior: Mapping[str, float], fixed: Sequence[str], ridge: float) -> float:
    """Held-out mean squared error / variance of the target, leave one manoeuvre out."""
    groups = np.unique(d.groups)
    if len(groups) < 2:
        raise DatasetError("cross-validation needs at least two manoeuvres")
    sq, count = 0.0, 0
    for g in groups:
        train, test = d.groups != g, d.groups == g
        sub = Design(d.equation, d.names, d.matrix[train], d.target[train], d.groups[train], d.scale[train])
        prior_vec = np.array([prior.get(n, 0.0) for n in d.names])
        free = np.array([n not in fixed for n in d.names])
        scale = np.maximum(np.abs(prior_vec), 10 * MAGNITUDE_FLOOR)
        theta, _ = _solve(sub.matrix, sub.target, prior_vec, free, ridge, scale)
        err = d.target[test] - d.matrix[test] @ theta
        sq += float(err @ err)
        count += len(err)
    return sq / count / max(float(np.var(d.target)), 1e-30)


@dataclass(frozen=True)
class CrossValidation:
    structure: str
    per_equation: dict[str, float]  # held-out MSE / variance of the hull force
    score: float  # mean over the equations

    def to_json(self) -> dict:
        return {"structure": self.structure,
                "per_equation_nmse": {k: finite_or_none(v) for k, v in self.per_equation.items()},
                "score": finite_or_none(self.score)}


def cross_validate(vessel: Vessel, data: Sequence[ForceData], fit: HullFit) -> CrossValidation:
    """Leave-one-manoeuvre-out error of a structure with the same fixed coefficients / ridge as `fit`."""
    priors = prior_values(vessel, fit.structure)
    per = {}
    for e in fit.equations:
        d = design(vessel, data, fit.structure, e.equation, fit.u0)
        fixed = [c.name for c in e.coefficients if c.status == "fixed to prior"]
        per[e.equation] = _cv_error(d, priors, fixed, e.ridge_weight)
    return CrossValidation(fit.structure, per, float(np.mean(list(per.values()))))


# ------------------------------------------------------------------------------------------ the whole job


@dataclass(frozen=True)
class IdentificationResult:
    vessel: Vessel  # the preset with the identified hull (and thrust maps)
    fit: HullFit  # of the chosen structure, on all data (small craft: small_craft_identification.JointFit)
    cross_validation: tuple[CrossValidation, ...]  # every candidate structure
    extra_terms: dict[str, float]  # abkowitz terms beyond the MMG hull (empty for mmg)
    data: tuple[ForceData, ...] = field(repr=False)
    notes: tuple[str, ...] = ()
    actuator_coefficients: tuple[Coefficient, ...] = ()  # profiled actuator gains (rudder_throttle's map gain)
    prior: Vessel | None = None  # the vessel file identified (what the exported model embeds: models/artifact.py)
    interaction: dict | None = None  # how the interaction factors were searched (fitting/interaction.py), or None
    trials: Mapping[str, str] = field(default_factory=lambda: WOULD_DETERMINE, repr=False)  # coefficient -> the
    # trial that would determine it, the hull model's table (fitting/hull_models.HULL_FITS)
    output_error: dict | None = None  # the output-error stage and stability check (fitting/output_error.py), or None

    @property
    def structure(self) -> str:
        return self.fit.structure

    def coefficients(self) -> list[Coefficient]:
        """Every coefficient: the fit's, then the profiled actuator gains."""
        return [*self.fit.coefficients(), *self.actuator_coefficients]

    def prior_used(self) -> list[str]:
        """The coefficients these manoeuvres do not determine (held at, or pulled to, the prior)."""
        return [c.name for c in self.coefficients() if not determined_by_data(c, self.fit.not_identifiable)]

    def held(self) -> list[dict]:
        """Per coefficient these manoeuvres do not determine (prior_used): its name, value, the description's value,
        how the prior set it and the trial that would determine it (`trials`)."""
        return [{"name": c.name, "value": finite_or_none(c.estimate), "prior": finite_or_none(c.prior),
                 "how": PRIOR_HOW.get(c.status, f"prior policy {self.fit.prior_policy}"),
                 "would_determine": would_determine(c.name, self.trials)}
                for c in self.coefficients() if not determined_by_data(c, self.fit.not_identifiable)]

    def held_message(self) -> str:
        """One line: the coefficients held at (or pulled to) the description's values and the trials that would
        determine them; "" when the data determine every coefficient."""
        names = self.prior_used()
        if not names:
            return ""
        return (f"not determined by these manoeuvres, so the vessel file's values ({self.fit.prior_policy}): "
                f"{', '.join(names)}; the trials that would determine them: "
                f"{trials_text(names, self.trials)}")

    def excitation(self) -> dict:
        """The range of drift angle and non-dimensional yaw rate the data cover (what the identified terms are fitted
        on); a manoeuvre beyond it extrapolates the nonlinear terms."""
        return excitation_range(self.data, self.vessel.geometry.L_pp)

    def to_json(self) -> dict:
        return {
            "structure": self.structure,
            "hull_model": self.vessel.hull_model_name,
            "actuator_layout": self.vessel.layout,
            "prior": self.fit.prior_policy,
            "u0_mps": self.fit.u0,
            "coefficients": [c.to_json() | coefficient_flags(c, self.fit.not_identifiable, self.fit.prior_policy)
                             for c in self.coefficients()],
            "prior_used": self.prior_used(),
            "held": self.held(),
            "excitation": self.excitation(),
            "actuators": {d.name: dict(d.actuator) for d in self.data if d.actuator},
            "not_identifiable_without_prior": list(self.fit.not_identifiable),
            "collinearity": [e.collinearity.to_json() for e in self.fit.equations],
            "residual_rms": {e.equation: finite_or_none(e.residual_rms) for e in self.fit.equations},
            "effective_samples": {e.equation: finite_or_none(e.effective_samples) for e in self.fit.equations},
            "cross_validation": [cv.to_json() for cv in self.cross_validation],
            "extra_terms": self.extra_terms,
            "interaction": self.interaction,
            "output_error": self.output_error,
            "manoeuvres": [d.name for d in self.data],
            "notes": list(self.notes),
        }


NOT_DETERMINED = "not determined by these manoeuvres; prior used"
# a coefficient whose fitted value makes the model diverge or not settle over its envelope, kept blended towards the
# description (fitting/output_error.regularise): its interval is still the fit's, its estimate the blend
REGULARISED = "regularised towards prior"
PRIOR_HOW = {"fixed to prior": "held at the vessel file's value",
             "ridge towards prior": "pulled towards the vessel file's value by the ridge",
             REGULARISED: "pulled towards the vessel file's value because the fitted model diverges or does not "
                          "settle over its envelope (the interval is the fit's; the estimate the blend)"}
EXCITATION_MIN_SPEED_FRACTION = 0.2  # samples slower than this fraction of the fastest are left out of v', r' (-)


# an interaction factor (fitting/interaction.py) chosen by the held-out simulation error whose force-data interval
# reaches its search box: set by the data (the motion), not by the prior, but only within the box
SEARCH_BOX = "identified at the search box"
SEARCH_BOX_NOTE = ("chosen by the held-out simulation error; the force-data 95 % interval reaches the search box "
                   "(the data bound it only within the box)")


def determined_by_data(c: Coefficient, not_identifiable: Sequence[str]) -> bool:
    """True when the data set the coefficient: identified (an interaction factor also at its search box), or ridged
    but identifiable without the prior."""
    return (c.status in ("identified", SEARCH_BOX)
            or (c.status == "ridge towards prior" and c.name not in not_identifiable))


def coefficient_flags(c: Coefficient, not_identifiable: Sequence[str], prior_policy: str) -> dict:
    """JSON flags of one coefficient: determined_by_data, and for a coefficient the data do not determine the note
    "not determined by these manoeuvres; prior used (how)" (so that a report says which values are the prior's)."""
    determined = determined_by_data(c, not_identifiable)
    how = PRIOR_HOW.get(c.status, f"prior policy {prior_policy}")
    if c.status == SEARCH_BOX:
        return {"determined_by_data": True, "note": SEARCH_BOX_NOTE}
    return {"determined_by_data": determined, "note": None if determined else f"{NOT_DETERMINED} ({how})"}


def excitation_range(data: Sequence[ForceData], L_pp: float) -> dict:
    """99th percentiles of |beta| (deg), |v'| = |v| / U and |r'| = |r| L / U over the samples faster than
    EXCITATION_MIN_SPEED_FRACTION of the fastest (MMG prime system, Yasukawa & Yoshimura 2015 eq. 2)."""
    nu = np.concatenate([d.nu for d in data]) if data else np.zeros((0, 3))  # (T, 3)
    speed = np.hypot(nu[:, 0], nu[:, 1])
    keep = speed > EXCITATION_MIN_SPEED_FRACTION * (speed.max() if len(speed) else 0.0)
    if not np.any(keep):
        return {"beta_deg_p99": None, "v_prime_p99": None, "r_prime_p99": None, "note": "no moving samples"}
    u, v, r, U = nu[keep, 0], nu[keep, 1], nu[keep, 2], speed[keep]
    beta = np.degrees(np.abs(np.arctan2(-v, u)))
    return {"beta_deg_p99": float(np.percentile(beta, 99.0)), "v_prime_p99": float(np.percentile(np.abs(v) / U, 99.0)),
            "r_prime_p99": float(np.percentile(np.abs(r) * L_pp / U, 99.0)),
            "note": "the range the identified terms are fitted on; a manoeuvre beyond it (a hard-over turning circle "
                    "usually is) extrapolates the nonlinear terms"}


def identified_vessel(vessel: Vessel, fit: HullFit) -> Vessel:
    values = fit.values()
    hull = Hull(**{n: values[n] for n in HULL_NAMES})
    return replace(vessel, name=f"{vessel.name}_identified", hull=hull,
                   provenance=f"{vessel.provenance.strip()} Hull derivatives identified by inverse-dynamics regression "
                              f"(structure {fit.structure}, prior {fit.prior_policy}; "
                              f"usv_predictor.fitting.identification).")


def scaled_thrust_map(m: ThrustMap, forward_N: float, reverse_N: float) -> ThrustMap:
    """The map with new full-command thrusts (N): a power law takes them as they are, a table has its ahead part
    (commands >= 0) scaled by forward_N / m.forward_N and its astern part by reverse_N / m.reverse_N (the shape of
    the datasheet curve kept, the ends set exactly)."""
    if not m.table_command:
        return replace(m, forward_N=float(forward_N), reverse_N=float(reverse_N))
    ahead = forward_N / m.forward_N
    astern = reverse_N / m.reverse_N if m.reverse_N > 0.0 else 0.0
    thrust = [t * (ahead if c >= 0.0 else astern) for c, t in zip(m.table_command, m.table_thrust_N)]
    thrust[0], thrust[-1] = -float(reverse_N), float(forward_N)
    return replace(m, forward_N=float(forward_N), reverse_N=float(reverse_N), table_thrust_N=tuple(thrust))


def with_known_forces(vessel: Vessel, data: Sequence[ForceData]) -> list[ForceData]:
    """The data with the steering and propulsion forces of `vessel` (another actuator gain) at their levels."""
    out = []
    for d in data:
        rudder, propeller = known_forces(vessel, d.nu, d.controls)
        out.append(replace(d, rudder=rudder, propeller=propeller))
    return out


def _least_squares_rss(vessel: Vessel, data: Sequence[ForceData], structure: str, u0: float,
                       held: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(RSS (3,), samples (3,), residual lag-1 correlation factor (3,) n/n_eff) of the plain least-squares hull fit
    of each equation (the coefficients in `held` at their values)."""
    rss, count, inflation = np.empty(3), np.empty(3), np.empty(3)
    for k, eq in enumerate(EQUATIONS):
        d = design(vessel, data, structure, eq, u0)
        free = np.array([n not in held for n in d.names])
        target = d.target - d.matrix[:, ~free] @ np.array([held[n] for n in d.names if n in held])
        theta, *_ = np.linalg.lstsq(d.matrix[:, free], target, rcond=None)
        residual = target - d.matrix[:, free] @ theta
        rss[k], count[k] = float(residual @ residual), len(residual)
        inflation[k] = len(residual) / effective_samples(residual, d.groups)
    return rss, count, inflation


def profile_throttle_gain(vessel: Vessel, data: Sequence[ForceData], structure: str, u0: float, *,
                          rel_ci_limit: float = REL_CI_LIMIT) -> Coefficient:
    """The throttle map's gain (throttle.forward_N, N) by profile likelihood: at each gain the hull is fitted by least
    squares and J(g) = sum over the equations of RSS_e(g) / sigma_e^2 (sigma_e of the vessel file's gain); the
    estimate minimises J over [g0 / PROFILE_SPAN, g0 PROFILE_SPAN] (log grid, then golden section), its 95 % CI is
    where J rises by CHI2_95 x n / n_eff (the likelihood-ratio interval, widened for autocorrelated residuals;
    Venzon & Moolgavkar 1988). A CI reaching the search span: not identifiable (rel_ci inf)."""
    g0 = vessel.throttle.forward_N

    def parts(gain: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        v = replace(vessel, throttle=scaled_thrust_map(vessel.throttle, gain, vessel.throttle.reverse_N))
        return _least_squares_rss(v, with_known_forces(v, data), structure, u0, {})

    rss0, count, _ = parts(g0)
    sigma2 = np.maximum(rss0 / np.maximum(count - 1.0, 1.0), 1e-30)

    def objective(log_gain: float) -> float:
        return float(np.sum(parts(math.exp(log_gain))[0] / sigma2))

    low, high = math.log(g0 / PROFILE_SPAN), math.log(g0 * PROFILE_SPAN)
    grid = np.linspace(low, high, PROFILE_POINTS)
    values = np.array([objective(x) for x in grid])
    best = int(np.argmin(values))
    a, b = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    golden = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(20):  # golden section on [a, b] (bracket of two grid steps: 0.618^20 of it)
        c, d = b - golden * (b - a), a + golden * (b - a)
        if objective(c) < objective(d):
            b = d
        else:
            a = c
    x_best = 0.5 * (a + b)
    j_best = objective(x_best)
    _, _, inflation = parts(math.exp(x_best))
    rise = CHI2_95 * float(np.mean(inflation))

    def crossing(direction: int) -> float:
        """The log gain where J = j_best + rise on one side (bisection), or nan when it is not reached in the span."""
        edge = high if direction > 0 else low
        if objective(edge) - j_best < rise:
            return math.nan
        inner, outer = x_best, edge
        for _ in range(20):
            mid = 0.5 * (inner + outer)
            if objective(mid) - j_best < rise:
                inner = mid
            else:
                outer = mid
        return 0.5 * (inner + outer)

    lo_ci, hi_ci = crossing(-1), crossing(+1)
    estimate = math.exp(x_best)
    if math.isnan(lo_ci) or math.isnan(hi_ci):
        ci, rel = (math.exp(lo_ci) if not math.isnan(lo_ci) else 0.0,
                   math.exp(hi_ci) if not math.isnan(hi_ci) else math.inf), math.inf
    else:
        ci = (math.exp(lo_ci), math.exp(hi_ci))
        rel = 0.5 * (ci[1] - ci[0]) / max(estimate, g0)
    status = "identified" if rel <= rel_ci_limit else "not identifiable"
    return Coefficient("throttle.forward_N", estimate, ci, g0, status, rel)


def identify(vessel: Vessel, recordings: Sequence[Recording], *, structure: str = "auto", prior: str = "none",
             smoother: SmootherConfig = SmootherConfig(), rel_ci_limit: float = REL_CI_LIMIT,
             data: Sequence[ForceData] | None = None, interaction: str = "fix",
             progress: Callable[[str], None] | None = None,
             search_interaction: Callable[..., Any] | None = None) -> IdentificationResult:
    """Smoother -> inverse dynamics -> regression of each candidate structure -> CV -> identified vessel.

    structure "auto" fits mmg and abkowitz and keeps abkowitz only if its CV error is lower by more than 5 %
    (the simpler structure wins ties: its coefficients are those the grey box and the preset share). The MMG hull
    only: fitting/hull_models.identify dispatches by hull model (a small-craft hull, twin thrusters, to
    fitting/small_craft_identification.py: structures diagonal / coupled). The actuator layout decides the levels and
    what is held (module docstring, "Actuator layouts").
    interaction "identify" (the INTERACTION_LAYOUTS): the rudder lift gradient, gamma_R, eta, w_P0 and t_P are
    searched with the hull by `search_interaction`
    (fitting/interaction.identify_interaction, SEARCHED_FACTORS; fitting/hull_models.identify gives it) and replace
    the description's when the held-out simulation says so; the other layouts have no such factors;
    "fix": held at the description's values (`replay identify` searches by default: docs/results/unknown_boats.md).
    The output-error stage that may follow (fitting/output_error.refine) is its caller's: fitting/hull_models.identify.
    """
    prior_vessel = vessel  # the vessel file as given (what the exported model embeds); `vessel` may take fitted gains
    if vessel.hull_model_name != "mmg":
        raise ConfigError(f"vessel {vessel.name}: identification.identify fits the MMG hull; the "
                          f"{vessel.hull_model_name} hull is identified through fitting/hull_models.identify")
    if vessel.layout == "twin_thrusters":
        raise ConfigError(f"vessel {vessel.name}: identification of twin thrusters needs the small_craft hull model "
                          "(the MMG hull is singular at the low speeds a twin-thruster boat turns at)")
    if structure not in STRUCTURES + ("auto",):
        raise ConfigError(f"unknown model structure {structure!r} for the MMG hull of {vessel.name}; use one of "
                          f"{list(STRUCTURES) + ['auto']}")
    if prior not in PRIORS:
        raise ConfigError(f"unknown prior policy {prior!r}; use one of {list(PRIORS)}")
    if interaction not in ("identify", "fix"):
        raise ConfigError(f"unknown interaction mode {interaction!r}; use 'identify' or 'fix'")
    names = sorted({r.name.split("#")[0].split("@")[0] for r in recordings})
    if len(names) < MIN_MANOEUVRES:
        raise DatasetError(f"identification needs at least {MIN_MANOEUVRES} manoeuvres (one is held out in turn "
                           f"for cross-validation); got {len(names)}: {', '.join(names) or 'none'}")
    forces = list(data) if data is not None else prepare(vessel, recordings, smoother=smoother, progress=progress)
    candidates = STRUCTURES if structure == "auto" else (structure,)
    notes: list[str] = []
    held: tuple[str, ...] = ()
    gains: tuple[Coefficient, ...] = ()
    if vessel.layout == "rudder_only":
        held = ("R0",)
        notes.append("rudder_only: the equivalent engine speed of each manoeuvre holds its approach speed with the "
                     "vessel file's resistance, so R0 is held at the vessel file's value (the data cannot separate it "
                     "from the unknown thrust); the model supports heading and track at a constant engine setting, "
                     "not speed changes")
    if vessel.layout == "rudder_throttle":
        if progress is not None:
            progress("profiling the throttle map's gain (throttle.forward_N)")
        u0 = float(np.median(np.concatenate([d.nu[:, 0] for d in forces])))
        gain = profile_throttle_gain(vessel, forces, candidates[0], u0, rel_ci_limit=rel_ci_limit)
        if gain.status != "identified":
            if prior == "none":
                raise NotIdentifiableError(
                    f"the throttle map's gain throttle.forward_N is not identifiable from {len(names)} manoeuvre(s) "
                    f"({', '.join(names)}): 95 % CI [{gain.ci95[0]:.4g}, {gain.ci95[1]:.4g}] N around "
                    f"{gain.estimate:.4g} "
                    "N. Options: prior='fix' (--prior fix) or 'ridge' holds it at the vessel file's value; or record "
                    f"{WOULD_DETERMINE['throttle.forward_N']} (the accelerations separate thrust from resistance)")
            gain = replace(gain, estimate=gain.prior, status="fixed to prior")
            notes.append("throttle.forward_N not identifiable: held at the vessel file's value (a profiled gain is "
                         "held, not ridged)")
        vessel = replace(vessel, throttle=scaled_thrust_map(vessel.throttle, gain.estimate, vessel.throttle.reverse_N))
        forces = with_known_forces(vessel, forces)
        gains = (gain,)
    searched = None
    if vessel.layout in INTERACTION_LAYOUTS and interaction == "identify":
        if search_interaction is None:
            raise ConfigError("interaction 'identify' needs the search of the interaction factors "
                              "(fitting/interaction.identify_interaction, given by fitting/hull_models.identify)")
        u0 = float(np.median(np.concatenate([d.nu[:, 0] for d in forces])))
        searched = search_interaction(vessel, forces, recordings, "mmg", "fix", u0, held=held, progress=progress)
        notes.append(searched.note())
        if searched.accepted:
            vessel = searched.vessel
            forces = with_known_forces(vessel, forces)
            gains = gains + searched.coefficients  # not accepted: the description's, as without the search
    fits, cvs = {}, []
    for s in candidates:
        if progress is not None:
            progress(f"fitting structure {s} (prior {prior})")
        fits[s] = fit_hull(vessel, forces, s, prior, rel_ci_limit=rel_ci_limit, held=held)
        cvs.append(cross_validate(vessel, forces, fits[s]))
    chosen = candidates[0]
    if structure == "auto":
        by = {cv.structure: cv.score for cv in cvs}
        chosen = "abkowitz" if by["abkowitz"] < 0.95 * by["mmg"] else "mmg"
        notes.append(f"auto: CV error mmg {by['mmg']:.4f}, abkowitz {by['abkowitz']:.4f} -> {chosen}")
    fit = fits[chosen]
    if fit.not_identifiable:
        notes.append(f"not identifiable without the prior: {', '.join(fit.not_identifiable)} -> {prior}")
    values = fit.values()
    extra = {n: values[n] for n in EXTRA_NAMES if n in values}
    return IdentificationResult(identified_vessel(vessel, fit), fit, tuple(cvs), extra, tuple(forces), tuple(notes),
                                gains, prior=prior_vessel,
                                interaction=searched.to_json() if searched is not None else None)


def hull_forces(vessel: Vessel, values: Mapping[str, float], nu: np.ndarray, u0: float,
                names: Sequence[str] | None = None) -> np.ndarray:
    """(T, 3) MMG hull [X, Y, N] of coefficient `values` (any structure) at velocities nu (N, N, N m)."""
    if vessel.hull_model_name != "mmg":
        raise ConfigError(f"vessel {vessel.name}: identification.hull_forces is the MMG hull's; the "
                          f"{vessel.hull_model_name} hull's forces are fitting/hull_models.hull_forces")
    g = vessel.geometry
    q = 0.5 * 1025.0 * g.L_pp * g.d
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    U = np.maximum(np.hypot(u, v), 1e-3)
    vp, rp = v / U, r * g.L_pp / U
    out = np.zeros((len(nu), 3))
    for name, value in values.items():
        if names is not None and name not in names:
            continue
        eq = 0 if name == "R0" else EQUATIONS.index(name[0])
        out[:, eq] += value * regressor(name, u, vp, rp, U, u0) * q * U * U * (g.L_pp if eq == 2 else 1.0)
    return out


def data_digest(recordings: Sequence[Recording]) -> str:
    """sha256 over the names and arrays the identification used."""
    h = hashlib.sha256()
    for r in recordings:
        h.update(r.name.encode())
        for array in (r.nu, r.psi, r.controls, r.position):
            h.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())
    return h.hexdigest()

"""Identification of the small-craft hull and the twin thrusters' thrust maps (Fossen 2021 ch. 6; twin_thrusters).

The method of fitting/identification.py (seed 001 sec. 3.2): EKF/RTS accelerations -> inverse dynamics -> least
squares with 95 % CIs, cross-validated by manoeuvre, prior none / fix / ridge towards the vessel file. What differs:

Equations (physics/dynamics.py SmallCraftHullForces + TwinThrusterForces; Fossen 2021 eq. 6.5 solved for tau):
    X = m11 u_dot - m22 v r - m x_G r^2                                    (M = M_RB + M_A, C_RB + C_A:
    Y = m22 v_dot + m23 r_dot + m11 u r                                     identification.inverse_dynamics_forces)
    N = m32 v_dot + m33 r_dot + m x_G u r - (Y_vdot - X_udot) u v           (the last term: the Munk moment of C_A)
      = hull   [X_u u + X_uu |u| u,  Y_v v + Y_r r + C_d y_cf,  N_v v + N_r r + N_rr |r| r + C_d n_cf]
      + thrust [T_p + T_s,  0,  (b/2) (T_p - T_s)]
    y_cf = -0.5 rho d sum |v + x r| (v + x r) dx, n_cf the same with x (strip theory, Fossen's crossFlowDrag);
    T_side = F_side phi+(c) - R_side phi-(c): c the command lagged by the map's time constant (identification.
    lagged_command, exactly as the grey box lags it), phi+ = c'^e for c' > 0 and phi- = |c'|^e for c' < 0 with c'
    past the dead band (a table map: its own curve divided by its full-command thrust, per side).
The forces are LINEAR in theta = [X_u, X_uu, Y_v, (Y_r), C_d, (N_v), N_r, N_rr, F_port, R_port, F_stbd, R_stbd]:
one stacked regression of the three equations (C_d enters Y and N, the thrust gains X and N, so a per-equation fit
would split them), each equation weighted by 1 / sigma_e of its residual (two passes; the equations have different
units). Coefficient CIs: sigma^2 (A_w^T A_w)^-1 widened by n / n_eff (lag-1 autocorrelation of the residuals,
as identification.effective_samples).

What is fixed, and why:
  - the mass, yaw inertia and x_G, and one scale anchor (ANCHORS): motion data alone cannot set the scale of the
    forces (M nu_dot + C nu = tau is unchanged when M, the damping and the thrust are all multiplied by the same k;
    the added masses X_udot, Y_vdot, N_rdot are regressors, added_mass_basis, exactly collinear with the rigid body),
    so either the added masses are held at the vessel file's (Fossen's rules for the Otter: -0.1 m, -1.5 m, -1.7 I_z)
    and the thrust gains fitted, or the thrust gains at the file's (the owner's datasheet) and the added masses
    fitted (N_rdot then also takes the error of the file's yaw inertia). identify fits both and keeps the datasheet
    only when it cross-validates better by more than 5 % (scale_anchored_fit): the Otter's rules applied to a boat of
    another shape (the unknown-boat suite's WAM-V-like catamarans, no added mass) bias every force, the gains 2-4 x;
  - each thrust map's dead band and time constant, and the thruster spacing b: with the gains free they are nearly
    collinear with them over the commands a run uses, so they come from the vessel file (a datasheet or a bollard
    test); the exponent too, unless the data determine it: the fit is repeated at each exponent of EXPONENT_GRID and
    one whose cross-validation error (held-out force NMSE) is lower than the file's by more than 5 % and below
    DECISIVE_CV replaces it (both said in the notes: forces the model cannot predict held out decide nothing);
  - a coefficient without excitation (no astern command: the reverse gains R) or with a 95 % CI wider than
    REL_CI_LIMIT of its size is NOT identifiable, and a free coefficient of the wrong sign (damping > 0, C_d < 0,
    a thrust gain < 0) is NOT physical: both are refused (prior "none", naming them and the prior to use), held at
    the vessel file's value ("fix", one at a time, worst first) or pulled towards it ("ridge", weight by CV).
  The size of a coefficient for that test is max(|estimate|, |prior|, FORCE_FLOOR rms(target) / rms(regressor)): a
  coefficient whose whole uncertainty moves its equation's force by less than a percent is determined, even at 0.
Structures: diagonal (Fossen's Otter: X_u, X_uu, Y_v, N_r, N_rr, C_d) and coupled (+ Y_r, N_v), compared by
leave-one-manoeuvre-out CV of the three forces ("auto": coupled only if its error is lower by more than 5 %, as the
MMG structures). The thrust exponent is held to a stricter test (DECISIVE_CV), because it extrapolates: a single
run's commands span a narrow range, and an exponent that wins a noisy within-run CV can lose on other commands.
A structure leaves its other coefficients at the vessel file's values.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, fields, replace
from typing import Callable, Mapping, Sequence

import numpy as np

from usv_predictor.data.recording import Recording
from usv_predictor.data.smoother import SmootherConfig
from usv_predictor.errors import ConfigError, DatasetError, NotIdentifiableError
from usv_predictor.fitting.identification import (
    EQUATIONS,
    MIN_MANOEUVRES,
    PRIORS,
    REL_CI_LIMIT,
    RIDGE_GRID,
    STRUCTURES_OF,
    Z95,
    Coefficient,
    Collinearity,
    CrossValidation,
    Design,
    EquationFit,
    ForceData,
    IdentificationResult,
    _solve,
    coefficient_status,
    collinearity,
    effective_samples,
    known_forces,
    prepare,
    scaled_thrust_map,
    would_determine,
)
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.vessel import RHO_WATER, SmallCraftHull, ThrustMap, Vessel, table_value

STRUCTURES = STRUCTURES_OF["small_craft"]
HULL_TERMS: Mapping[str, str] = {  # coefficient -> the equations it enters
    "X_u": "X", "X_uu": "X", "Y_v": "Y", "Y_r": "Y", "cross_flow_cd": "YN", "N_v": "N", "N_r": "N", "N_rr": "N",
}
STRUCTURE_TERMS: Mapping[str, tuple[str, ...]] = {
    "diagonal": ("X_u", "X_uu", "Y_v", "cross_flow_cd", "N_r", "N_rr"),
    "coupled": ("X_u", "X_uu", "Y_v", "Y_r", "cross_flow_cd", "N_v", "N_r", "N_rr"),
}
SIDES = ("port", "starboard")
GAIN_NAMES = tuple(f"thrusters.{side}.{part}" for side in SIDES for part in ("forward_N", "reverse_N"))
SIGN: Mapping[str, int] = {  # +1: must be >= 0, -1: must be <= 0 (Fossen's SNAME derivatives are negative dampings)
    "X_u": -1, "X_uu": -1, "Y_v": -1, "N_r": -1, "N_rr": -1, "cross_flow_cd": +1,
    **{name: +1 for name in GAIN_NAMES},
}
FORCE_FLOOR = 0.02  # a coefficient moving its equation's force by < 1 % of the force rms (half this) is determined
EXPONENT_GRID = (1.0, 1.5, 2.0)  # thrust ~ command^e tried when the data may determine e (2: shaft-speed command)
DECISIVE_CV = 0.5  # a CV comparison decides the exponent only below this held-out force NMSE
FOLD_EXCITATION = 0.1  # a CV fold holds at the prior a coefficient whose training column has < 10 % of its norm
# the added masses (kg, kg, kg m^2), each a regressor of the equations it enters (added_mass_basis): the Fossen 2021
# eq. 6.43 M_A nu_dot + C_A(nu) nu of the inverse dynamics, linear in them; the rigid-body mass sets the scale
ADDED_MASS_TERMS: Mapping[str, str] = {"X_udot": "XYN", "Y_vdot": "XYN", "N_rdot": "N"}
# the scale of every force (module docstring): motion data set the forces only up to a common factor, so one set of
# terms is held at the vessel file's values, the added masses (the file's formula) or the thrust gains (the owner's
# datasheet); identify_small_craft fits both and keeps the one that cross-validates better by more than 5 %
ANCHORS: Mapping[str, tuple[str, ...]] = {"added_mass": tuple(ADDED_MASS_TERMS), "thrust": GAIN_NAMES}
MIN_MASS_FRACTION = 0.5  # (-) the thrust anchor's fitted total masses m - X_udot, m - Y_vdot, I_z - N_rdot must be at
# least this x the rigid body's: an added mass is >= 0 (Fossen 2021 sec. 6.3); the margin is the smoother's bias of
# the accelerations (a few %) and of the yaw radius the file guessed; below it the fit trades mass for damping (the
# walkthrough otter: m - X_udot 17 kg of 80, a model that diverges)
ANCHOR_WHY: Mapping[str, str] = {
    "added_mass": "the vessel file's added masses (X_udot, Y_vdot, N_rdot) with the mass and inertia; the thrust "
                  "gains are the data's",
    "thrust": "the vessel file's thrust gains (the datasheet); the added masses are the data's (with the yaw "
              "inertia's error: N_rdot takes it)",
}


# ------------------------------------------------------------------------------------------ regressors


def thrust_basis(m: ThrustMap, level: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ahead (T,), astern (T,)) >= 0 with thrust = forward_N ahead - reverse_N astern at the lagged command `level`:
    the power law's c'^e on each side, or a table's curve divided by its full-command thrust (vessel.ThrustMap)."""
    effective = np.array([m.effective_command(float(c)) for c in level])
    if m.table_command:
        curve = np.array([table_value(m.table_command, m.table_thrust_N, e) for e in effective])
        ahead = np.where(effective >= 0.0, curve / m.forward_N, 0.0)
        astern = np.where(effective < 0.0, -curve / m.reverse_N, 0.0) if m.reverse_N > 0.0 else np.zeros_like(curve)
        return ahead, astern
    return (np.where(effective > 0.0, np.abs(effective) ** m.exponent, 0.0),
            np.where(effective < 0.0, np.abs(effective) ** m.exponent, 0.0))


def basis(vessel: Vessel, nu: np.ndarray, levels: np.ndarray) -> dict[str, np.ndarray]:
    """name -> (T, 3) force [X, Y, N] per unit of the coefficient (N per unit, N m in N), for every hull term of
    HULL_TERMS and the four thrust gains (module docstring)."""
    model = ManoeuvringModel(vessel)
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    zero = np.zeros_like(u)
    x = np.asarray(model.strip_x)  # (S,) strip centres (m)
    w = v[:, None] + x[None, :] * r[:, None]  # (T, S) cross-flow velocity along the hull (m/s)
    f = np.abs(w) * w  # (T, S)
    scale = -0.5 * RHO_WATER * vessel.geometry.d * model.strip_dx  # (kg/m^2 x m)
    out = {
        "X_u": np.column_stack([u, zero, zero]), "X_uu": np.column_stack([np.abs(u) * u, zero, zero]),
        "Y_v": np.column_stack([zero, v, zero]), "Y_r": np.column_stack([zero, r, zero]),
        "N_v": np.column_stack([zero, zero, v]), "N_r": np.column_stack([zero, zero, r]),
        "N_rr": np.column_stack([zero, zero, np.abs(r) * r]),
        "cross_flow_cd": np.column_stack([zero, scale * f.sum(axis=1), scale * (f * x[None, :]).sum(axis=1)]),
    }
    half = 0.5 * vessel.thrusters.spacing  # (m) lever arm; the port thruster at y = -b/2 turns the bow to starboard
    for k, side in enumerate(SIDES):
        ahead, astern = thrust_basis(getattr(vessel.thrusters, side), levels[:, k])
        arm = half if side == "port" else -half
        out[f"thrusters.{side}.forward_N"] = np.column_stack([ahead, zero, arm * ahead])
        out[f"thrusters.{side}.reverse_N"] = np.column_stack([-astern, zero, -arm * astern])
    return out


def added_mass_basis(nu: np.ndarray, nu_dot: np.ndarray) -> dict[str, np.ndarray]:
    """name -> (T, 3) [X, Y, N] per unit of each added mass of ADDED_MASS_TERMS: minus the derivative of the
    inverse dynamics M_A nu_dot + C_A(nu) nu (identification.inverse_dynamics_forces; Fossen 2021 eq. 6.43,
    X: -X_udot u_dot + Y_vdot v r, Y: -Y_vdot v_dot - X_udot u r, N: -N_rdot r_dot - (Y_vdot - X_udot) u v) by it,
    so that hull + thrust + sum(added mass x column) is the rigid-body part M_RB nu_dot + C_RB(nu) nu (N, N m)."""
    u, v, r = nu[:, 0], nu[:, 1], nu[:, 2]
    zero = np.zeros_like(u)
    return {"X_udot": np.column_stack([nu_dot[:, 0], u * r, -u * v]),
            "Y_vdot": np.column_stack([-v * r, nu_dot[:, 1], u * v]),
            "N_rdot": np.column_stack([zero, zero, nu_dot[:, 2]])}


def prior_values(vessel: Vessel) -> dict[str, float]:
    """The vessel file's value of every hull term, added mass and thrust gain."""
    values = {name: float(getattr(vessel.small_craft, name)) for name in (*HULL_TERMS, *ADDED_MASS_TERMS)}
    for side in SIDES:
        m = getattr(vessel.thrusters, side)
        values[f"thrusters.{side}.forward_N"] = m.forward_N
        values[f"thrusters.{side}.reverse_N"] = m.reverse_N
    return values


def coefficient_names(structure: str) -> tuple[str, ...]:
    if structure not in STRUCTURE_TERMS:
        raise ConfigError(f"unknown model structure {structure!r} for the small-craft hull; use one of "
                          f"{list(STRUCTURES) + ['auto']}")
    return STRUCTURE_TERMS[structure] + tuple(ADDED_MASS_TERMS) + GAIN_NAMES


def _equations_of(name: str) -> str:
    return HULL_TERMS.get(name) or ADDED_MASS_TERMS.get(name) or "XN"


@dataclass(frozen=True)
class JointDesign:
    """The stacked regression of X, Y and N over several manoeuvres (rows in SI: N or N m)."""

    names: tuple[str, ...]
    matrix: np.ndarray  # (n, p)
    target: np.ndarray  # (n,) force minus the parts held at the vessel file's values
    equation: np.ndarray  # (n,) 0, 1, 2 = X, Y, N
    groups: np.ndarray  # (n,) manoeuvre index
    force: np.ndarray | None = None  # (n,) the inverse-dynamics force with the file's added masses (None: target),
    #                                   the scale of the first pass and of the CV error, whatever the anchor

    def rows(self, eq: int) -> np.ndarray:
        return self.equation == eq

    @property
    def reference(self) -> np.ndarray:
        """(n,) the force the regression's scales are taken from (`force`, else `target`)."""
        return self.target if self.force is None else self.force


def joint_design(vessel: Vessel, data: Sequence[ForceData], structure: str) -> JointDesign:
    names = coefficient_names(structure)
    priors = prior_values(vessel)
    held = [n for n in HULL_TERMS if n not in names]
    blocks, targets, equations, groups, totals = [], [], [], [], []
    for g, d in enumerate(data):
        columns = {**basis(vessel, d.nu[d.keep], d.controls[d.keep]), **added_mass_basis(d.nu[d.keep],
                                                                                          d.nu_dot[d.keep])}
        # d.total carries the vessel file's added masses (inverse dynamics): back to the rigid-body part, which
        # the added masses' columns then explain (added_mass_basis)
        known = sum((priors[n] * columns[n] for n in held), np.zeros((int(d.keep.sum()), 3))) \
            - sum(priors[n] * columns[n] for n in ADDED_MASS_TERMS)
        for e in range(3):
            blocks.append(np.column_stack([columns[n][:, e] for n in names]))
            targets.append(d.total[d.keep, e] - known[:, e])
            totals.append(d.total[d.keep, e])
            equations.append(np.full(int(d.keep.sum()), e))
            groups.append(np.full(int(d.keep.sum()), g))
    if not blocks or sum(len(t) for t in targets) == 0:
        raise DatasetError("no samples left for regression (all below the speed limit or inside the smoother edges)")
    return JointDesign(names, np.vstack(blocks), np.concatenate(targets), np.concatenate(equations),
                       np.concatenate(groups), np.concatenate(totals))


# ------------------------------------------------------------------------------------------ regression


@dataclass(frozen=True)
class JointFit:
    """The fit of a structure, shaped like identification.HullFit (equations, coefficients(), values())."""

    structure: str
    prior_policy: str
    equations: tuple[EquationFit, ...]  # per equation: its coefficients, collinearity, residual, n_eff
    not_identifiable: tuple[str, ...]  # before any prior was applied (with the not physical ones)
    u0: float  # unused by the small-craft hull (no speed-referenced terms): 0
    all_coefficients: tuple[Coefficient, ...]
    weights: tuple[float, float, float]  # 1 / sigma_e of X, Y, N (1/N, 1/N, 1/(N m))
    ridge_weight: float = 0.0
    anchor: str = "added_mass"  # the terms of ANCHORS held as the scale of the forces

    def coefficients(self) -> list[Coefficient]:
        return list(self.all_coefficients)

    def values(self) -> dict[str, float]:
        return {c.name: c.estimate for c in self.all_coefficients}


def _weighted(d: JointDesign, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = weights[d.equation]
    return d.matrix * w[:, None], d.target * w


def _solve_joint(d: JointDesign, weights: np.ndarray, prior: np.ndarray, free: np.ndarray, ridge: float,
                 scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """identification._solve on the weighted rows; a free column that is zero in these rows (nothing excites it,
    e.g. no astern command) stays at the prior instead of the pseudo-inverse's 0."""
    a, y = _weighted(d, weights)
    excited = free & (np.linalg.norm(a, axis=0) > 0.0)
    theta, cov_excited = _solve(a, y, prior, excited, ridge, scale)
    cov = np.zeros((int(free.sum()), int(free.sum())))
    inside = excited[free]
    cov[np.ix_(inside, inside)] = cov_excited
    return theta, cov


def _sigma(d: JointDesign, theta: np.ndarray) -> np.ndarray:
    """(3,) rms residual of each equation (N, N, N m)."""
    residual = d.target - d.matrix @ theta
    return np.array([max(float(np.sqrt(np.mean(residual[d.rows(e)] ** 2))), 1e-12) for e in range(3)])


def _floors(d: JointDesign, weights: np.ndarray) -> np.ndarray:
    """(p,) FORCE_FLOOR rms(target) / rms(column) in the weighted problem (inf for a column without excitation)."""
    a, y = _weighted(d, weights)
    column = np.sqrt(np.mean(a**2, axis=0))
    return np.where(column > 0.0, FORCE_FLOOR * float(np.sqrt(np.mean(y**2))) / np.where(column > 0, column, 1.0),
                    np.inf)


def fit_joint(d: JointDesign, priors: Mapping[str, float], *, fixed: Sequence[str] = (), ridge: float = 0.0,
              weights: np.ndarray | None = None, structure: str = "", policy: str = "none") -> JointFit:
    """Weighted least squares (or ridge) of the stacked equations; CIs with the effective sample count."""
    names = d.names
    prior = np.array([priors[n] for n in names])
    free = np.array([n not in fixed for n in names])
    if weights is None:  # first pass unweighted per equation: sigma of each equation from its own scale
        scale0 = np.array([max(float(np.std(d.reference[d.rows(e)])), 1e-12) for e in range(3)])
        theta0, _ = _solve_joint(d, 1.0 / scale0, prior, free, 0.0, np.ones(len(names)))
        weights = 1.0 / _sigma(d, theta0)
    floors = _floors(d, weights)
    penalty = np.maximum(np.abs(prior), np.where(np.isfinite(floors), floors, 1.0))
    theta, cov = _solve_joint(d, weights, prior, free, ridge, penalty)
    a, y = _weighted(d, weights)
    residual_w = y - a @ theta
    groups = d.groups * 3 + d.equation  # autocorrelation within one equation of one manoeuvre
    n_eff = effective_samples(residual_w, groups)
    n, p_free = len(residual_w), int(free.sum())
    sigma2 = float(residual_w @ residual_w) / max(n - p_free, 1)
    column_norm = np.linalg.norm(a, axis=0)
    var = np.zeros(len(names))
    var[free] = np.diag(cov) * sigma2 * n / n_eff
    coefficients = []
    for k, name in enumerate(names):
        half = Z95 * math.sqrt(max(var[k], 0.0))
        if free[k] and column_norm[k] == 0.0:  # nothing in the data moves this coefficient
            half, rel = math.inf, math.inf
        else:
            rel = half / max(abs(theta[k]), abs(prior[k]), floors[k])
        coefficients.append(Coefficient(name, float(theta[k]), (float(theta[k] - half), float(theta[k] + half)),
                                        float(prior[k]), coefficient_status(bool(free[k]), ridge), rel))
    per_equation = []
    residual = d.target - d.matrix @ theta
    for e, eq in enumerate(EQUATIONS):
        rows = d.rows(e)
        own = [k for k, n in enumerate(names) if eq in _equations_of(n)]
        sub = Design(eq, tuple(names[k] for k in own), d.matrix[np.ix_(rows, own)], d.target[rows], d.groups[rows],
                     np.ones(int(rows.sum())))
        per_equation.append(EquationFit(eq, tuple(coefficients[k] for k in own), functools.partial(_collinearity, sub),
                                        float(np.sqrt(np.mean(residual[rows] ** 2))) if rows.any() else math.nan,
                                        effective_samples(residual[rows], d.groups[rows]) if rows.any() else 0.0,
                                        ridge))
    return JointFit(structure, policy, tuple(per_equation), (), 0.0, tuple(coefficients),
                    tuple(float(w) for w in weights), ridge)


def _collinearity(d: Design) -> Collinearity:
    """identification.collinearity, tolerant of a column without excitation (reported as such, NaN correlations)."""
    if d.matrix.shape[1] == 0 or d.matrix.shape[0] < 2:  # an equation without coefficients or rows
        return Collinearity(d.equation, d.names, np.full((len(d.names),) * 2, np.nan), math.nan,
                            {n: math.nan for n in d.names}, ())
    varying = np.std(d.matrix, axis=0) > 0
    if varying.all():
        return collinearity(d)
    part = collinearity(Design(d.equation, tuple(n for n, k in zip(d.names, varying) if k), d.matrix[:, varying],
                               d.target, d.groups, d.scale))
    corr = np.full((len(d.names), len(d.names)), np.nan)
    idx = np.flatnonzero(varying)
    corr[np.ix_(idx, idx)] = part.correlation
    vif = {n: part.vif.get(n, math.inf) for n in d.names}
    return Collinearity(d.equation, d.names, corr, math.inf, vif, part.pairs)


def problems(fit: JointFit, rel_ci_limit: float = REL_CI_LIMIT) -> dict[str, str]:
    """Free coefficients that are not identifiable (CI too wide, no excitation) or not physical (wrong sign)."""
    out = {}
    for c in fit.all_coefficients:
        if c.status != "identified":
            continue
        if not math.isfinite(c.rel_ci):
            out[c.name] = "no excitation in the data"
        elif c.rel_ci > rel_ci_limit:
            out[c.name] = f"95 % CI [{c.ci95[0]:.4g}, {c.ci95[1]:.4g}]"
        elif SIGN.get(c.name, 0) * c.estimate < 0.0:
            out[c.name] = f"wrong sign: {c.estimate:+.4g} (must be {'>=' if SIGN[c.name] > 0 else '<='} 0)"
    return out


# The trial that would determine each small-craft coefficient the data may leave undetermined (refused, held at or
# pulled to the vessel file's value): one record per coefficient, beside the hold decision (fit_small_craft), said in
# identify's message and JSON (`held[].would_determine`, IdentificationResult.trials). The surge damping and the
# ahead gains need two speeds (thrust and damping balance at each), the reverse gains commands astern, the linear
# sway and yaw terms both signs of v and r (zig-zags both ways), N_r apart from N_rr two yaw rates (two
# differentials), N_rr and the cross-flow drag high yaw rates (a hard turn).
WOULD_DETERMINE: Mapping[str, str] = {
    "X_u": "straight runs at two speeds",
    "X_uu": "straight runs at two speeds",
    "Y_v": "zig-zags both ways",
    "Y_r": "zig-zags both ways",
    "N_v": "zig-zags both ways",
    "N_r": "turns at two differentials both ways",
    "N_rr": "a turn at differential 0.8 both ways",
    "cross_flow_cd": "a turn at differential 0.8 both ways (drift in a hard turn)",
    **{f"thrusters.{side}.forward_N": "straight runs at two speeds" for side in SIDES},
    **{f"thrusters.{side}.reverse_N": "astern commands (each thruster astern: spins both ways, a stop)"
       for side in SIDES},
    **{n: "accelerations: speed changes, turn entries, zig-zags (with the thrust as the scale)"
       for n in ADDED_MASS_TERMS},
    "thrusters.time_constant_s": "thrust steps (a step of both commands at a steady speed; output-error stage)",
}
# the scale anchor's terms (ANCHORS): what would determine them is a measured force, not another manoeuvre
ANCHOR_DETERMINE: Mapping[str, Mapping[str, str]] = {
    "added_mass": {n: "a measured thrust (a bollard pull at two commands) that lets the added masses be fitted "
                      "instead (the datasheet's gains were the worse scale by the CV)" for n in ADDED_MASS_TERMS},
    "thrust": {n: "a bollard pull at two commands (the measured thrust is the scale of every force; held at the "
                  "datasheet's)" for n in GAIN_NAMES},
}


def _message(found: Mapping[str, str], fit: JointFit, manoeuvres: Sequence[str]) -> str:
    pairs = [f"{a}~{b} (rho {rho:+.2f})" for e in fit.equations for a, b, rho in e.collinearity.pairs]
    listed = "; ".join(f"{n}: {why}, would be determined by {would_determine(n, WOULD_DETERMINE)}"
                       for n, why in found.items())
    return (f"small-craft coefficients not identifiable from {len(manoeuvres)} manoeuvre(s) ({', '.join(manoeuvres)}): "
            f"{listed} (a 95 % CI wider than {REL_CI_LIMIT:.0%} of their size, no excitation, or the wrong sign)"
            + (f"; multicollinear regressors: {', '.join(pairs)}" if pairs else "")
            + ". Options: prior='fix' (--prior fix) holds them at the vessel file's values, prior='ridge' "
              "(--prior ridge) pulls every coefficient towards them; or record the trials named")


def _cv_errors(d: JointDesign, priors: Mapping[str, float], fixed: Sequence[str], ridge: float,
               weights: np.ndarray) -> dict[str, float]:
    """Held-out mean squared error / variance of each equation's force, leave one manoeuvre out."""
    groups = np.unique(d.groups)
    if len(groups) < 2:
        raise DatasetError("cross-validation needs at least two manoeuvres")
    prior = np.array([priors[n] for n in d.names])
    free = np.array([n not in fixed for n in d.names])
    floors = _floors(d, weights)
    penalty = np.maximum(np.abs(prior), np.where(np.isfinite(floors), floors, 1.0))
    sq, count = np.zeros(3), np.zeros(3)
    full_norm = np.linalg.norm(_weighted(d, weights)[0], axis=0)
    for g in groups:
        train, test = d.groups != g, d.groups == g
        sub = JointDesign(d.names, d.matrix[train], d.target[train], d.equation[train], d.groups[train])
        # a coefficient the training manoeuvres hardly excite (the held-out one had its astern commands) stays at
        # the prior in this fold, as the fit would hold it: a pseudo-inverse of a near-zero column predicts nonsense
        seen = np.linalg.norm(_weighted(sub, weights)[0], axis=0) >= FOLD_EXCITATION * full_norm
        theta, _ = _solve_joint(sub, weights, prior, free & seen, ridge, penalty)
        err = d.target[test] - d.matrix[test] @ theta
        for e in range(3):
            rows = d.equation[test] == e
            sq[e] += float(err[rows] @ err[rows])
            count[e] += int(rows.sum())
    return {eq: float(sq[e] / max(count[e], 1) / max(float(np.var(d.reference[d.rows(e)])), 1e-30))
            for e, eq in enumerate(EQUATIONS)}


def fit_small_craft(vessel: Vessel, data: Sequence[ForceData], structure: str = "diagonal", prior: str = "none", *,
                    rel_ci_limit: float = REL_CI_LIMIT, anchor: str = "added_mass") -> JointFit:
    """The regression with the prior policy of the module docstring, the terms of ANCHORS[anchor] held."""
    if prior not in PRIORS:
        raise ConfigError(f"unknown prior policy {prior!r}; use one of {list(PRIORS)}")
    if anchor not in ANCHORS:
        raise ConfigError(f"unknown scale anchor {anchor!r}; use one of {list(ANCHORS)}")
    return replace(_fit_small_craft(vessel, data, structure, prior, rel_ci_limit, ANCHORS[anchor]), anchor=anchor)


def _fit_small_craft(vessel: Vessel, data: Sequence[ForceData], structure: str, prior: str, rel_ci_limit: float,
                     anchored: tuple[str, ...]) -> JointFit:
    d = joint_design(vessel, data, structure)
    priors = prior_values(vessel)
    fit = fit_joint(d, priors, fixed=anchored, structure=structure, policy=prior)
    weights = np.array(fit.weights)
    found = problems(fit, rel_ci_limit)
    if found and prior == "none":
        raise NotIdentifiableError(_message(found, fit, [x.name for x in data]))
    if found and prior == "fix":
        # one at a time, the worst first (no excitation, then the widest CI, then the wrong sign): fixing one of a
        # collinear pair often makes the other identifiable
        fixed: list[str] = list(anchored)
        current = found
        for _ in range(len(d.names)):
            if not current:
                break
            rel = {c.name: c.rel_ci for c in fit.all_coefficients}
            fixed.append(max(current, key=lambda n: (rel[n], SIGN.get(n, 0) * -fit.values()[n])))
            fit = fit_joint(d, priors, fixed=tuple(fixed), weights=weights, structure=structure, policy=prior)
            current = problems(fit, rel_ci_limit)
    elif found and prior == "ridge":
        many = len(np.unique(d.groups)) >= 2
        weight = min(RIDGE_GRID, key=lambda r: sum(_cv_errors(d, priors, anchored, r, weights).values())) \
            if many else 1e-2
        fit = fit_joint(d, priors, fixed=anchored, ridge=weight, weights=weights, structure=structure, policy=prior)
        for _ in range(len(d.names)):  # a ridged estimate of the wrong sign is still held at the prior
            wrong = [c.name for c in fit.all_coefficients if c.status != "fixed to prior"
                     and SIGN.get(c.name, 0) * c.estimate < 0.0]
            if not wrong:
                break
            held = tuple(c.name for c in fit.all_coefficients if c.status == "fixed to prior") + (wrong[0],)
            fit = fit_joint(d, priors, fixed=held, ridge=weight, weights=weights, structure=structure, policy=prior)
    return replace(fit, not_identifiable=tuple(found))


def cross_validate(vessel: Vessel, data: Sequence[ForceData], fit: JointFit) -> CrossValidation:
    """Leave-one-manoeuvre-out error of a structure with the same fixed coefficients / ridge as `fit`."""
    d = joint_design(vessel, data, fit.structure)
    fixed = [c.name for c in fit.all_coefficients if c.status == "fixed to prior"]
    per = _cv_errors(d, prior_values(vessel), fixed, fit.ridge_weight, np.array(fit.weights))
    return CrossValidation(fit.structure, per, float(np.mean(list(per.values()))))


# ------------------------------------------------------------------------------------------ the whole job


def identified_vessel(vessel: Vessel, fit: JointFit) -> Vessel:
    """The vessel with the fitted small-craft derivatives and thrust gains (everything else from the file)."""
    values = fit.values()
    hull_fields = {f.name for f in fields(SmallCraftHull)}
    hull = replace(vessel.small_craft, **{n: v for n, v in values.items() if n in hull_fields})
    sides = {}
    for side in SIDES:
        m = getattr(vessel.thrusters, side)
        sides[side] = scaled_thrust_map(m, values[f"thrusters.{side}.forward_N"],
                                        max(values[f"thrusters.{side}.reverse_N"], 0.0))
    return replace(vessel, name=f"{vessel.name}_identified", small_craft=hull,
                   thrusters=replace(vessel.thrusters, **sides),
                   provenance=f"{vessel.provenance.strip()} Small-craft damping and thrust gains identified by "
                              f"inverse-dynamics regression (structure {fit.structure}, prior {fit.prior_policy}; "
                              "usv_predictor.fitting.small_craft_identification).")


def _check_layout(vessel: Vessel) -> None:
    if vessel.layout != "twin_thrusters":
        raise ConfigError(f"vessel {vessel.name}: identification of the small_craft hull supports the twin_thrusters "
                          f"layout; this vessel has {vessel.layout}")


def identify_small_craft(vessel: Vessel, recordings: Sequence[Recording], *, structure: str = "auto",
                         prior: str = "none", smoother: SmootherConfig = SmootherConfig(),
                         rel_ci_limit: float = REL_CI_LIMIT, data: Sequence[ForceData] | None = None,
                         progress: Callable[[str], None] | None = None) -> IdentificationResult:
    """Smoother -> inverse dynamics -> the joint regression of each candidate structure -> CV -> identified vessel
    (the small-craft record of fitting/hull_models.HULL_FITS)."""
    _check_layout(vessel)
    if structure not in STRUCTURES + ("auto",):
        raise ConfigError(f"unknown model structure {structure!r} for the small-craft hull of {vessel.name}; use one "
                          f"of {list(STRUCTURES) + ['auto']}")
    names = sorted({r.name.split("#")[0].split("@")[0] for r in recordings})
    if len(names) < MIN_MANOEUVRES:
        raise DatasetError(f"identification needs at least {MIN_MANOEUVRES} manoeuvres (one is held out in turn "
                           f"for cross-validation); got {len(names)}: {', '.join(names) or 'none'}")
    forces = list(data) if data is not None else prepare(vessel, recordings, smoother=smoother, progress=progress)
    candidates = STRUCTURES if structure == "auto" else (structure,)
    fits, cvs, notes = {}, [], []
    for s in candidates:
        if progress is not None:
            progress(f"fitting structure {s} (prior {prior})")
        fits[s], cv, note = scale_anchored_fit(vessel, forces, s, prior, rel_ci_limit)
        cvs.append(cv)
        notes.append(note)
    chosen = candidates[0]
    if structure == "auto":
        by = {cv.structure: cv.score for cv in cvs}
        chosen = "coupled" if by["coupled"] < 0.95 * by["diagonal"] else "diagonal"
        notes.append(f"auto: CV error diagonal {by['diagonal']:.4f}, coupled {by['coupled']:.4f} -> {chosen}")
    fit = fits[chosen]
    score = next(cv.score for cv in cvs if cv.structure == chosen)
    vessel, fit, note = _thrust_exponent(vessel, forces, fit, score, prior, rel_ci_limit, progress)
    if note:
        notes.append(note)
    notes.append(f"held at the vessel file's values as the scale of every force: {ANCHOR_WHY[fit.anchor]}; and the "
                 "mass, inertia, x_G, each thrust map's dead band and time constant, the spacing")
    if fit.not_identifiable:
        notes.append(f"not identifiable without the prior: {', '.join(fit.not_identifiable)} -> {prior}")
    identified = identified_vessel(vessel, fit)
    forces = [replace(f, rudder=st, propeller=pr)
              for f, (st, pr) in ((f, known_forces(identified, f.nu, f.controls)) for f in forces)]
    return IdentificationResult(identified, fit, tuple(cvs), {}, tuple(forces), tuple(notes),
                               trials={**WOULD_DETERMINE, **ANCHOR_DETERMINE[fit.anchor]})


def scale_anchored_fit(vessel: Vessel, data: Sequence[ForceData], structure: str, prior: str,
                       rel_ci_limit: float = REL_CI_LIMIT) -> tuple[JointFit, CrossValidation, str]:
    """(fit, its cross-validation, a note): fit_small_craft with each scale anchor of ANCHORS; the thrust anchor
    only when its leave-one-manoeuvre-out force error is lower than the added-mass anchor's by more than 5 % (the
    added masses of a formula for another boat bias every force of the fit, the datasheet's gains do not; with the
    file's added masses right both fit alike). A fit refused (prior none) is no candidate."""
    fits, scores = {}, {}
    refused: NotIdentifiableError | None = None
    for anchor in ANCHORS:
        try:
            fits[anchor] = fit_small_craft(vessel, data, structure, prior, rel_ci_limit=rel_ci_limit, anchor=anchor)
        except NotIdentifiableError as err:
            refused = refused or err
            continue
        scores[anchor] = cross_validate(vessel, data, fits[anchor])
    implausible = _implausible_masses(vessel, fits["thrust"]) if "thrust" in fits else ""
    if implausible and len(fits) > 1:
        del fits["thrust"], scores["thrust"]
    if not fits:
        raise refused  # type: ignore[misc]
    default = "added_mass" if "added_mass" in scores else "thrust"
    chosen = default
    if "thrust" in scores and scores["thrust"].score < 0.95 * scores[default].score:
        chosen = "thrust"
    listed = ", ".join(f"{a} {cv.score:.4g}" for a, cv in scores.items())
    out = f" (thrust anchor out: {implausible})" if implausible and "thrust" not in fits else ""
    return fits[chosen], scores[chosen], f"{structure}: scale anchor by CV error ({listed}){out} -> {chosen}"


def _implausible_masses(vessel: Vessel, fit: JointFit) -> str:
    """Why the fit's total masses are not physical (MIN_MASS_FRACTION of the rigid body's), or ""."""
    values = fit.values()
    m, g = vessel.mass, vessel.geometry
    rigid = {"X_udot": m, "Y_vdot": m, "N_rdot": m * (g.k_zz * g.L_pp) ** 2}  # (kg, kg, kg m^2)
    low = [f"{n}: total {rigid[n] - values[n]:.3g} of rigid {rigid[n]:.3g}" for n in ADDED_MASS_TERMS
           if rigid[n] - values[n] < MIN_MASS_FRACTION * rigid[n]]
    return "; ".join(low)


def with_exponent(vessel: Vessel, exponent: float) -> Vessel:
    """The vessel with both power-law thrust maps at `exponent` (the gains keep their meaning: thrust at full)."""
    t = vessel.thrusters
    return replace(vessel, thrusters=replace(t, port=replace(t.port, exponent=exponent),
                                             starboard=replace(t.starboard, exponent=exponent)))


def _thrust_exponent(vessel: Vessel, data: Sequence[ForceData], fit: JointFit, score: float, prior: str,
                     rel_ci_limit: float, progress: Callable[[str], None] | None) -> tuple[Vessel, JointFit, str]:
    """(vessel, fit, note): the thrust maps' exponent stays the vessel file's unless the data determine it: the
    structure is refitted at each exponent of EXPONENT_GRID and one whose cross-validation error is lower than the
    file's by more than 5 % and below DECISIVE_CV replaces it (the CV errors go into the note either way).
    Table maps are not profiled."""
    t = vessel.thrusters
    if t.port.table_command or t.starboard.table_command or t.port.exponent != t.starboard.exponent:
        return vessel, fit, ""
    scores = {t.port.exponent: score}
    fits = {t.port.exponent: fit}
    for exponent in EXPONENT_GRID:
        if exponent in scores:
            continue
        if progress is not None:
            progress(f"thrust map exponent {exponent:g} (the vessel file's: {t.port.exponent:g})")
        trial = with_exponent(vessel, exponent)
        try:
            fits[exponent] = fit_small_craft(trial, data, fit.structure, prior, rel_ci_limit=rel_ci_limit,
                                             anchor=fit.anchor)
        except NotIdentifiableError:
            continue  # with prior "none" an exponent whose fit is refused is no candidate
        scores[exponent] = cross_validate(trial, data, fits[exponent]).score
    best = min(scores, key=scores.__getitem__)
    listed = ", ".join(f"{e:g}: {v:.4f}" for e, v in sorted(scores.items()))
    if best != t.port.exponent and scores[best] < 0.95 * scores[t.port.exponent] and scores[best] < DECISIVE_CV:
        return (with_exponent(vessel, best), fits[best],
                f"thrust map exponent: the data determine it (CV error by exponent {listed}) -> {best:g} instead of "
                f"the vessel file's {t.port.exponent:g}")
    return vessel, fit, (f"thrust map exponent: the vessel file's {t.port.exponent:g} kept (CV error by exponent "
                         f"{listed}: none lower by more than 5 % with a CV error below {DECISIVE_CV:g})")


def hull_forces(vessel: Vessel, values: Mapping[str, float], nu: np.ndarray,
                names: Sequence[str] | None = None) -> np.ndarray:
    """(T, 3) small-craft hull [X, Y, N] (N, N, N m) of the coefficient `values` at velocities nu (the thrust gains and
    unknown names are ignored; the vessel file's value for a hull term not in `values`)."""
    columns = basis(vessel, nu, np.zeros((len(nu), 2)))
    priors = prior_values(vessel)
    out = np.zeros((len(nu), 3))
    for name in HULL_TERMS:
        if names is not None and name not in names:
            continue
        out += values.get(name, priors[name]) * columns[name]
    return out

"""Online estimation of the sea: an extended Kalman filter on the float grey box (pure Python + numpy, no torch).

The node (once per cycle, from its LiveState) and `replay evaluate --adaptive` (once per sample of a Recording) feed
it the same inputs: over-ground body velocities (u, v), the gyro yaw rate r, the heading psi, the layout's controls
and the time. It estimates the current and the drifting terms of the grey box with their covariance.

State (7,), SI, marine frames:
    x = [u_r, v_r, r, c_n, c_e, b_r, k_R]
    u_r, v_r (m/s), r (rad/s)  velocity through the water, body FRD (the grey box's state, dynamics.py)
    c_n, c_e (m/s)             current velocity toward north / east (grey-box term `current_ne`)
    b_r (rad/s)                gyro bias, measured - true (term `yaw_rate_bias`)
    k_R (-)                    relative change of the calm-water resistance (term `resistance_change`)

Process model (between two calls, t_{k-1} -> t_k, controls and actuator levels of t_{k-1} held, psi integrated
from the measured psi_{k-1} with r):
    nu_r_dot = M^-1 (tau(nu_r, a, b) - C(nu_r) nu_r) + [X_k / m11, 0, 0] + w_nu      (dynamics.ManoeuvringModel
                                                                                     .accelerations, Fossen 2021
                                                                                     eq. 6.5)
    X_k = -k_R (r1 u_r + r2 u_r |u_r|)            the resistance change exactly as models/greybox.py applies it
                                                  (r1, r2 = ManoeuvringModel.resistance_coefficients())
    c_dot = w_c, b_r_dot = w_b, k_R_dot = w_k     random walks (Brown & Hwang 2012 sec. 7.2; Fossen 2021 sec. 13.3)
    an engine the layout does not report (rudder_only) runs as the grey box's rollouts hold it (models/greybox.py
    RudderOnlyModule): at the engine speed that holds, in straight running, the water speed of the `reference`
    state (the held reference: replay the manoeuvre's approach, data.recording.held_reference; the node its latest
    straight running, node/live.ApproachTracker), u_ref - (c_n cos psi_ref + c_e sin psi_ref), against the
    resistance (1 + k_R) (r1 u + r2 u^2) less the wind and wave terms' surge force there
    (dynamics.RudderPropellerForces.engine_speed_for); without a reference at the present u_r (the grey box's
    start state). A boat slows down in a turn at the same engine setting: an engine speed taken from the present
    speed keeps it from settling, and the filter would explain the missing speed by a current.
propagated by RK4 with substeps <= max_substep_s; the transition matrix is Phi = (I + A h + (A h)^2 / 2)^n with
A = df/dx at the start of the interval (the 3 x 3 nu_r block by central differences of `accelerations`: 6 calls;
d u_dot / d k_R analytic; with a reference, nu_r_dot through the held engine speed's dependence on c_n, c_e, k_R by
central differences: 6 more); Q = diag(q^2) dt for the white-noise densities q of OnlineConfig.

Measurement model (Fossen 2021 eq. 2.40 with nu = nu_r + R(psi)^T V_c; the gyro with its bias):
    z = [u, v, r_gyro] = [u_r + c_n cos psi + c_e sin psi,  v_r - c_n sin psi + c_e cos psi,  r + b_r] + e
linear in x for the measured psi: H = [[1, 0, 0, cos, sin, 0, 0], [0, 1, 0, -sin, cos, 0, 0], [0, 0, 1, 0, 0, 1, 0]].
Components that are NaN or inf are left out of the update (a partial update), never written into the state.

Update (Joseph form, Bucy & Joseph 1968; Brown & Hwang 2012 eq. 4.2.18):
    S = H P H^T + R,  K = P H^T S^-1,  x += K y,  P = (I - K H) P (I - K H)^T + K R K^T
then P is symmetrised and its diagonal held between a floor and a ceiling (OnlineConfig): a floor keeps the filter
listening (never certain), a ceiling keeps an unobservable direction from growing without bound; both change P by
congruence or a diagonal addition, so it stays positive definite.

Gating: NIS = y^T S^-1 y against the chi^2 quantile of `gate_probability` for the measurement's dimension (Bar-Shalom,
Li & Kirubarajan 2001 sec. 5.4). A rejected measurement is counted and not used. When measurements are rejected
without a break for `change_after_s`, the sea has changed (a tidal front, a new heading into a channel): the
covariance of the current and of the velocity states goes back to the prior and the measurement is used (a
change detector in the sense of Gustafsson 2000 ch. 9: a step is not an outlier when it persists).

Resets (the state goes back to the prior around the measurement): time going backwards or jumping forward by
more than `reset_gap_s` (a clock jump, a new bag), or a non-finite state or covariance (never expected; counted).
A gap longer than `max_gap_s` (stale inputs, a drop-out) re-initialises the velocity states from the next
measurement and grows the covariance of the slow terms by their random walk over the gap.

Observability (docs/online.md): on a straight course the surge measurement sees u_r + c_along only; the dynamics
pin u_r to the model's steady speed, which a resistance error k_R shifts, so c_along and k_R are confounded and
their covariance stays large along the track: the filter says `converged: False` (the current's larger standard
deviation, the square root of the largest eigenvalue of its 2 x 2 covariance, exceeds converged_current_std_m_s)
instead of inventing a current. Turning separates them (the current turns in the body frame, the resistance does
not). The cross-track current is observable on any course. A compass offset is not estimated: with body-frame
velocity measurements it only turns the estimate by the offset (it invents no speed); it needs GNSS positions.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from statistics import NormalDist
from typing import Any

import numpy as np

from usv_predictor.data.recording import Recording, held_reference
from usv_predictor.errors import ConfigError
from usv_predictor.frames import compass_deg
from usv_predictor.physics import effects
from usv_predictor.physics.actuators import ActuatorLayout
from usv_predictor.physics.dynamics import ManoeuvringModel, SeaLoads
from usv_predictor.physics.vessel import Vessel

STATE_NAMES = ("u_r", "v_r", "r", "c_n", "c_e", "b_r", "k_R")
STATE_UNITS = ("m/s", "m/s", "rad/s", "m/s", "m/s", "rad/s", "-")
U_R, V_R, R, C_N, C_E, B_R, K_R = range(7)
N_STATE = 7
NU = slice(0, 3)  # the velocity states
TERMS = dict(zip(effects.ONLINE_TERMS, ((C_N, C_E), (B_R,), (K_R,))))  # grey-box term -> its states
# the terms the process model takes as they are
RUDDER_OFFSET, SIDE_FORCE, IMBALANCE, WIND, WAVE, WAVE_RESISTANCE = effects.FIXED_TERMS
FD_STEP = (1e-4, 1e-4, 1e-5)  # central-difference steps for d(nu_r_dot)/d(u_r, v_r, r) (m/s, m/s, rad/s)
HELD_FD_STEP = 1e-5  # central-difference step in k_R (-) of the held engine speed (rudder_only)


@dataclass(frozen=True)
class OnlineConfig:
    """Tuning of the online estimator, SI units; 1-sigma values. Process noise as white-noise densities q: the
    variance of a state grows by q^2 per second of prediction."""

    # prior at a (re)start, around the grey box's own terms (the artifact's; zero for the calm-water model)
    prior_velocity_std_m_s: float = 0.1  # u_r, v_r about (u, v) minus the current (m/s)
    prior_yaw_rate_std_rad_s: float = 0.005  # r about the gyro minus the bias (rad/s)
    prior_current_std_m_s: float = 0.5  # each of c_n, c_e (m/s)
    prior_yaw_rate_bias_std_rad_s: float = 0.01  # b_r (rad/s), 0.57 deg/s
    prior_resistance_std: float = 0.15  # k_R (-): 15 % of the calm-water resistance
    # process noise densities
    surge_accel_noise: float = 0.01  # on u_r ((m/s)/sqrt(s)): model error of the surge dynamics
    sway_accel_noise: float = 0.01  # on v_r ((m/s)/sqrt(s))
    yaw_accel_noise: float = 0.001  # on r ((rad/s)/sqrt(s))
    current_noise: float = 0.002  # random walk of c_n, c_e ((m/s)/sqrt(s)): 0.015 m/s in a minute
    bias_noise: float = 2e-6  # random walk of b_r ((rad/s)/sqrt(s))
    resistance_noise: float = 2e-4  # random walk of k_R (1/sqrt(s))
    # measurement noise of one (box-averaged) sample
    velocity_std_m_s: float = 0.02  # u, v over ground (m/s)
    yaw_rate_std_rad_s: float = 0.002  # gyro (rad/s)
    # robustness
    gate_probability: float = 0.9999  # chi^2 gate on the NIS (-): measurements beyond it are rejected
    change_after_s: float = 2.0  # rejected without a break this long: the sea changed, reopen the current (s)
    max_gap_s: float = 2.0  # a longer gap between calls re-initialises the velocity states (s)
    reset_gap_s: float = 300.0  # time jumping forward further than this (or backwards): full reset (s)
    max_substep_s: float = 0.1  # RK4 substep of the prediction (s)
    covariance_floor: float = 1e-4  # diagonal floor, as a fraction of the prior variance (-)
    covariance_ceiling: float = 4.0  # diagonal ceiling, as a multiple of the prior variance (-)
    # reporting
    converged_current_std_m_s: float = 0.05  # converged when the current's largest std is below this (m/s)
    nis_window_s: float = 30.0  # time constant of the running mean of the NIS (s)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise ConfigError(f"online estimator: {f.name}={value!r} must be a finite number")
            if f.name == "gate_probability":
                if not 0.5 < value < 1.0:
                    raise ConfigError(f"online estimator: gate_probability={value} must lie in (0.5, 1)")
            elif f.name in ("bias_noise", "resistance_noise", "covariance_floor"):
                if value < 0.0:
                    raise ConfigError(f"online estimator: {f.name}={value} must be >= 0")
            elif not value > 0.0:
                raise ConfigError(f"online estimator: {f.name}={value} must be > 0")
        if self.covariance_floor >= 1.0 or self.covariance_ceiling <= 1.0:
            raise ConfigError("online estimator: covariance_floor must be < 1 and covariance_ceiling > 1 (fractions "
                              "of the prior variance)")
        if self.reset_gap_s <= self.max_gap_s:
            raise ConfigError(f"online estimator: reset_gap_s={self.reset_gap_s} must exceed "
                              f"max_gap_s={self.max_gap_s}")

    def prior_std(self) -> np.ndarray:
        """(7,) prior standard deviations in STATE_NAMES order."""
        return np.array([self.prior_velocity_std_m_s, self.prior_velocity_std_m_s, self.prior_yaw_rate_std_rad_s,
                         self.prior_current_std_m_s, self.prior_current_std_m_s, self.prior_yaw_rate_bias_std_rad_s,
                         self.prior_resistance_std])

    def process_noise(self) -> np.ndarray:
        """(7,) white-noise densities q in STATE_NAMES order (variance growth q^2 per s)."""
        return np.array([self.surge_accel_noise, self.sway_accel_noise, self.yaw_accel_noise, self.current_noise,
                         self.current_noise, self.bias_noise, self.resistance_noise])

    def measurement_std(self) -> np.ndarray:
        """(3,) standard deviations of u, v (m/s) and the gyro (rad/s)."""
        return np.array([self.velocity_std_m_s, self.velocity_std_m_s, self.yaw_rate_std_rad_s])


def chi2_quantile(probability: float, dof: int) -> float:
    """The chi^2 quantile for 1-3 degrees of freedom, exact (Abramowitz & Stegun 1964 eq. 26.4.4-26.4.6):
    k = 1: z^2 with z the normal quantile of (1 + p)/2; k = 2: -2 ln(1 - p); k = 3: the root of
    F(x) = erf(sqrt(x/2)) - sqrt(2x/pi) exp(-x/2) = p by bisection (16.27 at p = 0.999)."""
    if dof == 1:
        return NormalDist().inv_cdf(0.5 * (1.0 + probability)) ** 2
    if dof == 2:
        return -2.0 * math.log(1.0 - probability)
    if dof != 3:
        raise ConfigError(f"chi2_quantile: {dof} degrees of freedom; the measurement has 1-3 components")
    low, high = 0.0, 200.0
    for _ in range(200):
        mid = 0.5 * (low + high)
        cdf = math.erf(math.sqrt(0.5 * mid)) - math.sqrt(2.0 * mid / math.pi) * math.exp(-0.5 * mid)
        low, high = (mid, high) if cdf < probability else (low, mid)
    return 0.5 * (low + high)


@dataclass(frozen=True)
class OnlineEstimate:
    """The filter's answer after a call (JSON-ready through to_json)."""

    t_s: float  # time of the estimate (s, the caller's clock)
    state: tuple[float, ...]  # (7,) x in STATE_NAMES order
    std: tuple[float, ...]  # (7,) square roots of the diagonal of P
    current_cov: tuple[float, float, float]  # P_nn, P_ne, P_ee of the current ((m/s)^2)
    converged: bool  # the current's largest std below converged_current_std_m_s
    status: str  # what the call did: "updated", "rejected", "predicted" (no usable measurement), "reset", ...
    nis: float  # NIS of this call's measurement (NaN when none)
    nis_mean: float  # running mean of the accepted NIS (expected: the measurement dimension, 3)
    updates: int
    rejections: int
    resets: int
    changes: int  # detected changes of the sea (covariance reopened)

    @property
    def current_ne(self) -> tuple[float, float]:
        return self.state[C_N], self.state[C_E]

    @property
    def current_speed_m_s(self) -> float:
        return math.hypot(self.state[C_N], self.state[C_E])

    @property
    def current_to_deg(self) -> float:
        return compass_deg(self.state[C_N], self.state[C_E])

    @property
    def current_std_max_m_s(self) -> float:
        """Standard deviation of the current along its worst-known direction (m/s)."""
        p_nn, p_ne, p_ee = self.current_cov
        half = 0.5 * (p_nn + p_ee)
        return math.sqrt(max(half + math.sqrt(max(0.25 * (p_nn - p_ee) ** 2 + p_ne * p_ne, 0.0)), 0.0))

    def terms(self) -> dict[str, list[float]]:
        """The grey-box terms (models/greybox.py names, SI) of the estimate."""
        return {name: [self.state[i] for i in index] for name, index in TERMS.items()}

    def to_json(self) -> dict[str, Any]:
        return {
            "t_s": self.t_s, "status": self.status, "converged": self.converged,
            "current_n_mps": self.state[C_N], "current_e_mps": self.state[C_E],
            "current_speed_mps": self.current_speed_m_s, "current_toward_deg": self.current_to_deg,
            "current_std_max_mps": self.current_std_max_m_s,
            "current_cov_nn_ne_ee_m2_s2": list(self.current_cov),
            "gyro_bias_deg_s": math.degrees(self.state[B_R]), "gyro_bias_std_deg_s": math.degrees(self.std[B_R]),
            "resistance_change_pct": 100.0 * self.state[K_R], "resistance_change_std_pct": 100.0 * self.std[K_R],
            "nis_mean": self.nis_mean if math.isfinite(self.nis_mean) else None,
            "updates": self.updates, "rejections": self.rejections, "resets": self.resets, "changes": self.changes,
        }


class OnlineEstimator:
    """The EKF (module docstring). step() once per cycle; run() over a whole series.

    vessel: the grey box's vessel (its hull as identified, if it is); terms: the grey-box terms the model already
    carries (models/greybox.py names, SI: current_ne, yaw_rate_bias, resistance_change are the prior means of the
    states; rudder_offset, propeller_side_force, thrust_imbalance, wind_ne, wave_ne, wave_resistance enter the
    process model as they are; actuator_delay is not modelled by the filter).
    """

    def __init__(self, vessel: Vessel, config: OnlineConfig | None = None,
                 terms: Mapping[str, Sequence[float]] | None = None) -> None:
        self.config = config or OnlineConfig()
        terms = {k: [float(x) for x in v] for k, v in (terms or {}).items()}
        self.model = ManoeuvringModel(vessel, propeller_side_force=_term(terms, SIDE_FORCE),
                                      thrust_imbalance=_term(terms, IMBALANCE))
        self.layout: ActuatorLayout = vessel.actuator_layout
        self.rudder_offset = _term(terms, RUDDER_OFFSET)  # (rad), added to a reported rudder
        wind = terms.get(WIND, [0.0, 0.0])  # wind velocity (toward) north/east (m/s)
        wave = terms.get(WAVE, [0.0, 0.0])
        wave_amp2 = math.hypot(*wave)  # zeta_a^2 (m^2) along the direction FROM
        # the wind and waves the model carries, fixed; the current is the filter's state (_sea)
        self._fixed_sea = SeaLoads(
            wind_speed=math.hypot(*wind), wind_from=math.atan2(-wind[1], -wind[0]) if any(wind) else 0.0,
            wave_amplitude=math.sqrt(wave_amp2), wave_from=math.atan2(wave[1], wave[0]) if any(wave) else 0.0,
            wave_resistance=_term(terms, WAVE_RESISTANCE))
        self.prior_mean = np.zeros(N_STATE)
        for name, index in TERMS.items():
            if name in terms:
                self.prior_mean[list(index)] = terms[name][:len(index)]
        self.r1, self.r2 = self.model.resistance_coefficients()
        self._columns = self._command_columns()
        self._prior_var = self.config.prior_std() ** 2
        self._floor = self.config.covariance_floor * self._prior_var
        self._ceiling = self.config.covariance_ceiling * self._prior_var
        self._q2 = self.config.process_noise() ** 2
        self._r2 = self.config.measurement_std() ** 2
        self._gates = {k: chi2_quantile(self.config.gate_probability, k) for k in (1, 2, 3)}
        self.updates = self.rejections = self.resets = self.changes = 0
        self._clear()

    # ------------------------------------------------------------------ set-up
    def _command_columns(self) -> tuple[tuple[int | None, str], ...]:
        """Per actuator state of the layout (its `commands`): the control column that reports it (None: not
        reported, rudder_only's engine) and the control's source ("state" or "command")."""
        names = self.layout.control_names
        out = []
        for command in self.layout.commands:
            if command in names:
                out.append((names.index(command), self.layout.controls[names.index(command)].source))
            else:
                out.append((None, "state"))
        return tuple(out)

    def _clear(self) -> None:
        """Forget the run: the next call initialises from its measurement."""
        self.x: np.ndarray | None = None  # (7,)
        self.P: np.ndarray | None = None  # (7, 7)
        self.t_s: float | None = None  # time of x (s)
        self._inputs: tuple[float, np.ndarray] | None = None  # psi (rad), controls (C,) at t_s
        self._levels: list[float] | None = None  # actuator levels (a, b) at t_s
        self._rejected_since: float | None = None
        self._nis_mean = math.nan
        self._last_nis = math.nan
        self._last_elapsed = 0.0  # (s) the last prediction's interval: the weight of the running NIS mean
        self._reference: np.ndarray | None = None  # (4,) the held reference of the latest call (step)

    def reset(self) -> None:
        """Back to the prior (the node calls it on a clock jump it detects itself; step() also does)."""
        self._clear()

    # ------------------------------------------------------------------ the public step
    def step(self, t_s: float, u: float, v: float, r: float, psi: float, controls: Sequence[float],
             reference: Sequence[float] | None = None) -> OnlineEstimate:
        """One cycle: predict to t_s, update with the measurement (u, v over ground in m/s, r gyro in rad/s),
        psi (rad) the measured heading, `controls` (C,) the layout's controls at t_s and `reference` (4,)
        [u, v, r, psi] as measured: the held reference whose engine speed a layout without propulsion data holds
        (module docstring; None: the present speed's; ignored by the other layouts) (the node's LiveState fields).
        NaN/inf in any input never reaches the state: without a finite psi, controls or reference nothing is done
        ("skipped"), non-finite measurement components are left out of the update."""
        controls = np.asarray(controls, dtype=float).reshape(-1)
        if controls.shape != (len(self.layout.controls),):
            raise ConfigError(f"online estimator: controls must be ({len(self.layout.controls)},) "
                              f"{self.layout.control_names}, got shape {controls.shape}")
        held = None if reference is None else np.asarray(reference, dtype=float).reshape(-1)
        if held is not None and held.shape != (4,):
            raise ConfigError(f"online estimator: reference must be (4,) [u, v, r, psi], got shape {held.shape}")
        z = np.array([u, v, r], dtype=float)
        if not (math.isfinite(t_s) and math.isfinite(psi) and np.isfinite(controls).all()
                and (held is None or np.isfinite(held).all())):
            return self._answer(t_s, "skipped: non-finite time, heading, controls or reference", math.nan)
        self._reference = held
        status = ""
        if self.t_s is not None:
            gap = t_s - self.t_s
            if gap < 0.0 or gap > self.config.reset_gap_s:
                self.resets += 1
                self._clear()
                status = "reset: clock jump"
            elif gap > self.config.max_gap_s:
                self._reopen_velocity(gap)
                status = "restarted after a gap"
        if self.x is None:
            if not np.isfinite(z).all():
                return self._answer(t_s, "waiting for a complete measurement", math.nan)
            self._initialise(t_s, z, psi, controls)
            return self._answer(t_s, status or "initialised", math.nan)
        if self._levels is None:  # after a gap: the velocity states from this measurement
            if not np.isfinite(z).all():
                return self._answer(t_s, "waiting for a complete measurement", math.nan)
            self._restart_velocity(t_s, z, psi, controls)
            return self._answer(t_s, status, math.nan)
        if t_s > self.t_s:
            self._predict(t_s - self.t_s, controls)
        else:  # the same time again: the levels of the new controls
            self._levels = self._levels_now(controls, self._levels)
        self.t_s = t_s
        self._inputs = (psi, controls.copy())
        known = np.isfinite(z)
        if not known.any():
            return self._answer(t_s, status or "predicted: no finite measurement", math.nan)
        nis, what = self._update(z, psi, known)
        if not (np.isfinite(self.x).all() and np.isfinite(self.P).all()):  # never expected: say so, start again
            self.resets += 1
            self._clear()
            return self._answer(t_s, "reset: the filter diverged", math.nan)
        return self._answer(t_s, status or what, nis)

    # ------------------------------------------------------------------ initialisation
    def _initialise(self, t_s: float, z: np.ndarray, psi: float, controls: np.ndarray) -> None:
        self.x = self.prior_mean.copy()
        self.P = np.diag(self._prior_var)
        self.t_s = t_s
        self._set_velocity(z, psi)
        self._inputs = (psi, controls.copy())
        self._levels = self._levels_now(controls, None)
        self._rejected_since = None

    def _set_velocity(self, z: np.ndarray, psi: float) -> None:
        """nu_r = measured nu minus the current in the body frame, r = gyro minus bias (the prior's around them)."""
        c, s = math.cos(psi), math.sin(psi)
        c_n, c_e = self.x[C_N], self.x[C_E]
        self.x[U_R] = z[0] - (c_n * c + c_e * s)
        self.x[V_R] = z[1] - (-c_n * s + c_e * c)
        self.x[R] = z[2] - self.x[B_R]

    def _reopen_velocity(self, gap: float) -> None:
        """A gap: the velocity states are forgotten (the next measurement re-initialises them), the slow terms
        keep their estimate with the covariance grown by their random walk over the gap (ceiling applies)."""
        self.P = self.P + np.diag(self._q2 * gap)
        self._levels = None

    def _restart_velocity(self, t_s: float, z: np.ndarray, psi: float, controls: np.ndarray) -> None:
        self.P[NU, :] = 0.0
        self.P[:, NU] = 0.0
        self.P[NU, NU] = np.diag(self._prior_var[NU])
        self.t_s = t_s
        self._set_velocity(z, psi)
        self._inputs = (psi, controls.copy())
        self._levels = self._levels_now(controls, None)
        self._rejected_since = None
        self._bound_covariance()

    # ------------------------------------------------------------------ process model
    def _levels_now(self, controls: np.ndarray, previous: list[float] | None) -> list[float]:
        """Actuator levels at the time of `controls`: a reported actuator state is its level (plus the rudder
        offset); a reported command keeps the lagged level (integrated in _predict; at a start: the command);
        an unreported engine (rudder_only) runs at the speed that holds the water speed in straight running."""
        levels = []
        for k, (column, source) in enumerate(self._columns):
            if column is None:
                levels.append(self._engine_speed(self.x))
            elif source == "command" and previous is not None:
                levels.append(previous[k])
            else:
                value = float(controls[column])
                levels.append(value + self.rudder_offset if self.layout.commands[k] == "delta" else value)
        return levels

    def _engine_speed(self, x: np.ndarray) -> float:
        """The engine speed (rpm) of a layout that does not report it, at the filter state x (7,) (module
        docstring): the one that holds the held reference's water speed in straight running; without a reference
        the present u_r's."""
        if not hasattr(self.model, "engine_speed_for"):
            return 0.0
        if self._reference is None:
            return self.model.engine_speed_for(max(x[U_R], 0.0), x[K_R])
        u_ref, psi_ref = float(self._reference[0]), float(self._reference[3])
        c, s = math.cos(psi_ref), math.sin(psi_ref)
        c_n, c_e = float(x[C_N]), float(x[C_E])
        water = u_ref - (c_n * c + c_e * s)  # the engine holds a speed through the water
        # the sea's surge force in that straight running (over ground: the water speed plus the current)
        wind, waves = self.model.environment_loads(psi_ref, water + c_n * c + c_e * s, -c_n * s + c_e * c,
                                                   self._sea())
        return self.model.engine_speed_for(max(water, 0.0), float(x[K_R]), wind[0] + waves[0])

    def _held_column(self) -> int | None:
        """The actuator level (index into the layout's commands) the layout does not report, or None."""
        return next((k for k, (column, _) in enumerate(self._columns) if column is None), None)

    def _commands(self, controls: np.ndarray, levels: list[float]) -> tuple[float, float]:
        """The commands that hold a reported state where it is and drive a reported command's lag."""
        out = []
        for k, (column, source) in enumerate(self._columns):
            out.append(levels[k] if column is None or source == "state" else float(controls[column]))
        return out[0], out[1]

    def _sea(self) -> SeaLoads:
        return replace(self._fixed_sea, current_n=float(self.x[C_N]), current_e=float(self.x[C_E]))

    def _accel(self, psi: float, u_r: float, v_r: float, r: float, a: float, b: float, k_r: float,
               sea: SeaLoads) -> tuple[float, float, float]:
        """nu_r_dot of the grey box with the resistance change k_R (module docstring)."""
        du, dv, dr = self.model.accelerations(psi, u_r, v_r, r, a, b, sea)
        return du - k_r * (self.r1 * u_r + self.r2 * u_r * abs(u_r)) / self.model.m11, dv, dr

    def _predict(self, elapsed: float, controls_end: np.ndarray) -> None:
        """x, P from t_s to t_s + elapsed (module docstring). The controls move linearly from those of t_s to
        `controls_end` (first-order hold, as the grey box's rollout: a rudder moves during a step); a reported
        actuator state is the level itself, a reported command drives the lag of the layout's motor."""
        self._last_elapsed = elapsed
        psi, controls = self._inputs
        start = self._levels
        end = self._levels_now(controls_end, start)
        sea = self._sea()
        k_r = float(self.x[K_R])
        n = max(1, math.ceil(elapsed / self.config.max_substep_s - 1e-9))
        h = elapsed / n
        jac = self._jacobian(psi, start[0], start[1], k_r, sea)
        model = self.model
        lagged = [source == "command" and column is not None for column, source in self._columns]
        cmd0 = self._commands(controls, start)
        cmd1 = self._commands(controls_end, end)

        def level(k: int, theta: float, y: list[float]) -> float:
            return y[4 + k] if lagged[k] else start[k] + theta * (end[k] - start[k])

        def f(theta: float, y: list[float]) -> list[float]:
            a, b = level(0, theta, y), level(1, theta, y)
            du, dv, dr = self._accel(y[0], y[1], y[2], y[3], a, b, k_r, sea)
            ca, cb = (cmd0[0] + theta * (cmd1[0] - cmd0[0]), cmd0[1] + theta * (cmd1[1] - cmd0[1]))
            da, db = model.actuator_rates(a, b, ca, cb)
            return [y[3], du, dv, dr, da if lagged[0] else 0.0, db if lagged[1] else 0.0]

        s = [psi, float(self.x[U_R]), float(self.x[V_R]), float(self.x[R]), start[0], start[1]]
        for i in range(n):
            t0, t1 = i / n, (i + 0.5) / n
            k1 = f(t0, s)
            k2 = f(t1, [p + 0.5 * h * q for p, q in zip(s, k1)])
            k3 = f(t1, [p + 0.5 * h * q for p, q in zip(s, k2)])
            k4 = f((i + 1.0) / n, [p + h * q for p, q in zip(s, k3)])
            s = [p + h / 6.0 * (q1 + 2.0 * q2 + 2.0 * q3 + q4) for p, q1, q2, q3, q4 in zip(s, k1, k2, k3, k4)]
        self.x[U_R], self.x[V_R], self.x[R] = s[1], s[2], s[3]
        self._levels = [s[4] if lagged[0] else end[0], s[5] if lagged[1] else end[1]]
        step = np.eye(N_STATE) + jac * h
        step = step + 0.5 * (jac @ jac) * (h * h)
        phi = np.linalg.matrix_power(step, n)
        self.P = phi @ self.P @ phi.T + np.diag(self._q2 * elapsed)
        self._bound_covariance()

    def _jacobian(self, psi: float, a: float, b: float, k_r: float, sea: SeaLoads) -> np.ndarray:
        """(7, 7) A = df/dx at the current state: central differences in nu_r, d u_dot / d k_R analytic."""
        A = np.zeros((N_STATE, N_STATE))
        base = [float(self.x[U_R]), float(self.x[V_R]), float(self.x[R])]
        for j, eps in enumerate(FD_STEP):
            up, down = list(base), list(base)
            up[j] += eps
            down[j] -= eps
            f_up = self._accel(psi, *up, a, b, k_r, sea)
            f_down = self._accel(psi, *down, a, b, k_r, sea)
            for i in range(3):
                A[i, j] = (f_up[i] - f_down[i]) / (2.0 * eps)
        u_r = base[0]
        A[U_R, K_R] = -(self.r1 * u_r + self.r2 * u_r * abs(u_r)) / self.model.m11
        held = self._held_column()
        if held is not None and self._reference is not None:  # the held engine speed moves with c_n, c_e, k_R
            for j, eps in ((C_N, FD_STEP[0]), (C_E, FD_STEP[0]), (K_R, HELD_FD_STEP)):
                rows = []
                for sign in (1.0, -1.0):
                    x = self.x.copy()
                    x[j] += sign * eps
                    levels = [a, b]
                    levels[held] = self._engine_speed(x)
                    rows.append(self._accel(psi, *base, levels[0], levels[1], k_r, sea))
                for i in range(3):
                    A[i, j] += (rows[0][i] - rows[1][i]) / (2.0 * eps)
        return A

    # ------------------------------------------------------------------ measurement update
    def _update(self, z: np.ndarray, psi: float, known: np.ndarray) -> tuple[float, str]:
        c, s = math.cos(psi), math.sin(psi)
        H = np.zeros((3, N_STATE))
        H[0, U_R], H[0, C_N], H[0, C_E] = 1.0, c, s
        H[1, V_R], H[1, C_N], H[1, C_E] = 1.0, -s, c
        H[2, R], H[2, B_R] = 1.0, 1.0
        H = H[known]
        Rm = np.diag(self._r2[known])
        y = z[known] - H @ self.x
        S = H @ self.P @ H.T + Rm
        try:
            S_inv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return math.nan, "rejected: singular innovation covariance"
        nis = float(y @ S_inv @ y)
        what = "updated"
        if not nis <= self._gates[int(known.sum())]:
            if self._rejected_since is None:
                self._rejected_since = float(self.t_s)
            if self.t_s - self._rejected_since < self.config.change_after_s:
                self.rejections += 1
                self._last_nis = nis
                return nis, "rejected: innovation beyond the gate"
            # the innovation persists: not an outlier, the sea changed. Reopen the current and the velocities.
            self.changes += 1
            keep = [i for i in range(N_STATE) if i not in (U_R, V_R, C_N, C_E)]
            reopened = np.diag(self._prior_var)
            reopened[np.ix_(keep, keep)] = self.P[np.ix_(keep, keep)]
            self.P = reopened
            S = H @ self.P @ H.T + Rm
            S_inv = np.linalg.inv(S)
            nis = float(y @ S_inv @ y)
            what = "updated: the sea changed, current reopened"
        self._rejected_since = None
        K = self.P @ H.T @ S_inv
        self.x = self.x + K @ y
        ikh = np.eye(N_STATE) - K @ H
        self.P = ikh @ self.P @ ikh.T + K @ Rm @ K.T
        self._bound_covariance()
        self.updates += 1
        self._last_nis = nis
        alpha = 1.0 / max(self.config.nis_window_s, 1e-9)
        weight = min(1.0, alpha * self._last_elapsed)
        dof = float(known.sum())
        normalised = nis * 3.0 / dof  # expressed for 3 components
        self._nis_mean = normalised if not math.isfinite(self._nis_mean) else \
            (1.0 - weight) * self._nis_mean + weight * normalised
        return nis, what

    def _bound_covariance(self) -> None:
        """Symmetrise P, raise its diagonal to the floor (a diagonal addition) and scale rows and columns whose
        variance exceeds the ceiling (a congruence): P stays symmetric positive definite."""
        P = 0.5 * (self.P + self.P.T)
        d = np.diag(P)
        over = d > self._ceiling
        if over.any():
            scale = np.ones(N_STATE)
            scale[over] = np.sqrt(self._ceiling[over] / d[over])
            P = P * scale[:, None] * scale[None, :]
        d = np.diag(P)
        low = d < self._floor
        if low.any():
            P = P + np.diag(np.where(low, self._floor - d, 0.0))
        self.P = P

    # ------------------------------------------------------------------ answers
    def _answer(self, t_s: float, status: str, nis: float) -> OnlineEstimate:
        if self.x is None:
            x = self.prior_mean.copy()
            P = np.diag(self._prior_var)
        else:
            x, P = self.x, self.P
        cov = (float(P[C_N, C_N]), float(P[C_N, C_E]), float(P[C_E, C_E]))
        std = tuple(float(math.sqrt(max(p, 0.0))) for p in np.diag(P))
        estimate = OnlineEstimate(
            t_s=float(t_s) if math.isfinite(t_s) else math.nan, state=tuple(float(v) for v in x), std=std,
            current_cov=cov, converged=False, status=status, nis=nis, nis_mean=self._nis_mean,
            updates=self.updates, rejections=self.rejections, resets=self.resets, changes=self.changes)
        converged = self.x is not None and estimate.current_std_max_m_s < self.config.converged_current_std_m_s
        return replace(estimate, converged=bool(converged))

    # ------------------------------------------------------------------ batch
    def run(self, t_s: np.ndarray, nu: np.ndarray, psi: np.ndarray, controls: np.ndarray,
            reference: np.ndarray | None = None) -> list[OnlineEstimate]:
        """step() over a series: t_s (T,) s, nu (T, 3) u, v, r, psi (T,), controls (T, C) (a Recording's arrays),
        reference (4,) | None the held reference of the whole series (step)."""
        t_s = np.asarray(t_s, dtype=float)
        nu = np.asarray(nu, dtype=float)
        out = []
        for k in range(len(t_s)):
            out.append(self.step(float(t_s[k]), float(nu[k, 0]), float(nu[k, 1]), float(nu[k, 2]), float(psi[k]),
                                 controls[k], reference))
        return out

    def run_recording(self, recording: Recording) -> list[OnlineEstimate]:
        """run() over a Recording with its held reference (data.recording.held_reference: a rudder_only boat's
        approach, the one its grey box's rollouts in replay hold; None for the other layouts): one estimate per
        sample."""
        return self.run(recording.t_s, recording.nu, recording.psi, recording.controls, held_reference(recording))


def _term(terms: Mapping[str, Sequence[float]], name: str) -> float:
    values = terms.get(name)
    return float(values[0]) if values else 0.0


def estimate_recording(recording: Recording, vessel: Vessel, config: OnlineConfig | None = None,
                       terms: Mapping[str, Sequence[float]] | None = None) -> list[OnlineEstimate]:
    """The estimator over a Recording (data/recording.py): one estimate per sample (OnlineEstimator.run_recording),
    causal (sample k's estimate uses samples 0..k only) but for a rudder_only recording's held reference: the
    manoeuvre's approach, its straight running before the first turn, held from its start as replay's rollouts
    hold it."""
    return OnlineEstimator(vessel, config, terms).run_recording(recording)

"""Accelerations from measured motions: an extended Kalman filter and Rauch-Tung-Striebel smoother (seed 001 sec. 3.2).

Inverse dynamics needs nu_dot, which no sensor here measures (the IMU's specific force carries gravity, wave
motion and mounting errors). Finite differences of noisy velocities amplify the noise by sqrt(2)/dt; seed 001
estimates the accelerations with an extended Kalman filter instead. This module does that, followed by the RTS
smoother (Rauch, Tung & Striebel 1965; Saerkkae 2013, "Bayesian Filtering and Smoothing", eq. 8.3 and
Algorithm 9.3) so every estimate uses the whole record.

State (marine convention, SI):      x = [x_n, y_e, psi, u, v, r, u_dot, v_dot, r_dot]   (9,)
Kinematic constant-acceleration model, white jerk w (Fossen 2021 eq. 2.40 for the position rates):
    [x_n, y_e]' = R(psi) [u, v],  psi' = r,  [u, v, r]' = [u_dot, v_dot, r_dot],  [u_dot, v_dot, r_dot]' = w
Discretised over a step h with the second-order Taylor term (the acceleration enters the position exactly to
h^2/2); the Jacobian F = df/dx is written out by hand (_jacobian_one). Process noise of the white jerk
(spectral density q per axis, Bar-Shalom et al. 2001 eq. 6.2.3-9):
    Q_axis = q [[h^5/20, h^4/8, h^3/6], [h^4/8, h^3/3, h^2/2], [h^3/6, h^2/2, h]]  on (velocity integral, velocity,
    acceleration) -- here used on (velocity, acceleration) as the lower 2x2 block, plus a small q_pose on x, y, psi
    for the model error of the position kinematics.
Measurement: z = [x_n, y_e, psi, u, v, r] (GNSS, compass, INS/DVL, gyro), H a selection; any NaN component of
z (GNSS drop-out) is left out of that update (NaN-tolerant). A record without velocity or gyro (a GNSS receiver and
a compass only, e.g. the Dalian USV of replay/convert/dalian.py) is smoothed from positions and heading alone: the
kinematics [x_n, y_e]' = R(psi) [u, v] make u, v observable from the track and psi' = r makes r observable from the
heading, so all three velocities come out of the smoother (over ground: a current is not removed).

Measurement noise: given, or estimated from the data by the second difference of each signal
(var(d2 z) = 6 sigma^2 for white noise on a signal smooth at the sample rate). Jerk spectral densities: given,
or tuned by the innovation log-likelihood over a grid of multipliers of a data-derived scale.

The filter and smoother loops run compiled (numba: _forward_compiled, _backward_compiled, ~20x the numpy loops
_forward, _backward, which stay as the reference test_smoother.py holds them to within 1e-9).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from usv_predictor.data.recording import Recording
from usv_predictor.errors import DatasetError
from usv_predictor.physics.kernel import CACHED

STATE_NAMES = ("x_n", "y_e", "psi", "u", "v", "r", "u_dot", "v_dot", "r_dot")
MEASURED_NAMES = ("x_n", "y_e", "psi", "u", "v", "r")
NOISE_FLOOR = np.array([1e-3, 1e-3, 1e-4, 1e-4, 1e-4, 1e-5])  # m, m, rad, m/s, m/s, rad/s: a quantisation floor
JERK_GRID = (0.01, 0.1, 1.0, 10.0, 100.0)  # multipliers of the data-derived jerk scale tried by tune()


@dataclass(frozen=True)
class SmootherConfig:
    """Noise model of the EKF/RTS smoother; None = estimate from the data."""

    measurement_std: tuple[float, ...] | None = None  # std of x_n, y_e (m), psi (rad), u, v (m/s), r (rad/s)
    jerk_psd: tuple[float, float, float] | None = None  # q of u, v (m^2/s^5) and r (rad^2/s^5)
    pose_psd: tuple[float, float, float] = (1e-4, 1e-4, 1e-8)  # model error of x_n, y_e (m^2/s), psi (rad^2/s)


@dataclass(frozen=True)
class Smoothed:
    """Smoothed states on the recording's grid with their standard deviations."""

    t_s: np.ndarray  # (T,)
    state: np.ndarray  # (T, 9) STATE_NAMES
    std: np.ndarray  # (T, 9)
    log_likelihood: float  # innovation log-likelihood of the forward pass
    config: SmootherConfig  # the noise model used (estimated values filled in)

    @property
    def nu(self) -> np.ndarray:
        return self.state[:, 3:6]  # (T, 3)

    @property
    def nu_dot(self) -> np.ndarray:
        return self.state[:, 6:9]  # (T, 3)

    @property
    def nu_dot_std(self) -> np.ndarray:
        return self.std[:, 6:9]


def measurements(recording: Recording) -> np.ndarray:
    """(T, 6) [x_n, y_e, psi, u, v, r] of a Recording (NaN where GNSS had no fix)."""
    return np.column_stack([recording.position, recording.psi, recording.nu])


def estimate_measurement_std(z: np.ndarray) -> np.ndarray:
    """(6,) white-noise std per column from second differences: robust (median) version of var(d2z) = 6 sigma^2.

    The differences are taken over the finite samples of each column in order (a sparse column, e.g. GNSS fixes at
    a third of the grid's rate, is judged at its own rate; a column's drop-outs are skipped, not differenced across).
    """
    out = np.empty(z.shape[1])
    for k in range(z.shape[1]):
        col = z[:, k][np.isfinite(z[:, k])]
        d2 = col[2:] - 2.0 * col[1:-1] + col[:-2]
        if len(d2) < 10:
            out[k] = NOISE_FLOOR[k] * 100.0  # too few samples to tell: weak but finite
            continue
        mad = np.median(np.abs(d2 - np.median(d2))) * 1.4826
        out[k] = max(mad / math.sqrt(6.0), NOISE_FLOOR[k])
    return out


def rough_velocities(z: np.ndarray, dt: float) -> np.ndarray:
    """(T, 3) u, v, r: the measured columns, or where a column has no finite sample at all, a rough estimate from the
    track and heading (positions and psi interpolated over their gaps, differenced over +-1 s, rotated into the body
    by psi: Fossen 2021 eq. 2.40 inverted). Used for starting values and the jerk scale, never as measurements."""
    nu = z[:, 3:6].copy()
    missing = [k for k in range(3) if not np.isfinite(nu[:, k]).any()]
    if not missing:
        return nu
    t = np.arange(len(z)) * dt
    filled = []
    for k in range(3):
        finite = np.isfinite(z[:, k])
        filled.append(np.interp(t, t[finite], z[finite, k]) if finite.sum() >= 2 else np.zeros(len(z)))
    half = max(1, int(round(1.0 / dt)))
    idx = np.arange(len(z))
    hi, lo = np.minimum(idx + half, len(z) - 1), np.maximum(idx - half, 0)
    span = np.maximum(t[hi] - t[lo], dt)
    vn, ve, rate = ((filled[k][hi] - filled[k][lo]) / span for k in range(3))
    c, s = np.cos(filled[2]), np.sin(filled[2])
    rough = (vn * c + ve * s, -vn * s + ve * c, rate)
    for k in missing:
        nu[:, k] = rough[k]
    return nu


def jerk_scale(z: np.ndarray, dt: float) -> np.ndarray:
    """(3,) data-derived jerk spectral density scale of u, v, r: (rms of the acceleration)^2 / (10 s)."""
    window = max(1, int(round(2.0 / dt)))  # 2 s moving average, then centred difference: a rough acceleration
    nu = rough_velocities(z, dt)
    out = np.empty(3)
    for k in range(3):
        col = nu[:, k]
        if len(col) < 2 * window + 3:
            out[k] = 1e-6
            continue
        smooth = np.convolve(col, np.ones(window) / window, mode="valid")
        acc = np.gradient(smooth, dt)
        out[k] = max(float(np.mean(acc**2)) / 10.0, 1e-12)
    return out


def _transition(x: np.ndarray, h: float) -> np.ndarray:
    """x_{k+1} for state columns x (9, n): constant acceleration over h, second-order position update."""
    psi, u, v, r, au, av, ar = x[2], x[3], x[4], x[5], x[6], x[7], x[8]
    c, s = np.cos(psi), np.sin(psi)
    vn, ve = u * c - v * s, u * s + v * c
    # d/dt of R(psi)[u, v] = R(psi)[u_dot - r v, v_dot + r u]
    bu, bv = au - r * v, av + r * u
    an, ae = bu * c - bv * s, bu * s + bv * c
    out = np.empty_like(x)
    out[0] = x[0] + h * vn + 0.5 * h * h * an
    out[1] = x[1] + h * ve + 0.5 * h * h * ae
    out[2] = psi + h * r + 0.5 * h * h * ar
    out[3] = u + h * au
    out[4] = v + h * av
    out[5] = r + h * ar
    out[6:9] = x[6:9]
    return out


def _jacobian(x: np.ndarray, h: float) -> np.ndarray:
    """(9, 9) dF/dx of _transition at the state x (9,), by hand (its derivatives are a few products; central
    differences would carry ~1e-10 of rounding per element, which the filter carries into the accelerations at ~1e-7
    of their scale)."""
    return _jacobian_one(np.asarray(x, dtype=float), h)


def process_noise(h: float, jerk_psd: np.ndarray, pose_psd: np.ndarray) -> np.ndarray:
    """(9, 9) Q for one step of length h."""
    q = np.zeros((9, 9))
    for k in range(3):
        q[k, k] = pose_psd[k] * h
        i, j = 3 + k, 6 + k
        q[i, i] += jerk_psd[k] * h**3 / 3.0
        q[i, j] = q[j, i] = jerk_psd[k] * h**2 / 2.0
        q[j, j] = jerk_psd[k] * h
    return q


def _initial(z: np.ndarray, std: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """First state from the first finite measurements, with a wide covariance; a velocity that is never measured
    starts at its rough value from the track (rough_velocities) with a (1 m/s)^2, (0.3 rad/s)^2 variance."""
    x0 = np.zeros(9)
    p0 = np.zeros(9)
    rough = rough_velocities(z, dt)
    for k in range(6):
        finite = np.flatnonzero(np.isfinite(z[:, k]))
        if len(finite):
            x0[k], p0[k] = z[finite[0], k], (10.0 * std[k]) ** 2
        elif k >= 3:
            x0[k], p0[k] = rough[0, k - 3], (1.0 if k < 5 else 0.1)
        else:
            x0[k], p0[k] = 0.0, 1e6
    p0[6:9] = [1.0, 1.0, 0.1]  # accelerations unknown: (1 m/s^2)^2, (0.3 rad/s^2)^2
    return x0, np.diag(p0)


def _forward(z: np.ndarray, dt: float, std: np.ndarray, jerk: np.ndarray, pose: np.ndarray):
    """EKF over the record: filtered/predicted means and covariances, Jacobians, log-likelihood."""
    n = len(z)
    x, p = _initial(z, std, dt)
    q = process_noise(dt, jerk, pose)
    r_full = np.diag(std**2)
    xf, pf = np.empty((n, 9)), np.empty((n, 9, 9))
    xp, pp = np.empty((n, 9)), np.empty((n, 9, 9))
    jac = np.empty((n, 9, 9))
    loglik = 0.0
    for k in range(n):
        if k > 0:
            f = _jacobian(xf[k - 1], dt)
            jac[k - 1] = f
            x = _transition(xf[k - 1][:, None], dt)[:, 0]
            p = f @ pf[k - 1] @ f.T + q
        xp[k], pp[k] = x, p
        seen = np.flatnonzero(np.isfinite(z[k]))
        if len(seen):
            innov = z[k, seen] - x[seen]
            s = p[np.ix_(seen, seen)] + r_full[np.ix_(seen, seen)]
            gain = np.linalg.solve(s, p[seen, :]).T  # (9, m) = P H^T S^-1 (S symmetric)
            x = x + gain @ innov
            ikh = np.eye(9)
            ikh[:, seen] -= gain
            # Joseph form keeps P symmetric positive definite over thousands of steps
            p = ikh @ p @ ikh.T + gain @ r_full[np.ix_(seen, seen)] @ gain.T
            sign, logdet = np.linalg.slogdet(s)
            loglik -= 0.5 * (logdet + innov @ np.linalg.solve(s, innov) + len(seen) * math.log(2.0 * math.pi))
        xf[k], pf[k] = x, p
    return xf, pf, xp, pp, jac, loglik


def _backward(xf: np.ndarray, pf: np.ndarray, xp: np.ndarray, pp: np.ndarray, jac: np.ndarray):
    """RTS smoother: G_k = P_k F_k^T P_{k+1|k}^-1; x_k^s = x_k + G_k (x_{k+1}^s - x_{k+1|k})."""
    n = len(xf)
    xs, ps = xf.copy(), pf.copy()
    for k in range(n - 2, -1, -1):
        g = np.linalg.solve(pp[k + 1], (pf[k] @ jac[k].T).T).T
        xs[k] = xf[k] + g @ (xs[k + 1] - xp[k + 1])
        ps[k] = pf[k] + g @ (ps[k + 1] - pp[k + 1]) @ g.T
    return xs, ps


# ---- the compiled loops ---------------------------------------------------------------------------------------------
# The EKF and RTS loops run compiled (numba): per step they are a few 9x9 products and one small solve, which numpy
# spends in call overhead (~50 us a step). Each entry takes arrays and scalars only and writes its results into arrays
# the caller made, returning a float or None: boxing an array for Python runs numba's `_numba_unpickle` (Python code)
# after the machine code, where a pending Ctrl-C is raised and surfaces as a SystemError; a float or None is boxed
# without Python code, so an interrupt lands in the caller as the KeyboardInterrupt it is.


@njit(cache=CACHED)
def _mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b by loops (numba's @ needs scipy's BLAS, which this package does not install)."""
    n, k, m = a.shape[0], a.shape[1], b.shape[1]
    out = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            total = 0.0
            for t in range(k):
                total += a[i, t] * b[t, j]
            out[i, j] = total
    return out


@njit(cache=CACHED)
def _mm_t(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b.T by loops, b read in place (a transposed view would be compiled as another layout: compile time)."""
    n, k, m = a.shape[0], a.shape[1], b.shape[0]
    out = np.zeros((n, m))
    for i in range(n):
        for j in range(m):
            total = 0.0
            for t in range(k):
                total += a[i, t] * b[j, t]
            out[i, j] = total
    return out


@njit(cache=CACHED)
def _solve(a: np.ndarray, b: np.ndarray) -> tuple:
    """(a^-1 b (n, m), log|det a|) by Gaussian elimination with partial pivoting (LAPACK's gesv, by loops)."""
    n, m = a.shape[0], b.shape[1]
    lu, x = a.copy(), b.copy()
    logdet = 0.0
    for c in range(n):
        pivot = c
        for i in range(c + 1, n):
            if abs(lu[i, c]) > abs(lu[pivot, c]):
                pivot = i
        if pivot != c:
            for j in range(n):
                lu[c, j], lu[pivot, j] = lu[pivot, j], lu[c, j]
            for j in range(m):
                x[c, j], x[pivot, j] = x[pivot, j], x[c, j]
        logdet += math.log(abs(lu[c, c]))
        for i in range(c + 1, n):
            factor = lu[i, c] / lu[c, c]
            for j in range(c, n):
                lu[i, j] -= factor * lu[c, j]
            for j in range(m):
                x[i, j] -= factor * x[c, j]
    for c in range(n - 1, -1, -1):
        for j in range(m):
            total = x[c, j]
            for t in range(c + 1, n):
                total -= lu[c, t] * x[t, j]
            x[c, j] = total / lu[c, c]
    return x, logdet


@njit(cache=CACHED)
def _transition_one(x: np.ndarray, h: float) -> np.ndarray:
    """_transition of one state (9,): the same operations, on scalars."""
    psi, u, v, r, au, av, ar = x[2], x[3], x[4], x[5], x[6], x[7], x[8]
    c, s = math.cos(psi), math.sin(psi)
    vn, ve = u * c - v * s, u * s + v * c
    bu, bv = au - r * v, av + r * u
    an, ae = bu * c - bv * s, bu * s + bv * c
    out = x.copy()
    out[0] = x[0] + h * vn + 0.5 * h * h * an
    out[1] = x[1] + h * ve + 0.5 * h * h * ae
    out[2] = psi + h * r + 0.5 * h * h * ar
    out[3] = u + h * au
    out[4] = v + h * av
    out[5] = r + h * ar
    return out


@njit(cache=CACHED)
def _jacobian_one(x: np.ndarray, h: float) -> np.ndarray:
    """(9, 9) dF/dx of _transition at x (9,): d/dpsi of R(psi) w is R(psi + pi/2) w, d/d(u, v, r) of the
    second-order term enter through b = [u_dot - r v, v_dot + r u]."""
    psi, u, v, r, au, av = x[2], x[3], x[4], x[5], x[6], x[7]
    c, s = math.cos(psi), math.sin(psi)
    vn, ve = u * c - v * s, u * s + v * c
    bu, bv = au - r * v, av + r * u
    an, ae = bu * c - bv * s, bu * s + bv * c
    hh = 0.5 * h * h
    f = np.eye(9)
    f[0, 2] = -h * ve - hh * ae
    f[0, 3] = h * c - hh * r * s
    f[0, 4] = -h * s - hh * r * c
    f[0, 5] = -hh * (v * c + u * s)
    f[0, 6] = hh * c
    f[0, 7] = -hh * s
    f[1, 2] = h * vn + hh * an
    f[1, 3] = h * s + hh * r * c
    f[1, 4] = h * c - hh * r * s
    f[1, 5] = hh * (u * c - v * s)
    f[1, 6] = hh * s
    f[1, 7] = hh * c
    f[2, 5] = h
    f[2, 8] = hh
    f[3, 6] = h
    f[4, 7] = h
    f[5, 8] = h
    return f


@njit(cache=CACHED)
def _forward_compiled(z: np.ndarray, dt: float, x0: np.ndarray, p0: np.ndarray, q: np.ndarray, r_full: np.ndarray,
                      means: np.ndarray, covs: np.ndarray) -> float:
    """_forward's EKF, step by step, from the initial state and Q made outside; fills means (2, n, 9) = [filtered,
    predicted] and covs (3, n, 9, 9) = [filtered, predicted, Jacobian F_k] and returns the innovation
    log-likelihood. Every array here is C-contiguous (one compiled layout each)."""
    xf, xp = means[0], means[1]
    pf, pp, jac = covs[0], covs[1], covs[2]
    n = z.shape[0]
    loglik = 0.0
    x, p = x0.copy(), p0.copy()
    for k in range(n):
        if k > 0:
            f = _jacobian_one(xf[k - 1], dt)
            jac[k - 1] = f
            x = _transition_one(xf[k - 1], dt)
            p = _mm_t(_mm(f, pf[k - 1]), f) + q
        xp[k], pp[k] = x, p
        seen = np.flatnonzero(np.isfinite(z[k]))
        m = len(seen)
        if m:
            innov = np.empty(m)
            s = np.empty((m, m))
            r_seen = np.empty((m, m))
            rhs = np.empty((m, 10))  # [P H^T rows | innovation]: one elimination for the gain and S^-1 innov
            for a in range(m):
                innov[a] = z[k, seen[a]] - x[seen[a]]
                rhs[a, :9] = p[seen[a]]
                rhs[a, 9] = innov[a]
                for b in range(m):
                    r_seen[a, b] = r_full[seen[a], seen[b]]
                    s[a, b] = p[seen[a], seen[b]] + r_seen[a, b]
            solved, logdet = _solve(s, rhs)
            gain = solved[:, :9].T.copy()  # (9, m) = P H^T S^-1
            x = x + _mm(gain, innov.reshape(m, 1))[:, 0]
            ikh = np.eye(9)
            for a in range(m):
                ikh[:, seen[a]] -= gain[:, a]
            # Joseph form keeps P symmetric positive definite over thousands of steps
            p = _mm_t(_mm(ikh, p), ikh) + _mm_t(_mm(gain, r_seen), gain)
            loglik -= 0.5 * (logdet + np.sum(innov * solved[:, 9]) + m * math.log(2.0 * math.pi))
        xf[k], pf[k] = x, p
    return loglik


@njit(cache=CACHED)
def _backward_compiled(means: np.ndarray, covs: np.ndarray, xs: np.ndarray, ps: np.ndarray) -> None:
    """_backward's RTS pass over _forward_compiled's means (2, n, 9) and covs (3, n, 9, 9) into xs (n, 9) and
    ps (n, 9, 9)."""
    xf, xp = means[0], means[1]
    pf, pp, jac = covs[0], covs[1], covs[2]
    n = len(xf)
    xs[n - 1], ps[n - 1] = xf[n - 1], pf[n - 1]
    for k in range(n - 2, -1, -1):
        g = _solve(pp[k + 1], _mm_t(pf[k], jac[k]).T.copy())[0].T.copy()
        xs[k] = xf[k] + _mm(g, (xs[k + 1] - xp[k + 1]).reshape(9, 1))[:, 0]
        ps[k] = pf[k] + _mm_t(_mm(g, ps[k + 1] - pp[k + 1]), g)


def _smooth_compiled(z: np.ndarray, dt: float, std: np.ndarray, jerk: np.ndarray, pose: np.ndarray):
    """(xs, ps, loglik) of the compiled loops, equal to _forward + _backward to rounding (test_smoother.py)."""
    n = len(z)
    x0, p0 = _initial(z, std, dt)
    means, covs = np.zeros((2, n, 9)), np.zeros((3, n, 9, 9))  # the last Jacobian is never set: zeros, not garbage
    loglik = _forward_compiled(np.ascontiguousarray(z), float(dt), x0, p0, process_noise(dt, jerk, pose),
                               np.diag(std**2), means, covs)
    xs, ps = np.empty((n, 9)), np.empty((n, 9, 9))
    _backward_compiled(means, covs, xs, ps)
    return xs, ps, loglik


def smooth_measurements(z: np.ndarray, dt: float, config: SmootherConfig = SmootherConfig(), *,
                        compiled: bool = True) -> Smoothed:
    """EKF + RTS smoother on (T, 6) measurements [x_n, y_e, psi (continuous), u, v, r] at step dt. compiled: the
    loops of _forward_compiled / _backward_compiled, else the numpy ones (_forward / _backward: the reference
    test_smoother.py holds them to)."""
    z = np.asarray(z, dtype=float)
    if z.ndim != 2 or z.shape[1] != 6:
        raise DatasetError(f"smoother needs (T, 6) measurements {MEASURED_NAMES}, got shape {z.shape}")
    if len(z) < 10:
        raise DatasetError(f"smoother needs at least 10 samples, got {len(z)}")
    missing = [MEASURED_NAMES[k] for k in range(2, 6) if not np.isfinite(z[:, k]).any()]
    track = bool(np.isfinite(z[:, 0:2]).all(axis=1).sum() >= 10)
    if "psi" in missing or (missing and not track):
        raise DatasetError(f"smoother: no finite samples of {missing} (the heading is required, and the velocities "
                           "unless GNSS positions are measured: then the track gives them)")
    if not dt > 0.0:
        raise DatasetError(f"smoother step dt={dt} s must be > 0")
    std = np.asarray(config.measurement_std, dtype=float) if config.measurement_std else estimate_measurement_std(z)
    jerk = np.asarray(config.jerk_psd, dtype=float) if config.jerk_psd else jerk_scale(z, dt)
    pose = np.asarray(config.pose_psd, dtype=float)
    if compiled:
        xs, ps, loglik = _smooth_compiled(z, dt, std, jerk, pose)
    else:
        xf, pf, xp, pp, jac, loglik = _forward(z, dt, std, jerk, pose)
        xs, ps = _backward(xf, pf, xp, pp, jac)
    used = replace(config, measurement_std=tuple(float(s) for s in std), jerk_psd=tuple(float(q) for q in jerk))
    std_states = np.sqrt(np.clip(np.diagonal(ps, axis1=1, axis2=2), 0.0, None))
    return Smoothed(np.arange(len(z)) * dt, xs, std_states, float(loglik), used)


def tune(z: np.ndarray, dt: float, config: SmootherConfig = SmootherConfig(),
         grid: tuple[float, ...] = JERK_GRID) -> Smoothed:
    """Smooth with the jerk scale multiplier of `grid` that maximises the innovation log-likelihood.

    A too-small jerk density lags the accelerations, a too-large one passes noise: the likelihood of the
    one-step predictions balances the two without ground truth.
    """
    z = np.asarray(z, dtype=float)
    std = config.measurement_std or tuple(float(s) for s in estimate_measurement_std(z))
    jerk = np.asarray(config.jerk_psd, dtype=float) if config.jerk_psd else jerk_scale(z, dt)
    best: Smoothed | None = None
    # coordinate-wise: the three axes interact only weakly through the kinematics
    for axis in range(3):
        base = jerk.copy()
        for factor in grid:
            trial_jerk = base.copy()
            trial_jerk[axis] *= factor
            if best is not None and tuple(trial_jerk) == tuple(jerk):
                continue  # the best so far again (factor 1 of a later axis): the same likelihood, never greater
            trial = smooth_measurements(z, dt, replace(config, measurement_std=std,
                                                       jerk_psd=tuple(float(q) for q in trial_jerk)))
            if best is None or trial.log_likelihood > best.log_likelihood:
                best, jerk = trial, trial_jerk
    assert best is not None  # grid is non-empty
    return best


def smooth_recording(recording: Recording, config: SmootherConfig = SmootherConfig(), *,
                     tune_noise: bool = True) -> Smoothed:
    """Smoothed states and accelerations of a Recording (jerk density tuned by likelihood unless given)."""
    z = measurements(recording)
    if tune_noise and config.jerk_psd is None:
        smoothed = tune(z, recording.dt, config)
    else:
        smoothed = smooth_measurements(z, recording.dt, config)
    return replace(smoothed, t_s=recording.t_s.copy())


def finite_difference_accelerations(recording: Recording) -> np.ndarray:
    """(T, 3) centred differences of the measured u, v, r: the baseline the smoother must beat."""
    return np.gradient(recording.nu, recording.dt, axis=0)

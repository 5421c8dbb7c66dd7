"""Output-error identification of the low-order model (models/nomoto.py) from recordings, with intervals.

Simulate and fit: rollouts of the model from the measured state every `stride_s`, each `horizon_s` long with the
recorded controls (the open-loop windows `replay evaluate` scores), and the coefficients that minimise the weighted
sum of squares of the predicted minus measured u, v, r, psi and position over every step of every window
(Ljung 1999 sec. 7.3, output error; multiple shooting from the measured states, so a window's error cannot grow from
another's). Each channel is weighted by 1 / sigma_c, sigma_c the RMS of its residual: fitted once with the nominal
scales of CHANNEL_SCALES, then again with the residual RMS of the first fit (maximum likelihood for Gaussian channels
of unknown variances). Minimiser: Levenberg-Marquardt with Marquardt's diagonal scaling (Nocedal & Wright 2006 sec.
10.3) on central-difference Jacobians, from the best of a few starts (an equation-error least-squares fit of
r_dot = a1 s + a2 + a3 r on the moving-average yaw rate, and fixed time constants). Time constants are fitted as
their logarithms (> 0), the second order's T2 as T1 * sigmoid(z) (0 < T2 < T1).

Intervals: the windows are cut into contiguous blocks by start time (at least half a window long: neighbouring windows
share samples, the residuals of one window are correlated) and the fit is repeated leaving out one block at a time;
the delete-one-block jackknife variance (Kuensch 1989) of each transformed coefficient gives its 95 % interval with
Student's t of G - 1 degrees of freedom, mapped back (asymmetric for the time constants). A turning-circle estimate
(steady_turn) gets its interval the same way, on log R.

Speed set point (models/nomoto.py): "command" (u_c = u_0 + u_p p) when the layout reports a propulsion level and the
data vary it (PROPULSION_SPREAD), else "reference" (the approach's speed: what a record without propulsion data
supports), said in the notes.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from usv_predictor.data.recording import Recording, held_reference
from usv_predictor.data.segments import VELOCITY_HEADING
from usv_predictor.errors import DatasetError, ModelError, NotIdentifiableError
from usv_predictor.models.nomoto import NomotoCoefficients, layout_weights, numpy_rollout

CHANNELS = ("u", "v", "r", "x_n", "y_e", "psi")  # the rollout's output columns the residuals compare
CHANNEL_SCALES = {"u": 0.05, "v": 0.05, "r": 0.01, "position": 1.0, "psi": 0.05}  # first-pass sigma (m/s, rad/s, m,
#                                                                                   rad)
PROPULSION_SPREAD = 0.1  # (-) the propulsion level's 5-95 % range / its median magnitude above which u_p is fitted
SMOOTHING_S = 2.0  # (s) moving average of r for the equation-error start
START_TIME_CONSTANTS_S = (2.0, 6.0, 20.0)  # (s) further starts of the yaw time constant
MAX_ITERATIONS = 80
JACKKNIFE_BLOCKS = (5, 12)  # fewest, most blocks of the interval
T_975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262, 10: 2.228,
         11: 2.201}  # Student's t, 97.5 % quantile by degrees of freedom (Abramowitz & Stegun 1964 table 26.10)


def sigmoid(z: float) -> float:
    """1 / (1 + exp(-z)) without overflow for any finite z."""
    if z >= 0.0:
        return 1.0 / (1.0 + math.exp(-z))
    e = math.exp(max(z, -700.0))
    return e / (1.0 + e)


def t_975(dof: int) -> float:
    return T_975.get(dof, 1.96 + 2.4 / max(dof, 1))  # beyond the table within 0.01 of it


@dataclass(frozen=True)
class NomotoFitOptions:
    """How the low-order model is fitted."""

    order: int = 1  # 1 or 2 (models/nomoto.py)
    horizon_s: float = 30.0  # (s) each fitted window's length (the longest open-loop horizon scored)
    stride_s: float = 2.5  # (s) between window starts
    speed_mode: str | None = None  # "reference" / "command"; None: from the layout and the data (module docstring)
    intervals: bool = True  # the jackknife intervals (fitting again per block)


@dataclass(frozen=True)
class Estimate:
    name: str
    estimate: float
    ci95: tuple[float, float]
    unit: str

    def to_json(self) -> dict[str, Any]:
        ci95 = [float(v) if math.isfinite(v) else None for v in self.ci95]  # None: no interval computed
        return {"name": self.name, "estimate": self.estimate, "ci95": ci95, "unit": self.unit}


@dataclass(frozen=True)
class Windows:
    """One recording's fit windows: starts (B,) sample indices, state (B, 4), controls (B, H, C), measured (B, H, 6)
    relative to each start's position, reference (B, 4) | None."""

    starts: np.ndarray
    state: np.ndarray
    controls: np.ndarray
    measured: np.ndarray
    reference: np.ndarray | None
    t_start_s: np.ndarray  # (B,) start times on one clock over all recordings (s), for the blocks


@dataclass(frozen=True)
class Parameterisation:
    """Transformed vector x <-> NomotoCoefficients for one order and speed mode."""

    order: int
    speed_mode: str
    proportional_offset: bool = False  # the offset is s_p p (a thrust imbalance), not s_0 (a rudder offset)

    @property
    def names(self) -> tuple[str, ...]:
        yaw = ("K", "log_T1") if self.order == 1 else ("K", "log_T1", "logit_T2_over_T1", "T3")
        speed = ("u_0", "u_p") if self.speed_mode == "command" else ()
        return (*yaw, "s_p" if self.proportional_offset else "s_0", "log_T_u", "k_r", "k_v", *speed)

    def coefficients(self, x: np.ndarray) -> NomotoCoefficients:
        v = dict(zip(self.names, (float(a) for a in x)))
        t1 = math.exp(min(v["log_T1"], 12.0))
        t2 = t3 = 0.0
        if self.order == 2:
            t2 = t1 * min(max(sigmoid(v["logit_T2_over_T1"]), 1e-4), 1.0 - 1e-4)
            t3 = v["T3"]
        return NomotoCoefficients(self.order, v["K"], t1, t2, t3, v.get("s_0", 0.0), math.exp(min(v["log_T_u"], 12.0)),
                                  v["k_r"], v["k_v"], self.speed_mode, v.get("u_0", 0.0), v.get("u_p", 0.0),
                                  v.get("s_p", 0.0))

    def vector(self, c: NomotoCoefficients) -> np.ndarray:
        values = {"K": c.K, "log_T1": math.log(c.T1), "s_0": c.s_0, "s_p": c.s_p, "log_T_u": math.log(c.T_u),
                  "k_r": c.k_r, "k_v": c.k_v, "u_0": c.u_0, "u_p": c.u_p, "T3": c.T3}
        if self.order == 2:
            ratio = min(max(c.T2 / c.T1, 1e-4), 1.0 - 1e-4) if c.T2 > 0.0 else 0.2
            values["logit_T2_over_T1"] = math.log(ratio / (1.0 - ratio))
        return np.array([values[n] for n in self.names])


@dataclass(frozen=True)
class NomotoFit:
    """The identified low-order model and how well the data determine it."""

    coefficients: NomotoCoefficients
    estimates: tuple[Estimate, ...]
    parameter_names: tuple[str, ...]
    x: np.ndarray  # the transformed coefficients
    jackknife: np.ndarray  # (G, p) the transformed coefficients of each delete-one-block fit
    channel_sigma: dict[str, float]  # the residual RMS of each channel (m/s, rad/s, m, rad)
    windows: int
    horizon_s: float
    notes: tuple[str, ...]
    steering_w: np.ndarray
    propulsion_w: np.ndarray
    dt: float

    def intervals(self) -> dict[str, tuple[float, float]]:
        return {e.name: e.ci95 for e in self.estimates}

    def predict(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
        """(1, B, H, 6): the fitted model's rollout (models/nomoto.numpy_rollout)."""
        return numpy_rollout(self.coefficients, self.steering_w, self.propulsion_w, self.dt,
                             np.asarray(state, float), np.asarray(controls, float),
                             None if reference is None else np.asarray(reference, float))

    def turning_circle(self, steering: float, u_c: float, propulsion: float = 0.0) -> dict[str, float]:
        """The steady turn of a held turn command `steering` at speed set point u_c (m/s) and propulsion level
        `propulsion` (NomotoCoefficients.steady_turn) with the jackknife 95 % interval of its radius (on log R; G - 1
        degrees of freedom)."""
        nominal = self.coefficients.steady_turn(steering, u_c, propulsion)
        form = Parameterisation(self.coefficients.order, self.coefficients.speed_mode, "s_p" in self.parameter_names)
        radii = np.array([form.coefficients(x).steady_turn(steering, u_c, propulsion)["radius_m"]
                          for x in self.jackknife])
        out = dict(nominal)
        if len(radii) >= 2 and np.all(np.isfinite(radii)) and np.all(radii > 0) and math.isfinite(nominal["radius_m"]):
            g = len(radii)
            logs = np.log(radii)
            se = math.sqrt((g - 1) / g * float(np.sum((logs - logs.mean()) ** 2)))
            half = min(t_975(g - 1) * se, 700.0)
            out["radius_ci95_m"] = (nominal["radius_m"] * math.exp(-half), nominal["radius_m"] * math.exp(half))
        else:
            out["radius_ci95_m"] = (math.nan, math.nan)
        return out

    def to_json(self) -> dict[str, Any]:
        return {"family": "nomoto", "order": self.coefficients.order, "speed_mode": self.coefficients.speed_mode,
                "coefficients": [e.to_json() for e in self.estimates], "channel_sigma": dict(self.channel_sigma),
                "windows": self.windows, "horizon_s": self.horizon_s, "jackknife_blocks": int(len(self.jackknife)),
                "notes": list(self.notes), "method": "output error over open-loop windows from the measured states, "
                                                    "Levenberg-Marquardt; 95 % intervals by delete-one-block jackknife"}


# ---------------------------------------------------------------------------------------------- data

def _start_states(rec: Recording) -> np.ndarray:
    """(T, 4) [u, v, r, psi] the windows start from: the EKF/RTS smoothed states (data/smoother.py). A start at a
    raw measured state biases the fit towards time constants that forget its noise (short T_u); where the smoother
    fails, the measured states."""
    from usv_predictor.data.smoother import smooth_recording

    try:
        smoothed = smooth_recording(rec)
    except DatasetError:
        return np.column_stack([rec.nu, rec.psi])
    return np.column_stack([smoothed.nu, rec.psi + np.angle(np.exp(1j * (smoothed.state[:, 2] - rec.psi)))])


def fit_windows(recordings: Sequence[Recording], dt: float, horizon_s: float, stride_s: float,
                smoothed_starts: bool = True) -> list[Windows]:
    """The open-loop windows of every recording (a recording shorter than a window: one window over it all), each
    from its smoothed state (_start_states; smoothed_starts False: the measured one); DatasetError when no recording
    has a finite start."""
    out, clock = [], 0.0
    for rec in recordings:
        if abs(rec.dt - dt) > 1e-9:
            raise DatasetError(f"recording {rec.name}: step {rec.dt:g} s, the fit's is {dt:g} s")
        series = np.column_stack([rec.nu, rec.position, rec.psi])  # (T, 6) [u, v, r, x_n, y_e, psi]
        begin = _start_states(rec) if smoothed_starts else series[:, list(VELOCITY_HEADING)]  # (T, 4)
        steps = min(int(round(horizon_s / dt)), len(rec) - 1)
        stride = max(1, int(round(stride_s / dt)))
        if steps < 2:
            continue
        starts = np.arange(0, len(rec) - steps, stride)
        starts = starts[np.all(np.isfinite(begin[starts]), axis=1) & np.all(np.isfinite(series[starts, 3:5]), axis=1)]
        if not len(starts):
            continue
        window = starts[:, None] + np.arange(steps)[None, :]  # (B, H)
        measured = series[window + 1].copy()  # (B, H, 6)
        measured[..., 3:5] -= series[starts][:, None, 3:5]
        reference = held_reference(rec)
        out.append(Windows(starts, begin[starts], rec.controls[window].astype(float), measured,
                           None if reference is None else np.repeat(reference[None, :], len(starts), axis=0),
                           clock + rec.t_s[starts] - rec.t_s[0]))
        clock += rec.duration_s + horizon_s  # the next recording's windows never share a block with these
    if not out:
        raise DatasetError("no window to fit the low-order model: every recording is shorter than 2 steps or has no "
                           "finite state and position at any start")
    return out


def proportional_offset(layout: Any) -> bool:
    """Whether the turn command's offset is a thrust imbalance (s_p p): its steering controls are propulsion controls
    too (a difference of thrusters), not a rudder."""
    return bool(layout.propulsion) and set(layout.steering) <= set(layout.propulsion)


def _speed_mode(recordings: Sequence[Recording], propulsion_w: np.ndarray, asked: str | None) -> tuple[str, str]:
    """(mode, note) of the speed set point (module docstring)."""
    if not np.any(propulsion_w):
        if asked == "command":
            raise NotIdentifiableError("the speed set point u_0 + u_p p needs a propulsion level, and this layout "
                                       "reports none: use the reference speed")
        return "reference", ("speed set point: the approach's speed (the layout reports no propulsion level: u_p "
                             "would be determined by straight runs at two logged engine settings)")
    level = np.concatenate([r.controls @ propulsion_w for r in recordings])
    level = level[np.isfinite(level)]
    spread = float(np.percentile(level, 95) - np.percentile(level, 5)) if len(level) else 0.0
    scale = max(abs(float(np.median(level))) if len(level) else 0.0, 1e-9)
    if asked is None:
        asked = "command" if spread > PROPULSION_SPREAD * scale else "reference"
        if asked == "reference":
            return asked, (f"speed set point: the start's speed (the propulsion level varies by {spread:.3g} over the "
                           f"data, {spread / scale:.0%} of its median: u_p would be determined by straight runs at "
                           "two settings)")
    return asked, f"speed set point: {asked}"


def _start_guess(recordings: Sequence[Recording], steering_w: np.ndarray, propulsion_w: np.ndarray,
                 form: Parameterisation) -> list[NomotoCoefficients]:
    """Starting points: the equation-error fit r_dot = a1 s + a2 + a3 r (K = -a1 / a3, T = -1 / a3, s_0 = a2 / a1) and
    the same K with the fixed START_TIME_CONSTANTS_S."""
    rows, target, vs, rs, us, ps = [], [], [], [], [], []
    for rec in recordings:
        n = max(1, int(round(SMOOTHING_S / rec.dt)))
        kernel = np.ones(n) / n
        r = np.convolve(np.nan_to_num(rec.nu[:, 2]), kernel, mode="same")
        s = rec.controls @ steering_w
        r_dot = np.gradient(r, rec.dt)
        keep = slice(n, len(r) - n) if len(r) > 2 * n + 2 else slice(None)
        rows.append(np.column_stack([s[keep], np.ones_like(r[keep]), r[keep]]))
        target.append(r_dot[keep])
        vs.append(rec.nu[keep, 1])
        rs.append(r[keep])
        us.append(rec.nu[keep, 0])
        ps.append((rec.controls @ propulsion_w)[keep])
    a, y = np.vstack(rows), np.concatenate(target)
    ok = np.all(np.isfinite(a), axis=1) & np.isfinite(y)
    theta = np.linalg.lstsq(a[ok], y[ok], rcond=None)[0] if ok.sum() > 3 else np.array([0.0, 0.0, -0.2])
    a1, a2, a3 = (float(t) for t in theta)
    t_ee = -1.0 / a3 if a3 < 0.0 else 6.0
    t_ee = min(max(t_ee, 0.5), 60.0)
    k_ee = a1 * t_ee
    s_0 = a2 / a1 if abs(a1) > 1e-12 else 0.0
    v, r, u, p = (np.concatenate(z) for z in (vs, rs, us, ps))
    p_typical = float(np.nanmedian(p)) if np.any(np.isfinite(p)) and abs(float(np.nanmedian(p))) > 1e-9 else 1.0
    good = np.isfinite(v) & np.isfinite(r)
    k_v = float(np.dot(v[good], r[good]) / max(np.dot(r[good], r[good]), 1e-12))
    u_0, u_p = float(np.nanmedian(u)), 0.0
    if form.speed_mode == "command":
        fine = np.isfinite(u) & np.isfinite(p)
        design = np.column_stack([np.ones(fine.sum()), p[fine]])
        u_0, u_p = (float(z) for z in np.linalg.lstsq(design, u[fine], rcond=None)[0])
    guesses = []
    for t1 in (t_ee, *START_TIME_CONSTANTS_S):
        t2 = 0.2 * t1 if form.order == 2 else 0.0
        guesses.append(NomotoCoefficients(form.order, k_ee, t1, t2, t2, 0.0 if form.proportional_offset else s_0,
                                          10.0, 0.0, k_v, form.speed_mode, u_0, u_p,
                                          s_0 / p_typical if form.proportional_offset else 0.0))
    return guesses


# ---------------------------------------------------------------------------------------------- fit

def _residuals(c: NomotoCoefficients, windows: Sequence[Windows], steering_w: np.ndarray, propulsion_w: np.ndarray,
               dt: float) -> np.ndarray:
    """(N, 6) predicted - measured of every window step, NaN where the measurement is missing."""
    parts = []
    for w in windows:
        pred = numpy_rollout(c, steering_w, propulsion_w, dt, w.state, w.controls, w.reference)[0]  # (B, H, 6)
        parts.append((pred - w.measured).reshape(-1, 6))
    return np.vstack(parts)


def _weighted(raw: np.ndarray, sigma: dict[str, float]) -> np.ndarray:
    scale = np.array([sigma["u"], sigma["v"], sigma["r"], sigma["position"], sigma["position"], sigma["psi"]])
    out = raw / scale
    return np.where(np.isfinite(raw), out, 0.0).ravel()  # a missing measurement weighs nothing


def levenberg_marquardt(fun: Callable[[np.ndarray], np.ndarray], x0: np.ndarray,
                        max_iterations: int = MAX_ITERATIONS) -> tuple[np.ndarray, float]:
    """(x, cost) minimising |fun(x)|^2 (module docstring); a step whose residuals are not finite is refused."""
    x = np.asarray(x0, float).copy()
    f = fun(x)
    cost = float(f @ f) if np.all(np.isfinite(f)) else math.inf
    if not math.isfinite(cost):
        return x, cost
    damping = 1e-3
    for _ in range(max_iterations):
        h = 1e-6 * np.maximum(1.0, np.abs(x))
        jac = np.empty((len(f), len(x)))
        for i in range(len(x)):
            e = np.zeros_like(x)
            e[i] = h[i]
            jac[:, i] = (fun(x + e) - fun(x - e)) / (2.0 * h[i])
        if not np.all(np.isfinite(jac)):
            jac = np.nan_to_num(jac, nan=0.0, posinf=0.0, neginf=0.0)
        gram, grad = jac.T @ jac, jac.T @ f
        diag = np.maximum(np.diag(gram), 1e-12)
        improved = False
        for _ in range(12):
            step = np.linalg.solve(gram + damping * np.diag(diag), -grad)
            trial = fun(x + step)
            trial_cost = float(trial @ trial) if np.all(np.isfinite(trial)) else math.inf
            if trial_cost < cost:
                relative = (cost - trial_cost) / max(cost, 1e-300)
                x, f, cost = x + step, trial, trial_cost
                damping = max(damping / 3.0, 1e-9)
                improved = True
                break
            damping *= 4.0
        if not improved or relative < 1e-10:
            break
    return x, cost


def _fit(form: Parameterisation, starts: Sequence[np.ndarray], windows: Sequence[Windows], steering_w: np.ndarray,
         propulsion_w: np.ndarray, dt: float, sigma: dict[str, float],
         max_iterations: int = MAX_ITERATIONS) -> tuple[np.ndarray, float]:
    def fun(x: np.ndarray) -> np.ndarray:
        try:
            c = form.coefficients(x)
        except ModelError:  # a trial outside the coefficients' domain: refused as an infinite cost
            return np.full(1, math.inf)
        return _weighted(_residuals(c, windows, steering_w, propulsion_w, dt), sigma)

    costs = [(float(np.sum(fun(x) ** 2)), i) for i, x in enumerate(starts)]
    best = min(costs)[1]
    return levenberg_marquardt(fun, starts[best], max_iterations)


def fit_nomoto(recordings: Sequence[Recording], options: NomotoFitOptions = NomotoFitOptions(),
               progress: Callable[[str], None] = lambda _: None) -> NomotoFit:
    """The low-order model of `recordings` (all of one actuator layout and step) by output error (module docstring);
    DatasetError without windows, NotIdentifiableError when the fit cannot leave its start (no turn in the data)."""
    if not recordings:
        raise DatasetError("no recordings to fit the low-order model to")
    dt = recordings[0].dt
    layout = recordings[0].actuator_layout
    steering_w, propulsion_w = layout_weights(layout)
    steering = np.concatenate([r.controls @ steering_w for r in recordings])
    if not np.nanmax(np.abs(steering - np.nanmedian(steering))) > 0.0:
        raise NotIdentifiableError("the turn command never changes in the data: K and T need a turn or a zig-zag")
    mode, mode_note = _speed_mode(recordings, propulsion_w, options.speed_mode)
    form = Parameterisation(options.order, mode, proportional_offset(layout))
    windows = fit_windows(recordings, dt, options.horizon_s, options.stride_s)
    starts = [form.vector(c) for c in _start_guess(recordings, steering_w, propulsion_w, form)]
    if options.order == 2:  # from the first-order fit: T3 = T2 is the first order exactly
        first = fit_nomoto(recordings, replace(options, order=1, intervals=False, speed_mode=mode))
        c1 = first.coefficients
        starts = [form.vector(replace(c1, order=2, T2=f * c1.T1, T3=f * c1.T1)) for f in (0.1, 0.3)]
    sigma = dict(CHANNEL_SCALES)
    x, _ = _fit(form, starts, windows, steering_w, propulsion_w, dt, sigma)
    raw = _residuals(form.coefficients(x), windows, steering_w, propulsion_w, dt)
    sigma = _channel_sigma(raw)
    x, cost = _fit(form, [x], windows, steering_w, propulsion_w, dt, sigma)
    raw = _residuals(form.coefficients(x), windows, steering_w, propulsion_w, dt)
    sigma = _channel_sigma(raw)
    progress(f"low-order model (Nomoto order {options.order}): {sum(len(w.starts) for w in windows)} windows of "
             f"{options.horizon_s:g} s, weighted cost {cost:.4g}")
    jack = _jackknife(form, x, windows, steering_w, propulsion_w, dt, sigma, options.horizon_s) \
        if options.intervals else np.empty((0, len(x)))
    estimates = _estimates(form, x, jack)
    notes = [mode_note, *_determination_notes(estimates if options.intervals else (), form, form.coefficients(x))]
    return NomotoFit(form.coefficients(x), estimates, form.names, x, jack, sigma,
                     int(sum(len(w.starts) for w in windows)), float(options.horizon_s), tuple(notes), steering_w,
                     propulsion_w, dt)


def _channel_sigma(raw: np.ndarray) -> dict[str, float]:
    def rms(values: np.ndarray, floor: float) -> float:
        values = values[np.isfinite(values)]
        return max(float(np.sqrt(np.mean(values ** 2))) if len(values) else floor, 1e-3 * floor)

    return {"u": rms(raw[:, 0], CHANNEL_SCALES["u"]), "v": rms(raw[:, 1], CHANNEL_SCALES["v"]),
            "r": rms(raw[:, 2], CHANNEL_SCALES["r"]), "position": rms(raw[:, 3:5].ravel(), CHANNEL_SCALES["position"]),
            "psi": rms(raw[:, 5], CHANNEL_SCALES["psi"])}


def _jackknife(form: Parameterisation, x: np.ndarray, windows: Sequence[Windows], steering_w: np.ndarray,
               propulsion_w: np.ndarray, dt: float, sigma: dict[str, float], horizon_s: float) -> np.ndarray:
    """(G, p) the fit without each block of window starts (module docstring), started at x."""
    times = np.concatenate([w.t_start_s for w in windows])
    span = float(times.max() - times.min()) + 1e-9
    lo, hi = JACKKNIFE_BLOCKS
    blocks = int(min(hi, max(lo, round(span / (0.5 * horizon_s)))))
    edges = np.linspace(times.min(), times.max() + 1e-9, blocks + 1)
    out = []
    for g in range(blocks):
        kept = []
        for w in windows:
            keep = ~((w.t_start_s >= edges[g]) & (w.t_start_s < edges[g + 1]))
            if keep.any():
                kept.append(Windows(w.starts[keep], w.state[keep], w.controls[keep], w.measured[keep],
                                    None if w.reference is None else w.reference[keep], w.t_start_s[keep]))
        if kept:
            out.append(_fit(form, [x], kept, steering_w, propulsion_w, dt, sigma, max_iterations=30)[0])
    return np.array(out)


UNITS = {"K": "1/s per turn-command unit", "T1": "s", "T2": "s", "T3": "s", "s_0": "turn-command unit",
         "s_p": "turn-command unit per propulsion unit", "T_u": "s",
         "k_r": "m/rad^2", "k_v": "m", "u_0": "m/s", "u_p": "m/s per propulsion unit"}


def _estimates(form: Parameterisation, x: np.ndarray, jack: np.ndarray) -> tuple[Estimate, ...]:
    """The physical coefficients with their 95 % intervals from the jackknife of the transformed ones."""
    c = form.coefficients(x)
    g = len(jack)
    half = np.full(len(x), math.nan)
    if g >= 2:
        half = t_975(g - 1) * np.sqrt((g - 1) / g * np.sum((jack - jack.mean(axis=0)) ** 2, axis=0))
    by_name = dict(zip(form.names, range(len(x))))

    def linear(name: str, value: float) -> tuple[float, float]:
        h = half[by_name[name]]
        return (value - h, value + h)

    def logged(name: str, value: float) -> tuple[float, float]:
        h = half[by_name[name]]
        h = min(h, 700.0)
        return (value * math.exp(-h), value * math.exp(h))

    out = [Estimate("K", c.K, linear("K", c.K), UNITS["K"]), Estimate("T1", c.T1, logged("log_T1", c.T1), "s")]
    if form.order == 2:
        z = x[by_name["logit_T2_over_T1"]]
        h = half[by_name["logit_T2_over_T1"]]
        ratio = [sigmoid(z + d) for d in (-h, h)] if math.isfinite(h) else [math.nan] * 2
        if at_bound(c):  # the time constants' intervals mean nothing there (_determination_notes says why)
            out[1] = Estimate("T1", c.T1, (math.nan, math.nan), "s")
            ratio = [math.nan] * 2
        out += [Estimate("T2", c.T2, (c.T1 * ratio[0], c.T1 * ratio[1]), "s"),
                Estimate("T3", c.T3, linear("T3", c.T3), "s")]
    offset = "s_p" if form.proportional_offset else "s_0"
    out += [Estimate(offset, getattr(c, offset), linear(offset, getattr(c, offset)), UNITS[offset]),
            Estimate("T_u", c.T_u, logged("log_T_u", c.T_u), "s"),
            Estimate("k_r", c.k_r, linear("k_r", c.k_r), UNITS["k_r"]),
            Estimate("k_v", c.k_v, linear("k_v", c.k_v), UNITS["k_v"])]
    if form.speed_mode == "command":
        out += [Estimate("u_0", c.u_0, linear("u_0", c.u_0), "m/s"), Estimate("u_p", c.u_p, linear("u_p", c.u_p),
                                                                               UNITS["u_p"])]
    return tuple(out)


WOULD_DETERMINE = {  # what trial would pin a coefficient whose interval spans zero or a decade
    "K": "a zig-zag or turns at two turn commands both ways",
    "T1": "a zig-zag with a faster command change (a larger or quicker rudder step)",
    "T2": "a zig-zag with steps faster than T1 (the second order needs them)",
    "T3": "a zig-zag with steps faster than T1 (the second order needs them)",
    "k_r": "a turning circle held to its steady speed",
    "T_u": "a speed change at a held command (an acceleration run)",
    "k_v": "a turning circle with GNSS (the drift of a steady turn)",
    "u_p": "straight runs at two propulsion settings",
}


def at_bound(c: NomotoCoefficients) -> bool:
    """A second order whose T2 / T1 reached the edge of (0, 1) the fit allows: the data support no second pole."""
    return c.order == 2 and not 2e-4 < c.T2 / c.T1 < 1.0 - 2e-4


def _determination_notes(estimates: Sequence[Estimate], form: Parameterisation,
                         coefficients: NomotoCoefficients) -> list[str]:
    notes = []
    if at_bound(coefficients):
        notes.append(f"the second order is not determined: T2 / T1 = {coefficients.T2 / coefficients.T1:.4g} is at "
                     "the edge of what the fit allows (the data show no second pole; order 1 is the model they "
                     "support; a zig-zag with steps faster than T1 would determine T2)")
    for e in estimates:
        lo, hi = e.ci95
        if not (math.isfinite(lo) and math.isfinite(hi)):
            if len(notes) == 0 or "second order" not in notes[0]:
                notes.append(f"{e.name}: no interval (too few blocks to leave out)")
            continue
        loose = (lo <= 0.0 <= hi and e.name not in ("s_0", "s_p", "T3")) or (lo > 0.0 and hi / lo > 10.0)
        if loose and e.name in WOULD_DETERMINE:
            notes.append(f"{e.name} = {e.estimate:.4g} {e.unit} is barely determined (95 % [{lo:.4g}, {hi:.4g}]): "
                         f"{WOULD_DETERMINE[e.name]} would determine it")
    return notes

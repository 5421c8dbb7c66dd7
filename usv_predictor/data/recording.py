"""A manoeuvre as aligned, resampled time series: the common input of datasets, models and evaluation.

Recording (marine convention, SI, uniform step dt):
    t_s (T,)           seconds since t0_ns
    nu (T, 3)          u, v (m/s, over ground, body FRD) from the velocity topic; r (rad/s) from the IMU gyro
    psi (T,)           heading (rad, clockwise from north), continuous (unwrapped) so it can be averaged
    controls (T, C)    the columns of the vessel's actuator layout (physics/actuators.py, `layout`), e.g.
                       rudder angle delta (rad, + to starboard) and engine speed (rpm) for rudder_propeller
    position (T, 2)    x_n, y_e (m) from GNSS in the local tangent plane of `datum` (NaN without GNSS)
    truth (T, 6) | None  ground truth x_n, y_e, psi, u, v, r: evaluation of simulated data only, never fitting

Resampling (seed 000 down-sampled 200 Hz to 2 Hz): signals faster than the step are averaged over the
window [t - dt/2, t + dt/2] (an anti-aliasing box filter, so noise drops by sqrt(samples)); slower ones
are interpolated linearly. The grid spans the time where every required signal covers whole windows.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from usv_predictor.errors import RecordingError
from usv_predictor.frames import LocalTangentPlane
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout, actuator_layout
from usv_predictor.records import NS_PER_S, Signal

NS = NS_PER_S  # the name tests import from here
MOTION_ROLES = ("imu", "velocity", "heading")  # the state [u, v, r, psi]; the controls' roles come from the layout


APPROACH_S = 5.0  # (s) the shortest approach of a manoeuvre: the straight running its engine setting holds


def approach_state(nu: np.ndarray, psi: np.ndarray, dt: float, straight: np.ndarray | None = None) -> np.ndarray:
    """(4,) [u, v, r, psi] of a manoeuvre's approach from its (T, 3) nu and (T,) psi at step dt (s): the medians (the
    heading as a circular mean, NaN samples left out) over its straight running before the first turn command (the
    leading run of `straight`, (T,) bool; straight_samples), at least the first APPROACH_S (a recording that starts in
    a turn: its first APPROACH_S). A rudder_only boat's engine speed is the one that holds this state's speed in
    straight running (models/greybox.py `reference`; identification's equivalent engine speed of the manoeuvre); the
    whole approach, not only its first seconds, averages out the first-order wave motion of the measured speed."""
    n = max(2, int(round(APPROACH_S / dt)))
    if straight is not None and len(straight):
        leading = int(np.argmin(straight)) if not np.all(straight) else len(straight)
        n = max(n, leading)
    rows = np.column_stack([nu[:n], psi[:n]])  # (n, 4)
    rows = rows[np.all(np.isfinite(rows), axis=1)]
    if not len(rows):
        return np.full(4, np.nan)
    heading = float(np.arctan2(np.sin(rows[:, 3]).mean(), np.cos(rows[:, 3]).mean()))
    return np.array([*np.median(rows[:, :3], axis=0), heading])


def held_reference(recording: "Recording", nu: np.ndarray | None = None, psi: np.ndarray | None = None
                   ) -> np.ndarray | None:
    """(4,) the approach state [u, v, r, psi] (approach_state) of a recording whose layout reports no propulsion
    (rudder_only): the straight running whose engine speed the boat holds all manoeuvre long, what its grey box's
    rollouts (models/greybox.py `reference`) and the online estimator's process model (fitting/online.py) hold the
    engine speed from. Of the recording's measured nu, psi, or of another series of the same samples (nu (T, 3),
    psi (T,): a reference track such as the ground truth). None for a layout with propulsion data, and when the
    approach has no finite sample."""
    layout = recording.actuator_layout
    if layout.propulsion:
        return None
    nu = recording.nu if nu is None else nu
    psi = recording.psi if psi is None else psi
    approach = approach_state(nu, psi, recording.dt, straight_samples(recording.controls, layout))
    return approach if np.all(np.isfinite(approach)) else None


def straight_samples(controls: np.ndarray, layout: ActuatorLayout) -> np.ndarray:
    """(T,) bool: the samples whose turn command is below the layout's straight_below (straight running)."""
    return np.abs(layout.steering_signal(controls)) < layout.straight_below


def required_roles(layout: ActuatorLayout = DEFAULT_LAYOUT) -> tuple[str, ...]:
    """The input roles a Recording (and the node's state) needs: the motion, then the layout's controls."""
    return MOTION_ROLES + layout.roles


REQUIRED_ROLES = required_roles(DEFAULT_LAYOUT)

# Plausible values of the decoded fields (SI, marine frames, after msg_adapters). Outside them the sample is
# corrupt or the configuration (units, sign) is wrong: the node refuses such a sample (live.check_values), the
# replay tool drops it with a warning (replay.recordings.clean_signal). The controls' ranges are their
# Control.plausible in the actuator layout.
PLAUSIBLE: dict[str, tuple[float, float]] = {
    "u": (-10.0, 30.0),  # m/s, surge over ground of a USV
    "v": (-15.0, 15.0),  # m/s
    "r": (-3.0, 3.0),  # rad/s (170 deg/s), ground-truth yaw rate
    "yaw_rate": (-3.0, 3.0),  # rad/s (170 deg/s), gyro
    "lat": (-89.9, 89.9),  # deg (the local tangent plane of the positions is singular at the poles)
    "lon": (-180.0, 180.0),  # deg
    "x_n": (-1.0e7, 1.0e7),  # m, ground-truth position in a local plane (a quarter of the Earth's circumference)
    "y_e": (-1.0e7, 1.0e7),  # m
}


def plausible_ranges(layout: ActuatorLayout = DEFAULT_LAYOUT) -> dict[str, tuple[float, float]]:
    """field -> plausible (low, high): PLAUSIBLE and the layout's controls (by their role's field name)."""
    return {**PLAUSIBLE, **{c.field: c.plausible for c in layout.controls}}


@dataclass(frozen=True)
class Recording:
    name: str
    source: str
    t0_ns: int
    dt: float
    t_s: np.ndarray
    nu: np.ndarray
    psi: np.ndarray
    controls: np.ndarray
    position: np.ndarray
    truth: np.ndarray | None = None
    datum: tuple[float, float] | None = None  # (lat, lon) deg of the position plane
    layout: str = DEFAULT_LAYOUT.name  # actuator layout: the names and units of the controls columns

    def __len__(self) -> int:
        return len(self.t_s)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) if len(self.t_s) else 0.0

    def state(self) -> np.ndarray:
        """(T, 4) [u, v, r, psi]: the state a model starts from and predicts."""
        return np.column_stack([self.nu, self.psi])

    @property
    def actuator_layout(self) -> ActuatorLayout:
        return actuator_layout(self.layout)


def recording_layout(recordings: Sequence[Recording]) -> ActuatorLayout:
    """The one actuator layout of these recordings (RecordingError when they mix layouts)."""
    layouts = sorted({rec.layout for rec in recordings})
    if len(layouts) > 1:
        raise RecordingError(f"recordings of different actuator layouts {layouts} cannot be used together")
    return actuator_layout(layouts[0]) if layouts else DEFAULT_LAYOUT


FROUDE_CONTROL_EXPONENTS = {"rad": 0.0, "rpm": 0.5}  # unit -> exponent e: a control is multiplied by scale**e
# (angles keep their value; a propeller's rate turns sqrt(lambda) times faster on the smaller hull). Other units
# (normalised, throttle, PWM commands: "-") are commands, kept as recorded: their thrust map is the model vessel's.


def froude_scaled(recording: Recording, scale: float) -> Recording:
    """The recording of a Froude-similar hull `scale` times SMALLER (scale = L_recorded / L_model; < 1: larger).

    Equal Froude number Fn = U / sqrt(g L) (ITTC 7.5-02-06-01, model-ship correlation of manoeuvres): lengths and
    positions / scale, times, the step and speeds / sqrt(scale), yaw rates and engine/propeller speeds
    (rpm) * sqrt(scale), angles (heading, rudder) unchanged, accelerations unchanged; forces would scale by
    scale^3 (times the density ratio), which no recorded topic carries. Normalised / PWM / throttle commands are
    kept (module constant FROUDE_CONTROL_EXPONENTS). The datum stays: positions are about it, in the scaled plane.
    """
    if not (math.isfinite(scale) and scale > 0.0):
        raise RecordingError(f"Froude scale {scale!r}: expected a finite number > 0 (L_recorded / L_model)")
    if scale == 1.0:
        return recording
    root = math.sqrt(scale)
    layout = recording.actuator_layout
    factors = np.array([scale ** FROUDE_CONTROL_EXPONENTS.get(c.unit, 0.0) for c in layout.controls])
    nu = recording.nu * np.array([1.0 / root, 1.0 / root, root])
    truth = None
    if recording.truth is not None:  # x_n, y_e, psi, u, v, r
        truth = recording.truth * np.array([1.0 / scale, 1.0 / scale, 1.0, 1.0 / root, 1.0 / root, root])
    return replace(recording, dt=recording.dt / root, t_s=recording.t_s / root, nu=nu,
                   controls=recording.controls * factors, position=recording.position / scale, truth=truth)


def window_resample(t_ns: np.ndarray, values: np.ndarray, grid_ns: np.ndarray, dt_ns: int) -> np.ndarray:
    """Box-filtered (N,) or (N, k) values at grid_ns: mean over [t - dt/2, t + dt/2], else interpolated.

    Where a window holds no sample (a signal slower than the step) the value is interpolated linearly.
    """
    values = np.asarray(values, dtype=float)
    flat = values.reshape(len(values), -1)
    half = dt_ns // 2
    lo = np.searchsorted(t_ns, grid_ns - half, side="left")
    hi = np.searchsorted(t_ns, grid_ns + half, side="right")  # closed window: symmetric about t
    counts = hi - lo
    sums = np.vstack([np.zeros((1, flat.shape[1])), np.cumsum(flat, axis=0)])
    out = np.empty((len(grid_ns), flat.shape[1]))
    has = counts > 0
    out[has] = (sums[hi[has]] - sums[lo[has]]) / counts[has, None]
    if not has.all():
        rel_t = (t_ns - t_ns[0]).astype(float)
        rel_g = (grid_ns[~has] - t_ns[0]).astype(float)
        for k in range(flat.shape[1]):
            out[~has, k] = np.interp(rel_g, rel_t, flat[:, k])
    return out.reshape((len(grid_ns),) + values.shape[1:])


def window_mean(t_ns: np.ndarray, values: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """(k,) mean of values[lo:hi] ((N, k), hi - lo >= 1 samples) computed as window_resample computes it: the
    difference of the prefix sums from the first sample, so that it equals window_resample(t_ns, values, [t], dt)[0]
    bit for bit when [lo, hi) are t's samples in [t - dt/2, t + dt/2] (the prefix sums of values[:hi] only: the
    samples after the window are never read). test_live.py proves the equality."""
    sums = np.cumsum(values[:hi], axis=0)  # sequential, as window_resample's cumsum over every sample
    upper = sums[hi - 1]
    return (upper - sums[lo - 1]) / (hi - lo) if lo > 0 else (upper - 0.0) / (hi - lo)


def largest_gap(t_ns: np.ndarray, start_ns: int, end_ns: int) -> tuple[float, int]:
    """(longest interval without a sample within [start, end] in s, where it starts in ns)."""
    inside = t_ns[(t_ns >= start_ns) & (t_ns <= end_ns)]
    edges = np.concatenate([[start_ns], inside, [end_ns]])
    gaps = np.diff(edges)
    k = int(np.argmax(gaps))
    return float(gaps[k]) / NS_PER_S, int(edges[k])


def recording_from_signals(signals: dict[str, Signal], dt: float, *, name: str, source: str = "",
                           max_gap_s: float | None = None, datum: tuple[float, float] | None = None,
                           layout: ActuatorLayout = DEFAULT_LAYOUT) -> Recording:
    """Align and resample role-keyed Signals (msg_adapters.ROLE_FIELDS) onto one grid of step dt.

    Raises RecordingError naming the missing role, the gap (role, time, length) or the too-short span.
    A gap longer than max_gap_s (default: the step dt) in any required signal is an error: the caller
    decides whether to cut the recording there (see split_at_gaps in the dataset stage).
    """
    roles = required_roles(layout)
    missing = [role for role in roles if role not in signals or len(signals[role]) == 0]
    if missing:
        raise RecordingError(f"{source or name}: no data for role(s) {missing}; need {list(roles)}")
    if not dt > 0.0:
        raise RecordingError(f"{source or name}: step dt={dt} s must be > 0")
    dt_ns = int(round(dt * NS_PER_S))
    for role in roles:
        t = signals[role].t_ns
        if np.any(np.diff(t) <= 0):
            k = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise RecordingError(f"{source or name}: {role} timestamps do not increase at "
                                 f"t={(t[k + 1] - t[0]) / NS_PER_S:.3f} s (sort or de-duplicate first)")
    # whole windows only: a window cut by the end of the data would bias the mean of a trend
    start = max(int(signals[r].t_ns[0]) for r in roles) + dt_ns // 2
    end = min(int(signals[r].t_ns[-1]) for r in roles) - dt_ns // 2
    steps = (end - start) // dt_ns
    if steps < 1:
        raise RecordingError(f"{source or name}: the signals overlap for {(end - start) / NS_PER_S:.2f} s, "
                             f"less than one step")
    grid = start + np.arange(steps + 1, dtype=np.int64) * dt_ns
    limit = dt if max_gap_s is None else max_gap_s
    for role in roles:
        gap, at = largest_gap(signals[role].t_ns, start, int(grid[-1]))
        if gap > limit + 1e-9:
            raise RecordingError(f"{source or name}: {role} has a {gap:.2f} s gap at "
                                 f"t={(at - start) / NS_PER_S:.2f} s, "
                                 f"longer than {limit:.2f} s")

    def resample(role: str, field: str) -> np.ndarray:
        s = signals[role]
        return window_resample(s.t_ns, s.column(field), grid, dt_ns)

    heading = signals["heading"]
    psi = window_resample(heading.t_ns, np.unwrap(heading.column("psi")), grid, dt_ns)
    nu = np.column_stack([resample("velocity", "u"), resample("velocity", "v"), resample("imu", "yaw_rate")])
    controls = np.column_stack([resample(c.role, c.field) for c in layout.controls])  # (T, C)
    position = np.full((len(grid), 2), np.nan)
    gnss = signals.get("gnss")
    if gnss is not None and len(gnss) >= 2:
        valid = np.isfinite(gnss.values[:, 0]) & np.isfinite(gnss.values[:, 1])
        if valid.sum() >= 2:
            lat, lon = gnss.values[valid, 0], gnss.values[valid, 1]
            datum = datum or (float(lat[0]), float(lon[0]))
            x_n, y_e = LocalTangentPlane(*datum).to_ned(lat, lon)
            t_valid = gnss.t_ns[valid]
            position = np.column_stack([window_resample(t_valid, x_n, grid, dt_ns),
                                        window_resample(t_valid, y_e, grid, dt_ns)])
            outside = (grid < t_valid[0]) | (grid > t_valid[-1])
            position[outside] = np.nan
    truth = None
    odom = signals.get("odometry")
    if odom is not None and len(odom) >= 2:
        vals = odom.values.copy()
        vals[:, 2] = np.unwrap(vals[:, 2])
        # point samples (not window means) so the truth is the state at the grid time
        rel = (odom.t_ns - odom.t_ns[0]).astype(float)
        g = (grid - odom.t_ns[0]).astype(float)
        truth = np.column_stack([np.interp(g, rel, vals[:, k]) for k in range(6)])
    return Recording(name=name, source=source, t0_ns=int(grid[0]), dt=dt, t_s=(grid - grid[0]) / NS_PER_S,
                     nu=nu, psi=psi, controls=controls, position=position, truth=truth, datum=datum,
                     layout=layout.name)

"""Manoeuvring metrics of naval architecture on tracks in the marine convention (pure numpy).

Inputs are time series: t (s, float, strictly increasing), x_n (m, north), y_e (m, east),
psi (rad, heading clockwise from north, wrapped or not) and, for zigzags, the rudder angle
(rad, positive turns the vessel to starboard). Results are frozen dataclasses of plain floats and
tuples (JSON-ready via dataclasses.asdict) whose field names carry their units.

Heading change points (seed 000, text of eq. 27 and Fig. 7): (X_A, Y_A) is where the heading
has "increased" by A degrees from the initial heading. We use |unwrap(psi) - psi_0| so the same
code serves starboard (psi increasing) and port (psi decreasing) turns, and interpolate t and
position linearly between the two samples that bracket A.

Drift (seed 000 eq. 27, 28): the two displacements D1 = P540 - P180 and D2 = P720 - P360 each
span one full turn, so on a steady circle in a uniform current each is the current velocity
times the turn period.
    distance  d = (|D1| + |D2|) / 2                                    (eq. 27)
    direction     = compass angle of (D1/|D1| + D2/|D2|), clockwise from north, in [0, 360):
                    the direction the track drifts TOWARD, like a current's "flows toward".
    speed         = d / mean(t540 - t180, t720 - t360)
Eq. 28 averages two arctan(dY/dX) with X east, Y north (their eq. 9). Averaging raw angles breaks
across 0/360 deg and plain arctan only spans (-90, 90) deg, so we average unit vectors with atan2.
Reading Table 4: the paper calls alpha_drift "the angle between the drift and north", but its
eq. 28 measures from the X (east) axis toward Y (north). Its six values (186.97 .. 239.43 deg)
lie in (180, 270) deg, which under EITHER reading is a drift toward the south-west quadrant
(213.54 deg read as a compass bearing is 33.54 deg west of south; read as the eq. 28 angle it
is the compass direction 90 - 213.54 = -123.54 = 236.46 deg). `seed_drift_angle_deg` converts our compass
direction to the eq. 28 reading so values can be set against the paper's tables.

Turning radius, two estimators:
  * `turning_radius` is seed 000 eq. 29: rotate the track so its x axis lies along the drift
    direction (Fig. 11), then r_t = mean over full 360 deg heading periods of
    (y_upper - y_lower) / 2 across the drift axis. On a steady circle drifting at a constant
    velocity the across-drift coordinate is exactly centre + R sin(.), so r_t = R. It is the
    paper's number (compare with Tables 6, 7) and needs no steady-state assumption, but it picks
    two extreme samples per circle: position noise biases it upward (about 1.7 sigma for 0.2 m
    GPS noise at 10 Hz on a 20 m circle), and an unsteady first circle (entry transient) enters
    the average.
  * `steady_turning_radius` removes the drift velocity (first estimated from the eq. 27 points,
    then refined jointly) and least-squares fits a circle to every sample after the entry
    transient: (x_n - c_n - V_n tau)^2 + (y_e - c_e - V_e tau)^2 = R^2. Every sample votes, so
    it is nearly unbiased under white position noise; it is right only when the turn is steady
    (constant speed, yaw rate and current) over the fitted part. Use it to compare models;
    use eq. 29 to reproduce the paper.

Turning circle (IMO MSC.137(76) definitions / ITTC 7.5-04-02-01), from position and heading at
rudder execute: advance = displacement along the original heading when the heading has changed
90 deg; transfer = |displacement across it| at 90 deg; tactical diameter = |displacement across
it| at 180 deg. A track of 360-720 deg of heading change (no eq. 27 drift) still gets an eq. 29
radius, from its first full circle, with a note.

Zigzag (IMO MSC.137(76) definitions; ITTC 7.5-04-02-01 sec. 2.2.2): the rudder is reversed each
time the heading deviation from the base heading (heading at first execute) reaches the check
angle; the overshoot angle is how far the heading swings beyond the heading at which the rudder
was reversed. Reversal instants come from the rudder signal itself (see `zigzag_overshoots`).

Open-loop errors: a model is rolled out from many start points without measurement feedback;
position error at fixed horizons (mean / median / 95th percentile) summarises the drift of the
prediction, the quantity the predictor node is judged on.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from usv_predictor.frames import compass_deg, wrap_angle

DRIFT_CHANGES_DEG = (180.0, 360.0, 540.0, 720.0)  # heading changes used by eq. 27, 28 (deg)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class HeadingPoint:
    """Where the heading first changed by `change_deg` from the start of the track."""

    change_deg: float
    t_s: float
    x_n_m: float
    y_e_m: float


@dataclass(frozen=True)
class Drift:
    """Seed 000 eq. 27, 28: drift distance over one turn, direction it drifts toward, speed."""

    distance_m: float
    direction_deg: float  # compass, clockwise from north, [0, 360); NaN if there is no drift
    speed_mps: float
    period_s: float  # mean time between the paired heading points (one full turn)


@dataclass(frozen=True)
class TurningRadius:
    """Seed 000 eq. 29: mean half-extent across the drift axis per full 360 deg heading period."""

    radius_m: float
    per_circle_m: tuple[float, ...]
    drift_direction_deg: float  # axis used for the rotation (compass deg)
    note: str = ""  # how the radius was obtained when the track did not allow eq. 29 as written ("" it did)


@dataclass(frozen=True)
class SteadyTurningRadius:
    """Least-squares circle in the frame moving with the drift velocity."""

    radius_m: float
    center_n_m: float  # centre at t = t_ref_s (m north)
    center_e_m: float  # centre at t = t_ref_s (m east)
    t_ref_s: float
    drift_north_mps: float
    drift_east_mps: float
    rms_residual_m: float  # RMS distance of the fitted samples from the circle
    samples: int


@dataclass(frozen=True)
class TurningCircle:
    """IMO MSC.137(76) turning-circle criteria measured from rudder execute."""

    advance_m: float  # along the original heading at 90 deg heading change (signed)
    transfer_m: float  # |across the original heading| at 90 deg
    tactical_diameter_m: float  # |across the original heading| at 180 deg
    time_to_90_s: float  # from execute
    time_to_180_s: float  # from execute
    turn_direction: int  # +1 starboard (psi increasing), -1 port
    execute_heading_deg: float  # heading at execute, compass [0, 360)


@dataclass(frozen=True)
class ZigZag:
    """ITTC zigzag parameters; per-reversal tuples are aligned, NaN where a peak was not observed."""

    overshoot_angles_deg: tuple[float, ...]
    first_overshoot_deg: float  # NaN when not observed
    second_overshoot_deg: float  # NaN when not observed
    initial_turning_time_s: float  # first execute -> first reversal (second execute)
    period_s: float  # mean time between successive executes to the same side; NaN if < 3
    execute_time_s: float
    base_heading_deg: float  # heading at first execute, compass [0, 360)
    reversal_times_s: tuple[float, ...]
    check_headings_deg: tuple[float, ...]  # heading deviation at each reversal (signed)
    peak_headings_deg: tuple[float, ...]  # heading deviation at each observed peak (signed)
    peak_times_s: tuple[float, ...]
    time_to_check_yaw_s: tuple[float, ...]  # reversal -> following heading peak
    rudder_amplitude_deg: float


@dataclass(frozen=True)
class HorizonError:
    """Position error statistics of open-loop predictions at one horizon over all start points."""

    horizon_s: float
    mean_m: float
    p50_m: float
    p95_m: float
    max_m: float
    count: int  # start points with a finite error at this horizon


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------
def _as_series(t: Sequence[float] | np.ndarray, **columns: Sequence[float] | np.ndarray) -> tuple[np.ndarray, ...]:
    """Float arrays of one length, finite, with strictly increasing t; named in the error."""
    t_arr = np.asarray(t, dtype=float)
    if t_arr.ndim != 1 or len(t_arr) < 2:
        raise ValueError(f"t must be a 1-D array of at least 2 samples, got shape {t_arr.shape}")
    out = [t_arr]
    for name, values in columns.items():
        arr = np.asarray(values, dtype=float)
        if arr.shape != t_arr.shape:
            raise ValueError(f"{name} has shape {arr.shape} but t has shape {t_arr.shape}")
        out.append(arr)
    for name, arr in zip(("t", *columns), out):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or infinite values")
    if np.any(np.diff(t_arr) <= 0.0):
        raise ValueError("t must be strictly increasing")
    return tuple(out)


def _interp_crossing(t: np.ndarray, values: np.ndarray, level: float, i: int) -> float:
    """Time where `values` crosses `level` between samples i and i + 1 (linear)."""
    v0, v1 = values[i], values[i + 1]
    frac = 0.0 if v1 == v0 else (level - v0) / (v1 - v0)
    return float(t[i] + min(max(frac, 0.0), 1.0) * (t[i + 1] - t[i]))


def unwrap_heading(psi: Sequence[float] | np.ndarray) -> np.ndarray:
    """Continuous heading (rad) from a wrapped one; assumes |change| < pi between samples."""
    return np.unwrap(np.asarray(psi, dtype=float))


# --------------------------------------------------------------------------------------------
# Heading change points and drift (seed 000 eq. 27, 28)
# --------------------------------------------------------------------------------------------
def heading_change_positions(
    t: Sequence[float] | np.ndarray,
    x_n: Sequence[float] | np.ndarray,
    y_e: Sequence[float] | np.ndarray,
    psi: Sequence[float] | np.ndarray,
    changes_deg: Sequence[float] = DRIFT_CHANGES_DEG,
) -> tuple[HeadingPoint, ...]:
    """Time and position where |heading change from the first sample| first reaches each value.

    Works for starboard and port turns; raises ValueError naming the heading change reached and
    the one needed when the track does not turn enough.
    """
    t, x_n, y_e, psi = _as_series(t, x_n=x_n, y_e=y_e, psi=psi)
    psi_u = unwrap_heading(psi)
    change = np.abs(psi_u - psi_u[0])  # rad, side independent
    reached_deg = float(np.degrees(change.max()))
    points = []
    for change_deg in changes_deg:
        if change_deg <= 0.0:
            raise ValueError(f"heading changes must be positive, got {change_deg} deg")
        target = math.radians(change_deg)
        above = np.nonzero(change >= target)[0]
        if len(above) == 0:
            raise ValueError(
                f"track turns only {reached_deg:.1f} deg from its initial heading "
                f"({t[-1] - t[0]:.1f} s of data); {change_deg:g} deg is needed"
            )
        i = int(above[0]) - 1  # i >= 0 because change[0] == 0 < target
        t_cross = _interp_crossing(t, change, target, i)
        points.append(
            HeadingPoint(
                change_deg=float(change_deg),
                t_s=t_cross,
                x_n_m=float(np.interp(t_cross, t[i : i + 2], x_n[i : i + 2])),
                y_e_m=float(np.interp(t_cross, t[i : i + 2], y_e[i : i + 2])),
            )
        )
    return tuple(points)


def _drift_points(t: np.ndarray, x_n: np.ndarray, y_e: np.ndarray, psi: np.ndarray) -> tuple[HeadingPoint, ...]:
    """The eq. 27 heading points P180 .. P720, with an error that says two turns are needed."""
    try:
        return heading_change_positions(t, x_n, y_e, psi, DRIFT_CHANGES_DEG)
    except ValueError as err:
        raise ValueError(f"drift (seed 000 eq. 27) needs 720 deg of heading change (two turns): {err}") from err


def _drift_displacements(points: tuple[HeadingPoint, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(2, 2) displacements [[dN, dE] of P540-P180, of P720-P360] and (2,) their durations (s)."""
    p180, p360, p540, p720 = points
    disp = np.array(
        [
            [p540.x_n_m - p180.x_n_m, p540.y_e_m - p180.y_e_m],
            [p720.x_n_m - p360.x_n_m, p720.y_e_m - p360.y_e_m],
        ]
    )
    durations = np.array([p540.t_s - p180.t_s, p720.t_s - p360.t_s])
    return disp, durations


def drift(
    t: Sequence[float] | np.ndarray,
    x_n: Sequence[float] | np.ndarray,
    y_e: Sequence[float] | np.ndarray,
    psi: Sequence[float] | np.ndarray,
) -> Drift:
    """Seed 000 eq. 27 (distance) and eq. 28 (direction, as a compass angle toward) of a turning track.

    Needs at least 720 deg of heading change (two full turns).
    """
    t, x_n, y_e, psi = _as_series(t, x_n=x_n, y_e=y_e, psi=psi)  # before the "needs 720 deg" wrapping
    disp, durations = _drift_displacements(_drift_points(t, x_n, y_e, psi))
    lengths = np.hypot(disp[:, 0], disp[:, 1])
    distance = float(lengths.mean())
    # Unit vectors, so both turns weigh equally and 359 deg and 1 deg average to 0 deg.
    units = disp[lengths > 0.0] / lengths[lengths > 0.0, None]
    resultant = units.sum(axis=0)
    direction = (
        compass_deg(resultant[0], resultant[1]) if np.hypot(*resultant) > 1e-12 else float("nan")
    )
    period = float(durations.mean())
    return Drift(distance_m=distance, direction_deg=direction, speed_mps=distance / period, period_s=period)


def seed_drift_angle_deg(direction_deg: float) -> float:
    """Compass direction (deg from north, clockwise) -> seed 000 eq. 28 angle (deg from east
    toward north, X east / Y north of their eq. 9), in [0, 360)."""
    return float((90.0 - direction_deg) % 360.0)


# --------------------------------------------------------------------------------------------
# Turning radius (seed 000 eq. 29) and steady circle fit
# --------------------------------------------------------------------------------------------
def turning_radius(
    t: Sequence[float] | np.ndarray,
    x_n: Sequence[float] | np.ndarray,
    y_e: Sequence[float] | np.ndarray,
    psi: Sequence[float] | np.ndarray,
    drift_direction_deg: float | None = None,
) -> TurningRadius:
    """Seed 000 eq. 29: r_t = mean over 360 deg heading periods of (upper - lower) / 2 across drift.

    Periods are [0, 360), [360, 720), ... deg of heading change from the first sample. Without
    `drift_direction_deg` the direction comes from `drift` (needs 720 deg); pass it (e.g. 0.0
    when there is no current) to measure a track of one to two turns. A track of 360-720 deg without
    it still gets the radius of its first full circle, across a north axis (no drift correction), and
    `note` says so: on a drifting circle that half-extent is off by up to the drift over one circle / 2.
    """
    t, x_n, y_e, psi = _as_series(t, x_n=x_n, y_e=y_e, psi=psi)
    note = ""
    if drift_direction_deg is None:
        turned = float(np.degrees(np.max(np.abs(unwrap_heading(psi) - unwrap_heading(psi)[0]))))
        if 360.0 <= turned < 720.0:
            drift_direction_deg = 0.0
            note = (f"the track turns {turned:.0f} deg (< 720): no drift estimate (eq. 27 needs two circles), so the "
                    f"radius is the half-extent of the first full circle without drift correction")
        else:
            drift_direction_deg = drift(t, x_n, y_e, psi).direction_deg
    if not math.isfinite(drift_direction_deg):
        raise ValueError("drift direction is undefined (no drift); pass drift_direction_deg explicitly")
    axis = math.radians(drift_direction_deg)
    # Coordinate across the drift axis (to its starboard side), the y of the paper's Fig. 11.
    across = -x_n * math.sin(axis) + y_e * math.cos(axis)
    change = np.abs(unwrap_heading(psi) - unwrap_heading(psi)[0])
    circles = int(np.degrees(change.max()) // 360.0)
    if circles < 1:
        raise ValueError(
            f"track turns only {np.degrees(change.max()):.1f} deg from its initial heading; "
            "360 deg (one full circle) is needed for eq. 29"
        )
    bounds = heading_change_positions(t, x_n, y_e, psi, [360.0 * k for k in range(1, circles + 1)])
    t_bounds = [t[0], *(p.t_s for p in bounds)]
    per_circle = []
    for t_start, t_end in zip(t_bounds[:-1], t_bounds[1:]):
        inside = (t >= t_start) & (t <= t_end)
        # Interpolated period ends belong to the period too (a sample may straddle them).
        ends = np.interp([t_start, t_end], t, across)
        values = np.concatenate([across[inside], ends])
        per_circle.append(float(values.max() - values.min()) / 2.0)
    return TurningRadius(
        radius_m=float(np.mean(per_circle)),
        per_circle_m=tuple(per_circle),
        drift_direction_deg=float(drift_direction_deg % 360.0),
        note=note,
    )


def _kasa_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Algebraic circle fit (Kasa 1976): linear least squares on x^2 + y^2 = 2ax + 2by + c."""
    design = np.column_stack([2.0 * x, 2.0 * y, np.ones_like(x)])
    (a, b, c), *_ = np.linalg.lstsq(design, x * x + y * y, rcond=None)
    return float(a), float(b), float(math.sqrt(max(c + a * a + b * b, 0.0)))


def _moving_circle_fit(
    tau: np.ndarray, x: np.ndarray, y: np.ndarray, params: np.ndarray, fit_drift: bool, iterations: int = 50
) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on geometric residuals |p - c - V tau| - R; params = [c_n, c_e, R, V_n, V_e]."""
    p = params.astype(float).copy()
    free = slice(0, 5) if fit_drift else slice(0, 3)
    for _ in range(iterations):
        dx = x - p[0] - p[3] * tau
        dy = y - p[1] - p[4] * tau
        rho = np.maximum(np.hypot(dx, dy), 1e-12)
        residual = rho - p[2]
        jac = np.column_stack([-dx / rho, -dy / rho, -np.ones_like(rho), -dx * tau / rho, -dy * tau / rho])
        step, *_ = np.linalg.lstsq(jac[:, free], -residual, rcond=None)
        p[free] += step
        if np.max(np.abs(step)) < 1e-10 * max(1.0, abs(p[2])):
            break
    dx = x - p[0] - p[3] * tau
    dy = y - p[1] - p[4] * tau
    return p, np.hypot(dx, dy) - p[2]


def steady_turning_radius(
    t: Sequence[float] | np.ndarray,
    x_n: Sequence[float] | np.ndarray,
    y_e: Sequence[float] | np.ndarray,
    psi: Sequence[float] | np.ndarray,
    start_change_deg: float = 180.0,
    drift_velocity_mps: tuple[float, float] | None = None,
    refine_drift: bool = True,
) -> SteadyTurningRadius:
    """Least-squares circle in the frame moving with the drift (robust alternative to eq. 29).

    Samples after the heading changed `start_change_deg` (skipping the entry transient) are fitted.
    The drift velocity (north, east) starts from `drift_velocity_mps` or, by default, from the
    eq. 27 points (D1 / (t540 - t180) + D2 / (t720 - t360)) / 2, which needs 720 deg; with
    `refine_drift` it is then fitted jointly with the circle.
    """
    t, x_n, y_e, psi = _as_series(t, x_n=x_n, y_e=y_e, psi=psi)
    if drift_velocity_mps is None:
        disp, durations = _drift_displacements(_drift_points(t, x_n, y_e, psi))
        drift_velocity = (disp / durations[:, None]).mean(axis=0)
    else:
        drift_velocity = np.asarray(drift_velocity_mps, dtype=float)
    t_start = t[0] if start_change_deg <= 0.0 else heading_change_positions(t, x_n, y_e, psi, [start_change_deg])[0].t_s
    keep = t >= t_start
    if np.count_nonzero(keep) < 5:
        raise ValueError(f"only {np.count_nonzero(keep)} samples after {start_change_deg:g} deg; 5 are needed")
    t_ref = float(t[keep].mean())  # centres tau so centre and drift velocity decouple
    tau = t[keep] - t_ref
    x = x_n[keep] - drift_velocity[0] * tau
    y = y_e[keep] - drift_velocity[1] * tau
    c_n, c_e, radius = _kasa_circle(x, y)
    start = np.array([c_n, c_e, radius, 0.0, 0.0])
    params, residual = _moving_circle_fit(tau, x, y, start, fit_drift=refine_drift)
    return SteadyTurningRadius(
        radius_m=float(abs(params[2])),
        center_n_m=float(params[0]),
        center_e_m=float(params[1]),
        t_ref_s=t_ref,
        drift_north_mps=float(drift_velocity[0] + params[3]),
        drift_east_mps=float(drift_velocity[1] + params[4]),
        rms_residual_m=float(np.sqrt(np.mean(residual**2))),
        samples=int(len(tau)),
    )


# --------------------------------------------------------------------------------------------
# Turning circle criteria (IMO MSC.137(76))
# --------------------------------------------------------------------------------------------
def turning_circle_criteria(
    t: Sequence[float] | np.ndarray,
    x_n: Sequence[float] | np.ndarray,
    y_e: Sequence[float] | np.ndarray,
    psi: Sequence[float] | np.ndarray,
    t_execute: float,
) -> TurningCircle:
    """Advance, transfer and tactical diameter measured from position and heading at rudder execute."""
    t, x_n, y_e, psi = _as_series(t, x_n=x_n, y_e=y_e, psi=psi)
    if not t[0] <= t_execute < t[-1]:
        raise ValueError(f"t_execute = {t_execute} s lies outside the track [{t[0]}, {t[-1]}) s")
    psi_u = unwrap_heading(psi)
    after = t > t_execute
    # The track restarted at the execute instant, so heading change and positions count from there.
    t_c = np.concatenate([[t_execute], t[after]])
    x_c = np.concatenate([[np.interp(t_execute, t, x_n)], x_n[after]])
    y_c = np.concatenate([[np.interp(t_execute, t, y_e)], y_e[after]])
    psi_c = np.concatenate([[np.interp(t_execute, t, psi_u)], psi_u[after]])
    try:
        p90, p180 = heading_change_positions(t_c, x_c, y_c, psi_c, (90.0, 180.0))
    except ValueError as err:
        raise ValueError(f"turning circle after execute at {t_execute} s: {err}") from err
    psi0 = psi_c[0]
    cos0, sin0 = math.cos(psi0), math.sin(psi0)

    def along_across(point: HeadingPoint) -> tuple[float, float]:
        d_n, d_e = point.x_n_m - x_c[0], point.y_e_m - y_c[0]
        return d_n * cos0 + d_e * sin0, -d_n * sin0 + d_e * cos0

    advance, transfer = along_across(p90)
    _, tactical = along_across(p180)
    turn = 1 if np.interp(p90.t_s, t_c, psi_c) > psi0 else -1
    return TurningCircle(
        advance_m=float(advance),
        transfer_m=float(abs(transfer)),
        tactical_diameter_m=float(abs(tactical)),
        time_to_90_s=p90.t_s - t_execute,
        time_to_180_s=p180.t_s - t_execute,
        turn_direction=turn,
        execute_heading_deg=float(np.degrees(psi0) % 360.0),
    )


# --------------------------------------------------------------------------------------------
# Zigzag (ITTC 7.5-04-02-01 sec. 2.2.2)
# --------------------------------------------------------------------------------------------
def _rudder_states(rudder: np.ndarray, threshold: float) -> np.ndarray:
    """Hysteresis side of the rudder: +1 / -1 once beyond +-threshold, kept until the other side; 0 before."""
    side = np.where(rudder >= threshold, 1, np.where(rudder <= -threshold, -1, 0))
    last_set = np.maximum.accumulate(np.where(side != 0, np.arange(len(side)), -1))
    return np.where(last_set >= 0, side[np.maximum(last_set, 0)], 0)


def _held_value(segment: np.ndarray, side: int) -> float:
    """Rudder angle held on one side: median of the samples beyond 75 % of the segment's own reach.

    The segment also holds the ramps in and out; keeping only its far part leaves the hold as the
    majority even when the hold is short, and the segment's own reach copes with a rudder offset.
    """
    reach = float(np.percentile(side * segment, 95.0))
    far = segment[side * segment >= 0.75 * reach]
    return float(np.median(far if len(far) else segment))


def _movement_start(t: np.ndarray, rudder: np.ndarray, j: int, held: float, target: float) -> float:
    """Instant the rudder left `held` on its way to `target`; j is the first sample on the new side.

    A straight line is fitted to the ramp samples between 20 % and 80 % of the way (the last
    20 % crossing before j, so noise on the held value cannot trigger early) and extrapolated back
    to `held`; a ramp faster than the sampling falls back to the 50 % crossing.
    """
    span = target - held
    progress = (rudder - held) / span  # 0 at held, 1 at target
    before = np.nonzero(progress[:j] < 0.2)[0]
    if len(before) == 0:
        return float(t[0])
    lo = int(before[-1])
    after = np.nonzero(progress[lo + 1 :] >= 0.8)[0]
    hi = lo + 1 + int(after[0]) if len(after) else len(t)
    ramp = slice(lo + 1, hi)
    if hi - lo - 1 >= 2:
        slope, intercept = np.polyfit(t[ramp], progress[ramp], 1)
        if slope > 0.0:
            return float(min(max(-intercept / slope, t[0]), t[lo + 1]))
    mid = np.nonzero(progress[lo + 1 :] >= 0.5)[0]
    i = lo + int(mid[0]) if len(mid) else lo
    return _interp_crossing(t, progress, 0.5, i) if i + 1 < len(t) else float(t[i])


def _local_fit(t: np.ndarray, y: np.ndarray, centre: float, half_width: float) -> np.ndarray | None:
    """Quadratic least-squares coefficients (highest first, in t - centre) near centre, or None."""
    near = np.abs(t - centre) <= half_width
    if np.count_nonzero(near) < 5:
        return None
    return np.polyfit(t[near] - centre, y[near], 2)


def _value_at(t: np.ndarray, y: np.ndarray, t0: float, half_width: float) -> float:
    """y at t0, from a local quadratic fit when smoothing (noise), else linear interpolation."""
    coeffs = _local_fit(t, y, t0, half_width) if half_width > 0.0 else None
    return float(np.interp(t0, t, y)) if coeffs is None else float(coeffs[-1])


def _value_before(t: np.ndarray, y: np.ndarray, t0: float, width: float) -> float:
    """y at t0 from a line through the samples of the preceding `width` seconds (steady approach).

    One-sided because the heading bends at execute; falls back to interpolation without samples.
    """
    near = (t >= t0 - width) & (t <= t0)
    if width <= 0.0 or np.count_nonzero(near) < 3:
        return float(np.interp(t0, t, y))
    _, intercept = np.polyfit(t[near] - t0, y[near], 1)
    return float(intercept)


def _peak(t: np.ndarray, dev: np.ndarray, lo: float, hi: float, sense: float, half_width: float):
    """(time, value) of the extreme of sense * dev on [lo, hi], or None if it sits at hi (not reached)."""
    inside = np.nonzero((t >= lo) & (t <= hi))[0]
    if len(inside) < 3:
        return None
    k = int(inside[np.argmax(sense * dev[inside])])
    if k == inside[-1]:
        return None  # still swinging when the interval (or the record) ends
    t_peak, value = float(t[k]), float(dev[k])
    coeffs = _local_fit(t, dev, t_peak, half_width) if half_width > 0.0 else None
    if coeffs is not None and sense * coeffs[0] < 0.0:  # a cap in the right direction
        offset = -coeffs[1] / (2.0 * coeffs[0])
        if abs(offset) <= half_width:
            t_peak, value = t_peak + offset, float(np.polyval(coeffs, offset))
    return t_peak, value


def zigzag_overshoots(
    t: Sequence[float] | np.ndarray,
    psi: Sequence[float] | np.ndarray,
    rudder: Sequence[float] | np.ndarray,
    rudder_threshold_rad: float | None = None,
    smoothing_fraction: float = 0.1,
) -> ZigZag:
    """Overshoot angles of a zigzag manoeuvre, one per rudder reversal.

    Executes are where the rudder passes +-`rudder_threshold_rad` (default: half its 95th
    percentile |angle|, so noise does not flip it); each execute instant is extrapolated back to
    where the rudder left its held value (median over the preceding hold). The base heading is the
    heading at the first execute; the check heading of reversal k is the heading deviation at its
    instant; the overshoot is |peak deviation before the next reversal - check heading|, the peak
    taken in the direction the heading was turning. Heading values at reversals and peaks come
    from local quadratic fits over +-`smoothing_fraction` of the median time between executes
    (0: raw samples); the base heading from a line through the approach before execute. All
    per-reversal tuples are aligned; a reversal whose peak is not in the record (the record ends,
    or the rudder reverses again while the heading still swings) has NaN peak and overshoot.
    """
    t, psi, rudder = _as_series(t, psi=psi, rudder=rudder)
    amplitude = float(np.percentile(np.abs(rudder), 95.0))
    threshold = 0.5 * amplitude if rudder_threshold_rad is None else float(rudder_threshold_rad)
    if threshold <= 0.0:
        raise ValueError("rudder never leaves zero; a zigzag needs rudder executes")
    states = _rudder_states(rudder, threshold)
    switches = np.nonzero(np.diff(states) != 0)[0] + 1  # first sample of each new side
    if states[0] != 0:
        switches = np.concatenate([[0], switches])
    if len(switches) < 2:
        raise ValueError(
            f"rudder changes side {max(len(switches) - 1, 0)} times past +-{math.degrees(threshold):.2f} deg; "
            "a zigzag needs a first execute and at least one reversal"
        )
    # Held rudder value of each side segment and of the neutral approach before the first execute.
    bounds = [*switches.tolist(), len(t)]
    held = [_held_value(rudder[a:b], int(states[a])) for a, b in zip(bounds[:-1], bounds[1:])]
    neutral = float(np.median(rudder[: switches[0]])) if switches[0] > 0 else 0.0
    starts = [float(t[0]) if switches[0] == 0 else _movement_start(t, rudder, int(switches[0]), neutral, held[0])]
    starts += [_movement_start(t, rudder, int(j), held[k], held[k + 1]) for k, j in enumerate(switches[1:])]

    psi_u = unwrap_heading(psi)
    # One fit width for the whole run: a fraction of the typical time between executes (half a cycle).
    width = max(smoothing_fraction, 0.0) * float(np.median(np.diff(starts)))
    base = _value_before(t, psi_u, starts[0], width)
    dev = np.degrees(psi_u - base)  # heading deviation from the base heading (deg)

    reversal_times, checks, peaks, peak_times, overshoots, check_yaw = [], [], [], [], [], []
    for k in range(1, len(starts)):
        check = _value_at(t, dev, starts[k], width)
        previous = _value_at(t, dev, starts[k - 1], width) if k > 1 else 0.0
        sense = math.copysign(1.0, check - previous)  # the side the heading was swinging to
        end = starts[k + 1] if k + 1 < len(starts) else float(t[-1])
        peak = _peak(t, dev, starts[k], end, sense, width)
        t_peak, peak_dev = (math.nan, math.nan) if peak is None else peak
        reversal_times.append(starts[k])
        checks.append(check)
        peak_times.append(t_peak)
        peaks.append(peak_dev)
        overshoots.append(abs(peak_dev - check))
        check_yaw.append(t_peak - starts[k])

    periods = [b - a for a, b in zip(starts[:-2], starts[2:])]
    return ZigZag(
        overshoot_angles_deg=tuple(overshoots),
        first_overshoot_deg=overshoots[0],
        second_overshoot_deg=overshoots[1] if len(overshoots) > 1 else math.nan,
        initial_turning_time_s=starts[1] - starts[0],
        period_s=float(np.mean(periods)) if periods else float("nan"),
        execute_time_s=starts[0],
        base_heading_deg=float(np.degrees(base) % 360.0),
        reversal_times_s=tuple(reversal_times),
        check_headings_deg=tuple(checks),
        peak_headings_deg=tuple(peaks),
        peak_times_s=tuple(peak_times),
        time_to_check_yaw_s=tuple(check_yaw),
        rudder_amplitude_deg=math.degrees(amplitude),
    )


# --------------------------------------------------------------------------------------------
# Prediction errors
# --------------------------------------------------------------------------------------------
def rmse(a: np.ndarray, b: np.ndarray, angle_columns: Sequence[int] = ()) -> np.ndarray:
    """Root-mean-square error per column of (N,) or (N, k) arrays -> () or (k,).

    Differences in `angle_columns` (rad) are wrapped so 359 deg vs 1 deg counts as 2 deg.
    """
    a_arr, b_arr = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if a_arr.shape != b_arr.shape or a_arr.ndim not in (1, 2) or len(a_arr) == 0:
        raise ValueError(f"rmse needs two (N,) or (N, k) arrays of one shape, got {a_arr.shape} and {b_arr.shape}")
    diff = a_arr - b_arr
    if angle_columns:
        if diff.ndim == 1:
            diff = wrap_angle(diff)
        else:
            cols = list(angle_columns)
            diff[:, cols] = wrap_angle(diff[:, cols])
    return np.sqrt(np.mean(diff**2, axis=0))


def position_error(
    x_pred: np.ndarray, y_pred: np.ndarray, x_meas: np.ndarray, y_meas: np.ndarray
) -> np.ndarray:
    """Euclidean horizontal distance (m) between predicted and measured positions, elementwise."""
    return np.hypot(np.asarray(x_pred, dtype=float) - x_meas, np.asarray(y_pred, dtype=float) - y_meas)


def open_loop_errors(
    predicted_xy: np.ndarray,
    measured_xy: np.ndarray,
    horizons_s: Sequence[float] = (10.0, 30.0, 60.0),
    dt: float = 0.1,
) -> tuple[HorizonError, ...]:
    """Position error statistics at each horizon over many open-loop start points.

    predicted_xy, measured_xy: (starts, steps, 2) positions [x_n, y_e] (m); step k is the state
    (k + 1) * dt seconds after its start point (the start state itself is not included), so the
    horizon h reads step h / dt - 1. Horizons must be multiples of dt within the rollout. Start
    points whose error is NaN at a horizon (e.g. missing GPS) are left out of that horizon.
    """
    pred = np.asarray(predicted_xy, dtype=float)
    meas = np.asarray(measured_xy, dtype=float)
    if pred.shape != meas.shape or pred.ndim != 3 or pred.shape[2] != 2:
        raise ValueError(f"need predicted and measured (starts, steps, 2) arrays, got {pred.shape} and {meas.shape}")
    if dt <= 0.0:
        raise ValueError(f"dt must be positive, got {dt} s")
    steps = pred.shape[1]
    errors = np.hypot(pred[..., 0] - meas[..., 0], pred[..., 1] - meas[..., 1])  # (starts, steps)
    results = []
    for horizon in horizons_s:
        steps_to = horizon / dt
        k = int(round(steps_to))
        if abs(steps_to - k) > 1e-6 * max(1.0, steps_to) or not 1 <= k <= steps:
            raise ValueError(
                f"horizon {horizon} s is not a multiple of dt = {dt} s within the rollout of "
                f"{steps} steps ({steps * dt:g} s)"
            )
        at_horizon = errors[:, k - 1]
        finite = at_horizon[np.isfinite(at_horizon)]
        if len(finite) == 0:
            stats = (float("nan"),) * 4
        else:
            stats = (
                float(finite.mean()),
                float(np.percentile(finite, 50.0)),
                float(np.percentile(finite, 95.0)),
                float(finite.max()),
            )
        results.append(HorizonError(float(horizon), *stats, count=int(len(finite))))
    return tuple(results)

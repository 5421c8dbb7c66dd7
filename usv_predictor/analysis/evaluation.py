"""Offline evaluation of a motion predictor on recorded manoeuvres (seed 000 sec. 3.3, 3.4; pure numpy).

A model is any object with
    metadata: dict  (at least "dt" in s; "model_id", "model_type", "feature_set" are reported)
    predict(state (B, 4) [u, v, r, psi], controls (B, H, 2) [delta, rpm]) -> (E, B, H, 6)
        = [u, v, r, x_n, y_e, psi] at dt .. H dt after the start, positions relative to the start (NED),
        psi continuous; controls[:, k] act from step k to k + 1; E ensemble members.
A model with `accepts_reference` (the grey boxes) also takes predict(..., reference=(B, 4)): for a layout that
reports no propulsion (rudder_only) every rollout of a recording gets the recording's approach state
(data.recording.approach_state), whose engine speed the boat holds all manoeuvre long.

Closed loop (seed 000 Fig. 3): the model starts from the recording's first state and is rolled out over the
whole recording with the recorded controls and no measurement feedback; its integrated positions (seed 000
eq. 9) are placed at the measured start position and set against the measured track. The reference is the
GNSS track with the measured u, v, r, psi ("gnss", what a sea trial has); the same measurements through the
EKF/RTS smoother ("smoothed", data/smoother.py: GNSS, compass, INS and gyro fused over the whole record), compared
against while the model still starts from the raw measured state and position (the smoothed start would use samples
after it); or, for simulated bags, the ground truth ("truth": the start state and the comparison both come from it).
Why "smoothed": eq. 27-29 take a few single GNSS samples per circle (the heading-change points, the extremes across
the drift), so GNSS noise enters them directly: on the shipped sea trial (0.3 m GNSS noise per axis at 5 Hz plus the
waves' first-order motion) the TRUE track scored against the raw GNSS track is off by up to 3.1 % in radius (eq. 29
is biased upward by noise), 1.9 deg in drift angle and 6.1 % in drift distance, against 0.4 %, 1.5 deg and 1.1 %
against the smoothed one (docs/results/study_hybrid.md "The metric's own noise").

Open loop: the same rollout from many start points (every `stride_s`), position error at 10 / 30 / 60 s
(metrics.open_loop_errors): what the online predictor is judged on.

Manoeuvre metrics on measured vs predicted tracks (metrics.py for the definitions):
    turning circles  turning radius eq. 29 and the steady circle fit, drift distance eq. 27, drift direction
                     eq. 28 (compass, toward), IMO advance, transfer and tactical diameter;
    zig-zags         first and second overshoot angles (ITTC);
    every recording  RMSE of u, v, r, psi and of the position along the closed-loop rollout.
Divergence: a model whose rollout leaves the numbers (NaN/inf: an unstable identified hull, a residual out of its
range) is reported as diverged, never as a metric over what is left. Closed loop: the recording's `diverged` record
says at what time of which manoeuvre, and its RMSEs and the predicted manoeuvre metrics and their errors are undefined
(JSON null) with a note; open loop: the windows that diverged are counted per horizon (`diverged`), the first named
(its start and how long after it), and the horizon's statistics are over the others, said in a note; the summary
counts the diverged recordings and windows (DIVERGENCE_KEYS).
Errors follow seed 000 Tables 7-8: relative (%) for lengths, absolute (deg) for angles, always
predicted - measured (the paper's tables mix both signs; one sign here so a bias reads one way).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from usv_predictor.analysis import metrics
from usv_predictor.atomic import finite_or_none
from usv_predictor.data.recording import Recording
from usv_predictor.data.recording import held_reference as recording_held_reference
from usv_predictor.errors import DatasetError, EvaluationError, ModelError
from usv_predictor.frames import angle_difference_deg
from usv_predictor.models import loading
from usv_predictor.models.loading import check_dt
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, CommandInput, actuator_layout
from usv_predictor.records import whole_steps

U, V, R, X_N, Y_E, PSI = range(6)  # columns of predicted and measured series (model output order)
COLUMNS = ("u_mps", "v_mps", "r_rad_s", "x_n_m", "y_e_m", "psi_rad")
REFERENCES = ("gnss", "smoothed", "truth")
DEFAULT_HORIZONS_S = (10.0, 30.0, 60.0)
DRIFT_DIRECTION_MIN_M = 1.0  # below this drift distance (m) its direction is noise
DIVERGENCE_KEYS = ("diverged_recordings", "open_loop_diverged_windows")  # summary counts, not errors
COUNT_KEYS = ("recordings", "turning_circles", "zigzags", *DIVERGENCE_KEYS)  # the summary's counts


class Predictor(Protocol):
    metadata: Mapping[str, Any]

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """(B, 4), (B, H, 2) -> (E, B, H, 6)."""


class WithoutReference:
    """`predictor` asked without the approach reference: every prediction holds the engine speed of its own start's
    water speed (the former rule for rudder_only; models/greybox.py). The comparison benchmarks and tests
    set it beside the reference rule on the same bags."""

    def __init__(self, predictor: Predictor) -> None:
        self.predictor = predictor
        self.metadata = predictor.metadata

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:  # (B, 4), (B, H, C) -> (E, B, H, 6)
        return self.predictor.predict(state, controls)


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Prediction:
    """A closed-loop rollout beside its reference, on the recording's time grid (row 0 = start)."""

    name: str
    reference: str  # "gnss" or "truth"
    t_s: np.ndarray  # (T,) s since the start
    controls: np.ndarray  # (T, C) the layout's controls, e.g. delta (rad), rpm
    measured: np.ndarray  # (T, 6) u, v, r, x_n, y_e, psi (NaN where the GNSS had no fix)
    predicted: np.ndarray  # (T, 6) ensemble mean, positions placed at the measured start
    predicted_std: np.ndarray  # (T, 6) ensemble spread (zeros for a single member)
    layout: str = DEFAULT_LAYOUT.name  # actuator layout of the controls (physics/actuators.py)

    @property
    def steering(self) -> np.ndarray:
        """(T,) the turn command (the rudder angle of a rudder boat), + to starboard."""
        return actuator_layout(self.layout).steering_signal(self.controls)


@dataclass(frozen=True)
class ManoeuvreKind:
    """What the controls say the recording is.

    The held turn command and the propulsion level are in the units the layout states them in (its turn_input and
    propulsion_input, physics/actuators.py): a rudder angle in deg and an engine speed in rpm for rudder boats, the
    normalised thrust difference port - starboard and the mean command (-) for twin thrusters. `rudder_deg` and
    `rpm` (the JSON keys of rudder boats) are NaN / null for a layout without a rudder or without an engine speed.
    """

    kind: str  # "turning_circle" | "zigzag" | "other"
    side: str  # "starboard" | "port" | "" (first side of the turn command)
    turn_command: float  # held |turn command| in turn_unit; NaN for "other" without a turn
    propulsion: float  # median propulsion level in propulsion_unit; NaN when the layout reports none
    execute_time_s: float  # first execute of the turn command (s from the start); NaN without one
    turn_unit: str = "deg"  # "deg" (a rudder angle) or "-" (a normalised differential)
    propulsion_unit: str = "rpm"  # "rpm" (engine speed) or "-" (a normalised throttle / mean thruster command)
    turn_name: str = "rudder"  # what the turn command is, for labels ("rudder", "differential")
    propulsion_name: str = "rpm"  # what the propulsion level is, for labels ("rpm", "throttle")

    @property
    def rudder_deg(self) -> float:
        """Held rudder magnitude (deg); NaN when the turn command is not a rudder angle."""
        return self.turn_command if self.turn_unit == "deg" else float("nan")

    @property
    def rpm(self) -> float:
        """Median engine speed (rpm); NaN when the propulsion level is not an engine speed."""
        return self.propulsion if self.propulsion_unit == "rpm" else float("nan")

    def _amount(self, value: float, unit: str, name: str) -> str:
        if not math.isfinite(value):
            return ""
        if unit in ("deg", "rpm"):
            return f"{value:.0f} {unit}"
        return f"{name} {value:.2f}"

    def label(self) -> str:
        """'turning circle, starboard, 15 deg, 650 rpm' (rudder boats) or 'turning circle, starboard, differential
        0.40, throttle 0.60' (twin thrusters) for titles and tables."""
        power = self._amount(self.propulsion, self.propulsion_unit, self.propulsion_name)
        if self.kind == "other":
            return ", ".join(p for p in ("other manoeuvre", power) if p)
        turn = self._amount(self.turn_command, self.turn_unit, self.turn_name)
        return ", ".join(p for p in (self.kind.replace("_", " "), self.side, turn, power) if p)

    def to_json(self) -> dict:
        """JSON (null where undefined: no held turn, no execute, no rudder or engine speed in the layout)."""
        return {"kind": self.kind, "side": self.side, "rudder_deg": finite_or_none(self.rudder_deg),
                "rpm": finite_or_none(self.rpm), "turn_command": finite_or_none(self.turn_command),
                "turn_unit": self.turn_unit, "propulsion": finite_or_none(self.propulsion),
                "propulsion_unit": self.propulsion_unit, "execute_time_s": finite_or_none(self.execute_time_s)}


@dataclass(frozen=True)
class OpenLoop:
    """Open-loop position errors from many start points."""

    stride_s: float
    horizon_s: float  # longest rollout (s)
    starts: int
    horizons: tuple[metrics.HorizonError, ...]
    mean_error_by_step_m: np.ndarray  # (H,) mean over starts of the error (k + 1) dt after the start
    diverged_by_horizon: tuple[int, ...] = ()  # per horizon: windows whose rollout is NaN/inf by then (left out)
    diverged: int = 0  # windows whose rollout went NaN/inf within the longest horizon
    first_diverged: tuple[float, float] | None = None  # (start s, after s) of the earliest window that diverged

    def to_json(self, dt: float) -> dict:
        diverged = self.diverged_by_horizon or (0,) * len(self.horizons)
        out: dict[str, Any] = {
            "start_stride_s": self.stride_s,
            "horizon_s": self.horizon_s,
            "start_points": self.starts,
            "horizons": [
                {"horizon_s": h.horizon_s, "mean_m": finite_or_none(h.mean_m), "p50_m": finite_or_none(h.p50_m),
                 "p95_m": finite_or_none(h.p95_m), "max_m": finite_or_none(h.max_m), "count": h.count,
                 "diverged": int(n)}
                for h, n in zip(self.horizons, diverged)
            ],  # null where no start point has a finite error at that horizon
            "step_s": dt,
            "mean_error_by_step_m": [finite_or_none(x) for x in self.mean_error_by_step_m],
            "diverged_start_points": self.diverged,
            "first_diverged": None if self.first_diverged is None else
            {"start_s": self.first_diverged[0], "after_s": self.first_diverged[1]},
        }
        for h in self.horizons:
            out[f"position_error_after_{h.horizon_s:g}s_m"] = finite_or_none(h.mean_m)
        return out


@dataclass(frozen=True)
class Comparison:
    """Measured and predicted values of one manoeuvre's metrics and their errors (JSON-ready floats)."""

    measured: dict[str, float | None]
    predicted: dict[str, float | None]
    errors: dict[str, float | None]
    notes: tuple[str, ...] = ()

    def to_json(self) -> dict:
        return {"measured": self.measured, "predicted": self.predicted, "errors": self.errors,
                "notes": list(self.notes)}


@dataclass(frozen=True)
class RecordingEvaluation:
    name: str
    source: str
    dt: float
    duration_s: float
    manoeuvre: ManoeuvreKind
    prediction: Prediction
    state_rmse: dict[str, float]
    turning: Comparison | None
    zigzag: Comparison | None
    open_loop: OpenLoop | None
    notes: tuple[str, ...] = ()
    diverged_at_s: float | None = None  # the closed loop's first NaN/inf sample (s from its start); None: it did not

    def diverged_json(self) -> dict | None:
        """Where the closed-loop rollout diverged: time, duration and manoeuvre; None when it did not."""
        if self.diverged_at_s is None:
            return None
        return {"at_s": self.diverged_at_s, "duration_s": float(self.prediction.t_s[-1]),
                "manoeuvre": self.manoeuvre.label()}

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "source": self.source,
            "dt_s": self.dt,
            "duration_s": self.duration_s,
            "manoeuvre": self.manoeuvre.to_json(),
            "manoeuvre_label": self.manoeuvre.label(),
            "closed_loop_rmse": {key: finite_or_none(value) for key, value in self.state_rmse.items()},
            "turning": None if self.turning is None else self.turning.to_json(),
            "zigzag": None if self.zigzag is None else self.zigzag.to_json(),
            "open_loop": None if self.open_loop is None else self.open_loop.to_json(self.dt),
            "diverged": self.diverged_json(),
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class EvaluationResult:
    model: dict[str, Any]
    reference: str
    recordings: tuple[RecordingEvaluation, ...]
    summary: dict[str, float | None]
    horizons_s: tuple[float, ...] = DEFAULT_HORIZONS_S
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {
            "model": self.model,
            "reference": self.reference,
            "open_loop_horizons_s": list(self.horizons_s),
            "recordings": [r.to_json() for r in self.recordings],
            "summary": self.summary,
            **self.extra,
        }


# --------------------------------------------------------------------------------------------
# Model plumbing
# --------------------------------------------------------------------------------------------
def rollout(model: Predictor, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None
            ) -> np.ndarray:
    """model.predict with its shapes checked: (B, 4), (B, H, 2) -> (E, B, H, 6). reference (4,): the approach
    state of the recording (held_reference), given to a model that accepts one."""
    state = np.asarray(state, dtype=float)
    controls = np.asarray(controls, dtype=float)
    if reference is not None and getattr(model, "accepts_reference", False):
        references = np.repeat(np.asarray(reference, dtype=float)[None, :], state.shape[0], axis=0)  # (B, 4)
        out = np.asarray(model.predict(state, controls, reference=references), dtype=float)
    else:
        out = np.asarray(model.predict(state, controls), dtype=float)
    expected = (state.shape[0], controls.shape[1], 6)
    if out.ndim != 4 or out.shape[1:] != expected:
        raise ModelError(f"model.predict returned shape {out.shape}, expected (E, {expected[0]}, {expected[1]}, 6)")
    return out


def held_reference(recording: Recording, series: np.ndarray) -> np.ndarray | None:
    """(4,) the approach state [u, v, r, psi] of the recording's reference `series` (T, 6) for a layout that reports
    no propulsion (rudder_only: the straight running whose engine speed its grey box holds); None for the others
    (and when the approach has no finite sample). data.recording.held_reference of the series."""
    return recording_held_reference(recording, series[:, [U, V, R]], series[:, PSI])


@dataclass(frozen=True)
class ReferenceTracks:
    """What a prediction is compared against and what it starts from, both (T, 6) [u, v, r, x_n, y_e, psi]."""

    measured: np.ndarray  # (T, 6) the reference the errors are taken against
    start: np.ndarray  # (T, 6) the states (and positions) a rollout starts from: only what was known at that time


def reference_tracks(recording: Recording, reference: str) -> ReferenceTracks:
    """The reference's tracks: gnss and truth start from what they compare against; smoothed compares against the
    RTS-smoothed measurements and starts from the raw measured ones (the smoother looks ahead)."""
    series = reference_series(recording, reference)
    if reference == "smoothed":
        return ReferenceTracks(series, reference_series(recording, "gnss"))
    return ReferenceTracks(series, series)


def reference_series(recording: Recording, reference: str) -> np.ndarray:
    """(T, 6) [u, v, r, x_n, y_e, psi] of the reference: measured + GNSS, the same smoothed (data.smoother: EKF + RTS,
    its noise tuned by likelihood), or ground truth."""
    if reference == "gnss":
        return np.column_stack([recording.nu, recording.position, recording.psi])
    if reference == "smoothed":
        from usv_predictor.data.smoother import smooth_recording

        try:
            smoothed = smooth_recording(recording).state  # (T, 9) [x_n, y_e, psi, u, v, r, u_dot, v_dot, r_dot]
        except DatasetError as err:
            raise EvaluationError(f"{recording.source or recording.name}: the smoothed reference: {err}") from err
        return np.column_stack([smoothed[:, 3:6], smoothed[:, 0:2], np.unwrap(smoothed[:, 2])])
    if reference == "truth":
        if recording.truth is None:
            raise EvaluationError(f"{recording.source or recording.name}: no ground truth (simulated bags carry "
                                  "it on ground_truth/odometry); use --reference gnss")
        x_n, y_e, psi, u, v, r = recording.truth.T
        return np.column_stack([u, v, r, x_n, y_e, np.unwrap(psi)])
    raise EvaluationError(f"reference must be one of {REFERENCES}, got {reference!r}")


# --------------------------------------------------------------------------------------------
# Closed loop (seed 000 Fig. 3) and open loop
# --------------------------------------------------------------------------------------------
def closed_loop(model: Predictor, recording: Recording, reference: str = "gnss",
                tracks: ReferenceTracks | None = None) -> Prediction:
    """Roll the model out over the whole recording from its first state with the recorded controls.

    Starts at the first sample with a position (GNSS may start late) so the predicted track can be placed at the
    start. tracks: reference_tracks(recording, reference) when the caller has them (the smoother is not cheap).
    """
    check_dt(model, recording.dt, f"recording {recording.name}")
    tracks = tracks or reference_tracks(recording, reference)
    measured, starts = tracks.measured, tracks.start
    held = held_reference(recording, starts)
    finite = np.flatnonzero(np.isfinite(starts[:, X_N]) & np.isfinite(starts[:, Y_E]))
    if len(finite) == 0:
        raise EvaluationError(f"{recording.source or recording.name}: no position fix ({reference}); "
                              "the closed-loop track needs a reference track")
    first = int(finite[0])
    measured = measured[first:]
    if len(measured) < 2:
        raise EvaluationError(f"{recording.name}: fewer than 2 samples after the first position fix")
    controls = recording.controls[first:]
    start = starts[first, [U, V, R, PSI]]
    out = rollout(model, start[None, :], controls[None, :-1], held)[:, 0]  # (E, T - 1, 6)
    out[..., X_N] += starts[first, X_N]
    out[..., Y_E] += starts[first, Y_E]
    mean = np.vstack([starts[first:first + 1], out.mean(axis=0)])
    std = np.vstack([np.zeros((1, 6)), out.std(axis=0)])
    return Prediction(name=recording.name, reference=reference, t_s=recording.t_s[first:] - recording.t_s[first],
                      controls=controls, measured=measured, predicted=mean, predicted_std=std, layout=recording.layout)


def open_loop(model: Predictor, recording: Recording, reference: str = "gnss",
              horizons_s: Sequence[float] = DEFAULT_HORIZONS_S, stride_s: float = 5.0,
              tracks: ReferenceTracks | None = None) -> OpenLoop | None:
    """Position errors of rollouts started every `stride_s` at the horizons that fit in the recording.

    None when the recording is shorter than the shortest horizon plus one step.
    """
    check_dt(model, recording.dt, f"recording {recording.name}")
    tracks = tracks or reference_tracks(recording, reference)
    return windowed_open_loop(recording, tracks, horizons_s, stride_s,
                              lambda starts, states, controls, held: rollout(model, states, controls, held))


WindowRollout = Callable[[np.ndarray, np.ndarray, np.ndarray, "np.ndarray | None"], np.ndarray]
"""predict(starts (B,) sample indices, states (B, 4) [u, v, r, psi], controls (B, H, C), held (4,) | None: the
held reference of every window, held_reference) -> (E, B, H, 6)."""


def windowed_open_loop(recording: Recording, tracks: ReferenceTracks, horizons_s: Sequence[float], stride_s: float,
                       predict: WindowRollout) -> OpenLoop | None:
    """The open-loop windows of a recording and their position errors: one rollout of the longest horizon that fits
    from every `stride_s` (from each sample whose start track has a position), each placed at its start position and
    compared with the measured track (k + 1) dt after the start. `predict` rolls all windows out in one batch
    (open_loop: the model as it is; analysis.adaptive: with the live estimate of each start), given the held
    reference of the start track (held_reference: a rudder_only layout's approach, whose engine speed every rollout
    holds; None for the others). None when no horizon fits or no start has a position."""
    dt = recording.dt
    measured, begin = tracks.measured, tracks.start
    fitting = [h for h in horizons_s if h / dt <= len(recording) - 0.5]  # round(h / dt) <= T - 1, for any h
    if not fitting:
        return None
    for h in fitting:
        whole_steps(h, dt, "open-loop horizon")
    steps = whole_steps(max(fitting), dt, "open-loop horizon")
    stride = whole_steps(min(stride_s, len(recording) * dt), dt, "--stride")  # longer than the recording: one start
    starts = np.arange(0, len(recording) - steps, stride)
    starts = starts[np.isfinite(begin[starts, X_N]) & np.isfinite(begin[starts, Y_E])]
    if len(starts) == 0:
        return None
    window = starts[:, None] + np.arange(steps)[None, :]  # (B, H) control indices
    out = predict(starts, begin[starts][:, [U, V, R, PSI]], recording.controls[window],
                  held_reference(recording, begin))  # (E, B, H, 6)
    predicted_xy = out.mean(axis=0)[..., [X_N, Y_E]] + begin[starts][:, None, [X_N, Y_E]]  # (B, H, 2)
    measured_xy = measured[window + 1][..., [X_N, Y_E]]
    errors = np.hypot(*(predicted_xy - measured_xy).transpose(2, 0, 1))  # (B, H)
    known = np.isfinite(errors)
    counts = known.sum(axis=0)
    by_step = np.where(counts > 0, np.where(known, errors, 0.0).sum(axis=0) / np.maximum(counts, 1), np.nan)
    first_bad = first_non_finite(out)  # (B,) step of each window's first NaN/inf, steps when none
    went = np.flatnonzero(first_bad < steps)
    earliest = None
    if len(went):
        k = int(went[np.argmin(recording.t_s[starts[went]] + first_bad[went] * dt)])
        earliest = (float(recording.t_s[starts[k]] - recording.t_s[0]), float((first_bad[k] + 1) * dt))
    return OpenLoop(stride_s=stride * dt, horizon_s=steps * dt, starts=int(len(starts)),
                    horizons=metrics.open_loop_errors(predicted_xy, measured_xy, fitting, dt),
                    mean_error_by_step_m=by_step,
                    diverged_by_horizon=tuple(int((first_bad < round(h / dt)).sum()) for h in fitting),
                    diverged=int(len(went)), first_diverged=earliest)


def first_non_finite(out: np.ndarray) -> np.ndarray:
    """(B,) the first step at which a rollout (E, B, H, 6) holds NaN/inf in any member or column; H where none."""
    bad = ~np.isfinite(out).all(axis=(0, 3))  # (B, H)
    return np.where(bad.any(axis=1), bad.argmax(axis=1), out.shape[2])


# --------------------------------------------------------------------------------------------
# What manoeuvre is it (from the controls only)
# --------------------------------------------------------------------------------------------
# A turn is a held turn command of the vessel's actuator layout (physics/actuators.py): a rudder angle, or a
# thrust difference; "straight" and "held" thresholds are the layout's (straight_below, hold_tolerance).
RPM_STEADY_FRACTION = 0.03  # propulsion steady: 5-95 % spread within 3 % of its median
HELD_FRACTION = 0.9  # a steady turn command holds its value for this share of the time after execute


def _side_states(delta: np.ndarray, threshold: float) -> np.ndarray:
    """+1 / -1 once past +-threshold, kept until the other side is reached (hysteresis); 0 before."""
    side = np.where(delta >= threshold, 1, np.where(delta <= -threshold, -1, 0))
    last = np.maximum.accumulate(np.where(side != 0, np.arange(len(side)), -1))
    return np.where(last >= 0, side[np.maximum(last, 0)], 0)


def _stated(command: CommandInput | None, fallback_unit: str, fallback_name: str) -> tuple[float, str, str]:
    """(factor from the layout's steering/propulsion unit to the stated unit, the unit, a name for labels)."""
    if command is None:
        return 1.0, fallback_unit, fallback_name
    return 1.0 / command.to_command, command.unit, command.option.lstrip("-")


def classify(recording: Recording) -> ManoeuvreKind:
    """turning circle (one steady turn command), zig-zag (reversals of one amplitude) or other, from the controls.

    delta below is the layout's turn command (the rudder angle of rudder_propeller, the thrust difference port -
    starboard of twin thrusters), rpm its propulsion level; both are reported in the units the layout states them
    in (deg for a rudder angle, the normalised differential as it is).
    """
    layout = recording.actuator_layout
    turn_factor, turn_unit, turn_name = _stated(layout.turn_input, "-", "turn")
    power_factor, power_unit, power_name = _stated(layout.propulsion_input, "-", "propulsion")
    delta, rpm = layout.steering_signal(recording.controls), layout.propulsion_signal(recording.controls)
    rpm_median = float(np.median(rpm)) * power_factor if layout.propulsion else float("nan")

    def kind_of(kind: str, side: str, turn: float, t_execute: float) -> ManoeuvreKind:
        return ManoeuvreKind(kind, side, turn * turn_factor, rpm_median, t_execute, turn_unit, power_unit, turn_name,
                             power_name)

    amplitude = float(np.percentile(np.abs(delta), 95.0))
    if amplitude < layout.straight_below:
        return kind_of("other", "", float("nan"), float("nan"))
    moved = np.flatnonzero(np.abs(delta) >= 0.1 * amplitude)
    execute = int(moved[0])
    after = slice(execute, None)
    spread = np.percentile(rpm[after], 95.0) - np.percentile(rpm[after], 5.0)
    rpm_steady = spread <= RPM_STEADY_FRACTION * max(abs(float(np.median(rpm))), 1.0)
    states = _side_states(delta, 0.5 * amplitude)
    first_side = int(states[np.flatnonzero(states)[0]])
    side = "starboard" if first_side > 0 else "port"
    changes = np.flatnonzero(np.diff(states[states != 0]) != 0)
    held = np.abs(delta[after])
    tolerance = max(layout.hold_tolerance, 0.15 * amplitude)
    t_execute = float(recording.t_s[execute])
    if len(changes) == 0:
        steady = np.mean(np.abs(held - np.median(held)) <= tolerance) >= HELD_FRACTION
        kind = "turning_circle" if steady and rpm_steady else "other"
        return kind_of(kind, side, float(np.median(held)), t_execute)
    # Zig-zag: every side segment holds about the same |turn command| (a spiral or random run does not).
    bounds = np.flatnonzero(np.diff(states) != 0) + 1
    segments = np.split(delta, bounds)
    holds = [float(np.median(np.abs(s[np.abs(s) >= 0.75 * np.percentile(np.abs(s), 95.0)])))
             for s, st in zip(segments, np.split(states, bounds)) if st[0] != 0 and len(s) >= 3]
    same = bool(holds) and max(holds) - min(holds) <= tolerance
    kind = "zigzag" if same and rpm_steady else "other"
    return kind_of(kind, side, float(np.median(holds)) if holds else float("nan"), t_execute)


# --------------------------------------------------------------------------------------------
# Manoeuvre metrics
# --------------------------------------------------------------------------------------------
def _finite_track(series: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, ...]:
    """t, x_n, y_e, psi where the position is known (GNSS drop-outs are left out)."""
    keep = np.isfinite(series[:, X_N]) & np.isfinite(series[:, Y_E]) & np.isfinite(series[:, PSI])
    return t_s[keep], series[keep, X_N], series[keep, Y_E], series[keep, PSI]


def _attempt(notes: list[str], what: str, fn: Callable[[], Any]) -> Any:
    """fn() or None with a note: one failing metric (a track that does not turn 720 deg) must not hide the rest."""
    try:
        return fn()
    except ValueError as err:
        notes.append(f"{what}: {err}")
        return None


def turning_metrics(t_s: np.ndarray, series: np.ndarray, execute_time_s: float, drift_axis_deg: float | None,
                    notes: list[str], what: str) -> dict[str, float | None]:
    """Seed 000 eq. 27-29, the steady circle fit and IMO criteria of one track (None where undefined)."""
    t_all, x_all, y_all, psi_all = _finite_track(series, t_s)
    # Eq. 27-29 count heading change from the execute: the straight approach would widen eq. 29's first circle.
    turn = t_all >= execute_time_s if math.isfinite(execute_time_s) else np.ones(len(t_all), dtype=bool)
    t, x_n, y_e, psi = t_all[turn], x_all[turn], y_all[turn], psi_all[turn]
    drift = _attempt(notes, f"{what} drift (eq. 27, 28)", lambda: metrics.drift(t, x_n, y_e, psi))
    axis = drift_axis_deg if drift_axis_deg is not None else (drift.direction_deg if drift else None)
    radius = None
    if axis is None or math.isfinite(axis):  # None: no eq. 27 drift; a 360-720 deg track uses its first circle
        radius = _attempt(notes, f"{what} turning radius (eq. 29)",
                          lambda: metrics.turning_radius(t, x_n, y_e, psi, drift_direction_deg=axis))
        if radius is not None and radius.note:
            notes.append(f"{what} turning radius (eq. 29): {radius.note}")
    steady = _attempt(notes, f"{what} steady circle fit", lambda: metrics.steady_turning_radius(t, x_n, y_e, psi))
    imo = None
    if math.isfinite(execute_time_s):
        imo = _attempt(notes, f"{what} IMO criteria",
                       lambda: metrics.turning_circle_criteria(t_all, x_all, y_all, psi_all,
                                                               max(execute_time_s, float(t_all[0]))))
    return {
        "turning_radius_m": radius.radius_m if radius else None,
        "steady_turning_radius_m": steady.radius_m if steady else None,
        "drift_distance_m": drift.distance_m if drift else None,
        "drift_direction_deg": drift.direction_deg if drift else None,
        "drift_angle_seed_eq28_deg": metrics.seed_drift_angle_deg(drift.direction_deg) if drift else None,
        "drift_speed_mps": drift.speed_mps if drift else None,
        "advance_m": imo.advance_m if imo else None,
        "transfer_m": imo.transfer_m if imo else None,
        "tactical_diameter_m": imo.tactical_diameter_m if imo else None,
    }


def relative_error_pct(predicted: float | None, measured: float | None) -> float | None:
    """100 (predicted - measured) / measured; None when either is missing or measured is 0."""
    if predicted is None or measured is None or measured == 0.0 or not math.isfinite(predicted + measured):
        return None
    return 100.0 * (predicted - measured) / measured


def angle_error_deg(predicted: float | None, measured: float | None) -> float | None:
    """predicted - measured wrapped to [-180, 180) deg; None when either is missing."""
    if predicted is None or measured is None or not math.isfinite(predicted + measured):
        return None
    return float(angle_difference_deg(predicted, measured))


def compare_turning(prediction: Prediction, execute_time_s: float) -> Comparison:
    """Turning-circle metrics of the measured and predicted tracks; eq. 29 uses the measured drift axis
    for both (seed 000 Fig. 11: the x axis is along the drift of the real track)."""
    notes: list[str] = []
    measured = turning_metrics(prediction.t_s, prediction.measured, execute_time_s, None, notes, "measured")
    axis = measured["drift_direction_deg"]
    predicted = turning_metrics(prediction.t_s, prediction.predicted, execute_time_s, axis, notes, "predicted")
    for what, values in (("measured", measured), ("predicted", predicted)):
        distance = values["drift_distance_m"]
        if distance is not None and distance < DRIFT_DIRECTION_MIN_M:
            # the direction of a drift of a few centimetres is noise: keep the number, say so
            notes.append(f"{what} drift distance {distance:.2f} m is under {DRIFT_DIRECTION_MIN_M:g} m: "
                         "its direction is not meaningful")
    errors = {
        "turning_radius_rel_pct": relative_error_pct(predicted["turning_radius_m"], measured["turning_radius_m"]),
        "steady_turning_radius_rel_pct": relative_error_pct(predicted["steady_turning_radius_m"],
                                                            measured["steady_turning_radius_m"]),
        "drift_distance_rel_pct": relative_error_pct(predicted["drift_distance_m"], measured["drift_distance_m"]),
        "drift_direction_abs_deg": angle_error_deg(predicted["drift_direction_deg"], measured["drift_direction_deg"]),
        "advance_rel_pct": relative_error_pct(predicted["advance_m"], measured["advance_m"]),
        "transfer_rel_pct": relative_error_pct(predicted["transfer_m"], measured["transfer_m"]),
        "tactical_diameter_rel_pct": relative_error_pct(predicted["tactical_diameter_m"],
                                                        measured["tactical_diameter_m"]),
    }
    return Comparison(measured, predicted, errors, tuple(notes))


def compare_zigzag(prediction: Prediction) -> Comparison:
    """First and second overshoot angles (ITTC) of the measured and predicted headings."""
    notes: list[str] = []
    values = {}
    for what, series in (("measured", prediction.measured), ("predicted", prediction.predicted)):
        zz = _attempt(notes, f"{what} zig-zag", lambda s=series: metrics.zigzag_overshoots(
            prediction.t_s, s[:, PSI], prediction.steering))
        values[what] = {
            "first_overshoot_deg": _finite_or_none(zz.first_overshoot_deg) if zz else None,
            "second_overshoot_deg": _finite_or_none(zz.second_overshoot_deg) if zz else None,
        }
    errors = {
        f"{key.removesuffix('_deg')}_abs_deg": (
            None if values["predicted"][key] is None or values["measured"][key] is None
            else values["predicted"][key] - values["measured"][key]
        )
        for key in ("first_overshoot_deg", "second_overshoot_deg")
    }
    return Comparison(values["measured"], values["predicted"], errors, tuple(notes))


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def state_rmse(prediction: Prediction) -> dict[str, float]:
    """Closed-loop RMSE of u, v (m/s), r (deg/s), psi (deg) and position (m) over the whole recording."""
    m, p = prediction.measured, prediction.predicted
    rm = metrics.rmse(p[:, [U, V, R, PSI]], m[:, [U, V, R, PSI]], angle_columns=(3,))
    keep = np.isfinite(m[:, X_N]) & np.isfinite(m[:, Y_E])
    position = metrics.position_error(p[keep, X_N], p[keep, Y_E], m[keep, X_N], m[keep, Y_E])
    return {
        "u_mps": float(rm[0]),
        "v_mps": float(rm[1]),
        "r_deg_s": math.degrees(float(rm[2])),
        "psi_deg": math.degrees(float(rm[3])),
        "position_m": float(np.sqrt(np.mean(position**2))) if len(position) else float("nan"),
        "final_position_error_m": float(position[-1]) if len(position) else float("nan"),
    }


# --------------------------------------------------------------------------------------------
# Evaluate a set of recordings
# --------------------------------------------------------------------------------------------
def evaluate_recording(model: Predictor, recording: Recording, reference: str = "gnss",
                       horizons_s: Sequence[float] = DEFAULT_HORIZONS_S, stride_s: float = 5.0,
                       tracks: ReferenceTracks | None = None) -> RecordingEvaluation:
    """Closed loop, manoeuvre metrics and open loop of one recording (tracks: reference_tracks, when the caller has
    them: several models on one recording smooth it once)."""
    kind = classify(recording)
    tracks = tracks or reference_tracks(recording, reference)
    prediction = closed_loop(model, recording, reference, tracks)
    notes: list[str] = []
    first = len(recording) - len(prediction.t_s)  # the rollout starts at the first position fix
    execute = kind.execute_time_s - float(recording.t_s[first])
    turning = compare_turning(prediction, execute) if kind.kind == "turning_circle" else None
    zigzag = compare_zigzag(prediction) if kind.kind == "zigzag" else None
    rmse = state_rmse(prediction)
    diverged_at = closed_loop_divergence(prediction)
    if diverged_at is not None:  # metrics of the part before it would read as a model that fits
        why = (f"closed loop: the model's rollout diverged (NaN/inf) at {diverged_at:.1f} s of "
               f"{float(prediction.t_s[-1]):.1f} s ({kind.label()}): its RMSEs and predicted manoeuvre metrics are "
               "undefined")
        notes.append(why)
        rmse = {key: math.nan for key in rmse}
        turning = None if turning is None else undefined_prediction(turning, why)
        zigzag = None if zigzag is None else undefined_prediction(zigzag, why)
    loop = open_loop(model, recording, reference, horizons_s, stride_s, tracks)
    if loop is None:
        notes.append(f"open loop: recording of {recording.duration_s:.1f} s is shorter than the shortest horizon "
                     f"{min(horizons_s):g} s")
    elif len(loop.horizons) < len(horizons_s):
        notes.append(f"open loop: horizons beyond {loop.horizon_s:g} s do not fit in {recording.duration_s:.1f} s")
    if loop is not None and loop.first_diverged is not None:
        start_s, after_s = loop.first_diverged
        notes.append(f"open loop: {loop.diverged} of {loop.starts} rollouts diverged (NaN/inf), the first from "
                     f"{start_s:.1f} s after {after_s:.1f} s ({kind.label()}); each horizon's errors are over the "
                     "others (its `diverged` count)")
    return RecordingEvaluation(
        name=recording.name, source=recording.source, dt=recording.dt, duration_s=recording.duration_s,
        manoeuvre=kind, prediction=prediction, state_rmse=rmse,
        turning=turning, zigzag=zigzag, open_loop=loop, notes=tuple(notes), diverged_at_s=diverged_at,
    )


def closed_loop_divergence(prediction: Prediction) -> float | None:
    """The time (s from the start) of the closed-loop rollout's first NaN/inf sample; None when it stays finite."""
    bad = ~np.isfinite(prediction.predicted).all(axis=1)  # (T,)
    return float(prediction.t_s[int(bad.argmax())]) if bad.any() else None


def undefined_prediction(comparison: Comparison, why: str) -> Comparison:
    """The comparison with the predicted values and the errors undefined (None) and `why` noted: the measured
    values stay (they do not depend on the model)."""
    return Comparison(comparison.measured, {key: None for key in comparison.predicted},
                      {key: None for key in comparison.errors}, (*comparison.notes, why))


def _max_abs(values: Sequence[float | None]) -> float | None:
    known = [abs(v) for v in values if v is not None and math.isfinite(v)]
    return max(known) if known else None


def summarise(evaluations: Sequence[RecordingEvaluation], horizons_s: Sequence[float]) -> dict[str, float | None]:
    """Seed 000's headline numbers (max |errors| over the turning tests) and pooled open-loop errors."""
    turning = [e.turning.errors for e in evaluations if e.turning is not None]
    zigzag = [e.zigzag.errors for e in evaluations if e.zigzag is not None]
    summary: dict[str, float | None] = {
        "recordings": float(len(evaluations)),
        "turning_circles": float(len(turning)),
        "zigzags": float(len(zigzag)),
        "max_abs_turning_radius_rel_error_pct": _max_abs([t["turning_radius_rel_pct"] for t in turning]),
        "max_abs_steady_turning_radius_rel_error_pct": _max_abs([t["steady_turning_radius_rel_pct"] for t in turning]),
        "max_abs_drift_direction_error_deg": _max_abs([t["drift_direction_abs_deg"] for t in turning]),
        "max_abs_drift_distance_rel_error_pct": _max_abs([t["drift_distance_rel_pct"] for t in turning]),
        "max_abs_tactical_diameter_rel_error_pct": _max_abs([t["tactical_diameter_rel_pct"] for t in turning]),
        "max_abs_first_overshoot_error_deg": _max_abs([z["first_overshoot_abs_deg"] for z in zigzag]),
        "mean_rmse_u_mps": _mean([e.state_rmse["u_mps"] for e in evaluations]),
        "mean_rmse_v_mps": _mean([e.state_rmse["v_mps"] for e in evaluations]),
        "mean_rmse_r_deg_s": _mean([e.state_rmse["r_deg_s"] for e in evaluations]),
        "diverged_recordings": float(sum(e.diverged_at_s is not None for e in evaluations)),
        "open_loop_diverged_windows": float(sum(e.open_loop.diverged for e in evaluations if e.open_loop is not None)),
    }
    summary.update(pooled_open_loop([e.open_loop for e in evaluations], horizons_s))
    return summary


def pooled_open_loop(loops: Sequence[OpenLoop | None], horizons_s: Sequence[float]) -> dict[str, float | None]:
    """mean_position_error_after_<h>s_m (m) per horizon: the open-loop errors of several recordings pooled over
    every start point with a finite error (the count-weighted mean of the means), so long recordings weigh more;
    None where no start point has one (summarise, analysis.adaptive.summarise)."""
    out: dict[str, float | None] = {}
    for horizon in horizons_s:
        pairs = [(h.mean_m, h.count) for loop in loops if loop is not None
                 for h in loop.horizons if h.horizon_s == horizon and h.count > 0]
        total = sum(c for _, c in pairs)
        out[f"mean_position_error_after_{horizon:g}s_m"] = sum(m * c for m, c in pairs) / total if total else None
    return out


def _mean(values: Sequence[float]) -> float | None:
    known = [v for v in values if math.isfinite(v)]
    return float(np.mean(known)) if known else None


def model_description(model: Predictor) -> dict[str, Any]:
    """The metadata entries worth reporting: scalars, strings and short lists (not normalisation arrays)."""
    out: dict[str, Any] = {}
    for key, value in dict(model.metadata).items():
        if isinstance(value, (str, int, float, bool)) or value is None:
            out[str(key)] = value
        elif isinstance(value, (list, tuple)) and len(value) <= 16 and all(
                isinstance(v, (str, int, float, bool)) for v in value):
            out[str(key)] = list(value)
    return out


def evaluate(model: Predictor, recordings: Sequence[Recording], reference: str = "gnss",
             horizons_s: Sequence[float] = DEFAULT_HORIZONS_S, stride_s: float = 5.0,
             progress: Callable[[str], None] | None = None) -> EvaluationResult:
    """Closed-loop, manoeuvre and open-loop evaluation of every recording, with the summary."""
    if not recordings:
        raise EvaluationError("no recordings to evaluate")
    if reference not in REFERENCES:
        raise EvaluationError(f"reference must be one of {REFERENCES}, got {reference!r}")
    evaluations = []
    for k, recording in enumerate(recordings):
        if progress is not None:
            progress(f"[{k + 1}/{len(recordings)}] evaluating {recording.name} ({recording.duration_s:.0f} s)")
        evaluations.append(evaluate_recording(model, recording, reference, horizons_s, stride_s))
    return EvaluationResult(model=model_description(model), reference=reference, recordings=tuple(evaluations),
                            summary=summarise(evaluations, horizons_s), horizons_s=tuple(horizons_s))


physics_predictor = loading.physics_predictor  # the calm-water physics baseline (it lives with the models)


# --------------------------------------------------------------------------------------------
# Series for plots (written beside the JSON so `report` can draw from an evaluation file)
# --------------------------------------------------------------------------------------------
def series_arrays(result: EvaluationResult) -> dict[str, np.ndarray]:
    """Flat name -> array mapping for np.savez: rec<k>_<field>."""
    arrays: dict[str, np.ndarray] = {}
    for k, e in enumerate(result.recordings):
        p = e.prediction
        arrays.update({f"rec{k}_t_s": p.t_s, f"rec{k}_controls": p.controls, f"rec{k}_measured": p.measured,
                       f"rec{k}_predicted": p.predicted, f"rec{k}_predicted_std": p.predicted_std})
    return arrays


def predictions_from_arrays(arrays: Mapping[str, np.ndarray], names: Sequence[str], reference: str) -> list[Prediction]:
    """Inverse of series_arrays for recordings named in order; EvaluationError on a missing array."""
    out = []
    for k, name in enumerate(names):
        try:
            prediction = Prediction(name=name, reference=reference, t_s=np.asarray(arrays[f"rec{k}_t_s"]),
                                    controls=np.asarray(arrays[f"rec{k}_controls"]),
                                    measured=np.asarray(arrays[f"rec{k}_measured"]),
                                    predicted=np.asarray(arrays[f"rec{k}_predicted"]),
                                    predicted_std=np.asarray(arrays[f"rec{k}_predicted_std"]))
        except KeyError as err:
            raise EvaluationError(f"series file has no array {err} for recording {name}") from err
        steps = prediction.t_s.shape[0] if prediction.t_s.ndim == 1 else -1
        shapes = {"t_s": (prediction.t_s, (steps,)), "controls": (prediction.controls, None),
                  "measured": (prediction.measured, (steps, 6)), "predicted": (prediction.predicted, (steps, 6)),
                  "predicted_std": (prediction.predicted_std, (steps, 6))}
        for field_name, (array, shape) in shapes.items():
            if array.dtype.kind not in "fiu" or (shape is not None and array.shape != shape) or steps < 1 \
                    or (shape is None and (array.ndim != 2 or array.shape[0] != steps)):
                raise EvaluationError(f"series file: rec{k}_{field_name} of recording {name} has shape {array.shape} "
                                      f"and type {array.dtype}, expected {shape or (steps, 'C')} numbers")
        out.append(prediction)
    return out


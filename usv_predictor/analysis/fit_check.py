"""A fit check before any answer: does a model (a vessel preset, an identified or learned model) describe these bags
at all, where the answer is unambiguous?

Compared, per recording, on every window where the recorded commands are held (physics/actuators.py: the layout's
steering and propulsion signals, whatever the layout: a rudder angle or a thrust difference, an engine speed, a
throttle or a mean thruster command) and the measured motion has settled:

    straight-running speed  measured u (mean over the window's last STEADY_S) against the model's steady u at the
                            window's commands: the model is rolled out from the measured state with the commands
                            held for SETTLE_S and its last STEADY_S averaged (a right model stays where it starts,
                            a wrong one runs to its own equilibrium);
    steady yaw rate         r (and u) at the end of held turns (|r| >= MIN_YAW_RATE), the model rolled out from the
                            turn's start with the recorded commands (the same stage of the turn: a slow ship's
                            zig-zag never reaches its steady turn);
    length scale            the data's Froude number Fn = U / sqrt(g L_pp) on the vessel's length, the model's at the
                            same commands, the Froude scale lambda = (U_measured / U_model)^2 a geometrically similar
                            hull would need (Froude similarity, e.g. ITTC 7.5-02-06-01), and the data's speed against
                            the top speed of the vessel at full propulsion command.

The ratios are medians over windows (predicted / measured). The verdict is `mismatch` when one lies beyond what any
hypothesis of the diagnosis vocabulary can explain (limits below, from the figures measured over the hidden-effect
suite's effects at the top of their ranges, README "Fit check"), `fits` otherwise, `unchecked` without a steady
window and without a vessel to compare the speeds with. `replay evaluate` and `replay diagnose` refuse a mismatch in
one line (FitCheckError, exit 2) naming the numbers and the remedy, unless told --no-fit-check.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from usv_predictor.analysis.evaluation import Predictor, held_reference, rollout
from usv_predictor.data.recording import Recording
from usv_predictor.errors import FitCheckError
from usv_predictor.physics.actuators import ActuatorLayout, actuator_layout
from usv_predictor.physics.vessel import Vessel

G = 9.80665  # (m/s^2) standard gravity
SETTLE_S = 120.0  # (s) how long the model runs at the held commands to reach its own steady state
STEADY_S = 10.0  # (s) the settled part of a window (measured) and of the rollout (predicted) that is averaged
MIN_HOLD_S = 5.0  # (s) shortest window of held commands that is compared
MIN_SPEED = 0.2  # (m/s) slower windows say nothing about the speed ratio
MIN_YAW_RATE = math.radians(0.5)  # (rad/s) weaker turns say nothing about the yaw-rate ratio
PROPULSION_HOLD = 0.03  # (-) a held propulsion command varies by less than this share of its level ...
PROPULSION_HOLD_ABS = 0.02  # ... plus this, in its unit (rpm, -)
SETTLED_SPEED = 0.05  # (-) measured u has settled when its two half-means over STEADY_S differ by < this share ...
SETTLED_SPEED_ABS = 0.05  # ... plus this (m/s)
SETTLED_YAW = 0.15  # (-) and r when they differ by < this share ...
SETTLED_YAW_ABS = math.radians(0.5)  # ... plus this (rad/s)
SPEED_RATIO_LIMIT = 1.5  # (-) predicted / measured speed beyond [1/1.5, 1.5]: no environmental cause explains it
YAW_RATE_RATIO_LIMIT = 2.0  # (-) predicted / measured steady yaw rate beyond [1/2, 2] (or of opposite sign)
TOP_SPEED_LIMIT = 1.5  # (-) the data runs faster than this times the vessel's top speed at full command
REMEDY = "identify this boat first (docs/your_boat.md)"


@dataclass(frozen=True)
class SteadyWindow:
    """One window of held commands with settled measured motion, and the model's steady state for it."""

    recording: str
    kind: str  # "straight" | "turn" (|steering| below / above the layout's straight_below)
    start_s: float
    end_s: float
    steering: float  # held turn command (the layout's steering unit: rad of rudder, thrust difference)
    propulsion: float  # held propulsion command (rpm, throttle, mean thruster command)
    measured_speed_mps: float
    predicted_speed_mps: float
    measured_yaw_rate_rad_s: float
    predicted_yaw_rate_rad_s: float

    def to_json(self) -> dict[str, Any]:
        return {"recording": self.recording, "kind": self.kind, "start_s": self.start_s, "end_s": self.end_s,
                "steering": self.steering, "propulsion": self.propulsion,
                "measured_speed_mps": self.measured_speed_mps, "predicted_speed_mps": self.predicted_speed_mps,
                "measured_yaw_rate_deg_s": math.degrees(self.measured_yaw_rate_rad_s),
                "predicted_yaw_rate_deg_s": math.degrees(self.predicted_yaw_rate_rad_s)}


@dataclass(frozen=True)
class FitCheck:
    """What the model predicts against what the bags measure where the answer is unambiguous (module docstring)."""

    model: str  # how the line names the model: "the preset jari_usv", "model 1a2b (dnn)"
    layout: str
    windows: tuple[SteadyWindow, ...]
    speed_ratio: float | None  # median predicted / measured speed (straight windows, else turns); None: none
    speed_windows: str  # "straight" | "turn" | "" : which windows the speed ratio comes from
    yaw_rate_ratio: float | None  # median predicted / measured steady yaw rate in turns; None: no turn
    length_m: float | None  # the vessel's L_pp (None: no vessel known)
    froude_measured: float | None  # median measured speed / sqrt(g L) of the speed windows
    froude_model: float | None  # the same for the model's speeds at the same commands
    froude_scale: float | None  # (U_measured / U_model)^2: the length ratio of a Froude-similar hull
    top_speed_mps: float | None  # the vessel's straight speed at full propulsion command
    data_speed_mps: float | None  # the 90th percentile of the measured |u| over all recordings
    verdict: str  # "fits" | "mismatch" | "unchecked"
    reasons: tuple[str, ...]  # what lies beyond the limits (verdict mismatch), one clause each

    @property
    def mismatch(self) -> bool:
        return self.verdict == "mismatch"

    def refusal(self, option: str = "--no-fit-check") -> str:
        """The one line a command refuses with."""
        return (f"{self.model} does not fit these bags: {'; '.join(self.reasons)} — beyond what any current, wind, "
                f"waves or sensor/actuator fault explains: {REMEDY}, or pass {option} to proceed anyway")

    def summary(self) -> str:
        parts = []
        if self.speed_ratio is not None:
            parts.append(f"speed ratio {self.speed_ratio:.2f} ({self.speed_windows} runs)")
        if self.yaw_rate_ratio is not None:
            parts.append(f"yaw-rate ratio {self.yaw_rate_ratio:.2f}")
        if self.froude_measured is not None:
            parts.append(f"Fn data {self.froude_measured:.3f} vs model {self.froude_model:.3f}")
        return f"fit check {self.verdict}: " + (", ".join(parts) or "no steady window") + \
            (f" ({'; '.join(self.reasons)})" if self.reasons else "")

    def to_json(self) -> dict[str, Any]:
        return {"verdict": self.verdict, "model": self.model, "actuator_layout": self.layout,
                "reasons": list(self.reasons), "speed_ratio": self.speed_ratio, "speed_windows": self.speed_windows,
                "yaw_rate_ratio": self.yaw_rate_ratio, "length_m": self.length_m,
                "froude_measured": self.froude_measured, "froude_model": self.froude_model,
                "froude_scale": self.froude_scale, "top_speed_mps": self.top_speed_mps,
                "data_speed_mps": self.data_speed_mps,
                "limits": {"speed_ratio": SPEED_RATIO_LIMIT, "yaw_rate_ratio": YAW_RATE_RATIO_LIMIT,
                           "top_speed": TOP_SPEED_LIMIT},
                "windows": [w.to_json() for w in self.windows]}


def held_windows(recording: Recording, layout: ActuatorLayout) -> list[tuple[int, int]]:
    """[(first, last + 1)] sample ranges where the turn and propulsion commands are held (at least MIN_HOLD_S)."""
    steering = layout.steering_signal(recording.controls)  # (T,)
    propulsion = layout.propulsion_signal(recording.controls)  # (T,)
    minimum = max(int(round(MIN_HOLD_S / recording.dt)), 2)
    windows, start = [], 0
    for k in range(1, len(recording) + 1):
        if k < len(recording):
            s0, p0 = np.median(steering[start:k]), np.median(propulsion[start:k])
            held = (abs(steering[k] - s0) <= layout.hold_tolerance
                    and abs(propulsion[k] - p0) <= PROPULSION_HOLD * abs(p0) + PROPULSION_HOLD_ABS)
            if held and np.isfinite(steering[k]) and np.isfinite(propulsion[k]):
                continue
        if k - start >= minimum:
            windows.append((start, k))
        start = k
    return windows


def _settled(values: np.ndarray, share: float, floor: float) -> bool:
    """The two half-means of `values` differ by less than share * |mean| + floor (and all are finite)."""
    if len(values) < 2 or not np.all(np.isfinite(values)):
        return False
    half = len(values) // 2
    return abs(values[:half].mean() - values[half:].mean()) <= share * abs(values.mean()) + floor


def steady_windows(predictor: Predictor, recordings: Sequence[Recording], layout: ActuatorLayout) -> list[SteadyWindow]:
    """Every window of held commands whose measured u and r have settled, with the model's u and r for it.

    Straight windows: the model starts from the settled measured state and runs SETTLE_S at the held commands (its
    own straight-running equilibrium). Turns: the model starts where the commands were first held and runs with the
    recorded commands to the window's end, so a turn that has not reached its steady state in the data (a zig-zag
    of a slow ship) is compared with the same stage of the model's turn, never with the model's steady turn.
    """
    dt = recordings[0].dt if recordings else 1.0
    settle_n = max(int(round(SETTLE_S / dt)), 2)
    steady_n = max(int(round(STEADY_S / dt)), 2)
    windows = []
    for rec in recordings:
        # rudder_only: the engine speed of the manoeuvre's approach, held in every rollout (evaluation.held_reference)
        held_state = held_reference(rec, np.column_stack([rec.nu, rec.position, rec.psi]))
        for first, end in held_windows(rec, layout):
            last = rec.nu[max(first, end - steady_n):end]  # (n, 3)
            if not (_settled(last[:, 0], SETTLED_SPEED, SETTLED_SPEED_ABS)
                    and _settled(last[:, 2], SETTLED_YAW, SETTLED_YAW_ABS)):
                continue
            held = rec.controls[first:end].mean(axis=0)  # (C,)
            steering = float(layout.steering_signal(held))
            straight = abs(steering) < layout.straight_below
            # a rudder_only model that takes no reference state holds the engine speed of the speed it starts from:
            # it starts where the commands were first held, as in a turn
            k = max(first, end - steady_n) if straight and layout.propulsion else first
            state = np.array([[*rec.nu[k], rec.psi[k]]])  # (1, 4)
            if straight:
                controls = np.repeat(held[None, None, :], max(settle_n, end - k), axis=1)  # (1, H, C)
            else:
                controls = rec.controls[None, k:end]  # (1, H, C) the recorded commands
            predicted = rollout(predictor, state, controls, held_state).mean(axis=0)  # (B, H, 6)
            predicted = predicted[0, -min(steady_n, controls.shape[1]):]
            measured = last.mean(axis=0)  # (3,)
            windows.append(SteadyWindow(
                rec.name, "straight" if straight else "turn", float(rec.t_s[first]), float(rec.t_s[end - 1]),
                steering, float(layout.propulsion_signal(held)), float(measured[0]), float(predicted[:, 0].mean()),
                float(measured[2]), float(predicted[:, 2].mean())))
    return windows


def _top_speed(vessel: Vessel) -> float | None:
    """Straight-running speed through the water at the largest propulsion command of the vessel (m/s)."""
    from usv_predictor.physics.dynamics import ManoeuvringModel

    layout = vessel.actuator_layout
    if layout.propulsion_input is None or layout.command_map is None:
        return None
    high = layout.propulsion_input.limits(vessel)[1] * layout.propulsion_input.to_command
    return float(ManoeuvringModel(vessel).straight_speed(high))


def _propulsion_text(layout: ActuatorLayout, value: float) -> str:
    command = layout.propulsion_input
    if command is None or not layout.propulsion:
        return "its held engine speed"
    if command.unit == "rpm":
        return f"{value / command.to_command:.0f} rpm"
    return f"{command.option.lstrip('-')} {value / command.to_command:.2f}"


def _median_window(windows: Sequence[SteadyWindow], ratio) -> SteadyWindow:
    """The window whose ratio is the median's (the one the refusal line quotes)."""
    values = np.array([ratio(w) for w in windows])
    return windows[int(np.argsort(values)[len(values) // 2])]


def check_fit(predictor: Predictor, recordings: Sequence[Recording], *, vessel: Vessel | None = None,
              label: str | None = None) -> FitCheck:
    """The fit check of `predictor` on `recordings` (module docstring); `vessel` (when known) gives the length and
    top speed, `label` how the refusal names the model (default from the predictor's metadata)."""
    meta = dict(predictor.metadata)
    layout = actuator_layout(str(meta.get("actuator_layout") or (recordings[0].layout if recordings else "")))
    label = label or f"model {meta.get('model_id', '?')} ({meta.get('model_type', '?')})"
    windows = steady_windows(predictor, recordings, layout) if recordings else []
    reasons: list[str] = []
    diverged = [w for w in windows if not (math.isfinite(w.predicted_speed_mps)
                                           and math.isfinite(w.predicted_yaw_rate_rad_s))]
    if diverged:
        reasons.append(f"its prediction is not finite at the held commands of {len(diverged)} of {len(windows)} "
                       f"steady window(s) (first: {diverged[0].recording} at {diverged[0].start_s:.0f} s)")
        windows = [w for w in windows if w not in diverged]

    usable = [w for w in windows if w.measured_speed_mps >= MIN_SPEED]
    straight = [w for w in usable if w.kind == "straight"]
    speed_set, speed_kind = (straight, "straight") if straight else (usable, "turn" if usable else "")
    if not layout.propulsion:  # rudder_only: the engine speed is the model's own; straight running from the
        # approach speed holds that speed in a right model (a grey box by construction), turns say nothing of it
        speed_set, speed_kind = (straight, "straight") if straight else ([], "")
    speed_ratio = None
    if speed_set:
        speed_ratio = float(np.median([w.predicted_speed_mps / w.measured_speed_mps for w in speed_set]))
        if not (1.0 / SPEED_RATIO_LIMIT <= speed_ratio <= SPEED_RATIO_LIMIT):
            w = _median_window(speed_set, lambda w: w.predicted_speed_mps / w.measured_speed_mps)
            turning = "" if w.kind == "straight" else " in a held turn"
            reasons.append(f"it runs at {w.predicted_speed_mps:.2g} m/s at {_propulsion_text(layout, w.propulsion)}"
                           f"{turning}, these bags at {w.measured_speed_mps:.2g} m/s (ratio {speed_ratio:.2f}, "
                           f"limit {SPEED_RATIO_LIMIT:g})")
    turns = [w for w in windows if w.kind == "turn" and abs(w.measured_yaw_rate_rad_s) >= MIN_YAW_RATE]
    yaw_ratio = None
    if turns:
        yaw_ratio = float(np.median([w.predicted_yaw_rate_rad_s / w.measured_yaw_rate_rad_s for w in turns]))
        if not (1.0 / YAW_RATE_RATIO_LIMIT <= yaw_ratio <= YAW_RATE_RATIO_LIMIT):
            w = _median_window(turns, lambda w: w.predicted_yaw_rate_rad_s / w.measured_yaw_rate_rad_s)
            reasons.append(f"it turns at {math.degrees(w.predicted_yaw_rate_rad_s):.2g} deg/s for a held turn command "
                           f"{w.steering:.3g} at {_propulsion_text(layout, w.propulsion)}, these bags at "
                           f"{math.degrees(w.measured_yaw_rate_rad_s):.2g} deg/s (ratio {yaw_ratio:.2f}, "
                           f"limit {YAW_RATE_RATIO_LIMIT:g})")

    length = vessel.geometry.L_pp if vessel is not None else None
    froude_measured = froude_model = froude_scale = None
    if speed_set and length:
        u_meas = float(np.median([w.measured_speed_mps for w in speed_set]))
        u_model = float(np.median([w.predicted_speed_mps for w in speed_set]))
        froude_measured, froude_model = u_meas / math.sqrt(G * length), u_model / math.sqrt(G * length)
        froude_scale = (u_meas / u_model) ** 2 if u_model > 0 else None
    speeds = np.concatenate([np.abs(r.nu[:, 0]) for r in recordings]) if recordings else np.zeros(0)
    speeds = speeds[np.isfinite(speeds)]
    data_speed = float(np.percentile(speeds, 90)) if len(speeds) else None
    top = _top_speed(vessel) if vessel is not None and layout.propulsion else None
    if top is not None and data_speed is not None and data_speed > TOP_SPEED_LIMIT * top:
        reasons.append(f"these bags run at {data_speed:.2g} m/s, {data_speed / top:.1f} times its top speed "
                       f"{top:.2g} m/s at full command (Fn {data_speed / math.sqrt(G * length):.2f} on its "
                       f"{length:g} m)")
    if froude_scale is not None and reasons and not (0.5 < froude_scale < 2.0):
        reasons.append(f"Froude-similar to a hull {froude_scale:.3g} times as long (model-scale vs full-scale?)")
    checked = speed_ratio is not None or yaw_ratio is not None or top is not None
    verdict = "mismatch" if reasons else ("fits" if checked else "unchecked")
    return FitCheck(label, layout.name, tuple(windows), speed_ratio, speed_kind, yaw_ratio, length, froude_measured,
                    froude_model, froude_scale, top, data_speed, verdict, tuple(reasons))


def require_fit(check: FitCheck, option: str = "--no-fit-check") -> None:
    """FitCheckError (the one refusal line) when the check found a mismatch."""
    if check.mismatch:
        raise FitCheckError(check.refusal(option))

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

The ratios are medians over windows (predicted / measured). Within the calm-water allowance (SPEED_RATIO_LIMIT,
YAW_RATE_RATIO_LIMIT, measured on the 15 m jari_usv: no hypothesis moved its ratios by more than 5 %, a resistance
off by +99 % moves its speed by ~30 %) a ratio needs no cause. Beyond it, what a sea or a fault can do depends on the
boat's size and speed (a 0.6 m/s current is 10 % of a 6 m/s boat and half of a 1.2 m/s one; the mean wave drift
force 0.5 rho g L zeta_a^2 C(chi), seed 000 eq. 19, of 1.5 m waves exceeds a 2 m boat's thrust). So, when the
vessel is known, the check asks the vessel's own physics (its grey box, models/greybox.py) what each simulated
hypothesis of the diagnosis vocabulary at the top of the hidden-effect suite's range (physics/effects.py: current
0.6 m/s, wind 15 m/s, waves H_s 1.5 m, from STRONGEST_DIRECTIONS directions; rudder offset, gyro bias, heading
offset, propeller side force, thrust imbalance with either sign) changes in each window's u and r, and widens the
limits to every ratio a right model would show under one such cause at some strength (_explain): unbounded where a
cause can stop the boat or its turn. The data's speed is held against the vessel's top speed the same way (a
following sea or a current may carry a small boat beyond its calm-water top speed). The verdict is `mismatch` when a
ratio or the speed lies beyond its limit, `fits` otherwise, `unchecked` without a steady window and without a
vessel to compare the speeds with. Without a vessel (a learned model of an unknown boat) the allowances are the
limits. `replay evaluate` and `replay diagnose` refuse a mismatch in one line (FitCheckError, exit 2) naming the
numbers, the boat's limit and the cause behind it, and the remedy, unless told --no-fit-check.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from itertools import product
from functools import lru_cache, partial
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from usv_predictor.analysis.evaluation import Predictor, held_reference, rollout
from usv_predictor.data.recording import Recording
from usv_predictor.errors import FitCheckError
from usv_predictor.physics import effects as fx
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
SPEED_RATIO_LIMIT = 1.5  # (-) calm-water allowance: predicted / measured speed within [1/1.5, 1.5] needs no cause
YAW_RATE_RATIO_LIMIT = 2.0  # (-) ... and steady yaw rate within [1/2, 2] (opposite sign: beyond)
STRONGEST_DIRECTIONS = 12  # compass directions a sea (current, wind, waves) at the top of its range is tried from
CAUSE_SUBSTEP_S = 0.125  # (s) longest integration step of the causes' rollouts for a CAUSE_SUBSTEP_L boat: a 2 m
# boat spun by 1.5 m waves has yaw dynamics of ~20 |r| 1/s (N_rr |r| / m_66), beyond explicit RK4's stability at 0.25 s
CAUSE_SUBSTEP_L = 2.0  # (m) ... and it scales with sqrt(L_pp / this): a hull's time scales go with sqrt(L / g)
# (Froude similarity; cause_substeps)
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
class Cause:
    """One simulated hypothesis of the diagnosis vocabulary at the top of the hidden-effect suite's range."""

    effect: str
    parameters: Mapping[str, float]  # its `replay simulate` parameters (physics/effects.py units)
    terms: Mapping[str, tuple[float, ...]]  # the grey-box terms it sets (SI)

    @property
    def label(self) -> str:
        """How a line names it: `wave_drift (--wave-height 1.5 --wave-from 120)`."""
        drawn = {p.name: p.flag for p in fx.EFFECTS[self.effect].parameters if not isinstance(p.draw, fx.Fixed)}
        return f"{self.effect} ({' '.join(f'{drawn[k]} {v:g}' for k, v in self.parameters.items() if k in drawn)})"

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "parameters": dict(self.parameters)}


def strongest_causes(layout: str) -> tuple[Cause, ...]:
    """Every simulated effect that applies to `layout` at the top of its draw range (physics/effects.py): the largest
    magnitude (both signs when drawn with a random sign), a direction drawn over the whole compass at
    STRONGEST_DIRECTIONS directions, a fixed parameter at its value; the grey-box terms from the effect's readout."""
    causes = []
    for name, effect in fx.simulated(layout).items():
        if not all(t.settled for t in effect.terms):  # a delay shifts when a held command acts, never a settled u or
            continue                                   # r (and the grey box holds it as one scalar, not one per row)
        choices: list[tuple[str, tuple[float, ...]]] = []
        for p in effect.parameters:
            if p.draw is None:
                continue
            if isinstance(p.draw, fx.Uniform) and p.unit == "deg" and p.draw.high - p.draw.low >= 360.0:
                values = tuple(360.0 * k / STRONGEST_DIRECTIONS for k in range(STRONGEST_DIRECTIONS))
            else:
                top = max(abs(x) for x in p.draw.extremes)
                values = tuple(sorted({x for x in p.draw.extremes if abs(x) == top}))
            choices.append((p.name, values))
        for combination in product(*(values for _, values in choices)):
            parameters = {key: float(value) for (key, _), value in zip(choices, combination)}
            terms = effect.readout.terms_from_truth(parameters)
            causes.append(Cause(name, parameters, {k: tuple(float(x) for x in v) for k, v in terms.items()}))
    return tuple(causes)


@dataclass(frozen=True)
class Explanation:
    """What the strongest causes can do to one ratio of a right model of this boat (_explain): the limits the ratio
    must lie within, the cause that sets the limit on the side the ratio lies, and whether it lies within."""

    limits: tuple[float, float]  # (low, high) of a positive ratio: the calm-water allowance widened to what one cause
    # can make of a right model of this boat (inf: a cause can stop the boat or its turn)
    reversed_below: float | None  # a negative ratio at or below this is explained (a cause reverses the turn)
    cause: Cause | None  # the cause behind the limit on the ratio's side (None: the allowance is wider there)
    explained: bool  # the ratio lies within the limits

    def to_json(self) -> dict[str, Any]:
        return {"limits": [x if math.isfinite(x) else None for x in self.limits],  # None: unbounded
                "reversed_below": self.reversed_below,
                "cause": None if self.cause is None else self.cause.to_json(), "explained": self.explained}


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
    speed_explanation: Explanation | None = None  # the strongest causes on the speed ratio (None: not needed/no vessel)
    yaw_rate_explanation: Explanation | None = None  # ... on the yaw-rate ratio

    @property
    def mismatch(self) -> bool:
        return self.verdict == "mismatch"

    def refusal(self, option: str = "--no-fit-check", data: str = "these bags") -> str:
        """The one line a command refuses with (data: what was measured, "the node's inputs" in the node)."""
        return (f"{self.model} does not fit {data}: {'; '.join(self.reasons)} — beyond what any current, wind, "
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
                "explained": {name: None if e is None else e.to_json() for name, e in
                              (("speed_ratio", self.speed_explanation), ("yaw_rate_ratio", self.yaw_rate_explanation))},
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
    """Every window of held commands whose measured u and r have settled, with the model's u and r for it
    (rolled_windows)."""
    return [w.window for w in rolled_windows(predictor, recordings, layout)]


@dataclass(frozen=True)
class Rolled:
    """A steady window and what its prediction was rolled out from (the causes are rolled out from the same)."""

    window: SteadyWindow
    state: np.ndarray = field(repr=False)  # (4,) [u, v, r, psi] measured at the rollout's start
    controls: np.ndarray = field(repr=False)  # (H, C) the controls of the rollout
    averaged: int  # the last `averaged` steps of the rollout are averaged
    reference: np.ndarray | None = field(default=None, repr=False)  # (4,) rudder_only: the approach whose engine
    #                                                                  speed the rollouts hold; None: the start state


Predict = Callable[[np.ndarray, np.ndarray, "np.ndarray | None"], np.ndarray]
"""predict(state (1, 4), controls (1, H, C), reference (4,) or None) -> (E, 1, H, 6): evaluation.rollout of a model."""


def rolled_windows(predictor: Predictor, recordings: Sequence[Recording], layout: ActuatorLayout,
                   reference: np.ndarray | None = None, predict: Predict | None = None) -> list[Rolled]:
    """Every window of held commands whose measured u and r have settled, with the model's u and r for it.
    predict: how a window is rolled out (default evaluation.rollout of `predictor`; the node's check serves the
    rollouts of windows it has rolled out before, node/fit.py).

    rudder_only: every rollout holds the engine speed of an approach (models/greybox.py `reference`): `reference`
    (4,) when given (the node's, node/live.ApproachTracker: its buffers may start inside a turn), else each
    recording's own (evaluation.held_reference); the layouts with propulsion data ignore it.

    Straight windows: the model starts from the settled measured state and runs SETTLE_S at the held commands (its
    own straight-running equilibrium). Turns: the model starts where the commands were first held and runs with the
    recorded commands to the window's end, so a turn that has not reached its steady state in the data (a zig-zag
    of a slow ship) is compared with the same stage of the model's turn, never with the model's steady turn.
    """
    predict = predict or partial(rollout, predictor)
    dt = recordings[0].dt if recordings else 1.0
    settle_n = max(int(round(SETTLE_S / dt)), 2)
    steady_n = max(int(round(STEADY_S / dt)), 2)
    windows = []
    for rec in recordings:
        # rudder_only: the engine speed of the manoeuvre's approach, held in every rollout (evaluation.held_reference)
        held_state = (None if layout.propulsion else np.asarray(reference, dtype=float)) if reference is not None \
            else held_reference(rec, np.column_stack([rec.nu, rec.position, rec.psi]))
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
            averaged = min(steady_n, controls.shape[1])
            predicted = predict(state, controls, held_state)
            predicted = predicted.mean(axis=0)[0, -averaged:]  # (steady, 6)
            measured = last.mean(axis=0)  # (3,)
            windows.append(Rolled(SteadyWindow(
                rec.name, "straight" if straight else "turn", float(rec.t_s[first]), float(rec.t_s[end - 1]),
                steering, float(layout.propulsion_signal(held)), float(measured[0]), float(predicted[:, 0].mean()),
                float(measured[2]), float(predicted[:, 2].mean())), state[0], controls[0], averaged, held_state))
    return windows


ChangesOf = Callable[[Sequence[Rolled], Sequence[Cause]], tuple[np.ndarray, np.ndarray]]
"""changes_of(rolled, causes) -> (du, dr), each (N causes, W windows): cause_changes of the windows."""


def cause_substeps(vessel: Vessel, dt: float) -> int:
    """RK4 substeps per step dt (s) of the causes' rollouts (at least 2): the longest substep is CAUSE_SUBSTEP_S
    for a 2 m boat, scaled with sqrt(L_pp / CAUSE_SUBSTEP_L) (a hull's time scales go with sqrt(L / g) at the same
    Froude number, and the strongest causes are the same for every boat: 0.6 m/s current, 15 m/s wind, 1.5 m
    waves, so a longer boat is spun less). Against 32 substeps on every preset and layout at dt 0.2 and 0.5 s, every
    cause's du and dr is as close as the 2 m boat's own rule gets (the 13.5 m jari_usv at dt 0.5 s: 2 substeps
    instead of 4, 4.7e-4 m/s and 1.2e-3 deg/s of changes up to 2.2 m/s and 7.2 deg/s; the otter at 4: 7.3e-4 m/s
    and 1.4e-3 deg/s); test_fit_check.py holds every preset whose substeps it changes within 1e-3 m/s
    and 2e-3 deg/s of 16 substeps."""
    longest = CAUSE_SUBSTEP_S * math.sqrt(max(vessel.geometry.L_pp, CAUSE_SUBSTEP_L) / CAUSE_SUBSTEP_L)  # (s)
    return max(2, math.ceil(dt / longest - 1e-9))


def cause_changes(vessel: Vessel, dt: float, rolled: Sequence[Rolled], causes: Sequence[Cause], *,
                  compiled: bool = True, scripted: bool = True, lean: bool = True,
                  substeps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(du, dr), each (N causes, W windows): what each cause changes in the vessel's u (m/s, over ground) and r
    (rad/s, as the gyro reports it) averaged where the window's prediction is, rolled out by the vessel's grey box
    from the same state with the same controls (straight windows steered: _steered_rollout). One batch: rows =
    windows x (calm + causes), every cause's terms set per row (the grey box's terms broadcast over the batch), the
    windows padded to the longest with their last controls (the rows are independent: a window's numbers do not
    depend on the others in its batch). rudder_only: every row holds the engine speed of its window's reference
    (Rolled.reference, the approach its prediction held; the start state without one).

    compiled: the rollout is the compiled kernel's (models/kernel_rollout.py: the grey box with every row's terms
    and its straight rows steered, equal to the torch forms below to 1e-9, test_fit_check.py); False: one of them.
    scripted: the module is run as TorchScript without the graph executor's optimisation (the interpreter runs the
    same aten ops in the same order as eager: the same numbers bit for bit, test_fit_check.py; half the time of eager
    here, whose per-op Python overhead is the cost of these small batches, ~0.4 ms per derivative of 45 rows; the
    profiling executor would spend its first two calls profiling a shape that each check changes); False: eager.
    lean: the rollout reduced to u and r (_causes_rollout: the same numbers bit for bit, fewer ops); False: the
    steered grey box's whole rollout (_steered_rollout), the reference the tests compare with. substeps: RK4
    substeps per step (default cause_substeps of the vessel)."""
    import torch

    rows = 1 + len(causes)
    horizon = max(r.controls.shape[0] for r in rolled)
    states = np.concatenate([np.repeat(r.state[None], rows, axis=0) for r in rolled])  # (W rows, 4)
    references = np.concatenate([np.repeat((r.state if r.reference is None else r.reference)[None], rows, axis=0)
                                 for r in rolled])  # (W rows, 4): the start state is what None means
    controls = np.concatenate([np.repeat(np.concatenate(
        [r.controls, np.repeat(r.controls[-1:], horizon - r.controls.shape[0], axis=0)])[None], rows, axis=0)
        for r in rolled])  # (W rows, H, C)
    substeps = cause_substeps(vessel, dt) if substeps is None else substeps
    terms = {}  # every extension term of the grey box, (size, W rows): each cause's on its rows, 0 elsewhere
    for name in {t for c in causes for t in c.terms}:
        values = np.zeros((len(next(c.terms[name] for c in causes if name in c.terms)), len(rolled), rows))
        for j, cause in enumerate(causes, start=1):
            if name in cause.terms:
                values[:, :, j] = np.asarray(cause.terms[name])[:, None]
        terms[name] = torch.as_tensor(values.reshape(values.shape[0], -1))
    free = torch.as_tensor(np.repeat([0.0 if r.window.kind == "straight" else 1.0 for r in rolled], rows))  # (W rows,)
    if compiled:
        kernel, lock = _compiled_causes(vessel, float(dt), substeps)
        with lock, torch.no_grad():
            for name, term in fx.grey_box_terms().items():
                setattr(kernel.module, name, torch.nn.Parameter(
                    terms[name] if name in terms else torch.zeros(term.size, dtype=torch.float64), requires_grad=False))
            out = kernel(torch.as_tensor(states), torch.as_tensor(controls), torch.as_tensor(references),
                         free=free)  # (1, W rows, H, 6)
        lean = False
    else:
        if scripted:
            run, lock = _scripted_causes(vessel, float(dt), substeps, lean)
        else:
            run, lock = ((_causes_rollout() if lean else _steered_rollout())(vessel, dt, substeps=substeps),
                         threading.Lock())
            run.register_buffer("free", free)
        # optimized_execution is thread-local: other threads' TorchScript is unaffected
        with lock, torch.no_grad(), torch.jit.optimized_execution(False):
            for name, term in fx.grey_box_terms().items():
                setattr(run, name, torch.nn.Parameter(terms[name] if name in terms else
                                                      torch.zeros(term.size, dtype=torch.float64), requires_grad=False))
            run.free = free
            out = run(torch.as_tensor(states), torch.as_tensor(controls), torch.as_tensor(references))
    # (W rows, H, 2) [u, r] of the lean rollout, (1, W rows, H, 6) [u, v, r, x_n, y_e, psi] of the whole one
    out = (out if lean else out[0, :, :, 0:3:2]).numpy().reshape(len(rolled), rows, horizon, 2)
    du, dr = np.zeros((len(causes), len(rolled))), np.zeros((len(causes), len(rolled)))
    for w, r in enumerate(rolled):
        end = r.controls.shape[0]
        mean = out[w, :, end - r.averaged:end].mean(axis=1)  # (rows, 2) [u, r]
        du[:, w], dr[:, w] = mean[1:, 0] - mean[0, 0], mean[1:, 1] - mean[0, 1]
    return du, dr


@lru_cache(maxsize=8)
def _compiled_causes(vessel: Vessel, dt: float, substeps: int) -> tuple[Any, threading.Lock]:
    """The kernel of the vessel's grey box at this step and substeps, kept, and the lock its users hold while they set
    its terms and run it."""
    from usv_predictor.models.greybox import GreyBoxRollout
    from usv_predictor.models.kernel_rollout import KernelRollout

    return KernelRollout(GreyBoxRollout(vessel, dt, substeps=substeps), live=True), threading.Lock()


@lru_cache(maxsize=8)
def _scripted_causes(vessel: Vessel, dt: float, substeps: int, lean: bool) -> tuple[Any, threading.Lock]:
    """The causes' rollout of a vessel, step and substeps, scripted once (scripting a module takes ~10-15 ms, a
    tenth of a rollout), and the lock its users hold while they set its terms and run it."""
    import torch

    model = (_causes_rollout() if lean else _steered_rollout())(vessel, dt, substeps=substeps)
    model.register_buffer("free", torch.ones(1, dtype=torch.float64))
    return torch.jit.script(model), threading.Lock()


@lru_cache(maxsize=None)
def _steered_rollout() -> type:
    """The grey box with the straight windows' rows steered: their sway and yaw held at the measured values (a
    straight run in a sea is a steered run; at held commands the model would veer to its own weathervane heading,
    where the sea acts otherwise than at the course the data held). Its buffer `free` (B,): 0 on a steered row, 1 on
    a free one, set by cause_changes. One class per process (TorchScript compiles a class once)."""
    from usv_predictor.models.greybox import GreyBoxRollout

    class SteeredRollout(GreyBoxRollout):
        def _model_accelerations(self, psi, u_r, v_r, r, a, b):
            acc = self._accelerations(psi, u_r, v_r, r, a, b)
            return [acc[0], acc[1] * self.free, acc[2] * self.free]

    return SteeredRollout


@lru_cache(maxsize=None)
def _causes_rollout() -> type:
    """_steered_rollout's rollout reduced to what cause_changes reads: forward -> (B, H, 2) [u over ground, r as the
    gyro reports it], the same equations (GreyBoxRollout's own methods) and RK4 steps, the same numbers bit for bit
    (test_fit_check.py), with fewer small ops per derivative (its cost is their count: 45 rows):
      - the state is [psi, u_r, v_r, r]: the positions (x_n, y_e) feed nothing back, they are not integrated;
      - what does not change over the rollout is computed once: the hull coefficients unbound (hull_list) and the
        sea terms' values (_sea_terms: the current's and wind's components, the wave amplitude and direction);
      - only u and r are output."""
    from typing import List, Optional

    import torch
    from torch import Tensor

    class CausesRollout(_steered_rollout()):
        def forward(self, state: Tensor, controls: Tensor, reference: Optional[Tensor] = None) -> Tensor:
            controls, x, carry = self._start(state, controls, reference)
            hull, sea = self.hull_list(), self._sea_terms()
            s = [x[2], x[3], x[4], x[5]]  # (B,) each: psi, u_r, v_r, r
            h = self.dt / self.substeps
            outputs: List[Tensor] = []
            steps = controls.shape[1]
            for k in range(steps):  # GreyBoxRollout._rollout's steps and substeps
                c0 = controls[:, k]
                dc = controls[:, min(k + 1, steps - 1)] - c0
                for j in range(self.substeps):
                    lv = self._stage(c0, dc, j, carry)
                    k1 = self._lean_derivative(hull, sea, s, lv[0], lv[1])
                    k2 = self._lean_derivative(hull, sea, [p + 0.5 * h * q for p, q in zip(s, k1)], lv[2], lv[3])
                    k3 = self._lean_derivative(hull, sea, [p + 0.5 * h * q for p, q in zip(s, k2)], lv[2], lv[3])
                    k4 = self._lean_derivative(hull, sea, [p + h * q for p, q in zip(s, k3)], lv[4], lv[5])
                    s = [p + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for p, b1, b2, b3, b4 in zip(s, k1, k2, k3, k4)]
                    carry = lv[6]
                u_g = s[1] + sea[0] * torch.cos(s[0]) + sea[1] * torch.sin(s[0])  # over ground, as _rollout's
                outputs.append(torch.stack([u_g, s[3] + self.yaw_rate_bias[0]], dim=-1))
            return torch.stack(outputs, dim=1)  # (B, H, 2)

        def _lean_derivative(self, hull: List[Tensor], sea: List[Tensor], s: List[Tensor], a: Tensor,
                             b: Tensor) -> List[Tensor]:
            """d/dt of [psi, u_r, v_r, r] (GreyBoxRollout._derivative without the positions; steered)."""
            acc = self._accelerations_with(hull, sea, s[0], s[1], s[2], s[3], a, b)
            return [s[3], acc[0], acc[1] * self.free, acc[2] * self.free]

    return CausesRollout


def _explain(ratio: float, predicted: np.ndarray, changes: np.ndarray, limit: float, floor: float,
             causes: Sequence[Cause]) -> Explanation:
    """The limits of a median ratio (predicted / measured) on this boat: predicted (W,) the model's values in the
    ratio's windows, changes (N, W) what each cause at the top of its range changes in them.

    Were the model right and the sea one cause, the data would show predicted + change, and the check the ratio
    1/m with m = median((predicted + change) / predicted), the share of the model's value the cause leaves. m moves
    continuously from 1 (no cause) to its value at the top of the range, so every ratio between 1 and 1/m is a
    right model in some strength of that cause; when m falls below floor / |predicted| (the cause stops the boat
    or its turn) every ratio beyond 1 is, and when it falls below -floor / |predicted| (reverses the turn) every
    ratio below 1/m too; a cause that raises the value (m > 1) explains the ratios between 1/m and 1. The limits: the
    calm-water
    allowance [1/limit, limit] or, where wider, what the causes reach (no allowance on top: the allowance already
    covers a model's error with the smaller causes of the sea in which it was measured)."""
    with np.errstate(divide="ignore", invalid="ignore"):  # a model value of 0: no share, the cause is not tried
        share = np.median((predicted[None, :] + changes) / predicted[None, :], axis=1)  # (N,)
    tried = np.isfinite(share)  # a rollout that diverged tries nothing
    share = np.where(tried, share, 1.0)
    smallest = floor / max(float(np.median(np.abs(predicted))), floor)
    grows = share > 1.0  # the data would run faster / turn harder: ratios 1/m in (0, 1)
    shrinks = (share < 1.0) & (share > smallest)  # slower: ratios 1/m in (1, ...)
    stops = share <= smallest  # the cause stops the boat or its turn: every ratio above 1
    reverses = share < -smallest  # ... and reverses it: negative ratios from -inf up to 1/m
    low = min(1.0 / limit, float((1.0 / share[grows]).min())) if grows.any() else 1.0 / limit
    high = math.inf if stops.any() else max(limit, float((1.0 / share[shrinks]).max()) if shrinks.any() else limit)
    reversed_below = float((1.0 / share[reverses]).max()) if reverses.any() else None
    cause = None
    if ratio >= 1.0 and high > limit:
        cause = causes[int(np.argmin(share))]
    elif 0.0 < ratio < 1.0 and low < 1.0 / limit:
        cause = causes[int(np.argmax(share))]
    elif ratio <= 0.0 and reversed_below is not None:
        cause = causes[int(np.argmin(np.where(reverses, share, np.inf)))]
    explained = low <= ratio <= high or (reversed_below is not None and ratio <= reversed_below)
    return Explanation((low, high), reversed_below, cause, bool(explained))


def _limit_text(ratio: float, limit: float, explanation: Explanation | None, size: str) -> str:
    """`limit 1.5` (the allowance), `limit 2 for the 2 m boat it describes, which no cause ... widens`, or `limit
    1.85 for the 13.5 m boat it describes: the most any one cause ... explains at the top of its range, ...`."""
    allowance = f"limit {limit:g}" if ratio >= 1.0 else f"limit 1/{limit:g}"
    if explanation is None:
        return allowance
    if explanation.cause is None:
        return f"{allowance} {size}, which no cause the diagnosis knows widens"
    value = explanation.limits[1] if ratio >= 1.0 else explanation.limits[0]
    return (f"limit {value:.3g} {size}: the most any one cause the diagnosis knows explains at the top of its range, "
            f"{explanation.cause.label}")


def _top_speed(vessel: Vessel) -> float | None:
    """Straight-running speed through the water at the largest propulsion command of the vessel (m/s)."""
    from usv_predictor.physics.dynamics import ManoeuvringModel

    layout = vessel.actuator_layout
    if layout.propulsion_input is None or layout.command_map is None:
        return None
    high = layout.propulsion_input.limits(vessel)[1] * layout.propulsion_input.to_command
    return float(ManoeuvringModel(vessel).straight_speed(high))


def _top_speed_in_a_sea(vessel: Vessel, dt: float, top: float, causes: Sequence[Cause]) -> tuple[float, Cause | None]:
    """The highest steered straight speed over ground (m/s) at full propulsion command with any one cause at the top
    of its range (cause_changes from the calm top speed over SETTLE_S), and that cause (None: none raises it)."""
    layout = vessel.actuator_layout
    full = layout.propulsion_input.limits(vessel)[1] * layout.propulsion_input.to_command
    steps = max(int(round(SETTLE_S / dt)), 2)
    controls = np.repeat(np.asarray(layout.to_commands(0.0, full), dtype=float)[None], steps, axis=0)  # (H, C)
    window = SteadyWindow("top speed", "straight", 0.0, SETTLE_S, 0.0, full, top, top, 0.0, 0.0)
    du, _ = cause_changes(vessel, dt, [Rolled(window, np.array([top, 0.0, 0.0, 0.0]), controls,
                                               min(max(int(round(STEADY_S / dt)), 2), steps))], causes)
    du = np.where(np.isfinite(du[:, 0]), du[:, 0], -np.inf)  # (N,)
    best = int(np.argmax(du))
    return (top + float(du[best]), causes[best]) if du[best] > 0.0 else (top, None)


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
              label: str | None = None, explain_always: bool = False) -> FitCheck:
    """The fit check of `predictor` on `recordings` (module docstring); `vessel` (when known) gives the length, the
    top speed and the physics the strongest causes are rolled out with, `label` how the refusal names the model
    (default from the predictor's metadata). The causes are rolled out when a ratio lies beyond the allowance, or
    always with explain_always (benchmarks/fit_check_sizes.py reports what they do to a right model)."""
    meta = dict(predictor.metadata)
    layout = actuator_layout(str(meta.get("actuator_layout") or (recordings[0].layout if recordings else "")))
    label = label or f"model {meta.get('model_id', '?')} ({meta.get('model_type', '?')})"
    rolled = rolled_windows(predictor, recordings, layout) if recordings else []
    speeds = np.concatenate([np.abs(r.nu[:, 0]) for r in recordings]) if recordings else np.zeros(0)
    return judge_windows(label, layout, rolled, speeds, recordings[0].dt if recordings else None, vessel=vessel,
                         explain_always=explain_always)


def judge_windows(label: str, layout: ActuatorLayout, rolled: Sequence[Rolled], speeds: np.ndarray,
                  dt: float | None, *, vessel: Vessel | None = None, explain_always: bool = False,
                  data: str = "these bags", changes_of: ChangesOf | None = None) -> FitCheck:
    """The verdict of check_fit on steady windows already rolled out (rolled_windows), `speeds` (N,) the measured
    |u| (m/s) the data's speed is the 90th percentile of, dt (s) the step of the windows' rollouts (None: no
    window), `data` how the reasons name what was measured, `changes_of(rolled, causes)` what the causes change in
    the windows whose ratio needs them (beyond its allowance, or explain_always; default cause_changes of the vessel
    at dt; the node's check keeps them per window). check_fit's
    second half, shared with the node's live fit check (node/fit.py), which collects its
    windows from its input buffers over time."""
    rolled = list(rolled)
    windows = [r.window for r in rolled]
    reasons: list[str] = []
    diverged = [w for w in windows if not (math.isfinite(w.predicted_speed_mps)
                                           and math.isfinite(w.predicted_yaw_rate_rad_s))]
    if diverged:
        reasons.append(f"its prediction is not finite at the held commands of {len(diverged)} of {len(windows)} "
                       f"steady window(s) (first: {diverged[0].recording} at {diverged[0].start_s:.0f} s)")
        rolled = [r for r in rolled if r.window not in diverged]
        windows = [r.window for r in rolled]
    causes = strongest_causes(layout.name) if vessel is not None and rolled else ()
    size = f"for the {vessel.geometry.L_pp:g} m boat it describes" if vessel is not None else ""
    usable = [w for w in windows if w.measured_speed_mps >= MIN_SPEED]
    straight = [w for w in usable if w.kind == "straight"]
    speed_set, speed_kind = (straight, "straight") if straight else (usable, "turn" if usable else "")
    if not layout.propulsion:  # rudder_only: the engine speed is the model's own; straight running from the
        # approach speed holds that speed in a right model (a grey box by construction), turns say nothing of it
        speed_set, speed_kind = (straight, "straight") if straight else ([], "")
    turns = [w for w in windows if w.kind == "turn" and abs(w.measured_yaw_rate_rad_s) >= MIN_YAW_RATE]
    speed_ratio = float(np.median([w.predicted_speed_mps / w.measured_speed_mps for w in speed_set])) \
        if speed_set else None
    yaw_ratio = float(np.median([w.predicted_yaw_rate_rad_s / w.measured_yaw_rate_rad_s for w in turns])) \
        if turns else None
    # the causes are rolled out (one batch) for the windows of a ratio beyond its allowance only: a straight window
    # is SETTLE_S of rollout, a turn a few seconds, and each window's changes are its own (cause_changes)
    needed = sorted({windows.index(w) for subset, ratio, limit in ((speed_set, speed_ratio, SPEED_RATIO_LIMIT),
                                                                   (turns, yaw_ratio, YAW_RATE_RATIO_LIMIT))
                     if causes and ratio is not None and (explain_always or not 1.0 / limit <= ratio <= limit)
                     for w in subset})
    changes: list[tuple[np.ndarray, np.ndarray]] = []  # [(du, dr)] of the needed windows, rolled out when first needed

    def change(index: list[int], which: int) -> np.ndarray:
        if not changes:
            changes.append((changes_of or partial(cause_changes, vessel, dt))([rolled[i] for i in needed], causes))
        return changes[0][which][:, [needed.index(i) for i in index]]  # (N, len(index))

    speed_explanation = None
    if speed_set:
        beyond = not (1.0 / SPEED_RATIO_LIMIT <= speed_ratio <= SPEED_RATIO_LIMIT)
        if causes and (beyond or explain_always):
            index = [windows.index(w) for w in speed_set]
            speed_explanation = _explain(speed_ratio, np.array([w.predicted_speed_mps for w in speed_set]),
                                         change(index, 0), SPEED_RATIO_LIMIT, MIN_SPEED, causes)
        if beyond and not (speed_explanation is not None and speed_explanation.explained):
            w = _median_window(speed_set, lambda w: w.predicted_speed_mps / w.measured_speed_mps)
            turning = "" if w.kind == "straight" else " in a held turn"
            reasons.append(f"it runs at {w.predicted_speed_mps:.2g} m/s at {_propulsion_text(layout, w.propulsion)}"
                           f"{turning}, {data} at {w.measured_speed_mps:.2g} m/s (ratio {speed_ratio:.2f}, "
                           f"{_limit_text(speed_ratio, SPEED_RATIO_LIMIT, speed_explanation, size)})")
    yaw_explanation = None
    if turns:
        beyond = not (1.0 / YAW_RATE_RATIO_LIMIT <= yaw_ratio <= YAW_RATE_RATIO_LIMIT)
        if causes and (beyond or explain_always):
            index = [windows.index(w) for w in turns]
            yaw_explanation = _explain(yaw_ratio, np.array([w.predicted_yaw_rate_rad_s for w in turns]),
                                       change(index, 1), YAW_RATE_RATIO_LIMIT, MIN_YAW_RATE, causes)
        if beyond and not (yaw_explanation is not None and yaw_explanation.explained):
            w = _median_window(turns, lambda w: w.predicted_yaw_rate_rad_s / w.measured_yaw_rate_rad_s)
            reasons.append(f"it turns at {math.degrees(w.predicted_yaw_rate_rad_s):.2g} deg/s for a held turn command "
                           f"{w.steering:.3g} at {_propulsion_text(layout, w.propulsion)}, {data} at "
                           f"{math.degrees(w.measured_yaw_rate_rad_s):.2g} deg/s (ratio {yaw_ratio:.2f}, "
                           f"{_limit_text(yaw_ratio, YAW_RATE_RATIO_LIMIT, yaw_explanation, size)})")

    length = vessel.geometry.L_pp if vessel is not None else None
    froude_measured = froude_model = froude_scale = None
    if speed_set and length:
        u_meas = float(np.median([w.measured_speed_mps for w in speed_set]))
        u_model = float(np.median([w.predicted_speed_mps for w in speed_set]))
        froude_measured, froude_model = u_meas / math.sqrt(G * length), u_model / math.sqrt(G * length)
        froude_scale = (u_meas / u_model) ** 2 if u_model > 0 else None
    speeds = np.asarray(speeds, dtype=float)
    speeds = speeds[np.isfinite(speeds)]
    data_speed = float(np.percentile(speeds, 90)) if len(speeds) else None
    top = _top_speed(vessel) if vessel is not None and layout.propulsion else None
    if top is not None and data_speed is not None and data_speed > TOP_SPEED_LIMIT * top:
        # a following sea or a current may carry a small boat beyond its calm-water top speed: the limit is the
        # top speed the strongest cause allows, if higher
        strongest = strongest_causes(layout.name) if dt is not None else ()
        top_sea, cause = _top_speed_in_a_sea(vessel, dt, top, strongest) if strongest else (top, None)
        if data_speed > TOP_SPEED_LIMIT * top_sea:
            sea = "" if cause is None else f", {top_sea:.2g} m/s with {cause.label}"
            reasons.append(f"{data} run at {data_speed:.2g} m/s, {data_speed / top:.1f} times its top speed "
                           f"{top:.2g} m/s at full command{sea} (Fn {data_speed / math.sqrt(G * length):.2f} on its "
                           f"{length:g} m)")
    if froude_scale is not None and reasons and not (0.5 < froude_scale < 2.0):
        reasons.append(f"Froude-similar to a hull {froude_scale:.3g} times as long (model-scale vs full-scale?)")
    checked = speed_ratio is not None or yaw_ratio is not None or top is not None
    verdict = "mismatch" if reasons else ("fits" if checked else "unchecked")
    return FitCheck(label, layout.name, tuple(windows), speed_ratio, speed_kind, yaw_ratio, length, froude_measured,
                    froude_model, froude_scale, top, data_speed, verdict, tuple(reasons), speed_explanation,
                    yaw_explanation)


def require_fit(check: FitCheck, option: str = "--no-fit-check") -> None:
    """FitCheckError (the one refusal line) when the check found a mismatch."""
    if check.mismatch:
        raise FitCheckError(check.refusal(option))

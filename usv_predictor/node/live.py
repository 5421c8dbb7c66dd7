"""Live prediction without ROS: input buffers, state assembly, staleness and range checks, the rollout.

The `predictor` node (node.py) is a thin rclpy shell around this module; tests and benchmarks drive it
directly. Everything here is in SI units and marine frames (NED earth, FRD body, heading clockwise from
north); stamps are int nanoseconds of the node's clock (sim time under use_sim_time).

State assembly is the replay tool's Recording (recording.py), taken online:

    window     W(now) = [t_end - dt, t_end],  t_end = now - state_delay_s (closed, as Recording's windows)
    state      x = [u, v, r, psi] at t_c = t_end - dt/2: u, v box-averaged from `velocity`, r from the `imu`
               gyro, psi from `heading` unwrapped then averaged; the controls of the vessel's actuator layout
               (physics/actuators.py, e.g. [delta, rpm] from `rudder_angle` and `engine_rpm`) the same way,
               held for the whole horizon (the current actuator commands)
    position   GNSS lat/lon -> NED in the local tangent plane of the datum (parameter, or the first fix),
               box-averaged like the rest; without a fix the path starts at (0, 0)
    reference  rudder_only (no propulsion data): the latest straight running (ApproachTracker), whose engine
               speed the grey box holds, as replay holds the manoeuvre's approach

Each average is recording.window_resample's on the buffered samples with grid [t_c] (computed by
recording.window_mean from the samples up to the window's end, bit for bit), so a state here equals
Recording.state() at the grid time t_c of the same samples (test_live.py proves it on a shipped bag).
Prediction k (k = 1 .. H) is the model's output at t_c + k dt.

Samples are checked on arrival (reject reasons are counted per input and reported): non-finite values in
a field the state uses, a stamp not after the previous one (backwards or a repeated header stamp; a header-less
message arriving at the same clock reading as the previous one supersedes it, InputSet.add), a stamp more than
max_future_s ahead of the clock, values outside data.recording.PLAUSIBLE or a control's plausible range (wrong units
configuration, e.g. heading configured as rad but > 2 pi, rudder degrees read as radians, absurd rpm), a GNSS fix
farther from the one before than GNSS_MAX_SPEED allows ("jump": one fix of null island, InputSet._check_jump).
Buffers are fixed-size rings: memory does not grow with the message rate.

Redundant inputs are checked against each other (at most once per CONSISTENCY_PERIOD_S, over the latest
CONSISTENCY_WINDOW_S), because a unit or sign mistake can give values that are each plausible:

    heading vs gyro      the heading's change over 1 s steps against the integrated imu yaw rate; judged once the
                         gyro has turned TURN_EVIDENCE_DEG, refused when sum |d psi - d theta| exceeds
                         HEADING_DISAGREEMENT of sum |d theta| (a heading in radians configured as degrees never
                         leaves +-6.3 "deg" while the boat turns circles; a wrong convention turns the other way)
    track vs GNSS        the velocity rotated by the heading and integrated (dead reckoning) against the GNSS
                         displacement; judged above TRACK_MIN_SPEED over ground, refused (the heading) when the
                         directions differ by more than TRACK_ANGLE_LIMIT_DEG, (the velocity) when the lengths
                         differ by more than TRACK_LENGTH_RATIO (a current of a third of the speed passes)

A refused input stops the predictions (CycleSkipped naming it and why) until a later check with enough evidence
finds it consistent again; the node shows the reason on /diagnostics.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from msg_adapters.standard import ScalarHeadingAdapter
from usv_predictor.data.recording import (
    APPROACH_S,
    Recording,
    plausible_ranges,
    recording_from_signals,
    required_roles,
    window_mean,
    window_resample,
)
from usv_predictor.errors import CycleSkipped, InputRejected, ModelError, RecordingError
from usv_predictor.frames import LocalTangentPlane, angle_difference_deg, body_to_ned, compass_deg, wrap_angle
from usv_predictor.models.artifact import MODEL_RUN_ERRORS, ModelArtifact, failure_reason
from usv_predictor.models.dnn import NumpyDnnRollout, fused_rollout, numpy_rollout
from usv_predictor.models.kernel_rollout import KernelRollout
from usv_predictor.models.nomoto import NumpyNomotoRollout
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout
from usv_predictor.records import NS_PER_S, Signal

POSITION_ROLE = "gnss"
# role -> the fields the state uses, in the order of recording_from_signals (the controls' roles: the layout's)
MOTION_FIELDS: Mapping[str, tuple[str, ...]] = {
    "velocity": ("u", "v"),
    "imu": ("yaw_rate",),
    "heading": ("psi",),
    POSITION_ROLE: ("lat", "lon"),
}


def state_fields(layout: ActuatorLayout = DEFAULT_LAYOUT) -> dict[str, tuple[str, ...]]:
    """role -> the fields the state uses: the motion and position fields, then each control's role and field."""
    fields = dict(MOTION_FIELDS)
    for role in layout.roles:
        fields[role] = layout.fields_of(role)
    return fields


STATE_FIELDS: Mapping[str, tuple[str, ...]] = state_fields(DEFAULT_LAYOUT)
RAW_HEADING_LIMIT = ScalarHeadingAdapter.RAW_LIMIT  # |raw heading| per configured unit: one turn
RATE_WINDOW_S = 1.0  # input rates are counted over this much of the latest samples (s)
WARM_UP_CALLS = 3  # rollouts run when a model is loaded
CONSISTENCY_WINDOW_S = 20.0  # s of the latest samples the consistency checks compare
CONSISTENCY_PERIOD_S = 1.0  # s between two consistency checks
CONSISTENCY_STEP_S = 1.0  # s: the heading and the integrated gyro are compared over steps this long
TURN_EVIDENCE_DEG = 60.0  # deg the gyro must turn (sum of |turn| per step) before the heading is judged
HEADING_DISAGREEMENT = 0.5  # share of the gyro's turning the heading may differ by (a 0.5 deg/s gyro bias passes)
MIN_CHECK_SPAN_S = 5.0  # s of overlapping data a check needs
RADIANS_AS_DEGREES_SPREAD = math.radians(2.0 * math.pi) + 1e-3  # rad: a heading in rad read as deg stays in 6.3 deg
TRACK_MIN_SPEED = 2.0  # m/s over ground (GNSS) before the dead-reckoned track is judged
TRACK_ANGLE_LIMIT_DEG = 60.0  # deg between the dead-reckoned and the GNSS displacement
TRACK_LENGTH_RATIO = (0.4, 2.5)  # dead-reckoned / GNSS displacement length accepted
TRACK_END_S = 1.0  # s of GNSS fixes at each end of the window, their median taken (0.3 m noise per fix)
GNSS_MAX_SPEED = 40.0  # m/s between two fixes: above any USV's speed over ground (PLAUSIBLE u: 30 m/s)
GNSS_JUMP_SLACK_M = 25.0  # m a fix may stray beyond that (noise, multipath, a fix of lower quality)
GNSS_REANCHOR_FIXES = 3  # consecutive refused fixes that agree with each other: the buffered fixes were the outliers
CONSISTENCY_LAG_LIMIT_S = 1.0  # s a stamped message may reach the node after its stamp before the checks that
#                                compare it with an input stamped on arrival (a header-less heading) stop judging
METRES_PER_DEG = 111_320.0  # m of latitude per degree (an equirectangular distance is enough to tell a jump)
BULK_ADD_MIN = 16  # samples of one input from which the node buffers a batch with add_many (~18 us a call against ~1 us
# per sample for add(), warm: benchmarks/bench_node.py's IMU at 200 Hz brings 20 per cycle, at 1 kHz 100)
STEADY_SPEED_LIMIT = 50.0  # m/s: a predicted speed beyond this is a diverged model, not a prediction
APPROACH_WINDOW_S = 30.0  # (s) the latest straight running whose medians are a rudder_only boat's approach online
#                           (ApproachTracker): long enough to average out the first-order wave motion of the
#                           measured speed, short enough to follow an engine setting changed while running straight


def check_raw_heading(raw: float, units: str) -> None:
    """A scalar heading in its configured unit must lie within one turn; the adapter wraps, so check before it."""
    limit = RAW_HEADING_LIMIT.get(units)
    if limit is not None and math.isfinite(raw) and abs(raw) > limit:
        hint = " (degrees configured as rad?)" if units == "rad" else ""
        raise InputRejected("range", f"heading {raw:g} {units} is more than one turn{hint}; check the units option")


def raw_headings_within_a_turn(raw: np.ndarray, units: str) -> bool:
    """Would check_raw_heading pass every one of these raw headings?"""
    limit = RAW_HEADING_LIMIT.get(units)
    raw = np.asarray(raw, dtype=np.float64)
    return limit is None or not bool((np.isfinite(raw) & (np.abs(raw) > limit)).any())


def check_values(role: str, fields: Sequence[str], values: Sequence[float],
                 layout: ActuatorLayout = DEFAULT_LAYOUT) -> None:
    """Used fields must be finite and plausible (InputRejected 'non_finite' or 'range' naming the field)."""
    _check_values(role, fields, values, state_fields(layout).get(role, ()), plausible_ranges(layout))


def _stamp_text(stamp_ns: int) -> str:
    """A stamp as the header writes it: sec.nanosec (9 digits)."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return f"{sec}.{nanosec:09d} s"


def _check_values(role: str, fields: Sequence[str], values: Sequence[float], used: Sequence[str],
                  plausible: Mapping[str, tuple[float, float]]) -> None:
    """check_values with the layout's used fields of the role and plausible ranges given (InputSet keeps them)."""
    for name, value in zip(fields, values):
        if name not in used:
            continue
        if not math.isfinite(value):
            if role == POSITION_ROLE:
                raise InputRejected("no_fix", "GNSS reports no fix")
            raise InputRejected("non_finite", f"{role}.{name} is {value}")
        low, high = plausible.get(name, (-math.inf, math.inf))
        if not low <= value <= high:
            raise InputRejected("range", f"{role}.{name} = {value:g} outside the plausible [{low:g}, {high:g}]: "
                                         f"wrong units or sign configuration?")


def _fix_distance_m(a: tuple[int, float, float], b: tuple[int, float, float]) -> float:
    """Ground distance (m) between two (stamp, lat, lon) fixes, equirectangular: enough to tell a jump."""
    north = (b[1] - a[1]) * METRES_PER_DEG
    east = (b[2] - a[2]) * METRES_PER_DEG * math.cos(math.radians(0.5 * (a[1] + b[1])))
    return math.hypot(north, east)


class Consistency(NamedTuple):
    """The verdict of one consistency check: judged (enough evidence), and what is wrong ("" when nothing); a check
    that could not judge says why (`why_not`): it refuses nothing then."""

    judged: bool
    problem: str = ""
    why_not: str = ""


NOT_JUDGED = Consistency(False)


def not_judged(why: str) -> Consistency:
    return Consistency(False, "", why)


def _cumulative(t_s: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Trapezoidal integral of `rate` over t_s, 0 at the first sample."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(t_s))])


def heading_vs_gyro(t_imu_s: np.ndarray, yaw_rate: np.ndarray, t_heading_s: np.ndarray, psi: np.ndarray,
                    start_s: float, end_s: float) -> Consistency:
    """Does the heading turn as the gyro does over [start_s, end_s]? (s on one clock; rad, rad/s)

    On 1 s steps: d theta = the integrated yaw rate, d psi = the unwrapped heading's change. Judged once
    sum |d theta| >= TURN_EVIDENCE_DEG; a problem when sum |d psi - d theta| > HEADING_DISAGREEMENT sum |d theta|.
    """
    start_s = max(start_s, float(t_imu_s[0]), float(t_heading_s[0]))
    end_s = min(end_s, float(t_imu_s[-1]), float(t_heading_s[-1]))
    if end_s - start_s < MIN_CHECK_SPAN_S or len(t_imu_s) < 2 or len(t_heading_s) < 2:
        return not_judged(f"less than {MIN_CHECK_SPAN_S:g} s of imu and heading samples together")
    grid = np.linspace(start_s, end_s, max(2, int((end_s - start_s) / CONSISTENCY_STEP_S) + 1))
    d_theta = np.diff(np.interp(grid, t_imu_s, _cumulative(t_imu_s, yaw_rate)))
    d_psi = np.diff(np.interp(grid, t_heading_s, np.unwrap(psi)))
    turned = float(np.abs(d_theta).sum())
    if turned < math.radians(TURN_EVIDENCE_DEG):
        return not_judged(f"the gyro turned {math.degrees(turned):.0f} deg, less than the {TURN_EVIDENCE_DEG:g} deg "
                          "that tell a heading's units")
    differs = float(np.abs(d_psi - d_theta).sum())
    if differs <= HEADING_DISAGREEMENT * turned:
        return Consistency(True)
    heading_turned = float(np.abs(d_psi).sum())
    inside = (t_heading_s >= start_s) & (t_heading_s <= end_s)
    spread = float(np.ptp(wrap_angle(psi[inside]))) if inside.any() else 0.0
    if spread <= RADIANS_AS_DEGREES_SPREAD:
        hint = (f"it never leaves a {math.degrees(spread):.1f} deg band: a heading published in radians with units "
                "deg configured?")
    elif heading_turned < 0.25 * turned:
        hint = "it hardly turns: the heading's units?"
    elif float(np.dot(d_psi, d_theta)) < 0.0:
        hint = "the heading turns the other way: its convention (compass / enu) or the gyro's sign?"
    else:
        hint = "the heading's units or the gyro's?"
    return Consistency(True, f"the heading disagrees with the gyro: over {end_s - start_s:.0f} s it turned "
                             f"{math.degrees(heading_turned):.0f} deg while the imu yaw rate integrates to "
                             f"{math.degrees(turned):.0f} deg; {hint}")


def track_vs_gnss(t_velocity_s: np.ndarray, u: np.ndarray, v: np.ndarray, t_heading_s: np.ndarray, psi: np.ndarray,
                  t_gnss_s: np.ndarray, x_n: np.ndarray, y_e: np.ndarray, start_s: float, end_s: float
                  ) -> tuple[str, Consistency]:
    """(the input to blame, verdict): the velocity rotated by the heading and integrated against the GNSS track.

    Over [start_s, end_s] (s), from the median GNSS position of the first TRACK_END_S to that of the last, with the
    dead-reckoned displacement between the same times (body_to_ned, Fossen eq. 2.40). Judged above
    TRACK_MIN_SPEED over ground; the heading is to blame when the directions differ by more than
    TRACK_ANGLE_LIMIT_DEG, the velocity when the length ratio leaves TRACK_LENGTH_RATIO.
    """
    start_s = max(start_s, float(t_velocity_s[0]), float(t_heading_s[0]), float(t_gnss_s[0]))
    end_s = min(end_s, float(t_velocity_s[-1]), float(t_heading_s[-1]), float(t_gnss_s[-1]))
    if end_s - start_s < MIN_CHECK_SPAN_S or len(t_velocity_s) < 2 or len(t_heading_s) < 2:
        return "velocity", not_judged(f"less than {MIN_CHECK_SPAN_S:g} s of velocity, heading and GNSS together")
    first = (t_gnss_s >= start_s) & (t_gnss_s <= start_s + TRACK_END_S)
    last = (t_gnss_s >= end_s - TRACK_END_S) & (t_gnss_s <= end_s)
    if not first.any() or not last.any():
        return "velocity", not_judged("no GNSS fix at one end of the window")
    t0, t1 = float(np.median(t_gnss_s[first])), float(np.median(t_gnss_s[last]))
    gnss = np.array([np.median(x_n[last]) - np.median(x_n[first]), np.median(y_e[last]) - np.median(y_e[first])])
    if t1 - t0 < MIN_CHECK_SPAN_S or float(np.hypot(*gnss)) < TRACK_MIN_SPEED * (t1 - t0):
        return "velocity", not_judged(f"slower than {TRACK_MIN_SPEED:g} m/s over ground (GNSS)")
    north, east = body_to_ned(u, v, np.interp(t_velocity_s, t_heading_s, np.unwrap(psi)))
    reckoned = np.array([np.diff(np.interp([t0, t1], t_velocity_s, _cumulative(t_velocity_s, north)))[0],
                         np.diff(np.interp([t0, t1], t_velocity_s, _cumulative(t_velocity_s, east)))[0]])
    length_g, length_r = float(np.hypot(*gnss)), float(np.hypot(*reckoned))
    angle = abs(angle_difference_deg(compass_deg(*reckoned), compass_deg(*gnss)))
    seen = (f"over {t1 - t0:.0f} s the velocity rotated by the heading moves {length_r:.0f} m toward "
            f"{compass_deg(*reckoned):.0f} deg, GNSS {length_g:.0f} m toward {compass_deg(*gnss):.0f} deg")
    if angle > TRACK_ANGLE_LIMIT_DEG:
        return "heading", Consistency(True, f"the heading disagrees with the GNSS track: {seen}; the heading's units, "
                                            "convention or offset?")
    low, high = TRACK_LENGTH_RATIO
    if not low * length_g <= length_r <= high * length_g:
        return "velocity", Consistency(True, f"the velocity disagrees with the GNSS track: {seen}; the velocity's "
                                             "units or frame?")
    return "velocity", Consistency(True)


class SampleBuffer:
    """The latest `capacity` samples of one input as a ring (oldest overwritten): bounded memory.

    Samples must arrive in increasing stamp order (push rejects the others), so the ring is sorted.
    """

    def __init__(self, fields: Sequence[str], capacity: int) -> None:
        if capacity < 2:
            raise ValueError(f"buffer capacity {capacity} must be >= 2")
        self.fields = tuple(fields)
        self.capacity = int(capacity)
        self._t = np.zeros(self.capacity, dtype=np.int64)
        self._v = np.zeros((self.capacity, len(self.fields)), dtype=np.float64)
        self._next = 0  # index the next sample goes to
        self.size = 0
        self.overwritten = 0  # samples pushed out by newer ones

    def __len__(self) -> int:
        return self.size

    @property
    def latest_ns(self) -> int | None:
        return int(self._t[(self._next - 1) % self.capacity]) if self.size else None

    @property
    def oldest_ns(self) -> int | None:
        return int(self._t[(self._next - self.size) % self.capacity]) if self.size else None

    @property
    def nbytes(self) -> int:
        return self._t.nbytes + self._v.nbytes

    def push(self, stamp_ns: int, values: Sequence[float]) -> None:
        self._t[self._next] = stamp_ns
        self._v[self._next] = values
        self._next = (self._next + 1) % self.capacity
        if self.size == self.capacity:
            self.overwritten += 1
        else:
            self.size += 1

    def push_many(self, stamps_ns: np.ndarray, values: np.ndarray) -> None:
        """push() of M samples (stamps (M,), values (M, k)) in order, in one write of the ring (the last `capacity`
        of them when M is larger: what M pushes would leave)."""
        count = len(stamps_ns)
        if count == 0:
            return
        self.overwritten += max(0, self.size + count - self.capacity)
        kept = min(count, self.capacity)
        at = (self._next + np.arange(count - kept, count)) % self.capacity
        self._t[at] = stamps_ns[count - kept:]
        self._v[at] = values[count - kept:]
        self._next = (self._next + count) % self.capacity
        self.size = min(self.capacity, self.size + count)

    def replace_latest(self, values: Sequence[float]) -> None:
        """The latest sample's values replaced (its stamp kept): a newer message at the same clock reading."""
        if not self.size:
            raise ValueError("replace_latest on an empty buffer")
        self._v[(self._next - 1) % self.capacity] = values

    def clear(self) -> None:
        self._next = self.size = 0

    def samples(self, columns: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(t_ns (N,), values (N, k)) oldest first (copies); `columns`: those value columns only.

        The ring's one or two contiguous runs copied (no index array over the whole capacity)."""
        start = (self._next - self.size) % self.capacity
        chosen = slice(None) if columns is None else list(columns)

        def run(first: int, end: int) -> tuple[np.ndarray, np.ndarray]:
            return self._t[first:end].copy(), self._v[first:end][:, chosen].copy()

        if start + self.size <= self.capacity:
            return run(start, start + self.size)
        (t_old, v_old), (t_new, v_new) = run(start, self.capacity), run(0, start + self.size - self.capacity)
        return np.concatenate((t_old, t_new)), np.concatenate((v_old, v_new))

    def rate_hz(self, now_ns: int, span_s: float = RATE_WINDOW_S) -> float:
        """Samples per second over the last span_s before now (0 when fewer than two)."""
        t, _ = self.samples()
        recent = t[t >= now_ns - int(span_s * NS_PER_S)]
        if len(recent) < 2 or recent[-1] <= recent[0]:
            return 0.0
        return (len(recent) - 1) * NS_PER_S / float(recent[-1] - recent[0])


@dataclass
class InputTrack:
    """One input: its ring, its staleness limit and what was rejected (counts and the latest reason)."""

    role: str
    buffer: SampleBuffer
    max_age_s: float
    received: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    last_reject: str = ""
    last_reject_ns: int | None = None
    last_accept_ns: int | None = None  # clock when the latest good sample was accepted
    superseded: int = 0  # arrival-stamped samples replaced by a newer message at the same clock (InputSet.add)
    refused: str = ""  # why the whole input is refused (it disagrees with a redundant input); "" when it is not

    def reject(self, kind: str, message: str, now_ns: int) -> None:
        self.rejected[kind] = self.rejected.get(kind, 0) + 1
        self.last_reject, self.last_reject_ns = message, now_ns

    def age_s(self, now_ns: int) -> float | None:
        """Age of the newest sample (by its stamp) on the clock now; None before the first sample."""
        latest = self.buffer.latest_ns
        return None if latest is None else (now_ns - latest) / NS_PER_S


@dataclass(frozen=True)
class LiveSettings:
    dt: float  # model and window step (s)
    horizon_steps: int  # H
    state_delay_s: float = 0.0  # window end = now - state_delay_s (s): room for late messages
    max_future_s: float = 0.5  # stamps further ahead of the clock are refused (s)
    capacity: int = 2048  # samples per input ring
    datum: tuple[float, float] | None = None  # (lat, lon) deg of the NED plane; None: the first fix

    @property
    def dt_ns(self) -> int:
        return int(round(self.dt * NS_PER_S))


class LiveState(NamedTuple):
    """What a prediction starts from (marine frames, SI)."""

    t_c_ns: int  # centre of the averaging window: the state's time
    state: np.ndarray  # (4,) u, v, r, psi (psi continuous within the window, not wrapped)
    controls: np.ndarray  # (C,) the layout's controls (e.g. delta rad, rpm): held over the horizon
    position: np.ndarray | None  # (2,) x_n, y_e (m) in the datum's plane; None without GNSS
    samples: Mapping[str, int]  # samples averaged per role
    reference: np.ndarray | None = None  # (4,) rudder_only: the approach (ApproachTracker.reference); None: the start


class ApproachTracker:
    """A rudder_only boat's approach, online: data.recording.approach_state for a node that knows no manoeuvres.

    A boat without propulsion data runs its grey box at the engine speed that holds, in straight running, the speed
    of a reference state (models/greybox.py); replay gives it the manoeuvre's approach, the straight running before
    the first turn command, because a boat slows down in a turn at the same engine setting: the engine speed of a
    start inside a turn runs slow. Online the approach is the latest straight running (|steering| below the layout's
    straight_below, physics/actuators.py) that lasted at least APPROACH_S (data.recording): the medians of its
    u, v, r and the circular mean of its heading over its latest APPROACH_WINDOW_S. It is kept through the turns
    that follow and replaced by the next straight running once that has lasted APPROACH_S; a gap of more than
    APPROACH_S in the states observed ends a straight run. None before the first such run: the start state, as
    before. Thread-safe (the prediction cycle and the fit check's timer feed it)."""

    def __init__(self, layout: ActuatorLayout) -> None:
        self.layout = layout
        self._lock = threading.Lock()
        self._run: list[tuple[int, np.ndarray]] = []  # the current straight run: (t_ns, (4,) state)
        self._last_ns: int | None = None  # the latest state observed
        self._reference: np.ndarray | None = None

    def clear(self) -> None:
        """Forget the approach (the clock jumped back: a replay restarted)."""
        with self._lock:
            self._run, self._last_ns, self._reference = [], None, None

    @property
    def reference(self) -> np.ndarray | None:
        """(4,) [u, v, r, psi] of the approach, or None (class docstring)."""
        with self._lock:
            return None if self._reference is None else self._reference.copy()

    def observe(self, t_ns: int, state: np.ndarray, controls: np.ndarray) -> None:
        """One state (4,) and its controls (C,) at t_ns; states not after the latest observed are ignored."""
        state = np.asarray(state, dtype=float)
        steering = float(self.layout.steering_signal(np.asarray(controls, dtype=float)))
        if not (np.all(np.isfinite(state)) and math.isfinite(steering)):
            return
        with self._lock:
            if self._last_ns is not None and t_ns <= self._last_ns:
                return
            if self._last_ns is not None and t_ns - self._last_ns > APPROACH_S * NS_PER_S:
                self._run = []  # a gap ends the straight run
            self._last_ns = t_ns
            if abs(steering) >= self.layout.straight_below:
                self._run = []  # a turn: the approach before it is kept
                return
            self._run.append((t_ns, state))
            oldest = t_ns - int(APPROACH_WINDOW_S * NS_PER_S)
            while self._run[0][0] < oldest:
                self._run.pop(0)
            if (t_ns - self._run[0][0]) / NS_PER_S >= APPROACH_S:
                rows = np.array([row for _, row in self._run])  # (n, 4)
                heading = float(np.arctan2(np.sin(rows[:, 3]).mean(), np.cos(rows[:, 3]).mean()))
                self._reference = np.array([*np.median(rows[:, :3], axis=0), heading])

    def observe_recording(self, recording: Recording) -> None:
        """Every step of a Recording (the fit check's buffered span), in time order."""
        t_ns = recording.t0_ns + np.round(recording.t_s * NS_PER_S).astype(np.int64)  # (T,)
        for k in range(len(recording)):
            self.observe(int(t_ns[k]), np.array([*recording.nu[k], recording.psi[k]]), recording.controls[k])


class InputSet:
    """The buffers of every configured input and the checks between a message and the state."""

    def __init__(self, fields_by_role: Mapping[str, Sequence[str]], max_age_s: Mapping[str, float],
                 settings: LiveSettings, layout: ActuatorLayout = DEFAULT_LAYOUT) -> None:
        self.layout = layout
        self._used = state_fields(layout)  # role -> the fields the state uses (check_values, once per sample)
        self._plausible = plausible_ranges(layout)
        self.required = required_roles(layout)
        self.fields = state_fields(layout)
        # a configuration without them still runs (and reports); it just never predicts
        self.missing = [role for role in self.required if role not in fields_by_role]
        self.settings = settings
        self.tracks = {role: InputTrack(role, SampleBuffer(fields, settings.capacity), float(max_age_s[role]))
                       for role, fields in fields_by_role.items()}
        self.datum: tuple[float, float] | None = settings.datum
        self._plane = None if self.datum is None else LocalTangentPlane(*self.datum)
        self._last_now_ns: int | None = None
        self.refusals: dict[str, tuple[str, str]] = {}  # check -> (refused role, why), see check_consistency
        self.unjudged: dict[str, str] = {}  # check -> why it could not judge at its latest run ("" once it did)
        self._datum_given = settings.datum is not None
        self._last_fix: tuple[int, float, float] | None = None  # (stamp ns, lat, lon) of the latest buffered fix
        self._jumps: list[tuple[int, tuple[float, ...]]] = []  # the fixes refused as jumps in a row, as given
        self._arrival_stamped: set[str] = set()  # inputs without a header: stamped with the clock at arrival
        self._lag = (0.0, -1)  # (s, clock ns) the latest stamped message that reached the node late, and when
        self._next_check_ns: int | None = None
        # rudder_only: the approach whose engine speed its grey box holds (fed by every assembled state)
        self.approach = None if layout.propulsion else ApproachTracker(layout)

    # --------------------------------------------------------------- messages in
    def add(self, role: str, stamp_ns: int, values: Sequence[float], now_ns: int, at_arrival: bool = False) -> None:
        """Check and buffer one decoded sample (InputRejected says why it was refused; it is also counted).

        at_arrival: the stamp is the node's clock at the message's arrival (a header-less message). Then a stamp equal
        to the buffer's latest is no repeated message: the clock did not advance between two arrivals (sim time
        moves in /clock steps, 10-25 ms, and a node busy for longer takes several queued messages at one reading),
        and the newer message supersedes the latest sample's values (counted in `superseded`). A header stamp
        equal to the previous one is a repeat and refused ("duplicate")."""
        track = self.tracks[role]
        track.received += 1
        try:
            _check_values(role, track.buffer.fields, values, self._used.get(role, ()), self._plausible)
            latest = track.buffer.latest_ns
            if latest is not None and stamp_ns <= latest:
                if stamp_ns == latest and at_arrival:
                    track.buffer.replace_latest(values)
                    track.superseded += 1
                    track.last_accept_ns = now_ns
                    return
                if stamp_ns == latest:
                    raise InputRejected("duplicate", f"{role}: header stamp {_stamp_text(stamp_ns)} repeats the "
                                                     f"previous message's")
                raise InputRejected("backwards",
                                    f"{role}: stamp {(latest - stamp_ns) / NS_PER_S:.3f} s before the previous one")
            ahead = (stamp_ns - now_ns) / NS_PER_S
            if ahead > self.settings.max_future_s:
                raise InputRejected("future", f"{role}: stamp {ahead:.3f} s ahead of the clock "
                                              f"(limit {self.settings.max_future_s:g} s; clock or "
                                              f"use_sim_time mismatch?)")
            if role == POSITION_ROLE:
                self._check_jump(track, stamp_ns, values)
        except InputRejected as err:
            track.reject(err.kind, str(err), now_ns)
            raise
        self._note_arrival(role, at_arrival, now_ns - stamp_ns, now_ns)
        if role == POSITION_ROLE:
            fields = track.buffer.fields
            self._last_fix = (stamp_ns, float(values[fields.index("lat")]), float(values[fields.index("lon")]))
            if self.datum is None:
                self.datum = self._last_fix[1:]
                self._plane = LocalTangentPlane(*self.datum)
        track.buffer.push(stamp_ns, values)
        track.last_accept_ns = now_ns

    def _check_jump(self, track: InputTrack, stamp_ns: int, values: Sequence[float]) -> None:
        """A GNSS fix farther from the latest buffered one than GNSS_MAX_SPEED allows in the time between them (plus
        GNSS_JUMP_SLACK_M) is refused ("jump"): one fix of null island or a stray multipath solution is kilometres
        off, and in the track check it would refuse the (right) heading. When GNSS_REANCHOR_FIXES fixes in a row are
        refused so but agree with each other, the buffered fixes were the outliers (a wrong first fix): the buffer
        restarts from these (and an automatic datum with them), the current one accepted."""
        fields = track.buffer.fields
        fix = (stamp_ns, float(values[fields.index("lat")]), float(values[fields.index("lon")]))
        if self._last_fix is None:
            return
        distance, seconds = _fix_distance_m(self._last_fix, fix), (stamp_ns - self._last_fix[0]) / NS_PER_S
        if distance <= GNSS_MAX_SPEED * seconds + GNSS_JUMP_SLACK_M:
            self._jumps.clear()
            return
        if self._jumps:
            previous = self._jumps[-1]
            before = (previous[0], previous[1][fields.index("lat")], previous[1][fields.index("lon")])
            if _fix_distance_m(before, fix) > GNSS_MAX_SPEED * (stamp_ns - before[0]) / NS_PER_S + GNSS_JUMP_SLACK_M:
                self._jumps.clear()
        self._jumps.append((stamp_ns, tuple(values)))
        if len(self._jumps) >= GNSS_REANCHOR_FIXES:
            track.buffer.clear()
            if not self._datum_given:
                self.datum = None
            self._last_fix = None
            for stamp, row in self._jumps[:-1]:  # the current one is buffered by the caller
                track.buffer.push(stamp, row)
                self._last_fix = (stamp, float(row[fields.index("lat")]), float(row[fields.index("lon")]))
                if self.datum is None:
                    self.datum = self._last_fix[1:]
                    self._plane = LocalTangentPlane(*self.datum)
            self._jumps.clear()
            return
        raise InputRejected("jump", f"gnss: fix {distance:.0f} m from the previous one {seconds:.2f} s before it "
                                    f"(faster than {GNSS_MAX_SPEED:g} m/s): an outlier")

    def add_many(self, role: str, stamps_ns: np.ndarray, values: np.ndarray, now_ns: np.ndarray,
                 at_arrival: bool = False) -> list[InputRejected]:
        """add() of M decoded samples in order (stamps (M,) int64, values (M, k), the clock at each one's arrival
        (M,) int64, at_arrival as add()): when every sample passes add()'s checks (the used fields finite and
        plausible, the stamps increasing from the buffer's latest -- or, at_arrival, not decreasing, a run of equal
        stamps keeping its last sample -- none ahead of its arrival clock by more than max_future_s) they are
        counted and buffered in one write; otherwise add() runs one sample at a time, so that the refusals (returned
        in order) and every count are add()'s. test_live.py proves both ways equal."""
        track = self.tracks[role]
        fields = track.buffer.fields
        used = [i for i, name in enumerate(fields) if name in self._used.get(role, ())]
        stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
        values = np.asarray(values, dtype=np.float64).reshape(len(stamps_ns), len(fields))
        now_ns = np.asarray(now_ns, dtype=np.int64)
        latest = track.buffer.latest_ns
        columns = values[:, used]
        low = np.array([self._plausible.get(fields[i], (-math.inf, math.inf))[0] for i in used])
        high = np.array([self._plausible.get(fields[i], (-math.inf, math.inf))[1] for i in used])
        steps = np.diff(stamps_ns)
        if at_arrival:  # equal stamps allowed (the later supersedes)
            ordered = bool((steps >= 0).all()) and (latest is None or int(stamps_ns[0]) >= latest)
        else:
            ordered = bool((steps > 0).all()) and (latest is None or int(stamps_ns[0]) > latest)
        bulk = (len(stamps_ns) > 0 and role != POSITION_ROLE and bool(np.isfinite(columns).all())
                and bool(((columns >= low) & (columns <= high)).all()) and ordered
                and bool(((stamps_ns - now_ns) / NS_PER_S <= self.settings.max_future_s).all()))
        if not bulk:
            refused = []
            for stamp, row, now in zip(stamps_ns.tolist(), values.tolist(), now_ns.tolist()):
                try:
                    self.add(role, stamp, tuple(row), now, at_arrival)
                except InputRejected as err:
                    refused.append(err)
            return refused
        track.received += len(stamps_ns)
        self._note_arrival(role, at_arrival, int((now_ns - stamps_ns).max()), int(now_ns[-1]))
        if at_arrival:  # the last of each run of equal stamps; a first run at the latest stamp replaces it
            last_of_run = np.append(steps > 0, True)  # (M,)
            track.superseded += len(stamps_ns) - int(last_of_run.sum())
            stamps_ns, values = stamps_ns[last_of_run], values[last_of_run]
            if latest is not None and int(stamps_ns[0]) == latest:
                track.buffer.replace_latest(values[0])
                track.superseded += 1
                stamps_ns, values = stamps_ns[1:], values[1:]
        track.buffer.push_many(stamps_ns, values)
        track.last_accept_ns = int(now_ns[-1])
        return []

    def _note_arrival(self, role: str, at_arrival: bool, late_ns: int, now_ns: int) -> None:
        """Remember which inputs are stamped on arrival, and when a stamped one arrived more than
        CONSISTENCY_LAG_LIMIT_S after its stamp (the node behind its inputs: a loaded machine)."""
        if at_arrival:
            self._arrival_stamped.add(role)
        elif late_ns > CONSISTENCY_LAG_LIMIT_S * NS_PER_S:
            self._lag = (late_ns / NS_PER_S, now_ns)

    def _lagging(self, roles: Sequence[str], now_ns: int) -> str:
        """Why a check over `roles` cannot judge now because the node was behind its inputs within the window (an
        input stamped on arrival then carries the node's delay, the others do not); "" when it can."""
        late_s, at_ns = self._lag
        stamped_on_arrival = sorted(set(roles) & self._arrival_stamped)
        if not stamped_on_arrival or at_ns < 0 or now_ns - at_ns > CONSISTENCY_WINDOW_S * NS_PER_S:
            return ""
        return (f"the node took messages up to {late_s:.1f} s after their stamps (behind its inputs), and "
                f"{', '.join(stamped_on_arrival)} has no header: stamped on arrival, it would seem late")

    def observe_clock(self, now_ns: int) -> bool:
        """Clear every buffer when the clock jumped back (a replay restarted); True if it did."""
        jumped = self._last_now_ns is not None and now_ns < self._last_now_ns
        self._last_now_ns = now_ns
        if jumped:
            for track in self.tracks.values():
                track.buffer.clear()
            if self.approach is not None:
                self.approach.clear()
            self._last_fix, self._jumps, self._lag = None, [], (0.0, -1)
            self.unjudged = {}
            self._set_refusals({})
            self._next_check_ns = None
        return jumped

    # --------------------------------------------------------------- redundant inputs
    def _series(self, role: str, field: str) -> tuple[np.ndarray, np.ndarray] | None:
        track = self.tracks.get(role)
        if track is None or len(track.buffer) < 2 or field not in track.buffer.fields:
            return None
        t, values = track.buffer.samples()
        return t / NS_PER_S, values[:, track.buffer.fields.index(field)]

    def _set_refusals(self, refusals: dict[str, tuple[str, str]]) -> None:
        self.refusals = refusals
        for role, track in self.tracks.items():
            track.refused = "; ".join(why for refused, why in refusals.values() if refused == role)

    def check_consistency(self, now_ns: int) -> None:
        """Compare the redundant inputs (module docstring) over the latest CONSISTENCY_WINDOW_S, at most once per
        CONSISTENCY_PERIOD_S; a check without enough evidence keeps its previous verdict."""
        if self._next_check_ns is not None and now_ns < self._next_check_ns:
            return
        self._next_check_ns = now_ns + int(CONSISTENCY_PERIOD_S * NS_PER_S)
        refusals = dict(self.refusals)
        gyro, heading = self._series("imu", "yaw_rate"), self._series("heading", "psi")
        if gyro is not None and heading is not None:
            verdict = self._judge(("imu", "heading"), (gyro[0], heading[0]), now_ns,
                                  lambda start_s, end_s: heading_vs_gyro(*gyro, *heading, start_s, end_s))
            self._verdict("heading_vs_gyro", "heading", verdict, refusals)
        surge, sway = self._series("velocity", "u"), self._series("velocity", "v")
        lat, lon = self._series(POSITION_ROLE, "lat"), self._series(POSITION_ROLE, "lon")
        if None not in (surge, sway, heading, lat, lon) and self._plane is not None:
            x_n, y_e = self._plane.to_ned(lat[1], lon[1])
            blamed = ["velocity"]

            def track(start_s: float, end_s: float) -> Consistency:
                role, verdict = track_vs_gnss(surge[0], surge[1], sway[1], *heading, lat[0], x_n, y_e, start_s, end_s)
                blamed[0] = role
                return verdict

            verdict = self._judge(("velocity", "heading", POSITION_ROLE), (surge[0], heading[0], lat[0]), now_ns, track)
            self._verdict("track_vs_gnss", blamed[0], verdict, refusals)
        self._set_refusals(refusals)

    def _judge(self, roles: Sequence[str], times_s: Sequence[np.ndarray], now_ns: int,
               check: Callable[[float, float], Consistency]) -> Consistency:
        """Run `check` over the CONSISTENCY_WINDOW_S that ends at the latest stamp all its inputs have (message
        stamps, not the clock: a node behind its inputs compares the same span); not judged while the node was
        behind inputs stamped on arrival (_lagging)."""
        lagging = self._lagging(roles, now_ns)
        if lagging:
            return not_judged(lagging)
        end_s = min(min(float(t[-1]) for t in times_s), now_ns / NS_PER_S)
        return check(end_s - CONSISTENCY_WINDOW_S, end_s)

    def _verdict(self, name: str, role: str, verdict: Consistency, refusals: dict[str, tuple[str, str]]) -> None:
        """A judged check replaces its previous verdict; one that cannot judge keeps it and says why (unjudged)."""
        if verdict.judged:
            self.unjudged.pop(name, None)
            refusals.pop(name, None)
            if verdict.problem:
                refusals[name] = (role, verdict.problem)
        else:
            self.unjudged[name] = verdict.why_not

    # --------------------------------------------------------------- the buffered span as a Recording
    def buffered_recording(self, max_gap_s: float, name: str = "inputs") -> Recording:
        """The buffered samples of the required inputs (and GNSS) as the replay tool's Recording on the model's step
        (recording_from_signals: the same box averages as a bag's), from the latest gap longer than max_gap_s (and
        dt) in any required input on, where the replay tool cuts a bag at every gap longer than dt
        (replay.recordings.gap_cuts): the caller says which gaps its use bridges (the live fit check: the messages
        a busy node drops from its sensor-data queues, fit.MAX_GAP_S); a step without a sample is interpolated, as
        recording_from_signals does. RecordingError when the span holds less than one step or an input is
        missing."""
        dt_ns = self.settings.dt_ns
        limit_ns = max(dt_ns, int(max_gap_s * NS_PER_S))
        signals: dict[str, Signal] = {}
        start = None
        for role in (*self.required, POSITION_ROLE):
            track = self.tracks.get(role)
            if track is None or len(track.buffer) == 0:
                if role == POSITION_ROLE:
                    continue
                raise RecordingError(f"input {role}: no sample buffered")
            t, values = track.buffer.samples()
            signals[role] = Signal(t, values, track.buffer.fields)
            if role != POSITION_ROLE:
                gaps = np.flatnonzero(np.diff(t) > limit_ns + 1)
                first = int(t[gaps[-1] + 1]) if len(gaps) else int(t[0])
                start = first if start is None else max(start, first)
        kept = {}
        for role, signal in signals.items():
            keep = signal.t_ns >= start
            kept[role] = Signal(signal.t_ns[keep], signal.values[keep], signal.fields)
        if POSITION_ROLE in kept and len(kept[POSITION_ROLE]) < 2:
            del kept[POSITION_ROLE]
        return recording_from_signals(kept, self.settings.dt, name=name, datum=self.datum, layout=self.layout,
                                      max_gap_s=limit_ns / NS_PER_S)

    # --------------------------------------------------------------- state out
    def _window_mean(self, role: str, columns: Sequence[str], t_c_ns: int) -> tuple[np.ndarray, int]:
        """(mean of `columns` over the window about t_c, samples in it): recording.window_resample's value at t_c
        (window_mean: the same prefix sums from the ring's first sample, bit for bit), reading the used columns
        only and no sample after the window."""
        track = self.tracks[role]
        t, chosen = track.buffer.samples([track.buffer.fields.index(c) for c in columns])
        half = self.settings.dt_ns // 2
        lo = int(np.searchsorted(t, t_c_ns - half, side="left"))
        hi = int(np.searchsorted(t, t_c_ns + half, side="right"))  # closed window, as window_resample's
        if t[0] > t_c_ns - half:  # as Recording: whole windows only (a cut window would bias the mean)
            raise CycleSkipped(f"input {role}: the averaging window starts before its first buffered sample")
        if hi == lo:
            raise CycleSkipped(f"input {role}: no sample in the averaging window "
                               f"(latest {(t_c_ns + half - int(t[-1])) / NS_PER_S:.2f} s before its end)")
        if role == "heading":
            chosen = np.unwrap(chosen[:hi], axis=0)  # as Recording: unwrap (from the first sample), then average
        return window_mean(t, chosen, lo, hi), hi - lo

    def assemble(self, now_ns: int) -> LiveState:
        """The state at now (see the module docstring); CycleSkipped naming the missing or stale input."""
        if self.missing:
            raise CycleSkipped(f"inputs {self.missing} are not configured; a prediction needs {list(self.required)}")
        for role in self.required:
            track = self.tracks[role]
            age = track.age_s(now_ns)
            if age is None:
                raise CycleSkipped(f"input {role}: no message yet")
            if age > track.max_age_s:
                raise CycleSkipped(f"input {role}: stale, newest sample {age:.2f} s old (limit {track.max_age_s:g} s)")
        self.check_consistency(now_ns)
        for role, why in self.refusals.values():
            raise CycleSkipped(f"input {role} refused: {why}")
        t_end = now_ns - int(round(self.settings.state_delay_s * NS_PER_S))
        t_c = t_end - self.settings.dt_ns // 2
        means, counts = {}, {}
        for role in self.required:
            means[role], counts[role] = self._window_mean(role, self.fields[role], t_c)
        state = np.array([means["velocity"][0], means["velocity"][1], means["imu"][0], means["heading"][0]])
        controls = np.array([means[c.role][self.layout.fields_of(c.role).index(c.field)] for c in self.layout.controls])
        position = self._position(t_c, now_ns, counts)
        reference = None
        if self.approach is not None:
            self.approach.observe(t_c, state, controls)
            reference = self.approach.reference
        return LiveState(t_c, state, controls, position, counts, reference)

    def _position(self, t_c_ns: int, now_ns: int, counts: dict[str, int]) -> np.ndarray | None:
        track = self.tracks.get(POSITION_ROLE)
        if track is None or self._plane is None or len(track.buffer) == 0:
            return None
        age = track.age_s(now_ns)
        if age is None or age > track.max_age_s:
            return None
        fields = track.buffer.fields
        t, values = track.buffer.samples([fields.index("lat"), fields.index("lon")])
        half = self.settings.dt_ns // 2
        lo = int(np.searchsorted(t, t_c_ns - half, side="left"))
        hi = int(np.searchsorted(t, t_c_ns + half, side="right"))
        counts[POSITION_ROLE] = hi - lo
        if hi > lo:  # window_resample's mean, bit for bit (window_mean), of the fixes up to the window's end
            return window_mean(t, np.column_stack(self._plane.to_ned(values[:hi, 0], values[:hi, 1])), lo, hi)
        x_n, y_e = self._plane.to_ned(values[:, 0], values[:, 1])  # no fix inside: interpolated
        grid = np.array([t_c_ns], dtype=np.int64)
        return np.array([window_resample(t, x_n, grid, self.settings.dt_ns)[0],
                         window_resample(t, y_e, grid, self.settings.dt_ns)[0]])


class Prediction(NamedTuple):
    """One published prediction (NED/FRD, SI). Row k is the time t_ns[k] = t_c + (k + 1) dt."""

    stamp_ns: int  # the clock when it was made
    t_ns: np.ndarray  # (H,) future times
    eta: np.ndarray  # (H, 3) ensemble mean x_n, y_e (m, anchored), psi (rad, continuous)
    nu: np.ndarray  # (H, 3) ensemble mean u, v, r
    eta_members: np.ndarray  # (E, H, 3) every member, anchored
    anchored: bool  # positions in the datum's plane (GNSS) or relative to (0, 0)
    state: LiveState
    compute_s: float  # wall time of the rollout (s)


class Rollout:
    """The model with preallocated inputs: one (1, 4) state and (1, H, C) controls.

    It runs `artifact.runner`: for a DNN the rollout fused at load time (models/loading.with_fused_rollout: numpy's
    NumpyDnnRollout, called with numpy arrays directly, or TorchScript's FusedDnnRollout), the code `replay evaluate`
    runs too; for a grey box or hybrid the compiled kernel (models/kernel_rollout.KernelRollout, which re-reads the
    module's terms the sea estimate sets); for a low-order model its compiled numpy form (models/nomoto.
    NumpyNomotoRollout); for other families the file's module. A fused DNN asked for fewer
    members than it has is fused again with those members only (what is not published is not computed); other
    modules compute every member and the output is sliced."""

    def __init__(self, artifact: ModelArtifact, horizon_steps: int, ensemble_size: int | None = None) -> None:
        available = artifact.ensemble_size
        self.members = available if ensemble_size is None else int(ensemble_size)
        if self.members > available:
            raise ModelError(f"model {artifact.path}: ensemble_size {self.members} requested, the model has "
                             f"{available} member(s)")
        self.artifact = artifact
        self.module = artifact.runner
        if artifact.inference is not None and self.members < available:
            fuse_again = numpy_rollout if isinstance(artifact.inference, NumpyDnnRollout) else fused_rollout
            try:
                self.module = fuse_again(artifact, members=self.members)
            except ModelError:  # then every member is computed and the output sliced, as for other modules
                self.module = artifact.runner
        # NumpyDnnRollout and the grey box's compiled kernel: numpy in and out, no tensors on the way
        kernel = isinstance(self.module, (KernelRollout, NumpyNomotoRollout))  # numpy in and out, takes a reference
        self._numpy = self.module.rollout if isinstance(self.module, NumpyDnnRollout) or kernel else None
        self.horizon_steps = int(horizon_steps)
        self.dtype = artifact.module.m_s.dtype if hasattr(artifact.module, "m_s") else torch.float64
        self._state = torch.zeros(1, 4, dtype=self.dtype)
        self.n_controls = len(artifact.metadata["control_layout"])  # C, the model's control columns
        self._controls = torch.zeros(1, self.horizon_steps, self.n_controls, dtype=self.dtype)
        # a rudder_only grey box takes the approach whose engine speed it holds (ApproachTracker); other models do not
        self.accepts_reference = (self.module is artifact.module or kernel) and artifact.accepts_reference
        self._reference = torch.zeros(1, 4, dtype=self.dtype)
        for _ in range(WARM_UP_CALLS):  # TorchScript profiles and optimises its first calls: not in a live cycle
            self(np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(self.n_controls))

    def __call__(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
        """(E, H, 6) [u, v, r, x_n, y_e, psi] relative to the start; controls (C,) held for every step, or (H, C);
        reference (4,): a rudder_only grey box's approach (LiveState.reference; ignored by a model that takes none).

        ModelError "model X fails when run: ..." when the model's code raises (at warm-up: a start-up error)."""
        try:
            if self._numpy is not None:
                held = np.broadcast_to(np.asarray(controls, dtype=np.float64), (1, self.horizon_steps, self.n_controls))
                start = np.asarray(state, dtype=np.float64).reshape(1, 4)
                if reference is not None and self.accepts_reference:
                    return self._numpy(start, held, np.asarray(reference, dtype=np.float64).reshape(1, 4))[
                        : self.members, 0]
                return self._numpy(start, held)[: self.members, 0]
            self._state[0].copy_(torch.from_numpy(np.asarray(state, dtype=np.float64)))
            self._controls[0].copy_(torch.from_numpy(np.asarray(controls, dtype=np.float64)))  # (C,) to (H, C)
            with torch.inference_mode():
                if reference is not None and self.accepts_reference:
                    self._reference[0].copy_(torch.from_numpy(np.asarray(reference, dtype=np.float64)))
                    out = self.module(self._state, self._controls, self._reference)  # (E, 1, H, 6)
                else:
                    out = self.module(self._state, self._controls)  # (E, 1, H, 6)
            return out[: self.members, 0].double().numpy()
        except MODEL_RUN_ERRORS as err:
            raise ModelError(f"model {self.artifact.path} fails when run: {failure_reason(err)}") from err

    def batch(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None,
              helper: Executor | None = None) -> np.ndarray:
        """(E, B, H, 6) from one state (4,) under B control sequences (B, H, C): one call of the model; reference
        (4,) as for __call__. helper: a NumpyDnnRollout's or the kernel's batch is split in two, the first half rolled
        out on this executor's thread while the caller rolls out the second (numpy releases the GIL inside its
        products and activations, the kernel for its whole rollout: two cores work on one answer); the columns are
        independent, so the halves are the whole batch's up to the float rounding of BLAS's blocking for a narrower
        product (test_dnn_fused.py), the kernel's bit for bit (test_kernel.py)."""
        controls = np.asarray(controls, dtype=np.float64)
        if controls.ndim != 3 or controls.shape[1:] != (self.horizon_steps, self.n_controls):
            raise ModelError(f"controls of shape {controls.shape}, expected (B, {self.horizon_steps}, "
                             f"{self.n_controls})")
        count = controls.shape[0]
        try:
            if self._numpy is not None:
                states = np.broadcast_to(np.asarray(state, dtype=np.float64), (count, 4))  # (B, 4)
                if reference is not None and self.accepts_reference:  # the kernel of a rudder_only grey box
                    references = np.broadcast_to(np.asarray(reference, dtype=np.float64), (count, 4))
                    return self._numpy(states, controls, references)[: self.members]
                if helper is not None and count >= 2:
                    half = count // 2
                    first = helper.submit(self._numpy, states[:half], controls[:half])
                    second = self._numpy(states[half:], controls[half:])  # (E, B - half, H, 6)
                    return np.concatenate([first.result(), second], axis=1)[: self.members]  # (E, B, H, 6)
                return self._numpy(states, controls)[: self.members]
            states = torch.from_numpy(np.asarray(state, dtype=np.float64)).to(self.dtype).expand(count, 4)  # (B, 4)
            with torch.inference_mode():
                if reference is not None and self.accepts_reference:
                    references = torch.from_numpy(np.asarray(reference, dtype=np.float64))
                    references = references.to(self.dtype).expand(count, 4)
                    out = self.module(states, torch.from_numpy(controls).to(self.dtype), references)  # (E, B, H, 6)
                else:
                    out = self.module(states, torch.from_numpy(controls).to(self.dtype))  # (E, B, H, 6)
            return out[: self.members].double().numpy()
        except MODEL_RUN_ERRORS as err:
            raise ModelError(f"model {self.artifact.path} fails when run: {failure_reason(err)}") from err


Schedule = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""schedule(grid_ns (H,), held (C,)) -> (N, H, C): the controls of N plans at the model's step times."""


def _check_output(out: np.ndarray) -> None:
    if not np.all(np.isfinite(out)):
        raise CycleSkipped("model output is not finite (NaN/inf): nothing published")
    speed = np.hypot(out[..., 0], out[..., 1])
    if float(speed.max(initial=0.0)) > STEADY_SPEED_LIMIT:
        raise CycleSkipped(f"model output diverged (speed {float(speed.max()):.1f} m/s > {STEADY_SPEED_LIMIT:g} m/s)")


def _anchored(out: np.ndarray, position: np.ndarray | None) -> np.ndarray:
    """(..., H, 3) [x_n, y_e, psi] of the model's (..., H, 6), moved to the measured position (or (0, 0));
    CycleSkipped when the position makes it non-finite (a Path never carries a NaN pose)."""
    origin = position if position is not None else np.zeros(2)
    eta = np.concatenate([out[..., 3:5] + origin, out[..., 5:6]], axis=-1)
    if not np.isfinite(eta).all():
        raise CycleSkipped(f"the anchored path is not finite (position {origin.tolist()}): nothing published")
    return eta


def step_times(live: LiveState, settings: LiveSettings, first: int = 0) -> np.ndarray:
    """(H,) t_c + (first + k) dt, k = 0 .. H-1: the controls' times (first 0) or the predictions' (first 1)."""
    return live.t_c_ns + settings.dt_ns * np.arange(first, first + settings.horizon_steps, dtype=np.int64)


def predict(inputs: InputSet, rollout: Rollout, now_ns: int, schedule: Schedule | None = None,
            observe: Callable[[LiveState], object] | None = None) -> Prediction:
    """State at now -> rollout -> anchored, checked prediction (CycleSkipped when it cannot be trusted).

    The controls are the current ones held, or schedule's (one plan, plans.py) at t_c + k dt. `observe` sees the
    state before the rollout (the online estimator, sea.py: it may set the model's terms for this rollout).
    """
    live = inputs.assemble(now_ns)
    if observe is not None:
        observe(live)
    controls = live.controls if schedule is None else schedule(step_times(live, inputs.settings), live.controls)[0]
    started = time.perf_counter()
    out = rollout(live.state, controls, live.reference)  # (E, H, 6)
    compute_s = time.perf_counter() - started
    _check_output(out)
    eta_members = _anchored(out, live.position)  # (E, H, 3)
    t_ns = step_times(live, inputs.settings, first=1)
    return Prediction(now_ns, t_ns, eta_members.mean(axis=0), out[..., 0:3].mean(axis=0), eta_members,
                      live.position is not None, live, compute_s)


class BatchPrediction(NamedTuple):
    """Predictions for N candidate plans from one state (NED/FRD, SI); row k is at t_ns[k]."""

    stamp_ns: int  # the clock when it was made
    t_ns: np.ndarray  # (H,) future times t_c + (k + 1) dt
    eta: np.ndarray  # (N, H, 3) ensemble mean x_n, y_e (anchored), psi
    nu: np.ndarray  # (N, H, 3) ensemble mean u, v, r
    anchored: bool
    state: LiveState
    compute_s: float  # wall time of the one batched rollout (s)


def predict_batch(inputs: InputSet, rollout: Rollout, now_ns: int, schedule: Schedule) -> BatchPrediction:
    """State at now -> one rollout of batch N under schedule's N control sequences -> checked predictions."""
    return predict_prepared(rollout, prepare_batch(inputs, now_ns, schedule), now_ns)


class PreparedBatch(NamedTuple):
    """What a batched prediction needs from the inputs (prepare_batch): the rollout can then run on another thread
    while the input buffers go on filling."""

    live: LiveState
    controls: np.ndarray  # (N, H, C)
    first_ns: np.ndarray  # (H,) the predicted steps' times (step_times(..., first=1))


def prepare_batch(inputs: InputSet, now_ns: int, schedule: Schedule) -> PreparedBatch:
    """The state at now (CycleSkipped when there is none) and schedule's N control sequences at its step times."""
    live = inputs.assemble(now_ns)
    controls = schedule(step_times(live, inputs.settings), live.controls)  # (N, H, C)
    return PreparedBatch(live, controls, step_times(live, inputs.settings, first=1))


def predict_prepared(rollout: Rollout, prepared: PreparedBatch, now_ns: int, helper: Executor | None = None
                     ) -> BatchPrediction:
    """One rollout of batch N from a prepare_batch -> checked predictions (ModelError: the model failed); helper:
    Rollout.batch's second thread."""
    live, controls = prepared.live, prepared.controls
    started = time.perf_counter()
    out = rollout.batch(live.state, controls, live.reference, helper)  # (E, N, H, 6)
    compute_s = time.perf_counter() - started
    _check_output(out)
    mean = out.mean(axis=0)  # (N, H, 6): anchoring moves every member alike, so the mean is anchored once
    return BatchPrediction(now_ns, prepared.first_ns, _anchored(mean, live.position),
                           mean[..., 0:3], live.position is not None, live, compute_s)


def enu_covariance(eta_members: np.ndarray) -> np.ndarray:
    """(H, 3, 3) ensemble covariance (population) of [x east (m), y north (m), yaw ENU (rad)] per step."""
    enu = np.stack([eta_members[..., 1], eta_members[..., 0], -eta_members[..., 2]], axis=-1)  # (E, H, 3)
    centred = enu - enu.mean(axis=0, keepdims=True)
    return np.einsum("ehi,ehj->hij", centred, centred) / max(1, enu.shape[0])

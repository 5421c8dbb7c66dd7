"""The fit check in the node (pure: no rclpy; node.py runs it on its own timer, off the prediction cycle).

The same check `replay evaluate` and `replay diagnose` run before they answer (analysis/fit_check.py), taken online:

    windows   every fit_check.period_s the node's input buffers become a Recording on the model's step
              (live.InputSet.buffered_recording: the replay tool's box averages, cut at the latest gap longer than
              MAX_GAP_S), and fit_check.rolled_windows finds its steady windows (held commands, settled u and r) and
              rolls the model out for each, as for a bag. The buffers hold the latest buffer_capacity samples (20 s of a
              100 Hz gyro), so a window is seen while it lasts: a window of a later check that overlaps an earlier
              one in time replaces it (the same held commands, seen longer), the others are kept, the latest
              MAX_WINDOWS of them. The measured |u| of every step seen is kept too (the latest SPEED_SAMPLES) for the
              data's speed against the vessel's top speed.
    verdict   fit_check.judge_windows on the kept windows: the median speed and yaw-rate ratios (predicted /
              measured) against the calm-water allowances widened by what the strongest cause the diagnosis knows
              can do to a right model of the node's vessel, and the speed against the top speed. `fits`,
              `mismatch` (the reasons name the numbers), or `unchecked` (no steady window yet).
    the model its own copy of the node's model file (loaded again): the rollouts of a check run in a worker
              thread beside the prediction cycle (a grey box's straight window is a SETTLE_S rollout, 1.5 s of
              TorchScript for a 0.2 s step on this machine; TorchScript releases the GIL), and the sea estimate the
              node applies to its own grey box (sea.py) never reaches the copy: the check judges the calm-water
              model, as the replay tool does. A check starts when period_s has passed and the previous one ended.
    the cache a window whose rollout inputs (start state, controls, reference, kind, averaged steps) are the same
              bytes as a window of the previous check does not get its causes rolled out again: their changes are
              served from that check (keyed on the content, never on the stamps: a window seen again on a shifted
              grid has other box means and is rolled out anew). The rollouts are deterministic, so the verdict and
              its numbers are the same with and without it (test_node_fit.py). It serves the kept windows (as the
              check did before by the window's identity) and windows found again with the same bytes (inputs that
              repeat bit for bit: a simulated or benchmark feed of constant values, in one process). The model's
              rollout of a window found by a check is made anew each time: live, a window found again is new content
              (its grid moves with the buffers' first samples, its length with their span; over DDS a cache of
              those rollouts served none of them, so there is none).

Between cycles: the check's own Python (the model's rollouts of its windows, the verdict, compiling the causes'
rollout) holds the GIL for a few ms at a time, and a cycle that starts meanwhile waits for it (up to the interpreter's
5 ms switch interval: the node's cycle took 8.5-10 ms at its p99 with the check, 2.6 ms without it:
docs/results/node_latency.md). So
the worker starts those parts in the gap after a cycle (CycleGap: within GAP_SHARE of a period after a cycle ended,
never waiting longer than WAIT_PERIODS periods: without cycles it does not wait for them); the causes' TorchScript
rollout itself releases the GIL and runs beside the cycles, in a worker thread that node.py makes FIT_NICE nicer
than the node (on busy cores the cycle gets the core first).

Reported on /diagnostics as `predictor: fit check`: OK with the ratios (or "no steady window yet"), WARN when a ratio
lies beyond the calm-water allowance and only a strong sea or fault at the top of its range explains it, or when the
check cannot run, ERROR on a mismatch with the numbers and the remedy (fit_check.REMEDY). On a mismatch the predictions
keep being published, flagged by that ERROR, unless fit_check.refuse is true: then the node publishes no prediction
(the cycle is skipped naming the refusal) until a later check finds the model fits. Publishing by default: a planner
that consumes predicted_path loses its input at once on a verdict from the few windows a live check has seen, and
the standard ROS place to act on a fault is /diagnostics (an aggregator, a monitor); a team that wants the replay
tool's refusal sets fit_check.refuse.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from usv_predictor.analysis import fit_check as fc
from usv_predictor.data.recording import Recording
from usv_predictor.errors import ConfigError
from usv_predictor.physics.actuators import ActuatorLayout
from usv_predictor.physics.vessel import Vessel
from usv_predictor.records import NS_PER_S

MAX_GAP_S = 2.0  # (s) a longer gap in a required input cuts the span a check reads (live.InputSet.buffered_recording):
# shorter ones are messages a busy node drops from its sensor-data queues (depth 5; a 0.44 s grey-box cycle loses
# 40 samples of a 100 Hz gyro and stamps the queued header-less headings alike), which a window of held commands
# (>= fit_check.MIN_HOLD_S) bridges by interpolation
MAX_WINDOWS = 40  # steady windows kept (the latest): bounds the cost of a check that rolls the causes out
SPEED_SAMPLES = 3000  # measured |u| samples kept, one per model step (10 min at dt 0.2 s)
PERIOD_RANGE_S = (0.5, 600.0)  # (s) allowed fit_check.period_s
COST_WINDOW = 50  # checks kept for the cost percentiles
GAP_SHARE = 0.25  # (-) the check's GIL-heavy parts start within this share of a cycle period after a cycle ended
WAIT_PERIODS = 1.5  # (-) and wait at most this many periods for one (no cycle ran: the node is not predicting)
DATA = "the node's inputs"  # how the reasons name what was measured


@dataclass(frozen=True)
class FitCheckSettings:
    """The parameters fit_check.* (docs/node.md)."""

    enabled: bool = True  # run the check
    period_s: float = 5.0  # (s) between two checks
    refuse: bool = False  # publish no prediction while the verdict is a mismatch

    def __post_init__(self) -> None:
        low, high = PERIOD_RANGE_S
        if not (isinstance(self.period_s, (int, float)) and low <= float(self.period_s) <= high):
            raise ConfigError(f"parameter fit_check.period_s = {self.period_s!r}: expected a number of seconds in "
                              f"[{low:g}, {high:g}]")


@dataclass(frozen=True)
class LiveWindow:
    """One steady window on the node's clock and its rollout (fit_check.Rolled)."""

    start_ns: int
    end_ns: int
    rolled: fc.Rolled


class CycleGap:
    """Where the node's prediction cycles leave room (module docstring, "Between cycles"): the cycle calls ended()
    at its end, the check's worker wait() before a part that holds the GIL. Thread-safe."""

    def __init__(self, period_s: float) -> None:
        self.period_s = float(period_s)  # (s) between two cycles (1 / rate_hz)
        self._ended: float | None = None  # time.monotonic() at the end of the latest cycle
        self._changed = threading.Condition()
        self.waited_s = 0.0  # (s) total time the check waited for a gap

    def ended(self) -> None:
        with self._changed:
            self._ended = time.monotonic()
            self._changed.notify_all()

    def wait(self) -> None:
        """Return within GAP_SHARE of a period after a cycle ended (at once when in such a gap now), or after
        WAIT_PERIODS periods without one."""
        started = time.monotonic()
        deadline = started + WAIT_PERIODS * self.period_s
        with self._changed:
            while True:
                now = time.monotonic()
                if (self._ended is not None and now - self._ended < GAP_SHARE * self.period_s) or now >= deadline:
                    self.waited_s += now - started
                    return
                self._changed.wait(deadline - now)


def content_key(*arrays: np.ndarray | None) -> tuple:
    """A hashable key of arrays' exact content (dtype, shape, bytes; None stays None): equal keys, equal inputs."""
    return tuple(None if a is None else (np.asarray(a).dtype.str, np.asarray(a).shape,
                                         np.ascontiguousarray(a).tobytes()) for a in arrays)


class LiveFitCheck:
    """The fit check of one model on the node's inputs: windows collected over time, the latest verdict."""

    def __init__(self, model: Any, vessel: Vessel | None, layout: ActuatorLayout, label: str,
                 settings: FitCheckSettings, cached: bool = True) -> None:
        self.model = model  # a fit_check Predictor (the ModelArtifact)
        self.vessel = vessel
        self.layout = layout
        self.label = label
        self.settings = settings
        self.windows: list[LiveWindow] = []
        self.speeds: deque[float] = deque(maxlen=SPEED_SAMPLES)  # measured |u| (m/s), one per step
        self._speeds_until_ns: int | None = None  # grid time of the latest |u| kept
        self.check: fc.FitCheck | None = None
        self.error = ""  # why the latest check could not run ("" when it ran)
        self.runs = 0
        self.cost_s: deque[float] = deque(maxlen=COST_WINDOW)
        self.last_run_ns: int | None = None
        self._next_ns: int | None = None
        self.last_reset = ""
        self._lock = threading.Lock()  # run() may work in another thread than reset() and report()
        self._generation = 0  # a reset while a check runs discards that check's result
        self.cached = cached  # serve the causes' changes of windows whose content the previous check rolled out
        #                      (False: the reference the tests compare with)
        self._changes: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}  # content -> (du (N,), dr (N,)), kept windows
        self.causes_rolled_out = 0  # windows whose causes were rolled out
        self.causes_served = 0  # windows whose causes' changes were served from the cache

    def due(self, now_ns: int) -> bool:
        """Is a check due (enabled, and period_s after the previous one)?"""
        return self.settings.enabled and (self._next_ns is None or now_ns >= self._next_ns)

    def reset(self, why: str) -> None:
        """Forget the windows and the verdict (a clock jump, a new model); a check running now is discarded."""
        with self._lock:
            self._generation += 1
            self.windows = []
            self._changes = {}
            self.speeds.clear()
            self._speeds_until_ns = None
            self.check = None
            self.error = ""
            self._next_ns = None
            self.last_reset = why

    def skip(self, why: str, now_ns: int) -> None:
        """A check that could not run (no span of the inputs without a gap, an input refused): the verdict stays."""
        with self._lock:
            self.error = why
            self._next_ns = now_ns + int(self.settings.period_s * NS_PER_S)

    def run(self, recording: Recording, now_ns: int, reference: np.ndarray | None = None,
            gap: CycleGap | None = None) -> fc.FitCheck | None:
        """One check on the buffered `recording` (live.InputSet.buffered_recording), the windows merged with the kept
        ones; the verdict of every kept window (module docstring), or None when a reset came while it ran.
        reference (4,): a rudder_only boat's approach (live.ApproachTracker, the predictions' own), whose engine speed
        the rollouts hold; None: the buffered span's own approach (which, in a buffer that starts inside a long
        turn, is the turn's slower speed). gap: the node's cycles, whose gaps the check's GIL-heavy parts wait for."""
        if gap is not None:
            gap.wait()
        started, waited = time.perf_counter(), gap.waited_s if gap is not None else 0.0
        with self._lock:
            generation = self._generation
            self._next_ns = now_ns + int(self.settings.period_s * NS_PER_S)
        found = fc.rolled_windows(self.model, [recording], self.layout, reference)  # the model's rollouts
        grid_ns = recording.t0_ns + np.round(recording.t_s * NS_PER_S).astype(np.int64)  # (T,)
        with self._lock:
            if generation != self._generation:
                return None
            windows = list(self.windows)
            for rolled in found:
                start = recording.t0_ns + int(round(rolled.window.start_s * NS_PER_S))
                end = recording.t0_ns + int(round(rolled.window.end_s * NS_PER_S))
                windows = [w for w in windows if w.end_ns < start or w.start_ns > end]  # seen longer now
                windows.append(LiveWindow(start, end, rolled))
            self.windows = sorted(windows, key=lambda w: w.end_ns)[-MAX_WINDOWS:]
            new = grid_ns > (self._speeds_until_ns if self._speeds_until_ns is not None else -1)
            self.speeds.extend(np.abs(recording.nu[new, 0]).tolist())
            if len(grid_ns):
                self._speeds_until_ns = int(grid_ns[-1])
            rolled_kept, speeds = [w.rolled for w in self.windows], np.array(self.speeds)
        check = fc.judge_windows(self.label, self.layout, rolled_kept, speeds, recording.dt, vessel=self.vessel,
                                 data=DATA, changes_of=partial(self._cause_changes, recording.dt, generation, gap))
        with self._lock:
            if generation != self._generation:
                return None
            self.check = check
            self.error = ""
            self.runs += 1
            self.last_run_ns = now_ns
            self.cost_s.append(time.perf_counter() - started - ((gap.waited_s - waited) if gap is not None else 0.0))
        return check

    def _cause_changes(self, dt: float, generation: int, gap: CycleGap | None, rolled: list[fc.Rolled],
                       causes: tuple[fc.Cause, ...]) -> tuple[np.ndarray, np.ndarray]:
        """fit_check.cause_changes of the windows, rolled out once per window content (a kept window is not rolled
        again, nor a new one the same as a kept one: the causes' rollouts are the check's most expensive part);
        (du, dr) each (N causes, W windows). Kept for the next check unless a reset came (generation)."""
        cache = self._changes if self.cached else {}  # this check's own reference (a reset rebinds self._changes)
        keys = [(dt, r.window.kind, r.averaged, *content_key(r.state, r.controls, r.reference)) for r in rolled]
        missing = {key: r for key, r in zip(keys, rolled) if key not in cache}
        if missing:
            if gap is not None:  # building the causes' batch (compiling their rollout the first time) holds the GIL
                gap.wait()
            du, dr = fc.cause_changes(self.vessel, dt, list(missing.values()), causes)
            cache = {**cache, **{key: (du[:, k], dr[:, k]) for k, key in enumerate(missing)}}
        self.causes_rolled_out += len(missing)
        self.causes_served += len(keys) - len(missing)
        cache = {key: cache[key] for key in keys}
        with self._lock:
            if self.cached and generation == self._generation:
                self._changes = cache
        return np.stack([cache[key][0] for key in keys], axis=1), np.stack([cache[key][1] for key in keys], axis=1)

    @property
    def refusing(self) -> str:
        """The refusal line while fit_check.refuse holds back the predictions of a model that does not fit; ""."""
        if self.settings.enabled and self.settings.refuse and self.check is not None and self.check.mismatch:
            return self.check.refusal("fit_check.refuse:=false", DATA)
        return ""

    def report(self, now_ns: int) -> tuple[str, str, dict[str, str]]:
        """(level "ok" | "warn" | "error", message, values) for /diagnostics (module docstring)."""
        with self._lock:
            return self._report(now_ns)

    def _report(self, now_ns: int) -> tuple[str, str, dict[str, str]]:
        values: dict[str, str] = {"enabled": str(self.settings.enabled).lower(),
                                  "refuse": str(self.settings.refuse).lower(),
                                  "period_s": f"{self.settings.period_s:g}", "checks": str(self.runs),
                                  "limits": f"speed ratio "
                                            f"1/{fc.SPEED_RATIO_LIMIT:g}..{fc.SPEED_RATIO_LIMIT:g}, yaw-rate "
                                            f"ratio 1/{fc.YAW_RATE_RATIO_LIMIT:g}..{fc.YAW_RATE_RATIO_LIMIT:g} (calm "
                                            "water; widened by the strongest cause the diagnosis knows)"}
        if self.cost_s:
            ms = np.array(self.cost_s) * 1e3
            values.update(compute_ms_p50=f"{np.percentile(ms, 50):.1f}", compute_ms_max=f"{ms.max():.1f}")
        if self.causes_rolled_out or self.causes_served:
            values["rollouts_served"] = (f"{self.causes_served} of {self.causes_served + self.causes_rolled_out} "
                                         "windows' causes (from the previous check: the same content)")
        if self.last_run_ns is not None:
            values["last_check_age_s"] = f"{(now_ns - self.last_run_ns) / NS_PER_S:.1f}"
        if self.last_reset:
            values["last_reset"] = self.last_reset
        if not self.settings.enabled:
            return "ok", "disabled (fit_check.enabled is false)", values
        check = self.check
        if check is not None:
            values.update(self._check_values(check))
        if self.error:
            values["not_run"] = self.error
        if check is None or not check.windows:
            if self.error:
                return "warn", f"not run: {self.error}", values
            top = ""
            if check is not None and check.verdict == "fits" and check.data_speed_mps is not None:
                top = (f"; speed {check.data_speed_mps:.2g} m/s within its top speed {check.top_speed_mps:.2g} m/s "
                       "at full command")
            if check is not None and check.mismatch:
                return "error", (f"{check.model} does not fit {DATA}: {'; '.join(check.reasons)}: {fc.REMEDY}; "
                                 f"{self._published()}"), values
            return "ok", (f"no steady window yet (commands held for {fc.MIN_HOLD_S:g} s or more with u and r "
                          f"settled over {fc.STEADY_S:g} s){top}"), values
        stale = f" (the latest check did not run: {self.error})" if self.error else ""
        if check.mismatch:
            return "error", (f"{check.model} does not fit {DATA}: {'; '.join(check.reasons)}: {fc.REMEDY}; "
                             f"{self._published()}{stale}"), values
        strong = self._explained_only_by_a_cause(check)
        if strong:
            return "warn", f"fits only with a strong sea or fault: {'; '.join(strong)}{stale}", values
        if stale:
            return "warn", f"fits: {self._ratios(check)}{stale}", values
        return "ok", f"fits: {self._ratios(check)}", values

    def _published(self) -> str:
        return ("predictions suppressed (fit_check.refuse)" if self.settings.refuse
                else "predictions still published, flagged here (fit_check.refuse is false)")

    @staticmethod
    def _ratios(check: fc.FitCheck) -> str:
        parts = []
        if check.speed_ratio is not None:
            parts.append(f"speed ratio {check.speed_ratio:.2f} ({check.speed_windows} runs)")
        if check.yaw_rate_ratio is not None:
            parts.append(f"yaw-rate ratio {check.yaw_rate_ratio:.2f}")
        return ", ".join(parts) + f" over {len(check.windows)} steady window(s)"

    @staticmethod
    def _explained_only_by_a_cause(check: fc.FitCheck) -> list[str]:
        """A ratio beyond the calm-water allowance that one cause at the top of its range explains: one clause each."""
        out = []
        for name, ratio, limit, explanation in (
                ("speed ratio", check.speed_ratio, fc.SPEED_RATIO_LIMIT, check.speed_explanation),
                ("yaw-rate ratio", check.yaw_rate_ratio, fc.YAW_RATE_RATIO_LIMIT, check.yaw_rate_explanation)):
            if ratio is None or 1.0 / limit <= ratio <= limit or explanation is None or not explanation.explained:
                continue
            cause = f" ({explanation.cause.label} at the top of its range)" if explanation.cause is not None else ""
            out.append(f"{name} {ratio:.2f} beyond the calm-water allowance {limit:g}, within what one cause the "
                       f"diagnosis knows explains{cause}")
        return out

    @staticmethod
    def _check_values(check: fc.FitCheck) -> dict[str, str]:
        straight = sum(w.kind == "straight" for w in check.windows)
        values = {"verdict": check.verdict, "model": check.model,
                  "windows": f"{len(check.windows)} ({straight} straight, {len(check.windows) - straight} turns)"}
        optional = {"speed_ratio": (check.speed_ratio, ".3f"), "yaw_rate_ratio": (check.yaw_rate_ratio, ".3f"),
                    "froude_data": (check.froude_measured, ".3f"), "froude_model": (check.froude_model, ".3f"),
                    "data_speed_mps": (check.data_speed_mps, ".3f"), "top_speed_mps": (check.top_speed_mps, ".3f")}
        for key, (value, spec) in optional.items():
            if value is not None and math.isfinite(value):
                values[key] = format(value, spec)
        if check.speed_ratio is not None:
            values["speed_windows"] = check.speed_windows
        if check.reasons:
            values["reasons"] = "; ".join(check.reasons)
            values["remedy"] = fc.REMEDY
        return values

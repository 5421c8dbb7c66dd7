"""First-order (wave-frequency) motion in measured manoeuvres, and the wave filter of the multiple-shooting residuals.

In waves a hull oscillates at the encounter frequency: its measured u, v, r and heading carry a zero-mean motion of
the wave period (seed 000 sec. 2.3: "the high-frequency part accounts for the oscillations of the measured motion
states"). A manoeuvring model does not predict it, by design, and should not: autopilots and DP systems remove it
from the feedback by a wave filter (Fossen 2021, "Handbook of Marine Craft Hydrodynamics and Motion Control",
sec. 13.4). In a diagnosis it is noise far above the sensors' (waves of H_s 1.0-1.4 m at T_p 3 s: a held-out loss
of ~53 noise units for the true model, the ceiling of a model that fits being 100), so

    detect   motion_level: the high-pass power (signal minus its zero-phase Gaussian smoothing of DETECT_S) of the
             measured u and v in the straight running before each manoeuvre's first turn command (where the controls
             are constant and the calm-water hull holds a steady state), in noise units (data/segments.SIGMA), the
             median over the manoeuvres; days without waves <= 0.2 (the 114 hidden-effect draws without waves:
             jari_usv <= 0.06, the Otter's gusts up to 0.18; the shipped Otter calm day 0.10); the shipped sea trials'
             0.25-0.5 m waves 5-7; waves of H_s 0.8-1.5 m at T_p 2-3 s 13-70. At or above MOTION_LEVEL the diagnosis
             filters;
    filter   the weighted residuals of a segment (prediction minus measurement) smoothed along its horizon by a
             Gaussian of FILTER_S (normalised over the segment's measured samples: a constant residual is unchanged,
             the ends need no padding). The same operator on both sides: the prediction's own fast dynamics and the
             measurement's are smoothed alike, so a model that matches the manoeuvre keeps a zero residual (the true
             model on a clean jari_usv day: held-out loss 0.10 -> 0.05 with it, test_wave_motion.py; a 4.9 m unknown
             boat's true model on its clean day 0.42 with the residuals smoothed over 0.75 s, 20 with the measured
             states smoothed instead), while the wave-frequency part is removed (the true model of a 15.6 m boat in
             1.42 m waves: 53.6 -> 12.7; of a 4.9 m boat in 1.35 m waves 13.4 with it; the rest is the wave velocity
             at the segment's measured start, which the rollout carries).
"""
from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from usv_predictor.data.recording import Recording, straight_samples

DETECT_S = 0.75  # (s) standard deviation of the Gaussian whose smoothing the detector subtracts (high-pass: a 3 s
#                  wave keeps 71 % of its amplitude, a 20 s trend 3 %)
FILTER_S = 1.5  # (s) standard deviation of the Gaussian that filters the residuals along a segment (gain at the
#                 wave period T: exp(-2 pi^2 (FILTER_S / T)^2): 0.007 at 3 s, 0.26 at 6 s, 0.71 at 12 s)
MOTION_LEVEL = 1.0  # (noise units) the high-pass power of u and v in straight running at which the residuals are
#                     filtered: 5 x the days without waves (<= 0.2), a thirteenth of the suites' waves (module
#                     docstring)
EDGE_S = 1.0  # (s) left out at each end of a straight run: the recording's start and the first turn command, which
#              the smoothing blends in
MIN_SAMPLES = 6  # straight samples (after the edges) a manoeuvre needs to be measured
MODES = ("auto", "on", "off")  # `replay diagnose --wave-filter`: by the detector, always, never


@dataclass(frozen=True)
class WaveFilter:
    """The wave filter of a diagnosis: what the detector measured and whether the residuals are filtered."""

    mode: str  # one of MODES
    motion_level: float  # (noise units) median over the measured manoeuvres; NaN when none has a straight run
    measured: int  # manoeuvres with a straight run long enough to measure
    applied: bool
    sigma_s: float  # (s) FILTER_S when applied, else 0

    def describe(self) -> str:
        level = (f"{self.motion_level:.3g} noise units of wave-frequency motion in straight running "
                 f"({self.measured} manoeuvre(s); filtered from {MOTION_LEVEL:g})" if np.isfinite(self.motion_level)
                 else "no straight running to measure wave-frequency motion in")
        if self.applied:
            return f"wave filter on ({self.mode}): {level}; residuals smoothed over {self.sigma_s:g} s"
        return f"wave filter off ({self.mode}): {level}"

    def to_json(self) -> dict:
        return {"mode": self.mode, "applied": self.applied, "sigma_s": self.sigma_s,
                "motion_level": float(self.motion_level) if np.isfinite(self.motion_level) else None,
                "measured_manoeuvres": self.measured, "threshold": MOTION_LEVEL}


def _kernel(sigma_steps: float) -> np.ndarray:
    """(2 h + 1,) Gaussian weights exp(-k^2 / (2 sigma^2)) at the lags k = -h..h, h = floor(4 sigma) (unnormalised)."""
    half = int(4.0 * max(sigma_steps, 1e-9))
    lag = np.arange(-half, half + 1) / max(sigma_steps, 1e-9)
    return np.exp(-0.5 * lag * lag)


def gaussian_smooth(x: np.ndarray, sigma_steps: float) -> np.ndarray:
    """(T, k) zero-phase Gaussian smoothing of (T, k) samples along time, truncated at 4 sigma and renormalised at the
    ends (the weighted mean of the samples present under the kernel, no padding): smoothing_operator(T) @ x, by
    convolution (a straight run of any length costs O(T), not a T x T matrix)."""
    kernel = _kernel(sigma_steps)
    half = len(kernel) // 2
    inside = slice(half, half + len(x))  # of the full convolution (T + 2 half,)
    norm = np.convolve(np.ones(len(x)), kernel)[inside]  # (T,) the kernel's weight inside the run
    return np.column_stack([np.convolve(x[:, j], kernel)[inside] / norm for j in range(x.shape[1])])


@functools.lru_cache(maxsize=64)
def smoothing_operator(steps: int, sigma_steps: float) -> np.ndarray:
    """(steps, steps) the same Gaussian weights (_kernel) as a matrix, G[i, j] = kernel[j - i], rows normalised to 1
    (read-only: it is cached)."""
    kernel = _kernel(sigma_steps)
    half = len(kernel) // 2
    lag = np.arange(steps)[None, :] - np.arange(steps)[:, None]  # (steps, steps) j - i
    op = np.where(np.abs(lag) <= half, kernel[np.clip(lag + half, 0, len(kernel) - 1)], 0.0)
    op /= op.sum(axis=1, keepdims=True)
    op.setflags(write=False)
    return op


def straight_run_power(recording: Recording, sigma: Sequence[float]) -> float:
    """(noise units) mean over the straight running before the first turn command (its interior: EDGE_S left out at
    each end) of the high-pass power of u and v, sum over the two of (x - smooth(x))^2 / sigma^2; NaN when that run is
    shorter than MIN_SAMPLES."""
    straight = straight_samples(recording.controls, recording.actuator_layout)
    leading = int(np.argmin(straight)) if not np.all(straight) else len(straight)
    edge = int(round(EDGE_S / recording.dt))
    run = recording.nu[:leading + edge, :2]  # the run and what follows it within the edge (smoothed together)
    if leading - 2 * edge < MIN_SAMPLES or not np.all(np.isfinite(run)):
        return float("nan")
    high = run - gaussian_smooth(run, DETECT_S / recording.dt)
    inner = high[edge:leading - edge] / np.asarray(sigma[:2])
    return float(np.mean(np.sum(inner * inner, axis=1)))


def wave_filter(recordings: Sequence[Recording], sigma: Sequence[float], mode: str = "auto") -> WaveFilter:
    """The detector over `recordings` (module docstring) and the filter it decides in `mode` (auto: at or above
    MOTION_LEVEL; on, off: as said, the level still measured and reported)."""
    if mode not in MODES:
        raise ValueError(f"wave filter mode {mode!r}: expected one of {', '.join(MODES)}")
    levels = [p for p in (straight_run_power(r, sigma) for r in recordings) if np.isfinite(p)]
    level = float(np.median(levels)) if levels else float("nan")
    applied = mode == "on" or (mode == "auto" and bool(levels) and level >= MOTION_LEVEL)
    return WaveFilter(mode, level, len(levels), applied, FILTER_S if applied else 0.0)

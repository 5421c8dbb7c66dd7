"""Multiple-shooting segments of recordings: the measured state at a segment's start, the recorded controls over its
horizon and what was measured over it, weighted by the noise scales SIGMA. One definition for the diagnosis (its
hypotheses' fits and losses, analysis/diagnosis.py) and the hybrid's multi-step training (fitting/hybrid_fit.py).

    state (B, 4) [u, v, r, psi]; controls (B, H, C) the layout's columns; target (B, H, 6) [u, v, r, x_n, y_e, psi]
    with positions from the segment's start (NED, m); weight (B, H, 6) 1 / sigma where measured, 0 where missing;
    reference (B, 4) the manoeuvre's approach state (the engine speed a rudder_only grey box holds); filter_steps the
    wave filter of the residuals along the horizon (data/wave_motion.py; 0: none).

weighted_residuals is the one definition of the residuals (prediction minus measurement, in noise scales) a fit and
a score of segments take.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from usv_predictor.data.recording import Recording, approach_state, straight_samples
from usv_predictor.data.wave_motion import smoothing_operator
from usv_predictor.errors import DiagnosisError
from usv_predictor.records import whole_steps

SIGMA = (0.05, 0.05, 0.005, 1.0, 1.0, 0.01)  # u, v (m/s), r (rad/s), x_n, y_e (m), psi (rad): noise scales
VELOCITY_HEADING = (0, 1, 2, 5)  # u, v, r, psi of a (B, H, 6) rollout or target: the multi-step fits' columns


@dataclass(frozen=True)
class Segments:
    """A batch of multiple-shooting segments (torch float64)."""

    state: torch.Tensor  # (B, 4) measured u, v, r, psi at the segment start
    controls: torch.Tensor  # (B, H, 2) measured delta, rpm
    target: torch.Tensor  # (B, H, 6) measured u, v, r, x_n, y_e (from the start), psi
    weight: torch.Tensor  # (B, H, 6) 1/sigma where measured, 0 where missing (no GNSS)
    recording: np.ndarray  # (B,) index of the recording each segment comes from
    reference: torch.Tensor  # (B, 4) measured u, v, r, psi of the approach of the segment's manoeuvre: the straight
    #                          running whose engine speed a rudder_only grey box holds (models/greybox.py)
    filter_steps: float = 0.0  # standard deviation (steps) of the wave filter of the residuals; 0: none

    def select(self, mask: np.ndarray) -> "Segments":
        m = torch.as_tensor(mask)
        return Segments(self.state[m], self.controls[m], self.target[m], self.weight[m], self.recording[mask],
                        self.reference[m], self.filter_steps)

    def __len__(self) -> int:
        return int(self.state.shape[0])


def weighted_residuals(predicted: np.ndarray | torch.Tensor, seg: Segments, *,
                       filtered: bool = True) -> np.ndarray | torch.Tensor:
    """(..., B, H, 6) (predicted - target) * weight of (..., B, H, 6) predictions (numpy or torch, the type of
    `predicted`; torch keeps the gradient). With the segments' wave filter (filtered and filter_steps > 0) the
    difference is smoothed along the horizon over the measured samples only (a normalised convolution with
    wave_motion.smoothing_operator: sum_i G_ji m_i d_i / sum_i G_ji m_i, m the measured mask) before the weight."""
    is_torch = isinstance(predicted, torch.Tensor)
    target, weight = (seg.target, seg.weight) if is_torch else (seg.target.numpy(), seg.weight.numpy())
    if not (filtered and seg.filter_steps > 0.0):
        return (predicted - target) * weight
    measured = weight > 0
    mask = measured.to(predicted.dtype) if is_torch else measured.astype(predicted.dtype)
    op = smoothing_operator(int(target.shape[-2]), float(seg.filter_steps))  # (H, H)
    if is_torch:
        op_t = torch.from_numpy(op.copy()).to(predicted.dtype)
        num = torch.einsum("jh,...hc->...jc", op_t, (predicted - target) * mask)
        den = torch.einsum("jh,...hc->...jc", op_t, mask)
        safe = torch.where(den > 0, den, torch.ones_like(den))
        return torch.where(den > 0, num / safe, torch.zeros_like(den)) * weight
    num = op @ ((predicted - target) * mask)  # (H, H) @ (..., H, 6): "jh,...hc->...jc", by BLAS (einsum's loop
    den = op @ mask  # without optimize is ~20x slower at H = 40, B = 48)
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0) * weight


def make_segments(recordings: Sequence[Recording], horizon_s: float = 20.0, stride_s: float = 5.0,
                  sigma: Sequence[float] = SIGMA, filter_s: float = 0.0) -> Segments:
    """Cut every recording into segments of horizon_s starting every stride_s; each carries its manoeuvre's approach
    state (data.recording.approach_state: a rudder_only boat holds the engine speed of its approach all manoeuvre
    long, not the one of the slower speed a segment inside a turn starts from). filter_s: the wave filter's standard
    deviation (s; data/wave_motion.py) the residuals of these segments are smoothed with (0: none)."""
    states, controls, targets, weights, index, references = [], [], [], [], [], []
    for i, rec in enumerate(recordings):
        approach = approach_state(rec.nu, rec.psi, rec.dt, straight_samples(rec.controls, rec.actuator_layout))  # (4,)
        h = whole_steps(horizon_s, rec.dt, "segment horizon")
        stride = whole_steps(min(stride_s, len(rec) * rec.dt), rec.dt, "segment stride")
        for k in range(0, len(rec) - h, stride):
            pos = rec.position[k + 1:k + h + 1] - rec.position[k]
            target = np.column_stack([rec.nu[k + 1:k + h + 1], pos, rec.psi[k + 1:k + h + 1]])
            finite = np.isfinite(target)
            states.append([*rec.nu[k], rec.psi[k]])
            controls.append(rec.controls[k:k + h])
            targets.append(np.where(finite, target, 0.0))
            weights.append(finite / np.asarray(sigma))
            index.append(i)
            references.append(np.where(np.isfinite(approach), approach, [*rec.nu[k], rec.psi[k]]))
    if not states:
        raise DiagnosisError(f"no recording is longer than the {horizon_s:.0f} s segment horizon; record longer "
                             "manoeuvres")
    as_t = lambda a: torch.tensor(np.array(a), dtype=torch.float64)  # noqa: E731
    return Segments(as_t(states), as_t(controls), as_t(targets), as_t(weights), np.array(index), as_t(references),
                    filter_s / recordings[0].dt if filter_s > 0.0 else 0.0)

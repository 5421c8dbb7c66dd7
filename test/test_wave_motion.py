"""The wave filter of the diagnosis (data/wave_motion.py): the detector tells waves from a clean day, the filter
removes the wave-frequency part of a residual and keeps its low-frequency part, and with it the true model on a day in
waves leaves a loss near the clean day's."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from usv_predictor.analysis.diagnosis import (NONE_LOSS, compiled_rollout, diagnosis_segments, loss, make_segments,
                                              set_terms)
from usv_predictor.data.recording import recording_from_signals
from usv_predictor.data.segments import SIGMA, Segments, weighted_residuals
from usv_predictor.data.wave_motion import FILTER_S, MOTION_LEVEL, gaussian_smooth, smoothing_operator, wave_filter
from usv_predictor.physics import effects as fx
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import diagnosis_runs
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

VESSEL = load_vessel("jari_usv")
WAVES = {"wave_height": 1.2, "wave_from_deg": 240.0, "wave_period_s": 3.0}


def _day(env: Environment) -> list:
    model = ManoeuvringModel(VESSEL)
    out = []
    for k, manoeuvre in enumerate(diagnosis_runs()):
        traj = simulate(model, manoeuvre, env, heading_deg=40.0 * k, seed=k)
        out.append(recording_from_signals(measure(traj, env, seed=10 + k), 0.5, name=manoeuvre.name))
    return out


@pytest.fixture(scope="module")
def days() -> dict[str, list]:
    return {"clean": _day(Environment()), "waves": _day(Environment(**WAVES))}


def test_the_detector_tells_a_day_in_waves_from_a_clean_one(days) -> None:
    clean, waves = wave_filter(days["clean"], SIGMA), wave_filter(days["waves"], SIGMA)
    assert clean.measured == waves.measured == 4  # every manoeuvre starts with a straight run
    assert clean.motion_level < 0.1 * MOTION_LEVEL and not clean.applied and clean.sigma_s == 0.0
    assert waves.motion_level > 10.0 * MOTION_LEVEL and waves.applied and waves.sigma_s == FILTER_S
    assert wave_filter(days["waves"], SIGMA, "off").applied is False
    assert wave_filter(days["clean"], SIGMA, "on").applied is True
    assert "wave filter on (auto)" in waves.describe() and waves.to_json()["applied"] is True
    with pytest.raises(ValueError, match="auto, on, off"):
        wave_filter(days["clean"], SIGMA, "sometimes")


def _segments(residual: np.ndarray, weight: np.ndarray, filter_steps: float) -> Segments:
    """One-channel-per-column segments whose target is minus `residual` (B, H, 6) against a zero prediction."""
    b = residual.shape[0]
    t = lambda a: torch.tensor(a, dtype=torch.float64)  # noqa: E731
    return Segments(t(np.zeros((b, 4))), t(np.zeros((b, residual.shape[1], 2))), t(-residual), t(weight),
                    np.zeros(b, dtype=int), t(np.zeros((b, 4))), filter_steps)


def test_the_filter_removes_the_wave_period_and_keeps_a_steady_error() -> None:
    h, dt = 40, 0.5
    k = np.arange(h)
    wave = np.sin(2.0 * math.pi * k * dt / 3.0)  # a 3 s oscillation (the suite's peak period)
    residual = np.zeros((1, h, 6))
    residual[0, :, 0] = 0.3 + wave  # a steady surge error under a wave-frequency one
    residual[0, :, 2] = wave
    weight = np.ones((1, h, 6))
    seg = _segments(residual, weight, FILTER_S / dt)
    filtered = weighted_residuals(np.zeros((1, h, 6)), seg)
    assert np.allclose(weighted_residuals(np.zeros((1, h, 6)), seg, filtered=False), residual)  # as before
    assert np.max(np.abs(filtered[0, 12:-12, 2])) < 0.01  # the oscillation is gone to 1 % of its amplitude ...
    assert np.max(np.abs(filtered[0, :, 2])) < 0.25  # ... and to a quarter at the ends (half a kernel there)
    assert np.allclose(filtered[0, 8:-8, 0], 0.3, atol=0.01)  # the steady error stays
    # a constant residual is unchanged to the ends (the weights are normalised over the segment)
    steady = _segments(np.full((1, h, 6), 0.7), weight, FILTER_S / dt)
    assert np.allclose(weighted_residuals(np.zeros((1, h, 6)), steady), 0.7)


def test_unmeasured_samples_do_not_enter_the_filter_and_torch_agrees_with_numpy() -> None:
    rng = np.random.default_rng(3)
    residual = rng.normal(size=(2, 20, 6))
    weight = np.ones((2, 20, 6)) / np.asarray(SIGMA)
    weight[0, 5:9, 3:5] = 0.0  # no GNSS fix there
    seg = _segments(residual, weight, 3.0)
    base = weighted_residuals(np.zeros((2, 20, 6)), seg)
    garbage = residual.copy()
    garbage[0, 5:9, 3:5] = 1e6  # what a missing sample holds never reaches the others
    assert np.allclose(weighted_residuals(np.zeros((2, 20, 6)), _segments(garbage, weight, 3.0)), base)
    assert np.all(base[0, 5:9, 3:5] == 0.0)
    predicted = torch.zeros((2, 20, 6), dtype=torch.float64, requires_grad=True)
    torch_r = weighted_residuals(predicted, seg)
    assert torch.allclose(torch_r.detach(), torch.from_numpy(base), atol=1e-12)
    (torch_r ** 2).sum().backward()
    assert predicted.grad is not None and torch.isfinite(predicted.grad).all()
    op = smoothing_operator(20, 3.0)
    assert np.allclose(op.sum(axis=1), 1.0) and not op.flags.writeable


def test_the_detectors_smoothing_is_the_operator_by_convolution() -> None:
    """The detector smooths a straight run by convolution: the normalised operator's product to rounding, ends
    included, and a run of any length without a T x T matrix (200 000 samples: 320 GB as a matrix)."""
    x = np.random.default_rng(5).normal(size=(37, 2))
    for sigma in (0.4, 1.5, 3.0, 20.0):  # 20: a kernel longer than the run
        assert np.allclose(gaussian_smooth(x, sigma), smoothing_operator(37, sigma) @ x, atol=1e-12), sigma
    assert np.allclose(gaussian_smooth(np.full((200_000, 2), 0.3), 3.0), 0.3)


def test_with_the_filter_the_true_model_in_waves_leaves_what_a_model_that_fits_leaves(days) -> None:
    """The true model with the true wave drift: in 1.2 m waves the wave-frequency motion alone leaves far above
    NONE_LOSS without the filter; with it, a few noise units; on the clean day the filter changes little."""
    rollout = compiled_rollout(VESSEL, 0.5)
    truth = fx.EFFECTS["wave_drift"].readout.terms_from_truth(WAVES)

    def true_loss(recordings, filtered: bool, terms) -> float:
        seg = (diagnosis_segments(recordings, 20.0, 5.0, "on" if filtered else "off")[0])
        set_terms(rollout, terms)
        return loss(rollout, seg)

    raw, filtered = true_loss(days["waves"], False, truth), true_loss(days["waves"], True, truth)
    assert raw > 4.0 * NONE_LOSS, raw
    assert filtered < 0.4 * raw, (raw, filtered)
    clean_raw, clean_filtered = true_loss(days["clean"], False, {}), true_loss(days["clean"], True, {})
    assert clean_raw < 0.5 and clean_filtered < 1.0, (clean_raw, clean_filtered)
    # the segments the detector decides on its own are the filtered ones in waves, the plain ones on a clean day
    assert diagnosis_segments(days["waves"], 20.0, 5.0)[0].filter_steps == FILTER_S / 0.5
    assert diagnosis_segments(days["clean"], 20.0, 5.0)[0].filter_steps == 0.0
    assert make_segments(days["clean"], 20.0, 5.0).filter_steps == 0.0

"""Alignment and resampling of role signals into a Recording."""
from __future__ import annotations

import math

import numpy as np
import pytest

from usv_predictor.data.recording import RecordingError, recording_from_signals, window_resample
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import TurningCircle
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.records import Signal

NS = 1_000_000_000


def test_window_resample_averages_fast_signals_and_interpolates_slow_ones():
    t = np.arange(0, 10 * NS, NS // 100, dtype=np.int64)  # 100 Hz
    ramp = t / NS
    grid = np.arange(1, 9, dtype=np.int64) * NS
    assert np.allclose(window_resample(t, ramp, grid, NS // 2), grid / NS, atol=1e-9)  # mean of a ramp = centre
    noisy = np.random.default_rng(0).normal(0.0, 1.0, len(t))
    assert np.std(window_resample(t, noisy, grid, NS // 2)) < 0.3  # 50 samples per window: noise / 7
    slow_t = np.arange(0, 11, 2, dtype=np.int64) * NS  # 0.5 Hz, slower than the step
    assert np.allclose(window_resample(slow_t, slow_t / NS * 2.0, grid, NS // 2), 2.0 * grid / NS)


@pytest.fixture(scope="module")
def signals():
    traj = simulate(ManoeuvringModel(load_vessel("jari_usv")), TurningCircle(20.0, 650.0, duration_s=60.0),
                    heading_deg=170.0)
    return traj, measure(traj, Environment(), SensorSpec().noiseless())


def test_recording_matches_the_truth_it_was_measured_from(signals):
    traj, sig = signals
    rec = recording_from_signals(sig, 0.5, name="turn")
    assert rec.dt == 0.5 and len(rec) == 120  # whole 0.5 s windows within 60 s
    t = (rec.t0_ns - traj.t_ns[0]) / NS + rec.t_s
    truth_r = np.interp(t, traj.t_s, traj.nu[:, 2])
    assert np.max(np.abs(rec.nu[:, 2] - truth_r)) < 5e-3  # window mean vs point value of a smooth signal
    # heading crosses 180 deg: unwrapped, so averaging across the wrap is right
    assert np.max(np.abs(rec.psi - np.interp(t, traj.t_s, traj.psi_unwrapped))) < 5e-3
    assert np.ptp(rec.psi) > math.pi / 2
    assert np.hypot(*rec.position[0]) < 3.0  # datum = first fix, 0.25 s earlier at ~5.5 m/s
    assert rec.truth is not None
    assert rec.truth.shape == (120, 6)
    assert np.allclose(rec.controls[-1], [math.radians(20.0), 650.0], atol=1e-6)


def test_missing_roles_gaps_and_disorder_are_named(signals):
    _, sig = signals
    with pytest.raises(RecordingError, match=r"no data for role\(s\) \['engine_rpm'\]"):
        recording_from_signals({k: v for k, v in sig.items() if k != "engine_rpm"}, 0.5, name="x")
    vel = sig["velocity"]
    keep = (vel.t_ns - vel.t_ns[0] < 10 * NS) | (vel.t_ns - vel.t_ns[0] > 13 * NS)
    gappy = dict(sig, velocity=Signal(vel.t_ns[keep], vel.values[keep], vel.fields))
    with pytest.raises(RecordingError, match=r"velocity has a 3.10 s gap at t=9.70 s"):
        recording_from_signals(gappy, 0.5, name="x")
    hdg = sig["heading"]
    backwards = dict(sig, heading=Signal(hdg.t_ns[::-1].copy(), hdg.values, hdg.fields))
    with pytest.raises(RecordingError, match="heading timestamps do not increase"):
        recording_from_signals(backwards, 0.5, name="x")

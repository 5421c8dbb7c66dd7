"""EKF + RTS smoother: accelerations of simulated manoeuvres with KNOWN accelerations (Trajectory.nu_dot); the
compiled loops equal the numpy ones.

Measured (INS/GNSS/compass noise of SensorSpec's defaults, resampled at 0.1 s): the smoother's acceleration
error is a fraction of the finite-difference error of the same noisy signals (measured: u_dot 0.029 vs 0.12,
v_dot 0.055 vs 0.12 m/s^2, r_dot 0.0027 vs 0.0037 rad/s^2 on a 20/20 zig-zag of the jari_usv preset).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from usv_predictor.data.recording import recording_from_signals
from usv_predictor.data import smoother
from usv_predictor.data.smoother import (
    finite_difference_accelerations,
    measurements,
    smooth_measurements,
    smooth_recording,
    tune,
)
from usv_predictor.errors import DatasetError
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import NS, simulate
from usv_predictor.physics.vessel import load_vessel

DT = 0.1
BAGS = Path(__file__).resolve().parents[1] / "bags"
EQUAL = 1e-9  # (-) of each column's largest value: the compiled and numpy loops differ by rounding (measured 1e-14)


@pytest.fixture(scope="module")
def zigzag():
    model = ManoeuvringModel(load_vessel("jari_usv"))
    env = Environment()
    traj = simulate(model, ZigZag(20.0, 20.0, 650.0, duration_s=100.0), env)
    rec = recording_from_signals(measure(traj, env, SensorSpec(), seed=1), DT, name="zigzag")
    t = (rec.t0_ns + np.round(rec.t_s * NS).astype(np.int64) - traj.t_ns[0]).astype(float)
    tt = (traj.t_ns - traj.t_ns[0]).astype(float)
    true = np.column_stack([np.interp(t, tt, traj.nu_dot[:, k]) for k in range(3)])
    return rec, true


def _rms(e: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(e[10:-10] ** 2, axis=0))  # the first/last second: smoother edges


def test_smoothed_accelerations_are_accurate_and_beat_finite_differences(zigzag):
    rec, true = zigzag
    smoothed = smooth_recording(rec)
    err = _rms(smoothed.nu_dot - true)
    fd = _rms(finite_difference_accelerations(rec) - true)
    assert np.all(err < fd), (err, fd)
    assert err[0] < 0.05 and err[1] < 0.08 and err[2] < 0.004  # m/s^2, m/s^2, rad/s^2
    assert err[0] < 0.5 * fd[0]
    assert err[1] < 0.6 * fd[1]
    # the reported standard deviations are of the size of the actual errors (within a factor 3)
    ratio = err / smoothed.nu_dot_std[10:-10].mean(axis=0)
    assert np.all((ratio > 1 / 3) & (ratio < 3)), ratio


def test_missing_gnss_is_tolerated(zigzag):
    rec, true = zigzag
    z = measurements(rec)
    z[200:600, 0:2] = np.nan  # 40 s GNSS outage
    full = smooth_measurements(measurements(rec), DT)
    gappy = smooth_measurements(z, DT, full.config)
    assert np.all(np.isfinite(gappy.state))
    assert _rms(gappy.nu_dot - true)[2] < 0.005
    # position uncertainty grows in the outage and is small where GNSS is present
    assert gappy.std[400, 0] > 1.2 * gappy.std[100, 0]


def test_velocities_from_track_and_heading_alone(zigzag):
    """A GNSS receiver and a compass only, at half the grid rate (the Dalian USV's record): u, v, r come from the
    kinematics. Measured: rms error 0.073 / 0.088 m/s and 0.0026 rad/s against a signal std of 0.60 / 0.74 m/s and
    0.22 rad/s (with the velocity sensors: 0.009 / 0.011 m/s, 0.0003 rad/s)."""
    rec, _ = zigzag
    z = measurements(rec)
    z[:, 3:6] = np.nan
    z[1::2, 0:3] = np.nan
    track = tune(z, DT)
    err = _rms(track.nu - rec.truth[:, 3:6])
    assert err[0] < 0.12 and err[1] < 0.15 and err[2] < 0.005, err  # m/s, m/s, rad/s
    assert np.all(err < 0.25 * rec.truth[:, 3:6].std(axis=0))
    assert np.all(np.isfinite(track.state))


def test_required_signals():
    z = np.zeros((50, 6))
    z[:, 2] = np.nan
    with pytest.raises(DatasetError, match="psi"):
        smooth_measurements(z, 0.1)
    z = np.zeros((50, 6))
    z[:, 3:6] = np.nan
    z[:, 0:2] = np.nan
    with pytest.raises(DatasetError, match="unless GNSS positions"):
        smooth_measurements(z, 0.1)
    with pytest.raises(DatasetError, match=r"\(T, 6\)"):
        smooth_measurements(np.zeros((50, 5)), 0.1)


def _equal(a: np.ndarray, b: np.ndarray) -> None:
    scale = np.maximum(np.max(np.abs(b), axis=0), 1e-12)
    assert np.all(np.max(np.abs(a - b), axis=0) <= EQUAL * scale), np.max(np.abs(a - b), axis=0) / scale


def _assert_twins(z: np.ndarray, dt: float) -> None:
    config = tune(z, dt).config  # the noise model identification smooths with
    compiled = smooth_measurements(z, dt, config, compiled=True)
    plain = smooth_measurements(z, dt, config, compiled=False)
    _equal(compiled.state, plain.state)
    _equal(compiled.std, plain.std)
    assert compiled.log_likelihood == pytest.approx(plain.log_likelihood, rel=EQUAL, abs=0.0)
    assert compiled.config == plain.config


@pytest.mark.parametrize("gaps", [False, True])
def test_the_compiled_loops_equal_the_numpy_ones(zigzag, gaps):
    z = measurements(zigzag[0])
    if gaps:  # GNSS drop-outs and no sway measurement: the NaN-tolerant updates of fewer components
        z[100:180, 0:2] = np.nan
        z[:, 4] = np.nan
    _assert_twins(z, DT)


def test_the_compiled_loops_equal_the_numpy_ones_on_the_shipped_recordings():
    from usv_predictor.replay.identify import identification_recordings

    recordings = identification_recordings([BAGS / "training"], 0.2)
    assert len(recordings) == 4
    for recording in recordings:
        _assert_twins(measurements(recording), recording.dt)


def test_the_jacobian_is_the_transitions_derivative():
    """By hand against central differences of _transition (their truncation and rounding: ~1e-9 here)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.normal(size=9) * np.array([50.0, 50.0, 3.0, 2.0, 0.5, 0.3, 0.3, 0.2, 0.05])
        h = float(rng.uniform(0.05, 0.5))
        eps = 1e-6 * np.maximum(1.0, np.abs(x))
        numeric = (smoother._transition(x[:, None] + np.diag(eps), h)
                   - smoother._transition(x[:, None] - np.diag(eps), h)) / (2.0 * eps)[None, :]
        assert np.max(np.abs(smoother._jacobian(x, h) - numeric)) < 1e-7

"""The compiled EKF/RTS loops (data/smoother.py _forward_compiled, _backward_compiled) equal the numpy ones.

Same operations in another order (loops instead of LAPACK and BLAS): the states, their standard deviations and the
log-likelihood agree to rounding, amplified over the record (measured on a 100 s zig-zag at 0.1 s: 3e-8 of each
column's scale); a wrong formula moves them by far more than the 1e-6 allowed.
"""
from __future__ import annotations

import numpy as np
import pytest

from usv_predictor.data.recording import recording_from_signals
from usv_predictor.data.smoother import measurements, smooth_measurements
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

DT = 0.1
RTOL = 1e-6  # (-) of each column's largest value


@pytest.fixture(scope="module")
def zigzag():
    model = ManoeuvringModel(load_vessel("jari_usv"))
    env = Environment()
    traj = simulate(model, ZigZag(20.0, 20.0, 650.0, duration_s=100.0), env)
    return measurements(recording_from_signals(measure(traj, env, SensorSpec(), seed=1), DT, name="zigzag"))


def _close(a: np.ndarray, b: np.ndarray) -> None:
    scale = np.maximum(np.max(np.abs(b), axis=0), 1e-12)
    assert np.all(np.max(np.abs(a - b), axis=0) <= RTOL * scale), np.max(np.abs(a - b), axis=0) / scale


@pytest.mark.parametrize("gaps", [False, True])
def test_the_compiled_smoother_equals_the_numpy_one(zigzag, gaps):
    z = zigzag.copy()
    if gaps:  # GNSS drop-outs and a missing sway measurement: the NaN-tolerant updates of fewer components
        z[100:180, 0:2] = np.nan
        z[:, 4] = np.nan
    compiled = smooth_measurements(z, DT, compiled=True)
    plain = smooth_measurements(z, DT, compiled=False)
    _close(compiled.state, plain.state)
    _close(compiled.std, plain.std)
    assert compiled.log_likelihood == pytest.approx(plain.log_likelihood, rel=RTOL)
    assert compiled.config == plain.config

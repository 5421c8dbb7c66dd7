"""features: seed 000 feature sets (eq. 11, 24, 26) on hand-computed cases."""
from __future__ import annotations

import math

import numpy as np
import pytest

from usv_predictor.data.features import FEATURE_SETS, FEATURE_UNITS, feature_names, feature_units, features
from usv_predictor.errors import DatasetError

STATE = np.array([5.0, -0.3, 0.02, 0.0])  # u m/s, v m/s, r rad/s, psi rad
CONTROLS = np.array([math.radians(20.0), 650.0])  # delta rad, rpm


def test_the_sets_are_those_of_seed_000():
    assert FEATURE_SETS["F0"] == ("u", "v", "r", "delta", "rpm")
    assert FEATURE_SETS["NAF"] == ("u", "v", "r", "delta", "rpm", "psi")
    assert FEATURE_SETS["NTF"] == ("u", "v", "r", "delta", "rpm", "sin_psi", "cos_psi")
    for name, columns in FEATURE_SETS.items():
        assert feature_units(name) == tuple(FEATURE_UNITS[c] for c in columns)
        assert features(name, STATE, CONTROLS).shape == (len(columns),)


@pytest.mark.parametrize("psi_deg, sin_psi, cos_psi", [
    (0.0, 0.0, 1.0), (90.0, 1.0, 0.0), (180.0, 0.0, -1.0), (-90.0, -1.0, 0.0), (30.0, 0.5, math.sqrt(3) / 2),
    (390.0, 0.5, math.sqrt(3) / 2),  # an unwrapped heading one turn later is the same input
])  # fmt: skip
def test_ntf_carries_sine_and_cosine_of_known_headings(psi_deg, sin_psi, cos_psi):
    state = STATE.copy()
    state[3] = math.radians(psi_deg)
    x = features("NTF", state, CONTROLS)
    assert np.allclose(x[:5], [5.0, -0.3, 0.02, math.radians(20.0), 650.0], rtol=0, atol=0)
    assert x[5] == pytest.approx(sin_psi, abs=1e-12)
    assert x[6] == pytest.approx(cos_psi, abs=1e-12)


@pytest.mark.parametrize("psi, wrapped", [
    (0.0, 0.0), (1.0, 1.0), (3 * math.pi / 2, -math.pi / 2), (7.0, 7.0 - 2 * math.pi), (-7.0, -7.0 + 2 * math.pi),
    (math.pi, -math.pi), (-math.pi, -math.pi),  # [-pi, pi): +pi and -pi are the same heading, one value
])  # fmt: skip
def test_naf_wraps_the_heading(psi, wrapped):
    state = STATE.copy()
    state[3] = psi
    assert features("NAF", state, CONTROLS)[5] == pytest.approx(wrapped, abs=1e-12)


def test_leading_dimensions_broadcast_row_by_row():
    rng = np.random.default_rng(3)
    state = rng.normal(size=(2, 7, 4)) * [1, 1, 0.1, 10]
    controls = rng.normal(size=(2, 7, 2)) * [0.3, 600]
    x = features("NTF", state, controls)
    assert x.shape == (2, 7, 7)
    assert np.array_equal(x[1, 4], features("NTF", state[1, 4], controls[1, 4]))
    assert np.array_equal(x[..., :3], state[..., :3])
    assert np.array_equal(x[..., 3:5], controls)
    assert np.array_equal(x[..., 5], np.sin(state[..., 3]))
    assert np.array_equal(x[..., 6], np.cos(state[..., 3]))
    assert np.array_equal(features("F0", state, controls), x[..., :5])


def test_unknown_sets_and_wrong_shapes_are_named():
    with pytest.raises(DatasetError, match=r"unknown feature set 'NXF'; known: \['F0', 'NAF', 'NTF'\]"):
        features("NXF", STATE, CONTROLS)
    with pytest.raises(DatasetError, match="unknown feature set"):
        feature_names("ntf")
    with pytest.raises(DatasetError, match=r"need state \(\.\.\., 4\).*got \(3,\) and \(2,\)"):
        features("F0", STATE[:3], CONTROLS)
    with pytest.raises(DatasetError, match="same leading shape"):
        features("F0", np.zeros((5, 4)), np.zeros((4, 2)))

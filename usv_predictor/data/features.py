"""Input features of the one-step motion model (seed 000 eq. 11, 24, 26).

state (..., 4)    [u, v, r, psi]   m/s, m/s, rad/s, rad (heading clockwise from north)
controls (..., 2) [delta, rpm]     rad (+ turns to starboard), rev/min

Feature sets:
    F0   [u, v, r, delta, rpm]                      eq. 11: motion and control only
    NAF  F0 + [psi]                                  eq. 24: network with angle feature; psi wrapped
                                                     to [-pi, pi) so the same heading is the same input
    NTF  F0 + [sin psi, cos psi]                     eq. 26: network with trigonometric feature; the
                                                     environment forces are linear in sin/cos psi (eq. 25)

The TorchScript rollout re-implements `features` in torch and is tested for equality against this
function: keep it a few exact numpy operations, in this order, nothing more.
"""
from __future__ import annotations

from types import MappingProxyType

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import wrap_angle

STATE_NAMES: tuple[str, ...] = ("u", "v", "r", "psi")
STATE_UNITS: tuple[str, ...] = ("m/s", "m/s", "rad/s", "rad")
CONTROL_NAMES: tuple[str, ...] = ("delta", "rpm")
CONTROL_UNITS: tuple[str, ...] = ("rad", "rpm")
TARGET_NAMES: tuple[str, ...] = ("u", "v", "r")  # the state at the next step (seed 000 eq. 7)
TARGET_UNITS: tuple[str, ...] = ("m/s", "m/s", "rad/s")

_F0 = ("u", "v", "r", "delta", "rpm")
FEATURE_SETS = MappingProxyType({
    "F0": _F0,
    "NAF": _F0 + ("psi",),
    "NTF": _F0 + ("sin_psi", "cos_psi"),
})  # fmt: skip
FEATURE_UNITS = MappingProxyType({
    "u": "m/s", "v": "m/s", "r": "rad/s", "delta": "rad", "rpm": "rpm",
    "psi": "rad", "sin_psi": "1", "cos_psi": "1",
})  # fmt: skip


def feature_names(feature_set: str) -> tuple[str, ...]:
    """The column names of a feature set; DatasetError listing the known sets otherwise."""
    try:
        return FEATURE_SETS[feature_set]
    except (KeyError, TypeError):
        raise DatasetError(f"unknown feature set {feature_set!r}; known: {sorted(FEATURE_SETS)}") from None


def feature_units(feature_set: str) -> tuple[str, ...]:
    return tuple(FEATURE_UNITS[name] for name in feature_names(feature_set))


def features(feature_set: str, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
    """(..., F) model inputs from state (..., 4) [u, v, r, psi] and controls (..., 2) [delta, rpm]."""
    feature_names(feature_set)  # unknown set -> DatasetError before any arithmetic
    state = np.asarray(state, dtype=np.float64)
    controls = np.asarray(controls, dtype=np.float64)
    if state.shape[-1:] != (4,) or controls.shape[-1:] != (2,) or state.shape[:-1] != controls.shape[:-1]:
        raise DatasetError(f"features({feature_set}): need state (..., 4) [u, v, r, psi] and controls (..., 2) "
                           f"[delta, rpm] with the same leading shape, got {state.shape} and {controls.shape}")
    columns = [state[..., 0:3], controls]  # u, v, r, delta, rpm
    psi = state[..., 3:4]
    if feature_set == "NAF":
        columns.append(wrap_angle(psi))
    elif feature_set == "NTF":
        columns += [np.sin(psi), np.cos(psi)]
    return np.concatenate(columns, axis=-1)  # (..., len(names)); test_features checks the widths

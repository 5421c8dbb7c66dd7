"""Input features of the one-step motion model (seed 000 eq. 11, 24, 26), for any actuator layout.

state (..., 4)    [u, v, r, psi]   m/s, m/s, rad/s, rad (heading clockwise from north)
controls (..., C) the vessel's control columns (physics/actuators.py), e.g. [delta, rpm] (rad, rev/min)

Feature sets (columns: the motion [u, v, r], the controls, then the heading columns of the set):
    F0   [u, v, r] + controls                       eq. 11: motion and control only
    NAF  F0 + [psi]                                  eq. 24: network with angle feature; psi wrapped
                                                     to [-pi, pi) so the same heading is the same input
    NTF  F0 + [sin psi, cos psi]                     eq. 26: network with trigonometric feature; the
                                                     environment forces are linear in sin/cos psi (eq. 25)

One implementation serves numpy arrays and torch tensors (the training loss recomputes features in torch,
with gradients). The DNN's TorchScript rollout (models/dnn.py) folds the heading columns into its step
matrices from HEADING_COLUMNS (sin, cos or wrap of psi), so the rollout and this function read one definition.
"""
from __future__ import annotations

from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from usv_predictor.errors import DatasetError
from usv_predictor.frames import wrap_angle
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout

STATE_NAMES: tuple[str, ...] = ("u", "v", "r", "psi")
STATE_UNITS: tuple[str, ...] = ("m/s", "m/s", "rad/s", "rad")
MOTION_NAMES: tuple[str, ...] = ("u", "v", "r")  # the motion columns that lead every feature set
TARGET_NAMES: tuple[str, ...] = ("u", "v", "r")  # the state at the next step (seed 000 eq. 7)
TARGET_UNITS: tuple[str, ...] = ("m/s", "m/s", "rad/s")
CONTROL_NAMES: tuple[str, ...] = DEFAULT_LAYOUT.control_names  # the default layout's (rudder_propeller)
CONTROL_UNITS: tuple[str, ...] = DEFAULT_LAYOUT.control_units

# heading column -> operation on psi: "wrap" to [-pi, pi) (frames.wrap_angle), "sin" or "cos"
HEADING_COLUMNS: Mapping[str, str] = MappingProxyType({"psi": "wrap", "sin_psi": "sin", "cos_psi": "cos"})
HEADING_SETS: Mapping[str, tuple[str, ...]] = MappingProxyType({
    "F0": (),
    "NAF": ("psi",),
    "NTF": ("sin_psi", "cos_psi"),
})  # fmt: skip
_UNITS = {"u": "m/s", "v": "m/s", "r": "rad/s", "psi": "rad", "sin_psi": "1", "cos_psi": "1"}


def feature_names(feature_set: str, layout: ActuatorLayout = DEFAULT_LAYOUT) -> tuple[str, ...]:
    """The column names of a feature set for a layout; DatasetError listing the known sets otherwise."""
    try:
        heading = HEADING_SETS[feature_set]
    except (KeyError, TypeError):
        raise DatasetError(f"unknown feature set {feature_set!r}; known: {sorted(HEADING_SETS)}") from None
    return MOTION_NAMES + layout.control_names + heading


def feature_units(feature_set: str, layout: ActuatorLayout = DEFAULT_LAYOUT) -> tuple[str, ...]:
    units = {**_UNITS, **dict(zip(layout.control_names, layout.control_units))}
    return tuple(units[name] for name in feature_names(feature_set, layout))


# The default layout's sets and units, for the command line and for models made before layouts had names.
FEATURE_SETS: Mapping[str, tuple[str, ...]] = MappingProxyType({name: feature_names(name) for name in HEADING_SETS})
FEATURE_UNITS: Mapping[str, str] = MappingProxyType({**_UNITS, **dict(zip(CONTROL_NAMES, CONTROL_UNITS))})


def _heading_column(operation: str, psi: Any) -> Any:
    if operation == "wrap":
        return wrap_angle(psi)  # the `%` of numpy and torch alike
    if hasattr(psi, "detach"):  # torch
        return psi.sin() if operation == "sin" else psi.cos()
    return np.sin(psi) if operation == "sin" else np.cos(psi)


def features(feature_set: str, state: Any, controls: Any, layout: ActuatorLayout = DEFAULT_LAYOUT) -> Any:
    """(..., F) model inputs from state (..., 4) [u, v, r, psi] and controls (..., C) in the layout's columns.

    numpy in, numpy out (float64); torch in, torch out (same dtype, differentiable).
    """
    names = feature_names(feature_set, layout)  # unknown set -> DatasetError before any arithmetic
    is_tensor = hasattr(state, "detach")
    if not is_tensor:
        state = np.asarray(state, dtype=np.float64)
        controls = np.asarray(controls, dtype=np.float64)
    width = len(layout.controls)
    if tuple(state.shape[-1:]) != (4,) or tuple(controls.shape[-1:]) != (width,) \
            or tuple(state.shape[:-1]) != tuple(controls.shape[:-1]):
        raise DatasetError(f"features({feature_set}): need state (..., 4) [u, v, r, psi] and controls (..., {width}) "
                           f"{list(layout.control_names)} with the same leading shape, got {tuple(state.shape)} and "
                           f"{tuple(controls.shape)}")
    psi = state[..., 3:4]
    columns = [state[..., 0:3], controls] + [_heading_column(HEADING_COLUMNS[n], psi) for n in names[3 + width:]]
    if is_tensor:
        import torch

        return torch.cat(columns, dim=-1)  # (..., F)
    return np.concatenate(columns, axis=-1)  # (..., F); test_features checks the widths

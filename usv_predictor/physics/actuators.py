"""Actuator layouts: which controls a boat has, their units and limits, where they are measured, how they act.

One record per layout (ACTUATOR_LAYOUTS, in the style of msg_adapters.standard.ADAPTER_CLASSES). A layout's
controls are the columns, in order, of every controls array of the package:

    Recording.controls (T, C)               data/recording.py, from the controls' input roles
    features of the learned model           data/features.py: [u, v, r] + controls + heading columns
    model artifact controls (B, H, C)       models/*: forward(state (B, 4), controls (B, H, C)); metadata
                                            `control_layout` = the control names, checked by the node
    the node's live state                   node/live.py: each control averaged from its role and field

Each Control names the input role that measures it (a key of msg_adapters.ROLE_FIELDS) and the field of
that role, its unit (SI, or rpm for engine speed) and the range a correctly configured input stays in (the
node refuses samples outside it: a wrong unit option, e.g. a rudder in degrees read as radians, exceeds it).
`steering` and `propulsion` are weights over the controls that give the turn command (+ turns to
starboard) and the propulsion level: a turn of a rudder boat is a held rudder angle, of a twin-thruster boat
a held thrust difference; evaluate classifies manoeuvres and diagnose checks turn sides with them.
`forces` names the force model that turns the controls into surge/sway/yaw loads (physics/dynamics.py and
its torch twin in models/greybox.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np

from usv_predictor.errors import ConfigError


@dataclass(frozen=True)
class Control:
    """One control column of a layout."""

    name: str  # column name in controls arrays, features and the artifact's control_layout
    unit: str  # unit of the column (SI; rpm for engine speed)
    role: str  # input role that measures it (msg_adapters.ROLE_FIELDS)
    field: str  # the field of that role
    plausible: tuple[float, float]  # range of a correctly configured input, in `unit`
    meaning: str


@dataclass(frozen=True)
class ActuatorLayout:
    """A boat's actuators: its control columns and how they steer and propel (module docstring)."""

    name: str
    description: str
    controls: tuple[Control, ...]
    steering: Mapping[str, float]  # control name -> weight; the sum is the turn command (+ to starboard)
    propulsion: Mapping[str, float]  # control name -> weight; the sum is the propulsion level
    forces: str  # force model of physics/dynamics.py (and models/greybox.py) that turns controls into loads
    straight_below: float  # |turn command| below which a run is straight (steering units)
    hold_tolerance: float  # a held turn command varies by less than this (steering units)

    def __post_init__(self) -> None:
        names = self.control_names
        if len(set(names)) != len(names):
            raise ConfigError(f"actuator layout {self.name}: control names repeat: {names}")
        for what, weights in (("steering", self.steering), ("propulsion", self.propulsion)):
            unknown = sorted(set(weights) - set(names))
            if unknown or not weights:
                raise ConfigError(f"actuator layout {self.name}: {what} weights {dict(weights)} must name its "
                                  f"controls {names}")

    @property
    def control_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.controls)

    @property
    def control_units(self) -> tuple[str, ...]:
        return tuple(c.unit for c in self.controls)

    @property
    def roles(self) -> tuple[str, ...]:
        """The input roles that carry the controls, in control order, each once."""
        return tuple(dict.fromkeys(c.role for c in self.controls))

    def fields_of(self, role: str) -> tuple[str, ...]:
        """The fields of `role` that hold controls of this layout (in control order)."""
        return tuple(c.field for c in self.controls if c.role == role)

    def index(self, name: str) -> int:
        """Column of control `name` (ConfigError naming the layout's controls otherwise)."""
        try:
            return self.control_names.index(name)
        except ValueError:
            raise ConfigError(f"actuator layout {self.name} has no control {name!r}; it has {self.control_names}") from None

    def _combine(self, weights: Mapping[str, float], controls: np.ndarray) -> np.ndarray:
        controls = np.asarray(controls, dtype=float)
        if controls.shape[-1:] != (len(self.controls),):
            raise ConfigError(f"actuator layout {self.name}: controls need {len(self.controls)} columns "
                              f"{self.control_names}, got shape {controls.shape}")
        return sum(w * controls[..., self.index(n)] for n, w in weights.items())

    def steering_signal(self, controls: np.ndarray) -> np.ndarray:
        """(...) turn command from controls (..., C): + turns to starboard, 0 when straight."""
        return self._combine(self.steering, controls)

    def propulsion_signal(self, controls: np.ndarray) -> np.ndarray:
        """(...) propulsion level from controls (..., C), in the unit of the propulsion controls."""
        return self._combine(self.propulsion, controls)


RUDDER_PROPELLER = ActuatorLayout(
    name="rudder_propeller",
    description="one rudder behind one propeller (single screw): rudder angle and engine speed, both measured",
    controls=(
        Control("delta", "rad", "rudder_angle", "delta", (-math.radians(60.0), math.radians(60.0)),
                "rudder angle, + turns the vessel to starboard (60 deg: no rudder turns further; a rudder in "
                "degrees read as radians exceeds it)"),
        Control("rpm", "rpm", "engine_rpm", "rpm", (-5000.0, 5000.0), "engine speed (rev/min), + ahead"),
    ),
    steering=MappingProxyType({"delta": 1.0}),
    propulsion=MappingProxyType({"rpm": 1.0}),
    forces="MMG rudder with propeller slipstream + propeller thrust K_T(J) (Yasukawa & Yoshimura 2015 eq. 10-16)",
    straight_below=math.radians(2.0),  # rad
    hold_tolerance=math.radians(1.5),  # rad
)

ACTUATOR_LAYOUTS: Mapping[str, ActuatorLayout] = MappingProxyType({
    RUDDER_PROPELLER.name: RUDDER_PROPELLER,
})  # fmt: skip
DEFAULT_LAYOUT = RUDDER_PROPELLER


def actuator_layout(name: str) -> ActuatorLayout:
    """The layout record of `name` (ConfigError listing the known layouts otherwise)."""
    try:
        return ACTUATOR_LAYOUTS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown actuator layout {name!r}; known: {', '.join(ACTUATOR_LAYOUTS)}") from None

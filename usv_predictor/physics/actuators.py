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
its torch twin in models/greybox.py, each with one registry line per layout).

Controls and commands. A Control is what a recording reports; its `source` says how: "state" is the feedback of
an actuator state (a rudder angle sensor, an engine tachometer: the models use it as the actuator position),
"command" is the command that was sent (a throttle, PWM or normalised thruster log: the models pass it through
the motor lag and the thrust map of the vessel, physics/vessel.ThrustMap). `commands` are the commands of the
simulated boat, in the order of its actuator states (ManoeuvringModel.derivative); a control of source "state"
reports the state of the same name, one of source "command" the command of the same name. `command_map` turns an
autopilot's (turn, propulsion) pair, in the layout's steering and propulsion units, into the commands;
`turn_input` / `propulsion_input` say how `replay simulate` and the manoeuvres state them (a rudder in degrees,
an engine speed in rpm, a normalised differential or throttle). `sections` are the vessel sections the layout's
physics needs (physics/vessel.py refuses the others).

Sign convention (Fossen 2021 sec. 2.2): body x forward, y to starboard, z down; a yaw moment N > 0 turns the bow to
starboard (heading increases). The port thruster of a twin sits at y = -b/2, so more port thrust turns to
starboard: the steering weights are port +1, starboard -1.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Callable, Mapping

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
    source: str = "state"  # "state": feedback of the actuator state of this name; "command": the command sent
    noise: str = ""  # physics.sensors.SensorSpec field: white-noise std of the simulated report ("" none)
    resolution: str = ""  # SensorSpec field: resolution (LSB) of the simulated report ("" none)

    def __post_init__(self) -> None:
        if self.source not in CONTROL_SOURCES:
            raise ConfigError(f"control {self.name}: source {self.source!r} is not one of {CONTROL_SOURCES}")


CONTROL_SOURCES = ("state", "command")


@dataclass(frozen=True)
class CommandInput:
    """How a turn or propulsion command is stated by `replay simulate` and in manoeuvre names."""

    option: str  # the `replay simulate` option (--rudder, --rpm, --differential, --throttle)
    unit: str  # unit of the option's value
    to_command: float  # option value * to_command = the layout's steering/propulsion unit (deg -> rad: pi/180)
    label: str  # format of the value in manoeuvre names ("{:g}deg" -> 20deg, "d{:g}" -> d0.4)
    default: float  # the option's default value (in `unit`)
    help: str
    limits: Callable[[Any], tuple[float, float, bool]]  # vessel -> (low, high, low allowed) of the option's value
    limited_by: str = "the range"  # how the error message names the limits ("the preset's range")

    def tag(self, value: float) -> str:
        return self.label.format(value)


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
    commands: tuple[str, ...] = ()  # commands of the simulated boat = its actuator states, in force-model order
    command_map: Callable[[float, float], tuple[float, ...]] | None = None  # (turn, propulsion) -> commands
    turn_input: CommandInput | None = None  # how the turn command is stated (replay simulate, manoeuvre names)
    propulsion_input: CommandInput | None = None  # how the propulsion command is stated
    sections: tuple[str, ...] = ()  # vessel sections its physics needs (physics/vessel.py)
    supports: str = ""  # what a model of this layout can and cannot predict, in one paragraph

    def __post_init__(self) -> None:
        names = self.control_names
        if len(set(names)) != len(names):
            raise ConfigError(f"actuator layout {self.name}: control names repeat: {names}")
        for what, weights in (("steering", self.steering), ("propulsion", self.propulsion)):
            unknown = sorted(set(weights) - set(names))
            if unknown or (what == "steering" and not weights):
                raise ConfigError(f"actuator layout {self.name}: {what} weights {dict(weights)} must name its "
                                  f"controls {names}")
        for control in self.controls:
            if self.commands and control.name not in self.commands:
                raise ConfigError(f"actuator layout {self.name}: control {control.name} reports no command or "
                                  f"actuator state of the layout {self.commands}")

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
            raise ConfigError(f"actuator layout {self.name} has no control {name!r}; it has "
                              f"{self.control_names}") from None

    @property
    def reported_commands(self) -> tuple[str, ...]:
        """The controls that report a command (source "command"): the models lag them through the thrust map."""
        return tuple(c.name for c in self.controls if c.source == "command")

    def _combine(self, weights: Mapping[str, float], controls: np.ndarray) -> np.ndarray:
        controls = np.asarray(controls, dtype=float)
        if controls.shape[-1:] != (len(self.controls),):
            raise ConfigError(f"actuator layout {self.name}: controls need {len(self.controls)} columns "
                              f"{self.control_names}, got shape {controls.shape}")
        if not weights:  # nothing reported (rudder_only's propulsion): a constant level
            return np.zeros(controls.shape[:-1])
        return sum(w * controls[..., self.index(n)] for n, w in weights.items())

    def steering_signal(self, controls: np.ndarray) -> np.ndarray:
        """(...) turn command from controls (..., C): + turns to starboard, 0 when straight."""
        return self._combine(self.steering, controls)

    def propulsion_signal(self, controls: np.ndarray) -> np.ndarray:
        """(...) propulsion level from controls (..., C), in the unit of the propulsion controls (0 when the
        layout reports no propulsion)."""
        return self._combine(self.propulsion, controls)

    def to_commands(self, turn: float, propulsion: float) -> tuple[float, ...]:
        """The simulated boat's commands for a turn and a propulsion command (steering / propulsion units)."""
        if self.command_map is None:
            raise ConfigError(f"actuator layout {self.name} has no force model: it cannot be simulated")
        return self.command_map(turn, propulsion)


def _turn_and_propulsion(turn: float, propulsion: float) -> tuple[float, float]:
    """Rudder layouts: the turn command is the rudder angle (rad), the propulsion command the second column."""
    return turn, propulsion


def _differential(turn: float, propulsion: float) -> tuple[float, float]:
    """Twin thrusters: port = p + d/2, starboard = p - d/2, each clipped to [-1, 1], for a differential d (the
    steering signal port - starboard) and a mean command p (the propulsion signal)."""
    half = 0.5 * turn
    return min(max(propulsion + half, -1.0), 1.0), min(max(propulsion - half, -1.0), 1.0)


RUDDER_DEG = CommandInput("--rudder", "deg", math.pi / 180.0, "{:g}deg", 20.0, "rudder angle (deg)",
                          lambda vessel: (0.0, vessel.actuators.rudder_max_deg, True), "the preset's range")
ENGINE_RPM = CommandInput("--rpm", "rpm", 1.0, "{:g}rpm", 650.0, "engine speed (rpm)",
                          lambda vessel: (max(vessel.actuators.rpm_min, 0.0), vessel.actuators.rpm_max, False),
                          "the preset's range")
THROTTLE = CommandInput("--throttle", "-", 1.0, "p{:g}", 0.6,
                        "normalised propulsion command in (0, 1] (the mean of both thrusters for a twin)",
                        lambda vessel: (0.0, 1.0, False))  # ahead
DIFFERENTIAL = CommandInput("--differential", "-", 1.0, "d{:g}", 0.4,
                            "normalised thrust difference port - starboard in (0, 2] (+ turns to starboard)",
                            lambda vessel: (0.0, 2.0, False))  # port +1, starboard -1 at most

_RUDDER = Control("delta", "rad", "rudder_angle", "delta", (-math.radians(60.0), math.radians(60.0)),
                  "rudder angle, + turns the vessel to starboard (60 deg: no rudder turns further; a rudder in "
                  "degrees read as radians exceeds it)", "state", "rudder_noise_std", "rudder_lsb")
_RUDDER_SECTIONS = ("propeller", "rudder", "actuators")
_RUDDER_FORCES = "MMG rudder with propeller slipstream + propeller thrust K_T(J) (Yasukawa & Yoshimura 2015 eq. 10-16)"


RUDDER_PROPELLER = ActuatorLayout(
    name="rudder_propeller",
    description="one rudder behind one propeller (single screw): rudder angle and engine speed, both measured",
    controls=(
        _RUDDER,
        Control("rpm", "rpm", "engine_rpm", "rpm", (-5000.0, 5000.0), "engine speed (rev/min), + ahead", "state",
                "rpm_noise_std", "rpm_lsb"),
    ),
    steering=MappingProxyType({"delta": 1.0}),
    propulsion=MappingProxyType({"rpm": 1.0}),
    forces=_RUDDER_FORCES,
    straight_below=math.radians(2.0),  # rad
    hold_tolerance=math.radians(1.5),  # rad
    commands=("delta", "rpm"),  # rudder (rad), engine speed (rpm)
    command_map=_turn_and_propulsion,
    turn_input=RUDDER_DEG,
    propulsion_input=ENGINE_RPM,
    sections=_RUDDER_SECTIONS,
    supports="rudder and engine-speed manoeuvres at any speed the MMG model covers (it is regularised below "
             "0.05 m/s: no turning on the spot)",
)

RUDDER_THROTTLE = ActuatorLayout(
    name="rudder_throttle",
    description="one rudder behind one propeller whose throttle / PWM command is logged instead of its speed",
    controls=(
        _RUDDER,
        Control("throttle", "-", "throttle", "command", (-1.1, 1.1),
                "normalised throttle command c in [-1, 1], + ahead (a PWM in microseconds read as normalised "
                "exceeds it)", "command", "command_noise_std", "command_lsb"),
    ),
    steering=MappingProxyType({"delta": 1.0}),
    propulsion=MappingProxyType({"throttle": 1.0}),
    forces="the rudder_propeller forces; the engine speed is the one whose static thrust rho n^2 D^4 K_T(0) equals "
           "the vessel's thrust map at the lagged command (astern commands give no thrust: the MMG propeller model "
           "is ahead only)",
    straight_below=math.radians(2.0),  # rad
    hold_tolerance=math.radians(1.5),  # rad
    commands=("delta", "throttle"),  # rudder (rad), throttle (-)
    command_map=_turn_and_propulsion,
    turn_input=RUDDER_DEG,
    propulsion_input=THROTTLE,
    sections=(*_RUDDER_SECTIONS, "throttle"),
    supports="rudder and throttle manoeuvres ahead; the thrust comes from the thrust map, so its error is the "
             "map's (the `resistance` hypothesis absorbs a uniform one)",
)

RUDDER_ONLY = ActuatorLayout(
    name="rudder_only",
    description="a rudder boat whose propulsion is not logged: only the rudder angle is measured",
    controls=(_RUDDER,),
    steering=MappingProxyType({"delta": 1.0}),
    propulsion=MappingProxyType({}),
    forces="the rudder_propeller forces at an equivalent engine speed that is a quantity of the model: held "
           "constant over a prediction, by default the speed that holds the initial water speed in straight "
           "running (the inverse of straight_speed)",
    straight_below=math.radians(2.0),  # rad
    hold_tolerance=math.radians(1.5),  # rad
    commands=("delta", "rpm"),  # the simulated boat still has an engine; its speed is not recorded
    command_map=_turn_and_propulsion,
    turn_input=RUDDER_DEG,
    propulsion_input=ENGINE_RPM,
    sections=_RUDDER_SECTIONS,
    supports="heading and track under rudder at a constant engine setting. It cannot see a change of engine "
             "speed, and in a turn it holds the thrust of the speed the prediction starts from, which is lower "
             "than the approach speed's: turns are predicted somewhat slow",
)

TWIN_THRUSTERS = ActuatorLayout(
    name="twin_thrusters",
    description="two fixed thrusters, port and starboard, steered by differential thrust (Otter, Heron, WAM-V)",
    controls=(
        Control("port", "-", "thruster_port", "command", (-1.1, 1.1),
                "normalised port thruster command c in [-1, 1], + ahead", "command", "command_noise_std",
                "command_lsb"),
        Control("starboard", "-", "thruster_starboard", "command", (-1.1, 1.1),
                "normalised starboard thruster command c in [-1, 1], + ahead", "command", "command_noise_std",
                "command_lsb"),
    ),
    steering=MappingProxyType({"port": 1.0, "starboard": -1.0}),  # more port thrust turns to starboard
    propulsion=MappingProxyType({"port": 0.5, "starboard": 0.5}),  # the mean command
    forces="per side the thrust map at the lagged command; surge = sum, yaw moment = (port - starboard) x half "
           "spacing (the thrust configuration tau = T K u of Fossen 2021 ch. 11 for two fixed thrusters; "
           "tau of Fossen's otter.py)",
    straight_below=0.02,  # (-) thrust difference
    hold_tolerance=0.02,  # (-)
    commands=("port", "starboard"),  # normalised commands (-)
    command_map=_differential,
    turn_input=DIFFERENTIAL,
    propulsion_input=THROTTLE,
    sections=("thrusters",),
    supports="any manoeuvre of the two thrusters, ahead and astern, including turning on the spot (with the "
             "small_craft hull model, which is regular at zero speed)",
)

ACTUATOR_LAYOUTS: Mapping[str, ActuatorLayout] = MappingProxyType({
    RUDDER_PROPELLER.name: RUDDER_PROPELLER,
    RUDDER_THROTTLE.name: RUDDER_THROTTLE,
    RUDDER_ONLY.name: RUDDER_ONLY,
    TWIN_THRUSTERS.name: TWIN_THRUSTERS,
})  # fmt: skip
DEFAULT_LAYOUT = RUDDER_PROPELLER


def control_roles() -> frozenset[str]:
    """Every input role that carries a control of some layout."""
    return frozenset(c.role for layout in ACTUATOR_LAYOUTS.values() for c in layout.controls)


def unused_roles(layout: ActuatorLayout) -> frozenset[str]:
    """Control roles of other layouts that this layout does not use: a configuration may list their topics
    (config/predictor.yaml lists every layout's), the tools leave them alone for a vessel of this layout."""
    return control_roles() - set(layout.roles)


def actuator_layout(name: str) -> ActuatorLayout:
    """The layout record of `name` (ConfigError listing the known layouts otherwise)."""
    try:
        return ACTUATOR_LAYOUTS[name]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown actuator layout {name!r}; known: {', '.join(ACTUATOR_LAYOUTS)}") from None


def check_layout_inputs(layout: ActuatorLayout, inputs: Mapping[str, str], source: str) -> tuple[str, ...]:
    """The configured inputs (role -> topic) against a vessel's layout: ConfigError (one line naming the roles and
    the layout) when a control role of the layout has no input; returns one note per configured control role of
    another layout, which is ignored (no subscription, not read from bags): e.g. a rudder topic on a twin-thruster
    boat. For the node's start-up log or /diagnostics and replay's warnings."""
    missing = [role for role in layout.roles if role not in inputs]
    if missing:
        raise ConfigError(f"{source}: actuator layout {layout.name} needs input(s) {missing} "
                          f"(controls {list(layout.control_names)}); configure their topics and types")
    unused = unused_roles(layout)
    return tuple(f"input {role} (topic {inputs[role]!r}) is ignored: not a control of actuator layout {layout.name}"
                 for role in sorted(inputs) if role in unused)

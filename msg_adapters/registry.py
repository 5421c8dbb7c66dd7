"""Roles, the Adapter protocol, and option validation shared by every adapter.

A role is what a signal means for the predictor (e.g. "rudder_angle"); a ROS type is how one
robot happens to publish it. `ROLE_FIELDS` fixes each role's value columns, in order, in SI
units and marine frames (NED earth, FRD body, heading clockwise from north; rpm for engine speed).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

from usv_predictor.errors import AdapterError

ROLE_FIELDS: dict[str, tuple[str, ...]] = {
    # r rad/s FRD (= -angular_velocity.z FLU); accel = specific force m/s^2 FRD (level IMU at rest:
    # accel_z = -9.81); heading rad NED from orientation, NaN when orientation_covariance[0] == -1 (REP-145)
    "imu": ("yaw_rate", "accel_x", "accel_y", "accel_z", "heading"),
    "velocity": ("u", "v", "r"),  # body velocity over ground FRD: m/s, m/s, rad/s
    "heading": ("psi",),  # rad, NED, clockwise from north, wrapped to [-pi, pi)
    "rudder_angle": ("delta",),  # rad, positive turns the vessel to starboard
    "engine_rpm": ("rpm",),  # rev/min
    # normalised commands c in [-1, 1], + ahead (a PWM, rpm or thrust in N is converted by adapter options)
    "throttle": ("command",),  # the propeller's throttle of a rudder_throttle boat
    "thruster_port": ("command",),  # the port thruster of a twin_thrusters boat
    "thruster_starboard": ("command",),  # the starboard thruster
    "gnss": ("lat", "lon", "alt"),  # deg, deg, m (WGS-84); NaN when there is no fix
    "odometry": ("x_n", "y_e", "psi", "u", "v", "r"),  # m, m (NED in the odom frame), rad, m/s, m/s, rad/s
}


class Adapter(Protocol):
    """Converts one ROS message type to/from one role's plain numbers.

    decode(msg) -> (stamp_ns or None for header-less types, values in `fields` order). It accepts
    one message or a structure of arrays over N messages (then stamp (N,) int64, values (N,) arrays).
    encode(t_ns, values, make, frame_id) builds a message with make(type_name) -> class.
    """

    role: str
    ros_type: str

    @property
    def fields(self) -> tuple[str, ...]: ...

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]: ...

    def encode(self, t_ns: Any, values: Sequence[Any], make: Callable[[str], Any], frame_id: str = "") -> Any: ...


# ---- option validators: value -> normalised value, or ValueError describing what is allowed


def choice(*allowed: object) -> Callable[[object], object]:
    def check(value: object) -> object:
        for candidate in allowed:
            if value == candidate:
                return candidate
        raise ValueError(f"allowed values are {list(allowed)}")

    return check


def sign_option(value: object) -> object:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value in (1, -1):
        return int(value)
    raise ValueError("allowed values are [1, -1]")


def non_negative(value: object) -> object:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0:
        return float(value)
    raise ValueError("expected a finite number >= 0")


def finite_number(value: object) -> object:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value):
        return float(value)
    raise ValueError("expected a finite number")


def positive(value: object) -> object:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0:
        return float(value)
    raise ValueError("expected a finite number > 0")


def exponent_option(value: object) -> object:
    if isinstance(value, (int, float)) and not isinstance(value, bool) and 0.0 < value <= 4.0:
        return float(value)
    raise ValueError("expected a number in (0, 4]")


def non_negative_integer(value: object) -> object:
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return int(value)
    raise ValueError("expected an integer >= 0")


def boolean(value: object) -> object:
    if isinstance(value, bool):
        return value
    raise ValueError("expected true or false")


def non_empty_string(value: object) -> object:
    if isinstance(value, str) and value:
        return value
    raise ValueError("expected a non-empty string")


def validate_options(
    role: str,
    ros_type: str,
    options: Mapping[str, object],
    spec: Mapping[str, Callable[[object], object]],
    required: tuple[str, ...] = (),
) -> dict[str, object]:
    """Check `options` against `spec` (name -> validator); AdapterError names the culprit."""
    where = f"adapter {role!r} for {ros_type}"
    unknown = sorted(set(options) - set(spec))
    if unknown:
        allowed = sorted(spec) or "none"
        raise AdapterError(f"{where}: unknown option(s) {unknown}; allowed options: {allowed}")
    missing = [name for name in required if name not in options]
    if missing:
        raise AdapterError(f"{where}: option(s) {missing} required")
    checked: dict[str, object] = {}
    for name, value in options.items():
        try:
            checked[name] = spec[name](value)
        except ValueError as err:
            raise AdapterError(f"{where}: option {name}={value!r} is invalid: {err}") from err
    return checked

"""The adapters for standard ROS 2 message types (sensor_msgs, geometry_msgs, nav_msgs, std_msgs).

Conversions (REP-103/105 <-> marine, helpers from usv_predictor.frames):
    body FLU -> FRD: (x, y, z) -> (x, -y, -z): v = -linear.y, r = -angular.z
    ENU position (east, north) -> NED (x_n = north, y_e = east)
    ENU yaw (CCW from east) -> heading psi = pi/2 - yaw (clockwise from north), wrapped
REP-145: orientation_covariance[0] == -1 means "no orientation": heading decodes as NaN.
Decoding uses numpy operations only, so it also accepts a structure of arrays over N messages;
the exception is sensor_msgs/JointState (names are a per-message sequence): not vectorisable.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from msg_adapters import _codec as c
from msg_adapters.registry import (
    ROLE_FIELDS,
    boolean,
    choice,
    exponent_option,
    finite_number,
    non_empty_string,
    non_negative,
    non_negative_integer,
    positive,
    sign_option,
    validate_options,
)
from usv_predictor.errors import AdapterError
from usv_predictor.frames import (
    enu_yaw_to_heading,
    heading_to_enu_yaw,
    quaternion_to_yaw,
    wrap_angle,
    yaw_to_quaternion,
)

RAD_PER_S_TO_RPM = 60.0 / (2.0 * math.pi)  # (rev/min) / (rad/s)

# Documented default variances written by encode (what the simulator's sensors roughly are)
DEFAULT_GYRO_VARIANCE = 1.0e-6  # (rad/s)^2, 0.06 deg/s standard deviation
DEFAULT_ACCEL_VARIANCE = 1.0e-3  # (m/s^2)^2
DEFAULT_HEADING_VARIANCE = 3.0e-4  # rad^2, 1 deg standard deviation
DEFAULT_VELOCITY_VARIANCE = 1.0e-3  # (m/s)^2 and (rad/s)^2 on the twist diagonal
DEFAULT_POSITION_VARIANCE = 1.0  # m^2 on each GNSS axis (DIAGONAL_KNOWN)

NO_COVARIANCE = np.array([-1.0] + [0.0] * 8)  # REP-145: element 0 = -1 -> quantity not provided
IDENTITY_QUATERNION = (0.0, 0.0, 0.0, 1.0)


@dataclass(frozen=True)
class _Base:
    role: str
    ros_type: str

    OPTIONS: ClassVar[Mapping[str, Callable[[object], object]]] = MappingProxyType({})
    REQUIRED: ClassVar[tuple[str, ...]] = ()

    @property
    def fields(self) -> tuple[str, ...]:
        return ROLE_FIELDS[self.role]

    @classmethod
    def build(cls, role: str, ros_type: str, options: Mapping[str, object]) -> _Base:
        return cls(role, ros_type, **validate_options(role, ros_type, options, cls.OPTIONS, cls.REQUIRED))

    def _values(self, values: Sequence[Any]) -> list[np.ndarray]:
        return c.column_values(values, len(self.fields), self.ros_type)


# ---------------------------------------------------------------- orientation / twist pieces


def _heading_from_quaternion(q: Any, ros_type: str) -> np.ndarray:
    yaw = quaternion_to_yaw(*(c.field(q, axis, ros_type) for axis in "xyzw"))
    return enu_yaw_to_heading(np.asarray(yaw, dtype=np.float64))


def _quaternion_from_heading(make: c.MakeFn, psi: np.ndarray) -> Any:
    """Level-body orientation for heading psi; identity where psi is not finite."""
    valid = np.isfinite(psi)
    qx, qy, qz, qw = yaw_to_quaternion(heading_to_enu_yaw(np.where(valid, psi, 0.0)))
    return c.quaternion(make, qx, qy, np.where(valid, qz, 0.0), np.where(valid, qw, 1.0))


def _orientation_covariance(psi: np.ndarray, heading_variance: float) -> np.ndarray:
    valid = np.isfinite(psi)[..., None]
    return np.where(valid, c.diagonal_covariance([heading_variance] * 3), NO_COVARIANCE)


def _decode_twist(twist: Any, ros_type: str) -> tuple[Any, Any, Any]:
    u = c.field(twist, "linear.x", ros_type)
    v = -np.asarray(c.field(twist, "linear.y", ros_type), dtype=np.float64)  # FLU left -> FRD starboard
    r = -np.asarray(c.field(twist, "angular.z", ros_type), dtype=np.float64)  # FLU up -> FRD down
    return u, v, r


def _encode_twist(make: c.MakeFn, u: Any, v: Any, r: Any) -> Any:
    return make("geometry_msgs/msg/Twist")(
        linear=c.vector3(make, u, -v, 0.0), angular=c.vector3(make, 0.0, 0.0, -r)
    )


def _twist_covariance(variance: float) -> np.ndarray:
    return c.diagonal_covariance([variance] * 6)


def _encode_odometry(
    make: c.MakeFn, t_ns: Any, frame_id: str, child_frame_id: str, eta: Sequence[Any], nu: Sequence[Any],
    pose_variance: float, twist_variance: float,
) -> Any:
    x_n, y_e, psi = eta
    pose = make("geometry_msgs/msg/Pose")(
        position=c.vector3(make, y_e, x_n, 0.0, "geometry_msgs/msg/Point"),
        orientation=_quaternion_from_heading(make, psi),
    )
    return make("nav_msgs/msg/Odometry")(
        header=c.header(make, t_ns, frame_id),
        child_frame_id=child_frame_id,
        pose=make("geometry_msgs/msg/PoseWithCovariance")(
            pose=pose, covariance=c.diagonal_covariance([pose_variance] * 6)
        ),
        twist=make("geometry_msgs/msg/TwistWithCovariance")(
            twist=_encode_twist(make, *nu), covariance=_twist_covariance(twist_variance)
        ),
    )


# ---------------------------------------------------------------- imu


@dataclass(frozen=True)
class ImuAdapter(_Base):
    """sensor_msgs/Imu -> yaw rate, specific force (FRD) and heading (NaN if orientation absent).

    Options: gyro_variance ((rad/s)^2, default 1e-6), accel_variance ((m/s^2)^2, default 1e-3),
    heading_variance (rad^2, default 3e-4) - written on the covariance diagonals by encode.
    """

    gyro_variance: float = DEFAULT_GYRO_VARIANCE
    accel_variance: float = DEFAULT_ACCEL_VARIANCE
    heading_variance: float = DEFAULT_HEADING_VARIANCE

    OPTIONS: ClassVar = MappingProxyType(
        {"gyro_variance": non_negative, "accel_variance": non_negative, "heading_variance": non_negative}
    )

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        t = self.ros_type
        gyro_z = np.asarray(c.field(msg, "angular_velocity.z", t), dtype=np.float64)
        ax = c.field(msg, "linear_acceleration.x", t)
        ay = np.asarray(c.field(msg, "linear_acceleration.y", t), dtype=np.float64)
        az = np.asarray(c.field(msg, "linear_acceleration.z", t), dtype=np.float64)
        return c.stamp_ns(msg, t), c.values_out(-gyro_z, ax, -ay, -az, _imu_heading(msg, t))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        r, ax, ay, az, psi = self._values(values)
        return make(self.ros_type)(
            header=c.header(make, t_ns, frame_id),
            orientation=_quaternion_from_heading(make, psi),
            orientation_covariance=_orientation_covariance(psi, self.heading_variance),
            angular_velocity=c.vector3(make, 0.0, 0.0, -r),
            angular_velocity_covariance=c.diagonal_covariance([self.gyro_variance] * 3),
            linear_acceleration=c.vector3(make, ax, -ay, -az),
            linear_acceleration_covariance=c.diagonal_covariance([self.accel_variance] * 3),
        )


def _imu_heading(msg: Any, ros_type: str) -> np.ndarray:
    psi = _heading_from_quaternion(c.field(msg, "orientation", ros_type), ros_type)
    covariance = np.asarray(c.field(msg, "orientation_covariance", ros_type), dtype=np.float64)
    return np.where(covariance[..., 0] == -1.0, np.nan, psi)


@dataclass(frozen=True)
class ImuHeadingAdapter(_Base):
    """sensor_msgs/Imu orientation -> heading (NaN when REP-145 says orientation is absent).

    encode writes only the orientation; angular velocity and acceleration are marked absent
    (covariance[0] = -1). Option heading_variance (rad^2, default 3e-4).
    """

    heading_variance: float = DEFAULT_HEADING_VARIANCE

    OPTIONS: ClassVar = MappingProxyType({"heading_variance": non_negative})

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        return c.stamp_ns(msg, self.ros_type), c.values_out(_imu_heading(msg, self.ros_type))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (psi,) = self._values(values)
        return make(self.ros_type)(
            header=c.header(make, t_ns, frame_id),
            orientation=_quaternion_from_heading(make, psi),
            orientation_covariance=_orientation_covariance(psi, self.heading_variance),
            angular_velocity=c.vector3(make, 0.0, 0.0, 0.0),
            angular_velocity_covariance=NO_COVARIANCE.copy(),
            linear_acceleration=c.vector3(make, 0.0, 0.0, 0.0),
            linear_acceleration_covariance=NO_COVARIANCE.copy(),
        )


# ---------------------------------------------------------------- velocity


@dataclass(frozen=True)
class TwistStampedAdapter(_Base):
    """geometry_msgs/TwistStamped (body FLU) -> [u, v, r] FRD."""

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        twist = c.field(msg, "twist", self.ros_type)
        return c.stamp_ns(msg, self.ros_type), c.values_out(*_decode_twist(twist, self.ros_type))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        return make(self.ros_type)(header=c.header(make, t_ns, frame_id),
                                   twist=_encode_twist(make, *self._values(values)))


@dataclass(frozen=True)
class TwistWithCovarianceStampedAdapter(_Base):
    """geometry_msgs/TwistWithCovarianceStamped (body FLU) -> [u, v, r] FRD.

    Option twist_variance (diagonal written by encode, default 1e-3).
    """

    twist_variance: float = DEFAULT_VELOCITY_VARIANCE

    OPTIONS: ClassVar = MappingProxyType({"twist_variance": non_negative})

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        twist = c.field(msg, "twist.twist", self.ros_type)
        return c.stamp_ns(msg, self.ros_type), c.values_out(*_decode_twist(twist, self.ros_type))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        twist = make("geometry_msgs/msg/TwistWithCovariance")(
            twist=_encode_twist(make, *self._values(values)), covariance=_twist_covariance(self.twist_variance)
        )
        return make(self.ros_type)(header=c.header(make, t_ns, frame_id), twist=twist)


@dataclass(frozen=True)
class OdometryVelocityAdapter(_Base):
    """nav_msgs/Odometry twist part (FLU, child frame) -> [u, v, r] FRD.

    encode writes a zero pose with identity orientation (pose unknown) and marks it so with a
    negative pose covariance diagonal; options child_frame_id (default "base_link"), twist_variance.
    """

    child_frame_id: str = "base_link"
    twist_variance: float = DEFAULT_VELOCITY_VARIANCE

    OPTIONS: ClassVar = MappingProxyType({"child_frame_id": non_empty_string, "twist_variance": non_negative})

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        twist = c.field(msg, "twist.twist", self.ros_type)
        return c.stamp_ns(msg, self.ros_type), c.values_out(*_decode_twist(twist, self.ros_type))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        nu = self._values(values)
        return _encode_odometry(make, t_ns, frame_id, self.child_frame_id, (0.0, 0.0, 0.0), nu, -1.0,
                                self.twist_variance)


# ---------------------------------------------------------------- odometry


@dataclass(frozen=True)
class OdometryAdapter(_Base):
    """nav_msgs/Odometry: pose ENU in header.frame_id, twist FLU in child_frame_id -> eta NED, nu FRD.

    Options child_frame_id (default "base_link"), pose_variance (m^2/rad^2, default 1.0),
    twist_variance (default 1e-3).
    """

    child_frame_id: str = "base_link"
    pose_variance: float = DEFAULT_POSITION_VARIANCE
    twist_variance: float = DEFAULT_VELOCITY_VARIANCE

    OPTIONS: ClassVar = MappingProxyType(
        {"child_frame_id": non_empty_string, "pose_variance": non_negative, "twist_variance": non_negative}
    )

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        t = self.ros_type
        east = c.field(msg, "pose.pose.position.x", t)
        north = c.field(msg, "pose.pose.position.y", t)
        psi = _heading_from_quaternion(c.field(msg, "pose.pose.orientation", t), t)
        u, v, r = _decode_twist(c.field(msg, "twist.twist", t), t)
        return c.stamp_ns(msg, t), c.values_out(north, east, psi, u, v, r)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        x_n, y_e, psi, u, v, r = self._values(values)
        return _encode_odometry(
            make, t_ns, frame_id, self.child_frame_id, (x_n, y_e, psi), (u, v, r), self.pose_variance,
                                self.twist_variance
        )


# ---------------------------------------------------------------- heading


@dataclass(frozen=True)
class ScalarHeadingAdapter(_Base):
    """std_msgs/Float64|Float32 heading (header-less: stamp None).

    Options: units "deg" (default) | "rad"; convention "compass" (clockwise from north, default;
    encode writes [0, 360) deg or [0, 2 pi) rad) | "enu" (counter-clockwise from east, wrapped).
    A value more than one turn (RAW_LIMIT) from zero is not a heading in the configured unit (a corrupt value, or
    degrees configured as rad): it decodes as NaN instead of being wrapped into a plausible-looking angle.
    """

    units: str = "deg"
    convention: str = "compass"

    OPTIONS: ClassVar = MappingProxyType({"units": choice("deg", "rad"), "convention": choice("compass", "enu")})
    RAW_LIMIT: ClassVar = MappingProxyType({"rad": 2.0 * math.pi + 1e-6, "deg": 360.0 + 1e-6})  # |raw| per unit

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        angle = np.asarray(c.field(msg, "data", self.ros_type), dtype=np.float64)
        angle = np.where(np.abs(angle) <= self.RAW_LIMIT[self.units], angle, np.nan)
        angle = np.radians(angle) if self.units == "deg" else angle
        psi = wrap_angle(angle) if self.convention == "compass" else enu_yaw_to_heading(angle)
        return None, c.values_out(psi)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (psi,) = self._values(values)
        angle = np.mod(psi, 2.0 * math.pi) if self.convention == "compass" else heading_to_enu_yaw(psi)
        angle = np.degrees(angle) if self.units == "deg" else angle
        return make(self.ros_type)(data=c.leaf(angle))


@dataclass(frozen=True)
class QuaternionHeadingAdapter(_Base):
    """geometry_msgs/QuaternionStamped (ENU orientation of a level body) -> heading."""

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        psi = _heading_from_quaternion(c.field(msg, "quaternion", self.ros_type), self.ros_type)
        return c.stamp_ns(msg, self.ros_type), c.values_out(psi)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (psi,) = self._values(values)
        return make(self.ros_type)(header=c.header(make, t_ns, frame_id),
                                   quaternion=_quaternion_from_heading(make, psi))


# ---------------------------------------------------------------- actuators


@dataclass(frozen=True)
class ScalarRudderAdapter(_Base):
    """std_msgs/Float64|Float32 rudder angle. Options units "rad" (default) | "deg", sign 1 | -1
    (-1 when the boat's positive rudder turns it to port)."""

    units: str = "rad"
    sign: int = 1

    OPTIONS: ClassVar = MappingProxyType({"units": choice("rad", "deg"), "sign": sign_option})

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        angle = self.sign * np.asarray(c.field(msg, "data", self.ros_type), dtype=np.float64)
        return None, c.values_out(np.radians(angle) if self.units == "deg" else angle)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (delta,) = self._values(values)
        angle = np.degrees(delta) if self.units == "deg" else delta
        return make(self.ros_type)(data=c.leaf(self.sign * angle))


@dataclass(frozen=True)
class ScalarRpmAdapter(_Base):
    """std_msgs/Float64|Float32 engine speed in rev/min."""

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        return None, c.values_out(c.field(msg, "data", self.ros_type))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (rpm,) = self._values(values)
        return make(self.ros_type)(data=c.leaf(rpm))


# ---------------------------------------------------------------- commands: a throttle, one thruster

# units -> (default neutral, default full_scale) in that unit; None: full_scale has no default (the option is required)
COMMAND_UNITS: Mapping[str, tuple[float, float | None]] = MappingProxyType({
    "normalised": (0.0, 1.0),  # (-) the command c itself
    "percent": (0.0, 100.0),  # (%) of full ahead
    "pwm": (1500.0, 500.0),  # (us) RC pulse width: 1500 us neutral, 2000 us full ahead, 1000 us full astern
    "rpm": (0.0, None),  # (rev/min) shaft speed; full_scale = the rpm at full ahead
    "rad_per_s": (0.0, None),  # (rad/s) shaft speed (what sensor_msgs/JointState velocity holds)
    "newton": (0.0, None),  # (N) thrust; full_scale = the thrust at full ahead (VRX thrusters)
})
_UNIT_WORDS = MappingProxyType({"normalised": "a normalised command", "percent": "a percent", "pwm": "a PWM in us",
                                "rpm": "a shaft speed in rpm", "rad_per_s": "a shaft speed in rad/s",
                                "newton": "a thrust in N"})
COMMAND_LIMIT = 1.2  # (-) a decoded |c| beyond this is no command of the configured scale: refused


def _likely_mistake(units: str, raw: float) -> str:
    """What a raw value far outside the configured scale most likely is (for the refusal)."""
    size = abs(raw)
    if units != "pwm" and 800.0 <= size <= 2200.0:
        return f"a PWM in microseconds configured as {_UNIT_WORDS[units]}?"
    if units == "pwm" and size <= 100.0 * COMMAND_LIMIT:
        return "a normalised or percent command configured as pwm (or a wrong neutral)?"
    if units == "normalised" and size <= 100.0 * COMMAND_LIMIT:
        return "a percent configured as normalised?"
    if units in ("rpm", "rad_per_s", "newton"):
        return f"is full_scale really {_UNIT_WORDS[units]} at full ahead?"
    return "check the units, neutral and full_scale options"


@dataclass(frozen=True)
class CommandScale:
    """A raw actuator value (PWM, percent, rpm, N, ...) <-> the normalised command c in [-1, 1] (+ ahead).

    decode: d = sign (raw - neutral); r = d / full_scale for d >= 0, d / reverse_full_scale for d < 0 (the astern
    full scale, e.g. a propeller's lower astern rpm); c = sign(r) |r|^(1/exponent). exponent 1 (default) is a
    linear command; 2 reads a thrust in N of a propeller whose command is proportional to shaft speed
    (T ~ n|n|, Fossen 2021 eq. 9.1, the Otter's thrust map). encode inverts it: raw = neutral + sign s sign(c)
    |c|^exponent with s the full scale of c's direction. With the defaults (normalised) c = raw exactly.
    """

    units: str
    neutral: float
    full_scale: float  # raw units above neutral at full ahead (> 0)
    reverse_full_scale: float  # raw units below neutral at full astern (> 0)
    sign: int  # +1, or -1 when the raw value's positive direction is astern
    exponent: float  # raw ~ |c|^exponent (-)

    def ratio(self, raw: Any) -> np.ndarray:
        """r: the raw value's distance from neutral as a fraction of the full scale of its direction."""
        d = self.sign * (np.asarray(raw, dtype=np.float64) - self.neutral)
        return np.where(d >= 0.0, d / self.full_scale, d / self.reverse_full_scale)

    def to_command(self, raw: Any) -> np.ndarray:
        r = self.ratio(raw)
        return r if self.exponent == 1.0 else np.sign(r) * np.abs(r) ** (1.0 / self.exponent)

    def to_raw(self, command: Any) -> np.ndarray:
        c = np.asarray(command, dtype=np.float64)
        r = c if self.exponent == 1.0 else np.sign(c) * np.abs(c) ** self.exponent
        return self.neutral + self.sign * np.where(r >= 0.0, r * self.full_scale, r * self.reverse_full_scale)

    def describe(self) -> str:
        text = f"units {self.units} neutral {self.neutral:g} full_scale {self.full_scale:g}"
        if self.reverse_full_scale != self.full_scale:
            text += f" reverse_full_scale {self.reverse_full_scale:g}"
        if self.exponent != 1.0:
            text += f" exponent {self.exponent:g}"
        return text + (" sign -1" if self.sign == -1 else "")


def check_command(role: str, source: str, raw: Any, command: Any, ratio: Any, setting: str,
                  hint: Callable[[float], str],
                  limit: float = COMMAND_LIMIT) -> None:
    """AdapterError when a decoded |command| exceeds `limit` (NaN passes): names the role, the field, the setting
    and the likely mistake (a PWM configured as thrust, ...)."""
    command = np.asarray(command, dtype=np.float64)
    bad = np.abs(command) > limit
    if not bad.any():
        return
    k = int(np.flatnonzero(bad.ravel())[0])
    value = float(np.broadcast_to(np.asarray(raw, dtype=np.float64), command.shape).ravel()[k])
    size = float(np.broadcast_to(np.asarray(ratio, dtype=np.float64), command.shape).ravel()[k])
    count = f" ({int(bad.sum())} of {bad.size} samples)" if bad.size > 1 else ""
    raise AdapterError(f"{role} = {value:g} ({source}) with {setting} is {abs(size):.3g} x full scale, beyond "
                       f"{limit:g}{count}: {hint(value)}")


@dataclass(frozen=True)
class _CommandBase(_Base):
    """Options shared by the command adapters (one number per role): units, neutral, full_scale,
    reverse_full_scale (default full_scale), sign, exponent (see CommandScale); defaults per units in COMMAND_UNITS."""

    units: str = "normalised"
    neutral: float | None = None
    full_scale: float | None = None
    reverse_full_scale: float | None = None
    sign: int = 1
    exponent: float = 1.0

    OPTIONS: ClassVar = MappingProxyType({
        "units": choice(*COMMAND_UNITS), "neutral": finite_number, "full_scale": positive,
        "reverse_full_scale": positive, "sign": sign_option, "exponent": exponent_option,
    })

    def __post_init__(self) -> None:
        neutral, full_scale = COMMAND_UNITS[self.units]
        if self.full_scale is None and full_scale is None:
            raise AdapterError(f"adapter {self.role!r} for {self.ros_type}: units {self.units} need the option "
                               f"full_scale ({_UNIT_WORDS[self.units]} at full ahead)")
        object.__setattr__(self, "neutral", neutral if self.neutral is None else self.neutral)
        object.__setattr__(self, "full_scale", full_scale if self.full_scale is None else self.full_scale)
        if self.reverse_full_scale is None:
            object.__setattr__(self, "reverse_full_scale", self.full_scale)

    @property
    def scale(self) -> CommandScale:
        return CommandScale(self.units, float(self.neutral), float(self.full_scale), float(self.reverse_full_scale),
                            self.sign, self.exponent)

    @property
    def source(self) -> str:
        """The message field the command is read from, for messages."""
        return "data"

    def command(self, raw: Any) -> np.ndarray:
        """The checked normalised command of raw values (AdapterError naming the likely mistake)."""
        scale = self.scale
        command = scale.to_command(raw)
        check_command(self.role, self.source, raw, command, scale.ratio(raw), scale.describe(),
                      lambda value: _likely_mistake(self.units, value))
        return command


@dataclass(frozen=True)
class ScalarCommandAdapter(_CommandBase):
    """std_msgs/Float64|Float32 -> a normalised command c in [-1, 1] (+ ahead): a throttle or one thruster.

    The number is in `units` (default normalised: c as it is); VRX thrusters: units newton, full_scale the thrust
    at full ahead; PWM: units pwm (neutral 1500, full_scale 500 us by default). See CommandScale.
    """

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        return None, c.values_out(self.command(c.field(msg, "data", self.ros_type)))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (command,) = self._values(values)
        return make(self.ros_type)(data=c.leaf(self.scale.to_raw(command)))


# ---- several roles on one topic (Float64MultiArray, JointState, Wrench carry both thrusters)
#
# An adapter of a type that can carry several roles has SHARES_TOPIC = True, a `slot` (what part of the message it
# reads; adapters on one topic need different slots), `message_options` (options about the whole message that
# adapters on one topic must agree on) and a classmethod encode_shared(adapters, t_ns, values, make, frame_id)
# building one message from the values of every role; encode(...) is encode_shared of one adapter (the other slots
# neutral). msg_adapters.encode_shared checks a group and calls it.


def _multiarray_value(msg: Any, index: int, ros_type: str) -> np.ndarray:
    """data[data_offset + index] of one message ((k,) data) or of a structure of arrays ((N, k) data)."""
    data = np.asarray(c.field(msg, "data", ros_type), dtype=np.float64)
    offset = np.asarray(c.field(msg, "layout.data_offset", ros_type), dtype=np.int64)
    position = offset + index
    size = data.shape[-1] if data.ndim else 0
    if data.ndim == 0 or np.any(position >= size):
        raise AdapterError(f"{ros_type}: data has {size} entries, expected entry {index} (after data_offset "
                           f"{int(np.max(offset))}); is `index` right?")
    if data.ndim == 1:
        return data[int(position)]
    return np.take_along_axis(data, np.broadcast_to(position, data.shape[:-1])[..., None], axis=-1)[..., 0]


@dataclass(frozen=True)
class MultiArrayCommandAdapter(_CommandBase):
    """std_msgs/Float64MultiArray|Float32MultiArray entry `index` (required option; after layout.data_offset) -> a
    normalised command, with the CommandScale options (e.g. left/right PWM in one message: index 0 and 1, units pwm).
    Two roles may share the topic (different indices). encode writes an empty layout.dim, data_offset 0, and 0 in
    the entries no role writes."""

    index: int = 0

    OPTIONS: ClassVar = MappingProxyType({**_CommandBase.OPTIONS, "index": non_negative_integer})
    REQUIRED: ClassVar = ("index",)
    SHARES_TOPIC: ClassVar[bool] = True

    @property
    def source(self) -> str:
        return f"data[{self.index}]"

    @property
    def slot(self) -> object:
        return self.index

    @property
    def message_options(self) -> tuple:
        return ()

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        return None, c.values_out(self.command(_multiarray_value(msg, self.index, self.ros_type)))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        return self.encode_shared((self,), t_ns, (values,), make, frame_id)

    @classmethod
    def encode_shared(cls, adapters: Sequence[MultiArrayCommandAdapter], t_ns: Any, values: Sequence[Sequence[Any]],
                      make: c.MakeFn, frame_id: str = "") -> Any:
        raws = [a.scale.to_raw(a._values(v)[0]) for a, v in zip(adapters, values)]
        shape = np.broadcast_shapes(*(r.shape for r in raws))
        data = np.zeros((*shape, max(a.index for a in adapters) + 1))  # (..., k)
        for adapter, raw in zip(adapters, raws):
            data[..., adapter.index] = raw
        if "Float32" in adapters[0].ros_type:
            data = data.astype(np.float32)  # rclpy's array('f') takes float32 only
        layout = make("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0)
        return make(adapters[0].ros_type)(layout=layout, data=data)


JOINT_FIELDS = ("position", "velocity", "effort")


@dataclass(frozen=True)
class JointStateCommandAdapter(_CommandBase):
    """sensor_msgs/JointState `field` (position | velocity | effort, default velocity) of joint `joint` (required)
    -> a normalised command, with the CommandScale options. The number is taken in `units` as it is: a driver that
    follows ROS and publishes the propeller's velocity in rad/s needs units rad_per_s (full_scale in rad/s), one
    that publishes rpm there units rpm. Two roles may share the topic (different joints or fields). Decode handles
    one message at a time (not vectorisable). encode writes the joints of its roles and 0 in the fields no role
    of a joint reads (empty fields no role reads)."""

    joint: str = ""
    field: str = "velocity"

    OPTIONS: ClassVar = MappingProxyType({**_CommandBase.OPTIONS, "joint": non_empty_string,
                                          "field": choice(*JOINT_FIELDS)})
    REQUIRED: ClassVar = ("joint",)
    SHARES_TOPIC: ClassVar[bool] = True

    @property
    def source(self) -> str:
        return f"{self.field} of joint {self.joint!r}"

    @property
    def slot(self) -> object:
        return (self.joint, self.field)

    @property
    def message_options(self) -> tuple:
        return ()

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        raw = _joint_value(msg, self.joint, self.ros_type, self.field)
        return c.stamp_ns(msg, self.ros_type), c.values_out(self.command(raw))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        return self.encode_shared((self,), t_ns, (values,), make, frame_id)

    @classmethod
    def encode_shared(cls, adapters: Sequence[JointStateCommandAdapter], t_ns: Any, values: Sequence[Sequence[Any]],
                      make: c.MakeFn, frame_id: str = "") -> Any:
        raws = [a.scale.to_raw(a._values(v)[0]) for a, v in zip(adapters, values)]
        shape = np.broadcast_shapes(np.shape(t_ns), *(r.shape for r in raws))
        joints = list(dict.fromkeys(a.joint for a in adapters))
        columns = {name: np.zeros((*shape, len(joints))) if any(a.field == name for a in adapters) else np.zeros(0)
                   for name in JOINT_FIELDS}  # (..., joints) or empty
        for adapter, raw in zip(adapters, raws):
            columns[adapter.field][..., joints.index(adapter.joint)] = raw
        return make(adapters[0].ros_type)(header=c.header(make, t_ns, frame_id), name=joints, **columns)


@dataclass(frozen=True)
class WrenchCommandAdapter(_Base):
    """geometry_msgs/Wrench|WrenchStamped as a normalised surge/yaw command (Otter drivers) -> one thruster.

    Mixing (Fossen 2021 ch. 11, two fixed thrusters): s = force.x / surge_full_scale (+ ahead) and the yaw command
    y = -sign torque.z / yaw_full_scale, + turning to starboard (FRD; torque.z of the message is FLU, + turning to
    port; sign -1 for a driver whose positive torque.z turns to starboard). Then
        port = s + y,  starboard = s - y
    (more port thrust turns to starboard). encode inverts it: s = (port + starboard) / 2, y = (port - starboard) / 2;
    one role alone encodes the other side at 0. |s|, |y| and, unless saturate, the mixed command beyond 1.2 are
    refused; saturate: true clips the mixed command to [-1, 1] as drivers do (surge 1 with yaw 0.3 is full port).
    Both roles on one topic must have the same options.
    """

    surge_full_scale: float = 1.0  # force.x at full ahead (the message's unit: normalised, or N)
    yaw_full_scale: float = 1.0  # |torque.z| of a full differential (normalised, or N m)
    sign: int = 1
    saturate: bool = False

    OPTIONS: ClassVar = MappingProxyType({"surge_full_scale": positive, "yaw_full_scale": positive,
                                          "sign": sign_option, "saturate": boolean})
    SIDE: ClassVar = MappingProxyType({"thruster_port": 1.0, "thruster_starboard": -1.0})  # c = s + side * y
    SHARES_TOPIC: ClassVar[bool] = True

    @property
    def slot(self) -> object:
        return self.role

    @property
    def message_options(self) -> tuple:
        return (self.surge_full_scale, self.yaw_full_scale, self.sign, self.saturate)

    def _wrench(self, msg: Any) -> Any:
        return c.field(msg, "wrench", self.ros_type) if self.ros_type.endswith("Stamped") else msg

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        wrench = self._wrench(msg)
        force_x = np.asarray(c.field(wrench, "force.x", self.ros_type), dtype=np.float64)
        torque_z = np.asarray(c.field(wrench, "torque.z", self.ros_type), dtype=np.float64)
        surge = force_x / self.surge_full_scale
        yaw = -self.sign * torque_z / self.yaw_full_scale
        setting = f"surge_full_scale {self.surge_full_scale:g} yaw_full_scale {self.yaw_full_scale:g}"
        hint = lambda value: ("is the full scale the message's value at full command "  # noqa: E731
                              "(N or N m for a wrench in SI)?")
        check_command(self.role, "force.x, the surge", force_x, surge, surge, setting, hint)
        check_command(self.role, "torque.z, the yaw", torque_z, yaw, yaw, setting, hint)
        command = surge + self.SIDE[self.role] * yaw
        if self.saturate:
            command = np.clip(command, -1.0, 1.0)
        else:
            check_command(self.role, "force.x and torque.z mixed", command, command, command, setting,
                          lambda value: "a surge plus yaw beyond full: set saturate: true if the driver clips")
        stamp = c.stamp_ns(msg, self.ros_type) if self.ros_type.endswith("Stamped") else None
        return stamp, c.values_out(command)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        return self.encode_shared((self,), t_ns, (values,), make, frame_id)

    @classmethod
    def encode_shared(cls, adapters: Sequence[WrenchCommandAdapter], t_ns: Any, values: Sequence[Sequence[Any]],
                      make: c.MakeFn, frame_id: str = "") -> Any:
        side = {a.role: a._values(v)[0] for a, v in zip(adapters, values)}
        port, starboard = side.get("thruster_port", 0.0), side.get("thruster_starboard", 0.0)
        first = adapters[0]
        surge = 0.5 * (port + starboard) * first.surge_full_scale
        torque_z = -first.sign * 0.5 * (port - starboard) * first.yaw_full_scale
        wrench = make("geometry_msgs/msg/Wrench")(force=c.vector3(make, surge, 0.0, 0.0),
                                                   torque=c.vector3(make, 0.0, 0.0, torque_z))
        if not first.ros_type.endswith("Stamped"):
            return wrench
        return make(first.ros_type)(header=c.header(make, t_ns, frame_id), wrench=wrench)


def _joint_index(msg: Any, joint: str, ros_type: str) -> int:
    names = c.field(msg, "name", ros_type)
    if not all(isinstance(name, str) for name in names):
        raise AdapterError(
            f"{ros_type}: decode is not vectorisable (joint names are a per-message sequence); "
            "decode messages one by one"
        )
    try:
        return list(names).index(joint)
    except ValueError:
        raise AdapterError(f"{ros_type}: no joint {joint!r} in the message; names present: {list(names)}") from None


def _joint_value(msg: Any, joint: str, ros_type: str, sequence: str) -> float:
    index = _joint_index(msg, joint, ros_type)
    column = c.field(msg, sequence, ros_type)
    if len(column) <= index:
        raise AdapterError(
            f"{ros_type}: joint {joint!r} is entry {index} of name but {sequence} has only {len(column)} entries"
        )
    return float(column[index])


@dataclass(frozen=True)
class JointStateRudderAdapter(_Base):
    """sensor_msgs/JointState position of joint `joint` (required option) -> rudder angle rad;
    option sign 1 | -1. Decode handles one message at a time (not vectorisable)."""

    joint: str = ""
    sign: int = 1

    OPTIONS: ClassVar = MappingProxyType({"joint": non_empty_string, "sign": sign_option})
    REQUIRED: ClassVar = ("joint",)

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        position = _joint_value(msg, self.joint, self.ros_type, "position")
        return c.stamp_ns(msg, self.ros_type), c.values_out(self.sign * position)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (delta,) = self._values(values)
        return make(self.ros_type)(
            header=c.header(make, t_ns, frame_id),
            name=[self.joint],
            position=(self.sign * delta)[..., None],
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )


@dataclass(frozen=True)
class JointStateRpmAdapter(_Base):
    """sensor_msgs/JointState velocity (rad/s) of joint `joint` (required option) -> rpm.
    Decode handles one message at a time (not vectorisable)."""

    joint: str = ""

    OPTIONS: ClassVar = MappingProxyType({"joint": non_empty_string})
    REQUIRED: ClassVar = ("joint",)

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        omega = _joint_value(msg, self.joint, self.ros_type, "velocity")
        return c.stamp_ns(msg, self.ros_type), c.values_out(omega * RAD_PER_S_TO_RPM)

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        (rpm,) = self._values(values)
        return make(self.ros_type)(
            header=c.header(make, t_ns, frame_id),
            name=[self.joint],
            position=np.zeros(0),
            velocity=(rpm / RAD_PER_S_TO_RPM)[..., None],
            effort=np.zeros(0),
        )


# ---------------------------------------------------------------- gnss


@dataclass(frozen=True)
class NavSatFixAdapter(_Base):
    """sensor_msgs/NavSatFix -> lat, lon (deg), alt (m); NaN when status.status < 0 (no fix).

    encode writes STATUS_FIX / SERVICE_GPS for finite rows and STATUS_NO_FIX otherwise, with a
    DIAGONAL_KNOWN covariance; option position_variance (m^2, default 1.0).
    """

    position_variance: float = DEFAULT_POSITION_VARIANCE

    OPTIONS: ClassVar = MappingProxyType({"position_variance": non_negative})

    STATUS_NO_FIX: ClassVar[int] = -1
    STATUS_FIX: ClassVar[int] = 0
    SERVICE_GPS: ClassVar[int] = 1
    COVARIANCE_TYPE_DIAGONAL_KNOWN: ClassVar[int] = 2

    def decode(self, msg: Any) -> tuple[Any, tuple[Any, ...]]:
        t = self.ros_type
        no_fix = np.asarray(c.field(msg, "status.status", t)) < 0
        position = [np.asarray(c.field(msg, name, t), dtype=np.float64)
                    for name in ("latitude", "longitude", "altitude")]
        return c.stamp_ns(msg, t), c.values_out(*(np.where(no_fix, np.nan, p) for p in position))

    def encode(self, t_ns: Any, values: Sequence[Any], make: c.MakeFn, frame_id: str = "") -> Any:
        lat, lon, alt = self._values(values)
        fix = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(alt)
        status = make("sensor_msgs/msg/NavSatStatus")(
            status=c.int_leaf(np.where(fix, self.STATUS_FIX, self.STATUS_NO_FIX)), service=self.SERVICE_GPS
        )
        return make(self.ros_type)(
            header=c.header(make, t_ns, frame_id),
            status=status,
            latitude=c.leaf(lat),
            longitude=c.leaf(lon),
            altitude=c.leaf(alt),
            position_covariance=c.diagonal_covariance([self.position_variance] * 3),
            position_covariance_type=self.COVARIANCE_TYPE_DIAGONAL_KNOWN,
        )


# ---------------------------------------------------------------- the registry (immutable)

ADAPTER_CLASSES: Mapping[tuple[str, str], type[_Base]] = MappingProxyType(
    {
        ("imu", "sensor_msgs/msg/Imu"): ImuAdapter,
        ("velocity", "geometry_msgs/msg/TwistStamped"): TwistStampedAdapter,
        ("velocity", "geometry_msgs/msg/TwistWithCovarianceStamped"): TwistWithCovarianceStampedAdapter,
        ("velocity", "nav_msgs/msg/Odometry"): OdometryVelocityAdapter,
        ("heading", "std_msgs/msg/Float64"): ScalarHeadingAdapter,
        ("heading", "std_msgs/msg/Float32"): ScalarHeadingAdapter,
        ("heading", "geometry_msgs/msg/QuaternionStamped"): QuaternionHeadingAdapter,
        ("heading", "sensor_msgs/msg/Imu"): ImuHeadingAdapter,
        ("rudder_angle", "std_msgs/msg/Float64"): ScalarRudderAdapter,
        ("rudder_angle", "std_msgs/msg/Float32"): ScalarRudderAdapter,
        ("rudder_angle", "sensor_msgs/msg/JointState"): JointStateRudderAdapter,
        ("engine_rpm", "std_msgs/msg/Float64"): ScalarRpmAdapter,
        ("engine_rpm", "std_msgs/msg/Float32"): ScalarRpmAdapter,
        ("engine_rpm", "sensor_msgs/msg/JointState"): JointStateRpmAdapter,
        ("throttle", "std_msgs/msg/Float64"): ScalarCommandAdapter,
        ("throttle", "std_msgs/msg/Float32"): ScalarCommandAdapter,
        ("throttle", "std_msgs/msg/Float64MultiArray"): MultiArrayCommandAdapter,
        ("throttle", "std_msgs/msg/Float32MultiArray"): MultiArrayCommandAdapter,
        ("throttle", "sensor_msgs/msg/JointState"): JointStateCommandAdapter,
        ("thruster_port", "std_msgs/msg/Float64"): ScalarCommandAdapter,
        ("thruster_port", "std_msgs/msg/Float32"): ScalarCommandAdapter,
        ("thruster_port", "std_msgs/msg/Float64MultiArray"): MultiArrayCommandAdapter,
        ("thruster_port", "std_msgs/msg/Float32MultiArray"): MultiArrayCommandAdapter,
        ("thruster_port", "sensor_msgs/msg/JointState"): JointStateCommandAdapter,
        ("thruster_port", "geometry_msgs/msg/Wrench"): WrenchCommandAdapter,
        ("thruster_port", "geometry_msgs/msg/WrenchStamped"): WrenchCommandAdapter,
        ("thruster_starboard", "std_msgs/msg/Float64"): ScalarCommandAdapter,
        ("thruster_starboard", "std_msgs/msg/Float32"): ScalarCommandAdapter,
        ("thruster_starboard", "std_msgs/msg/Float64MultiArray"): MultiArrayCommandAdapter,
        ("thruster_starboard", "std_msgs/msg/Float32MultiArray"): MultiArrayCommandAdapter,
        ("thruster_starboard", "sensor_msgs/msg/JointState"): JointStateCommandAdapter,
        ("thruster_starboard", "geometry_msgs/msg/Wrench"): WrenchCommandAdapter,
        ("thruster_starboard", "geometry_msgs/msg/WrenchStamped"): WrenchCommandAdapter,
        ("gnss", "sensor_msgs/msg/NavSatFix"): NavSatFixAdapter,
        ("odometry", "nav_msgs/msg/Odometry"): OdometryAdapter,
    }
)

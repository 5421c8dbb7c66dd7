"""msg_adapters: round trips with rosbags and rclpy messages, frame conversions against hand-computed
cases, options, REP-145, errors, vectorised (structure of arrays) decoding, and no rclpy import."""
from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

import msg_adapters
from msg_adapters import ROLE_FIELDS, columnar_factory, get_adapter, rclpy_factory, registered, rosbags_factory
from msg_adapters.outputs import decode_path, decode_predicted_velocities, encode_path, encode_predicted_velocities
from usv_predictor.errors import AdapterError
from usv_predictor.frames import quaternion_to_yaw

REPO_ROOT = Path(__file__).resolve().parents[1]
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
FACTORIES = {"rosbags": rosbags_factory(TYPESTORE), "rclpy": rclpy_factory()}
OPTIONS = {
    "sensor_msgs/msg/JointState": {"joint": "rudder_joint"},
    "std_msgs/msg/Float64MultiArray": {"index": 1},
    "std_msgs/msg/Float32MultiArray": {"index": 1},
}
HEADERLESS = {"geometry_msgs/msg/Wrench"}  # and every std_msgs type
COMMAND_ROLES = ("throttle", "thruster_port", "thruster_starboard")
T_NS = 1_700_000_123_456_789_012

# One plausible sample per role (SI, marine frames); heading 2.5 rad is deliberately not pi/2.
SAMPLES = {
    "imu": (0.1, 0.2, -0.3, -9.81, 2.5),
    "velocity": (3.0, 1.0, 0.1),
    "heading": (2.5,),
    "rudder_angle": (0.2,),
    "engine_rpm": (1200.0,),
    "throttle": (0.6,),
    "thruster_port": (0.75,),
    "thruster_starboard": (-0.25,),
    "gnss": (59.1234567, 10.7654321, 3.5),
    "odometry": (120.0, -45.0, -2.0, 3.0, -0.4, -0.05),
}


def adapter_for(role: str, ros_type: str, **extra):
    return get_adapter(role, ros_type, **{**OPTIONS.get(ros_type, {}), **extra})


def tolerance(ros_type: str) -> float:
    return 1e-5 if "Float32" in ros_type else 1e-12


def stack(messages: list) -> SimpleNamespace | np.ndarray | str | list:
    """Structure of arrays from rosbags messages: numeric leaves stacked along a new first axis."""
    first = messages[0]
    if dataclasses.is_dataclass(first):
        return SimpleNamespace(
            **{f.name: stack([getattr(m, f.name) for m in messages]) for f in dataclasses.fields(first)}
        )
    if isinstance(first, str):
        return first
    if isinstance(first, list):
        return first  # sequences of strings (JointState names): kept per message
    return np.stack([np.asarray(m) for m in messages])


@pytest.mark.parametrize("factory", sorted(FACTORIES))
@pytest.mark.parametrize(("role", "ros_type"), registered())
def test_round_trip_every_adapter(role: str, ros_type: str, factory: str) -> None:
    adapter = adapter_for(role, ros_type)
    assert adapter.fields == ROLE_FIELDS[role]
    msg = adapter.encode(T_NS, SAMPLES[role], FACTORIES[factory], "frame")
    stamp, values = adapter.decode(msg)
    assert stamp == (None if ros_type in HEADERLESS or ros_type.startswith("std_msgs") else T_NS)
    np.testing.assert_allclose(values, SAMPLES[role], rtol=tolerance(ros_type), atol=tolerance(ros_type))
    if factory == "rosbags":  # the typestore can serialise what encode built
        assert len(TYPESTORE.serialize_cdr(msg, ros_type)) > 4


def test_imu_frame_conversions_by_hand() -> None:
    make = FACTORIES["rclpy"]
    imu = get_adapter("imu", "sensor_msgs/msg/Imu")
    # yaw rate r=+0.1 (starboard turn) -> FLU angular_velocity.z = -0.1; sway accel to starboard -> +y FRD
    # is -y FLU; a level IMU at rest reads -9.81 FRD z = +9.81 FLU; heading 90 deg (east) -> ENU yaw 0
    msg = imu.encode(T_NS, (0.1, 0.5, 0.25, -9.81, math.pi / 2), make, "imu_link")
    assert msg.angular_velocity.z == pytest.approx(-0.1)
    assert (msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z) == pytest.approx(
        (0.5, -0.25, 9.81)
    )
    assert (msg.orientation.z, msg.orientation.w) == pytest.approx((0.0, 1.0))
    assert msg.header.frame_id == "imu_link"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (T_NS // 10**9, T_NS % 10**9)
    # heading 0 (north) is ENU yaw +90 deg: quaternion (0, 0, sin 45, cos 45)
    north = imu.encode(T_NS, (0.0, 0.0, 0.0, -9.81, 0.0), make)
    assert quaternion_to_yaw(north.orientation.x, north.orientation.y, north.orientation.z, north.orientation.w) == (
        pytest.approx(math.pi / 2)
    )
    assert north.orientation_covariance[0] == pytest.approx(imu.heading_variance)
    assert north.angular_velocity_covariance[4] == pytest.approx(imu.gyro_variance)


def test_velocity_and_odometry_frame_conversions_by_hand() -> None:
    make = FACTORIES["rosbags"]
    twist = get_adapter("velocity", "geometry_msgs/msg/TwistStamped").encode(T_NS, (2.0, 1.0, 0.1), make)
    assert (twist.twist.linear.x, twist.twist.linear.y, twist.twist.angular.z) == pytest.approx((2.0, -1.0, -0.1))
    odom = get_adapter("odometry", "nav_msgs/msg/Odometry", child_frame_id="hull").encode(
        T_NS, (10.0, 5.0, math.pi, 1.0, 1.0, 0.1), make, "odom"
    )
    # NED (north 10, east 5) -> ENU (x east 5, y north 10); heading south -> ENU yaw -90 deg
    assert (odom.pose.pose.position.x, odom.pose.pose.position.y) == pytest.approx((5.0, 10.0))
    q = odom.pose.pose.orientation
    assert quaternion_to_yaw(q.x, q.y, q.z, q.w) == pytest.approx(-math.pi / 2)
    assert (odom.twist.twist.linear.y, odom.twist.twist.angular.z) == pytest.approx((-1.0, -0.1))
    assert (odom.header.frame_id, odom.child_frame_id) == ("odom", "hull")


def test_decoding_hand_made_rclpy_messages() -> None:
    from geometry_msgs.msg import TwistStamped
    from sensor_msgs.msg import Imu

    twist = TwistStamped()
    twist.twist.linear.x, twist.twist.linear.y, twist.twist.angular.z = 1.5, 0.5, 0.2  # left and CCW in FLU
    assert get_adapter("velocity", "geometry_msgs/msg/TwistStamped").decode(twist)[1] == pytest.approx(
        (1.5, -0.5, -0.2)
    )
    imu = Imu()
    imu.orientation.z, imu.orientation.w = math.sin(math.pi / 4), math.cos(math.pi / 4)  # ENU yaw 90 = north
    imu.linear_acceleration.z = 9.81
    _, (r, ax, ay, az, psi) = get_adapter("imu", "sensor_msgs/msg/Imu").decode(imu)
    assert (az, psi) == pytest.approx((-9.81, 0.0))


@pytest.mark.parametrize(
    ("options", "data", "expected_psi"),
    [
        ({}, 90.0, math.pi / 2),  # compass degrees (default): east
        ({}, 350.0, -math.radians(10.0)),  # wrapped to [-pi, pi)
        ({"units": "rad"}, math.pi, -math.pi),
        ({"convention": "enu"}, 0.0, math.pi / 2),  # ENU yaw 0 = facing east = heading 90 deg
        ({"convention": "enu", "units": "rad"}, math.pi / 2, 0.0),  # ENU yaw 90 deg = north
    ],
)
def test_scalar_heading_options(options: dict, data: float, expected_psi: float) -> None:
    adapter = get_adapter("heading", "std_msgs/msg/Float64", **options)
    make = FACTORIES["rosbags"]
    stamp, (psi,) = adapter.decode(make("std_msgs/msg/Float64")(data=data))
    assert stamp is None
    assert psi == pytest.approx(expected_psi)
    assert adapter.decode(adapter.encode(0, (psi,), make))[1][0] == pytest.approx(expected_psi)


def test_compass_heading_encodes_in_0_to_360_degrees() -> None:
    msg = get_adapter("heading", "std_msgs/msg/Float64").encode(0, (-math.pi / 2,), FACTORIES["rclpy"])
    assert msg.data == pytest.approx(270.0)


@pytest.mark.parametrize(
    ("options", "delta", "data"),
    [
        ({}, 0.1, 0.1),
        ({"units": "deg"}, 0.1, math.degrees(0.1)),
        ({"sign": -1}, 0.1, -0.1),  # the boat's positive means port
        ({"sign": -1, "units": "deg"}, -0.2, math.degrees(0.2)),
    ],
)
def test_rudder_units_and_sign(options: dict, delta: float, data: float) -> None:
    adapter = get_adapter("rudder_angle", "std_msgs/msg/Float64", **options)
    msg = adapter.encode(0, (delta,), FACTORIES["rclpy"])
    assert msg.data == pytest.approx(data)
    assert adapter.decode(msg)[1][0] == pytest.approx(delta)


def test_joint_state_rudder_sign_and_rpm_conversion() -> None:
    make = FACTORIES["rosbags"]
    joint_state = make("sensor_msgs/msg/JointState")
    header = make("std_msgs/msg/Header")(stamp=make("builtin_interfaces/msg/Time")(sec=3, nanosec=5), frame_id="")
    msg = joint_state(
        header=header, name=["propeller", "rudder"], position=np.array([7.0, 0.3]),
        velocity=np.array([2.0 * math.pi, 0.0]), effort=np.zeros(0),
    )  # fmt: skip
    assert get_adapter("rudder_angle", ros_type := "sensor_msgs/msg/JointState", joint="rudder", sign=-1).decode(
        msg
    ) == (3_000_000_005, pytest.approx((-0.3,)))
    assert get_adapter("engine_rpm", ros_type, joint="propeller").decode(msg)[1] == pytest.approx((60.0,))  # 1 rev/s


def test_joint_state_errors_name_the_joint_and_the_names_present() -> None:
    make = FACTORIES["rclpy"]
    msg = get_adapter("rudder_angle", "sensor_msgs/msg/JointState", joint="rudder").encode(0, (0.1,), make)
    adapter = get_adapter("rudder_angle", "sensor_msgs/msg/JointState", joint="steering")
    with pytest.raises(AdapterError, match=r"'steering'.*\['rudder'\]"):
        adapter.decode(msg)
    rpm = get_adapter("engine_rpm", "sensor_msgs/msg/JointState", joint="rudder")  # rudder has no velocity entry
    with pytest.raises(AdapterError, match="velocity has only 0 entries"):
        rpm.decode(msg)
    with pytest.raises(AdapterError, match=r"\['joint'\] required"):
        get_adapter("engine_rpm", "sensor_msgs/msg/JointState")


def test_rep145_no_orientation_decodes_nan_heading() -> None:
    from sensor_msgs.msg import Imu

    imu_adapter = get_adapter("imu", "sensor_msgs/msg/Imu")
    for factory in FACTORIES.values():
        msg = imu_adapter.encode(T_NS, (0.1, 0.0, 0.0, -9.81, math.nan), factory)
        assert msg.orientation_covariance[0] == -1.0
        stamp, values = imu_adapter.decode(msg)
        assert values[:4] == pytest.approx((0.1, 0.0, 0.0, -9.81))
        assert math.isnan(values[4])
    hand_made = Imu()
    hand_made.orientation_covariance[0] = -1.0
    assert math.isnan(get_adapter("heading", "sensor_msgs/msg/Imu").decode(hand_made)[1][0])


def test_navsatfix_without_fix_is_nan() -> None:
    make = FACTORIES["rosbags"]
    adapter = get_adapter("gnss", "sensor_msgs/msg/NavSatFix")
    msg = adapter.encode(T_NS, (math.nan, math.nan, math.nan), make)
    assert msg.status.status == -1
    fixed = adapter.encode(T_NS, (59.0, 10.0, 1.0), make)
    assert fixed.status.status == 0
    fixed.status.status = -1  # receiver says no fix although numbers are present
    assert all(math.isnan(x) for x in adapter.decode(fixed)[1])


def test_nan_passes_through_decode() -> None:
    adapter = get_adapter("velocity", "geometry_msgs/msg/TwistStamped")
    _, (u, v, r) = adapter.decode(adapter.encode(0, (math.nan, 1.0, 0.0), FACTORIES["rclpy"]))
    assert math.isnan(u)
    assert v == pytest.approx(1.0)


def test_wrong_message_type_names_type_and_field() -> None:
    float_msg = FACTORIES["rosbags"]("std_msgs/msg/Float64")(data=1.0)
    with pytest.raises(AdapterError, match=r"sensor_msgs/msg/Imu.*'angular_velocity\.z'"):
        get_adapter("imu", "sensor_msgs/msg/Imu").decode(float_msg)


def test_get_adapter_errors() -> None:
    with pytest.raises(AdapterError, match=r"role 'rudder_angle'.*'std_msgs/msg/Int32'.*std_msgs/msg/Float64"):
        get_adapter("rudder_angle", "std_msgs/msg/Int32")
    with pytest.raises(AdapterError, match=r"unknown role 'thrust'"):
        get_adapter("thrust", "std_msgs/msg/Float64")
    with pytest.raises(AdapterError, match=r"unknown option.*'unit'.*allowed options: \['convention', 'units'\]"):
        get_adapter("heading", "std_msgs/msg/Float64", unit="deg")
    with pytest.raises(AdapterError, match=r"units='grad'.*\['deg', 'rad'\]"):
        get_adapter("heading", "std_msgs/msg/Float64", units="grad")
    with pytest.raises(AdapterError, match=r"sign=2.*\[1, -1\]"):
        get_adapter("rudder_angle", "std_msgs/msg/Float64", sign=2)
    with pytest.raises(AdapterError, match="gyro_variance"):
        get_adapter("imu", "sensor_msgs/msg/Imu", gyro_variance=-1.0)


def test_encode_checks_value_count() -> None:
    with pytest.raises(AdapterError, match="expects 3 values, got 2"):
        get_adapter("velocity", "geometry_msgs/msg/TwistStamped").encode(0, (1.0, 2.0), FACTORIES["rclpy"])


def _random_rows(role: str, n: int, rng: np.random.Generator) -> np.ndarray:
    rows = np.asarray(SAMPLES[role]) + rng.normal(scale=0.3, size=(n, len(SAMPLES[role])))
    if role in ("imu", "gnss"):
        rows[1, -1] = np.nan  # one message without orientation / altitude (-> no fix)
    if role in COMMAND_ROLES:
        rows = np.clip(rows, -1.0, 1.0)  # commands beyond +-1.2 are refused (test_command_refusals)
    return rows


VECTORISABLE = [(role, t) for role, t in registered() if t != "sensor_msgs/msg/JointState"]


@pytest.mark.parametrize(("role", "ros_type"), VECTORISABLE)
def test_structure_of_arrays_decodes_like_one_by_one(role: str, ros_type: str) -> None:
    adapter = adapter_for(role, ros_type)
    rng = np.random.default_rng(7)
    rows = _random_rows(role, 5, rng)
    stamps = T_NS + np.arange(5) * 10_000_000
    make = FACTORIES["rosbags"]
    messages = [adapter.encode(int(t), list(row), make, "f") for t, row in zip(stamps, rows)]
    one_by_one = [adapter.decode(m) for m in messages]
    stamp, columns = adapter.decode(stack(messages))
    expected = np.array([values for _, values in one_by_one])  # (5, k)
    np.testing.assert_array_equal(np.column_stack(columns), expected)  # NaN == NaN here
    if one_by_one[0][0] is None:
        assert stamp is None
    else:
        assert stamp.dtype == np.int64
        np.testing.assert_array_equal(stamp, [s for s, _ in one_by_one])


@pytest.mark.parametrize(("role", "ros_type"), VECTORISABLE)
def test_columnar_encode_decode_round_trip(role: str, ros_type: str) -> None:
    adapter = adapter_for(role, ros_type)
    rows = _random_rows(role, 6, np.random.default_rng(3))
    if role == "gnss":
        rows[1] = np.nan  # encode marks the whole row as no fix
    stamps = T_NS + np.arange(6) * 10_000_000
    columns = adapter.encode(stamps, list(rows.T), columnar_factory(), "f")
    assert columns.__msgtype__ == ros_type
    stamp, values = adapter.decode(columns)
    expected = rows.copy()
    if role in ("heading", "odometry", "imu"):
        column = adapter.fields.index("psi" if role != "imu" else "heading")
        expected[:, column] = (expected[:, column] + math.pi) % (2 * math.pi) - math.pi
    np.testing.assert_allclose(np.column_stack(values), expected, atol=tolerance(ros_type))
    if stamp is not None:
        np.testing.assert_array_equal(stamp, stamps)


def test_joint_state_structure_of_arrays_is_not_vectorisable() -> None:
    adapter = get_adapter("rudder_angle", "sensor_msgs/msg/JointState", joint="rudder_joint")
    make = FACTORIES["rosbags"]
    messages = [adapter.encode(i, (0.1 * i,), make) for i in range(3)]
    soa = stack(messages)
    soa.name = [m.name for m in messages]
    with pytest.raises(AdapterError, match="not vectorisable"):
        adapter.decode(soa)


@pytest.mark.parametrize("factory", sorted(FACTORIES))
def test_output_messages_round_trip_and_conventions(factory: str) -> None:
    make = FACTORIES[factory]
    stamp = T_NS
    t_ns = stamp + np.array([100_000_000, 1_600_000_000, 3_000_000_000])
    eta = np.array([[1.0, 2.0, math.pi / 2], [3.0, 4.0, 0.5], [5.0, -6.0, -2.0]])
    nu = np.array([[2.0, 1.0, 0.1], [2.1, 0.5, -0.2], [1.9, 0.0, 0.0]])
    path = encode_path(stamp, t_ns, eta, "odom", make)
    first = path.poses[0].pose
    assert (first.position.x, first.position.y) == pytest.approx((2.0, 1.0))  # ENU = (east, north)
    assert (first.orientation.z, first.orientation.w) == pytest.approx((0.0, 1.0))  # heading east = yaw 0
    assert path.header.frame_id == "odom"
    assert path.poses[2].header.frame_id == "odom"
    decoded_t, decoded_eta = decode_path(path)
    np.testing.assert_array_equal(decoded_t, t_ns)
    np.testing.assert_allclose(decoded_eta, eta, atol=1e-12)

    trajectory = encode_predicted_velocities(stamp, t_ns, eta, nu, "odom", "base_link", make)
    assert list(trajectory.joint_names) == ["base_link"]
    point = trajectory.points[1]
    assert (point.time_from_start.sec, point.time_from_start.nanosec) == (1, 600_000_000)
    assert (point.velocities[0].linear.y, point.velocities[0].angular.z) == pytest.approx((-0.5, 0.2))
    assert point.transforms[0].translation.x == pytest.approx(4.0)
    decoded_t, decoded_nu = decode_predicted_velocities(trajectory)
    np.testing.assert_array_equal(decoded_t, t_ns)
    np.testing.assert_allclose(decoded_nu, nu, atol=1e-12)
    if factory == "rosbags":
        assert len(TYPESTORE.serialize_cdr(trajectory, "trajectory_msgs/msg/MultiDOFJointTrajectory")) > 0


def test_output_shape_mismatch_is_reported() -> None:
    with pytest.raises(AdapterError, match=r"eta must have shape \(2, 3\)"):
        encode_path(0, np.array([1, 2]), np.zeros((3, 3)), "odom", FACTORIES["rclpy"])


def test_importing_msg_adapters_does_not_import_rclpy() -> None:
    code = (
        "import sys, msg_adapters, msg_adapters.outputs\n"
        "make = msg_adapters.rclpy_factory()\n"
        "make('sensor_msgs/msg/Imu')\n"
        "assert 'rclpy' not in sys.modules, sorted(m for m in sys.modules if m.startswith('rclpy'))\n"
        "print('ok')\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "ok"


def test_factories_report_unknown_types() -> None:
    with pytest.raises(AdapterError, match="not in the rosbags typestore"):
        FACTORIES["rosbags"]("usv_msgs/msg/Nothing")
    with pytest.raises(AdapterError, match="cannot import usv_msgs.msg.Nothing"):
        FACTORIES["rclpy"]("usv_msgs/msg/Nothing")
    with pytest.raises(AdapterError, match="package/msg/Name"):
        FACTORIES["rclpy"]("Imu")


def test_registry_covers_every_role() -> None:
    assert {role for role, _ in registered()} == set(ROLE_FIELDS)
    assert msg_adapters.registered() == registered()


# ---------------------------------------------------------------- commands: units, options, sharing, refusals


@pytest.mark.parametrize(
    ("options", "raw", "command"),
    [
        ({}, 0.4, 0.4),  # normalised: as it is
        ({"sign": -1}, 0.4, -0.4),  # the driver's positive is astern
        ({"units": "pwm"}, 1750.0, 0.5),  # 1500 us neutral, 500 us full scale
        ({"units": "pwm"}, 1000.0, -1.0),
        ({"units": "pwm", "neutral": 1520.0, "full_scale": 380.0, "reverse_full_scale": 420.0}, 1100.0, -1.0),
        ({"units": "pwm", "sign": -1}, 1250.0, 0.5),  # reversed servo
        ({"units": "percent"}, -25.0, -0.25),
        ({"units": "rpm", "full_scale": 1800.0, "reverse_full_scale": 1200.0}, -600.0, -0.5),
        ({"units": "rad_per_s", "full_scale": 100.0}, 50.0, 0.5),
        ({"units": "newton", "full_scale": 250.0, "reverse_full_scale": 100.0}, -100.0, -1.0),  # VRX clamps
        ({"units": "newton", "full_scale": 119.682, "exponent": 2.0}, 119.682 / 4.0, 0.5),  # Otter: T ~ c|c|
        ({"units": "newton", "full_scale": 119.682, "reverse_full_scale": 66.708, "exponent": 2.0}, -66.708 / 4.0,
         -0.5),
    ],
)
def test_command_units_by_hand(options: dict, raw: float, command: float) -> None:
    adapter = get_adapter("thruster_port", "std_msgs/msg/Float64", **options)
    make = FACTORIES["rclpy"]
    assert adapter.decode(make("std_msgs/msg/Float64")(data=raw)) == (None, (pytest.approx(command, abs=1e-12),))
    assert adapter.encode(0, (command,), make).data == pytest.approx(raw, abs=1e-9)  # encode inverts decode


def test_command_defaults_keep_the_value_bit_exact() -> None:
    adapter = get_adapter("throttle", "std_msgs/msg/Float64")
    values = np.random.default_rng(4).uniform(-1.0, 1.0, 50)
    _, (decoded,) = adapter.decode(SimpleNamespace(data=values))
    np.testing.assert_array_equal(decoded, values)


@pytest.mark.parametrize(
    ("role", "ros_type", "options", "raw", "message"),
    [
        ("thruster_port", "std_msgs/msg/Float64", {"units": "newton", "full_scale": 120.0}, 1500.0,
         r"thruster_port = 1500 \(data\) with units newton neutral 0 full_scale 120 is 12\.5 x full scale.*"
         r"a PWM in microseconds configured as a thrust in N\?"),
        ("thruster_starboard", "std_msgs/msg/Float32", {}, 1500.0, r"PWM in microseconds configured as a normalised"),
        ("throttle", "std_msgs/msg/Float64", {}, 60.0, r"throttle = 60 .* a percent configured as normalised\?"),
        ("throttle", "std_msgs/msg/Float64", {"units": "pwm"}, 0.8, r"normalised or percent command configured as pwm"),
        ("thruster_port", "std_msgs/msg/Float64", {"units": "rpm", "full_scale": 100.0}, 500.0,
         r"is full_scale really a shaft speed in rpm at full ahead\?"),
    ],
)
def test_command_refusals_name_the_likely_mistake(role: str, ros_type: str, options: dict, raw: float,
                                                  message: str) -> None:
    adapter = get_adapter(role, ros_type, **options)
    with pytest.raises(AdapterError, match=message):
        adapter.decode(FACTORIES["rosbags"](ros_type)(data=raw))


def test_command_refusal_counts_samples_and_nan_passes() -> None:
    adapter = get_adapter("thruster_port", "std_msgs/msg/Float64", units="pwm")
    _, (c,) = adapter.decode(SimpleNamespace(data=np.array([1500.0, np.nan, 2000.0])))
    assert c[0] == 0.0
    assert math.isnan(c[1])
    assert c[2] == 1.0
    assert adapter.decode(SimpleNamespace(data=2100.0))[1] == (pytest.approx(1.2),)  # at the limit: accepted
    with pytest.raises(AdapterError, match=r"= 2200 .*\(2 of 4 samples\)"):
        adapter.decode(SimpleNamespace(data=np.array([1500.0, 2200.0, 800.0, 1600.0])))


def test_command_option_errors() -> None:
    with pytest.raises(AdapterError,
                       match=r"units rpm need the option full_scale \(a shaft speed in rpm at full ahead\)"):
        get_adapter("throttle", "std_msgs/msg/Float64", units="rpm")
    with pytest.raises(AdapterError, match=r"units='us'.*'pwm'"):
        get_adapter("throttle", "std_msgs/msg/Float64", units="us")
    with pytest.raises(AdapterError, match=r"full_scale=0.*> 0"):
        get_adapter("throttle", "std_msgs/msg/Float64", units="pwm", full_scale=0)
    with pytest.raises(AdapterError, match=r"exponent=5.*\(0, 4\]"):
        get_adapter("throttle", "std_msgs/msg/Float64", exponent=5)
    with pytest.raises(AdapterError, match=r"\['index'\] required"):
        get_adapter("thruster_port", "std_msgs/msg/Float64MultiArray")
    with pytest.raises(AdapterError, match=r"index=-1.*integer >= 0"):
        get_adapter("thruster_port", "std_msgs/msg/Float64MultiArray", index=-1)
    with pytest.raises(AdapterError, match=r"field='torque'.*'position', 'velocity', 'effort'"):
        get_adapter("thruster_port", "sensor_msgs/msg/JointState", joint="left", field="torque")
    with pytest.raises(AdapterError, match=r"unknown option.*'units'"):
        get_adapter("thruster_port", "geometry_msgs/msg/Wrench", units="pwm")
    with pytest.raises(AdapterError, match=r"saturate=1.*true or false"):
        get_adapter("thruster_port", "geometry_msgs/msg/Wrench", saturate=1)


def _pair(ros_type: str, port: dict, starboard: dict) -> list:
    return [get_adapter("thruster_port", ros_type, **port), get_adapter("thruster_starboard", ros_type, **starboard)]


@pytest.mark.parametrize("factory", sorted(FACTORIES))
def test_multiarray_left_right_pwm_in_one_message(factory: str) -> None:
    make = FACTORIES[factory]
    pair = _pair("std_msgs/msg/Float64MultiArray", {"index": 0, "units": "pwm"}, {"index": 1, "units": "pwm"})
    msg = msg_adapters.encode_shared(pair, T_NS, [(0.5,), (-0.2,)], make)
    assert list(msg.data) == pytest.approx([1750.0, 1400.0])
    assert [a.decode(msg) for a in pair] == [(None, (pytest.approx(0.5),)), (None, (pytest.approx(-0.2),))]
    # data_offset is honoured: index counts after it
    hand = make("std_msgs/msg/Float64MultiArray")(
        layout=make("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=1), data=np.array([7.0, 1600.0, 1300.0]))
    assert [a.decode(hand)[1][0] for a in pair] == pytest.approx([0.2, -0.4])
    with pytest.raises(AdapterError, match=r"data has 1 entries, expected entry 1.*`index`"):
        pair[1].decode(make("std_msgs/msg/Float64MultiArray")(
            layout=make("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0), data=np.array([1500.0])))


@pytest.mark.parametrize("factory", sorted(FACTORIES))
def test_joint_state_thrusters_fields_and_units(factory: str) -> None:
    make = FACTORIES[factory]
    ros_type = "sensor_msgs/msg/JointState"
    pair = _pair(ros_type, {"joint": "left_prop", "units": "rad_per_s", "full_scale": 150.0},
                 {"joint": "right_prop", "units": "rad_per_s", "full_scale": 150.0, "reverse_full_scale": 100.0})
    msg = msg_adapters.encode_shared(pair, T_NS, [(0.4,), (-0.5,)], make, "base_link")
    assert list(msg.name) == ["left_prop", "right_prop"]
    assert list(msg.velocity) == pytest.approx([60.0, -50.0])
    assert len(msg.position) == 0
    assert len(msg.effort) == 0
    assert [a.decode(msg) for a in pair] == [(T_NS, (pytest.approx(0.4),)), (T_NS, (pytest.approx(-0.5),))]
    effort = get_adapter("throttle", ros_type, joint="engine", field="effort", units="percent")
    header = make("std_msgs/msg/Header")(stamp=make("builtin_interfaces/msg/Time")(sec=1, nanosec=0), frame_id="")
    hand = make(ros_type)(header=header, name=["rudder", "engine"], position=np.zeros(2),
                          velocity=np.zeros(0), effort=np.array([3.0, 80.0]))
    assert effort.decode(hand)[1] == (pytest.approx(0.8),)


@pytest.mark.parametrize("ros_type", ["geometry_msgs/msg/Wrench", "geometry_msgs/msg/WrenchStamped"])
def test_wrench_mixing_by_hand(ros_type: str) -> None:
    make = FACTORIES["rosbags"]
    wrench = make("geometry_msgs/msg/Wrench")(force=make("geometry_msgs/msg/Vector3")(x=0.5, y=0.0, z=0.0),
                                              torque=make("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=-0.2))
    msg = wrench if ros_type.endswith("Wrench") else make(ros_type)(
        header=make("std_msgs/msg/Header")(stamp=make("builtin_interfaces/msg/Time")(sec=2, nanosec=0), frame_id=""),
        wrench=wrench)
    # torque.z -0.2 (FLU: clockwise from above) asks to turn to starboard: yaw y = +0.2, port = s + y
    port, starboard = _pair(ros_type, {}, {})
    assert port.decode(msg)[1] == (pytest.approx(0.7),)
    assert starboard.decode(msg)[1] == (pytest.approx(0.3),)
    flipped = _pair(ros_type, {"sign": -1}, {"sign": -1})  # a driver whose torque.z + turns to starboard
    assert [a.decode(msg)[1][0] for a in flipped] == pytest.approx([0.3, 0.7])
    scaled = _pair(ros_type, {"surge_full_scale": 200.0, "yaw_full_scale": 50.0},
                   {"surge_full_scale": 200.0, "yaw_full_scale": 50.0})
    back = msg_adapters.encode_shared(scaled, T_NS, [(0.9,), (-0.3,)], make)
    force = (back if ros_type.endswith("Wrench") else back.wrench).force.x
    assert force == pytest.approx(0.3 * 200.0)  # surge (0.9 - 0.3) / 2 of full scale
    assert [a.decode(back)[1][0] for a in scaled] == pytest.approx([0.9, -0.3], abs=1e-12)


def test_wrench_beyond_full_is_refused_or_saturated() -> None:
    make = FACTORIES["rclpy"]
    msg = make("geometry_msgs/msg/Wrench")()
    msg.force.x, msg.torque.z = 1.0, -0.5  # full ahead and half a turn to starboard: port 1.5
    with pytest.raises(AdapterError, match=r"thruster_port = 1\.5 \(force\.x and torque\.z mixed\).*saturate: true"):
        get_adapter("thruster_port", "geometry_msgs/msg/Wrench").decode(msg)
    assert get_adapter("thruster_port", "geometry_msgs/msg/Wrench", saturate=True).decode(msg)[1] == (1.0,)
    assert get_adapter("thruster_starboard", "geometry_msgs/msg/Wrench", saturate=True).decode(msg)[1] == (
        pytest.approx(0.5),)
    msg.force.x = 120.0  # a wrench in N read with the normalised default scale
    with pytest.raises(AdapterError, match=r"= 120 \(force\.x, the surge\).*120 x full scale"):
        get_adapter("thruster_port", "geometry_msgs/msg/Wrench", saturate=True).decode(msg)


def test_check_shared_refuses_roles_that_cannot_share_a_topic() -> None:
    with pytest.raises(AdapterError, match=r"topic 'thrusters': roles \['thruster_port', 'thruster_starboard'\] "
                                           r"cannot share a std_msgs/msg/Float64 topic"):
        msg_adapters.check_shared("thrusters", _pair("std_msgs/msg/Float64", {}, {}))
    with pytest.raises(AdapterError, match=r"read the same part of the message \(0\)"):
        msg_adapters.check_shared("thrusters", _pair("std_msgs/msg/Float64MultiArray", {"index": 0}, {"index": 0}))
    with pytest.raises(AdapterError, match=r"different types"):
        msg_adapters.check_shared("thrusters", [get_adapter("thruster_port", "std_msgs/msg/Float64MultiArray", index=0),
                                                get_adapter("thruster_starboard", "sensor_msgs/msg/JointState",
                                                            joint="r")])
    with pytest.raises(AdapterError, match=r"same message options.*surge_full_scale"):
        msg_adapters.check_shared("cmd", _pair("geometry_msgs/msg/Wrench", {}, {"yaw_full_scale": 2.0}))
    msg_adapters.check_shared("cmd", _pair("geometry_msgs/msg/Wrench", {}, {}))  # these can
    msg_adapters.check_shared("joints", _pair("sensor_msgs/msg/JointState", {"joint": "a"}, {"joint": "b"}))


def test_shared_encoding_through_cdr_and_the_bulk_decoder() -> None:
    """Raw CDR: what encode_shared builds serialises with rosbags and decodes through cdr_fast (the bag path)."""
    from usv_predictor.replay.cdr_fast import decode_many, has_fast_layout

    ros_type = "geometry_msgs/msg/WrenchStamped"
    pair = _pair(ros_type, {"yaw_full_scale": 40.0}, {"yaw_full_scale": 40.0})
    rows = np.random.default_rng(9).uniform(-1.0, 1.0, size=(7, 2))
    raws = [bytes(TYPESTORE.serialize_cdr(msg_adapters.encode_shared(pair, T_NS + k, [(p,), (s,)],
                                                                     FACTORIES["rosbags"]), ros_type))
            for k, (p, s) in enumerate(rows)]
    assert has_fast_layout(ros_type, TYPESTORE)
    columns = decode_many(ros_type, raws, TYPESTORE)
    for k, adapter in enumerate(pair):
        stamp, (c,) = adapter.decode(columns)
        np.testing.assert_allclose(c, rows[:, k], atol=1e-12)
        np.testing.assert_array_equal(stamp, T_NS + np.arange(7))

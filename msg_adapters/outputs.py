"""The predictor's output messages: predicted path, predicted velocities, covariance, candidates, diagnostics.

Inputs are marine (eta (H, 3) = [x_n, y_e, psi] NED, nu (H, 3) = [u, v, r] FRD, times in int ns);
messages are REP-103/105:
  nav_msgs/Path: header (stamp = prediction time, frame_id e.g. "odom"); poses[i] stamped with
    the future time t_ns[i], position ENU (x = y_e, y = x_n, z = 0), level orientation from psi.
  trajectory_msgs/MultiDOFJointTrajectory: joint_names = [child_frame_id] (the body frame);
    points[i].transforms[0] the same ENU pose, velocities[0] the body twist FLU (linear.x = u,
    linear.y = -v, angular.z = -r), accelerations empty, time_from_start = t_ns[i] - stamp.
  candidate predictions (the batch form, one message for N plans): a MultiDOFJointTrajectory whose
    joint_names are the N candidate names; points[k].transforms[i] / velocities[i] are candidate i's
    pose and twist at t_ns[k] as above; header.stamp = the candidates' stamp.
  std_msgs/Float64MultiArray covariance: dim [("step", H), ("cov_x_y_yaw_enu", 9)], data H row-major 3 x 3.
  geometry_msgs/TwistWithCovarianceStamped, the estimated current (fitting/online.py): header frame_id e.g.
    "odom" (ENU), twist.linear = (c_e, c_n, 0) m/s (x east, y north), angular = 0; covariance 6 x 6 row-major
    over (x, y, z, rot x, rot y, rot z): the 2 x 2 block of the current converted NED -> ENU, the four components
    the estimator does not estimate marked unknown by UNKNOWN_VARIANCE on their diagonal (zero correlations).
  diagnostic_msgs/DiagnosticArray from plain `Status` records.

Two builders per message: `encode_*` makes message objects with make(type_name) (rclpy, rosbags,
columnar), `*_cdr` writes the serialized CDR bytes directly with numpy (fixed layouts, msg_adapters.cdr),
what the node publishes. Both take their numbers from the same vectorised conversions (`enu_poses`,
`flu_twists`), and test_output_cdr.py proves the bytes equal rclpy's serialisation of the objects.
"""
from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from msg_adapters import _codec as c
from msg_adapters.cdr_writer import CdrLayout, CdrWriter, time_parts
from usv_predictor.errors import AdapterError
from usv_predictor.frames import enu_yaw_to_heading, heading_to_enu_yaw, quaternion_to_yaw, yaw_to_quaternion

PATH_TYPE = "nav_msgs/msg/Path"
TRAJECTORY_TYPE = "trajectory_msgs/msg/MultiDOFJointTrajectory"
COVARIANCE_TYPE = "std_msgs/msg/Float64MultiArray"
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
CURRENT_TYPE = "geometry_msgs/msg/TwistWithCovarianceStamped"
# Variance of a twist component that is not estimated ((m/s)^2 or (rad/s)^2): "unknown" in the convention of
# robot_localization and REP-145's spirit (a huge variance: a consumer that fuses the message gives it no weight).
# Not -1: a negative variance makes the matrix invalid for a consumer that inverts it (only sensor_msgs/Imu
# documents -1, and only in its first element).
UNKNOWN_VARIANCE = 1e6
COVARIANCE_LABELS = ("step", "cov_x_y_yaw_enu")


def _check_shapes(t_ns: np.ndarray, **arrays: np.ndarray) -> None:
    for name, array in arrays.items():
        if array.ndim != 2 or array.shape != (len(t_ns), 3):
            raise AdapterError(f"{name} must have shape ({len(t_ns)}, 3) to match t_ns, got {array.shape}")


def enu_poses(eta: np.ndarray) -> np.ndarray:
    """(..., 3) [x_n, y_e, psi] NED -> (..., 7) geometry_msgs Pose [x east, y north, z 0, qx, qy, qz, qw] ENU."""
    eta = np.asarray(eta, dtype=np.float64)
    qx, qy, qz, qw = yaw_to_quaternion(heading_to_enu_yaw(eta[..., 2]))
    return np.stack([eta[..., 1], eta[..., 0], np.zeros_like(qz), qx, qy, qz, qw], axis=-1)


def flu_twists(nu: np.ndarray) -> np.ndarray:
    """(..., 3) [u, v, r] FRD -> (..., 6) geometry_msgs Twist [linear x y z, angular x y z] FLU."""
    nu = np.asarray(nu, dtype=np.float64)
    zero = np.zeros_like(nu[..., 0])
    return np.stack([nu[..., 0], -nu[..., 1], zero, zero, zero, -nu[..., 2]], axis=-1)


def _pose(make: c.MakeFn, row: np.ndarray) -> Any:
    return make("geometry_msgs/msg/Pose")(position=c.vector3(make, *row[:3], "geometry_msgs/msg/Point"),
                                          orientation=c.quaternion(make, *row[3:]))


def encode_path(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, frame_id: str, make: c.MakeFn) -> Any:
    """nav_msgs/Path of the predicted poses eta (H, 3) NED at times t_ns (H,)."""
    t_ns, eta = np.asarray(t_ns, dtype=np.int64), np.asarray(eta, dtype=np.float64)
    _check_shapes(t_ns, eta=eta)
    poses = [make("geometry_msgs/msg/PoseStamped")(header=c.header(make, int(t_i), frame_id), pose=_pose(make, row))
             for t_i, row in zip(t_ns, enu_poses(eta))]
    return make(PATH_TYPE)(header=c.header(make, int(stamp_ns), frame_id), poses=poses)


def decode_path(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """nav_msgs/Path -> (t_ns (H,) int64 from each pose's stamp, eta (H, 3) NED)."""
    poses = c.field(msg, "poses", PATH_TYPE)
    t_ns = np.array([c.stamp_ns(p, PATH_TYPE) for p in poses], dtype=np.int64)
    eta = np.empty((len(poses), 3))
    for i, pose_stamped in enumerate(poses):
        pose = c.field(pose_stamped, "pose", PATH_TYPE)
        eta[i, 0] = c.field(pose, "position.y", PATH_TYPE)
        eta[i, 1] = c.field(pose, "position.x", PATH_TYPE)
        quat = c.field(pose, "orientation", PATH_TYPE)
        eta[i, 2] = enu_yaw_to_heading(quaternion_to_yaw(*(c.field(quat, a, PATH_TYPE) for a in "xyzw")))
    return t_ns, eta


def encode_predicted_velocities(
    stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, nu: np.ndarray, frame_id: str, child_frame_id: str, make: c.MakeFn
) -> Any:
    """trajectory_msgs/MultiDOFJointTrajectory carrying pose (ENU) and body twist (FLU) per future time."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    eta, nu = np.asarray(eta, dtype=np.float64), np.asarray(nu, dtype=np.float64)
    _check_shapes(t_ns, eta=eta, nu=nu)
    return encode_candidate_predictions(stamp_ns, t_ns, eta[None], nu[None], frame_id, [child_frame_id], make)


def encode_candidate_predictions(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, nu: np.ndarray, frame_id: str,
                                 names: Sequence[str], make: c.MakeFn) -> Any:
    """MultiDOFJointTrajectory of N bodies: eta, nu (N, H, 3) -> joint i = names[i], point k at t_ns[k]."""
    poses, twists = _check_batch(t_ns, eta, nu, names)
    points = []
    for k, t_k in enumerate(np.asarray(t_ns, dtype=np.int64)):
        transforms = [make("geometry_msgs/msg/Transform")(translation=c.vector3(make, *row[:3]),
                                                          rotation=c.quaternion(make, *row[3:])) for row in poses[:, k]]
        velocities = [make("geometry_msgs/msg/Twist")(linear=c.vector3(make, *row[:3]),
                                                      angular=c.vector3(make, *row[3:]))
                      for row in twists[:, k]]
        points.append(make("trajectory_msgs/msg/MultiDOFJointTrajectoryPoint")(
            transforms=transforms, velocities=velocities, accelerations=[],
            time_from_start=c.time_msg(make, int(t_k) - int(stamp_ns), "builtin_interfaces/msg/Duration")))
    return make(TRAJECTORY_TYPE)(header=c.header(make, int(stamp_ns), frame_id), joint_names=list(names), points=points)


def _check_batch(t_ns: np.ndarray, eta: np.ndarray, nu: np.ndarray,
                 names: Sequence[str]) -> tuple[np.ndarray, np.ndarray]:
    """(N, H, 7) poses and (N, H, 6) twists, or AdapterError naming the mismatched shape."""
    eta, nu = np.asarray(eta, dtype=np.float64), np.asarray(nu, dtype=np.float64)
    expected = (len(names), len(t_ns), 3)
    for name, array in (("eta", eta), ("nu", nu)):
        if array.shape != expected:
            raise AdapterError(f"{name} must have shape {expected} (names, times, 3), got {array.shape}")
    return enu_poses(eta), flu_twists(nu)


def decode_predicted_velocities(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """MultiDOFJointTrajectory -> (t_ns (H,) = stamp + time_from_start, nu (H, 3) FRD)."""
    stamp = c.stamp_ns(msg, TRAJECTORY_TYPE)
    points = c.field(msg, "points", TRAJECTORY_TYPE)
    t_ns = np.array(
        [stamp + c.stamp_ns(p, TRAJECTORY_TYPE, "time_from_start") for p in points], dtype=np.int64
    )
    nu = np.empty((len(points), 3))
    for i, point in enumerate(points):
        velocities = c.field(point, "velocities", TRAJECTORY_TYPE)
        if len(velocities) < 1:
            raise AdapterError(f"{TRAJECTORY_TYPE}: point {i} has no velocities[0] (body twist)")
        twist = velocities[0]
        nu[i] = (
            c.field(twist, "linear.x", TRAJECTORY_TYPE),
            -c.field(twist, "linear.y", TRAJECTORY_TYPE),
            -c.field(twist, "angular.z", TRAJECTORY_TYPE),
        )
    return t_ns, nu


# ---------------------------------------------------------------- serialized CDR (what the node publishes)


@functools.lru_cache(maxsize=16)
def _path_layout(steps: int, frame_id: str) -> CdrLayout:
    w = CdrWriter()
    w.slot("stamp", "<i4", 2)  # builtin_interfaces/Time: sec int32, nanosec uint32 (< 1e9: same bytes as int32)
    w.string(frame_id)
    w.uint32(steps)
    for _ in range(steps):  # geometry_msgs/PoseStamped
        w.slot("pose_stamp", "<i4", 2)
        w.string(frame_id)
        w.slot("pose", "<f8", 7)
    return w.layout()


def path_cdr(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, frame_id: str) -> bytes:
    """Serialized nav_msgs/Path, byte-equal to rclpy's serialisation of encode_path(...)."""
    t_ns, eta = np.asarray(t_ns, dtype=np.int64), np.asarray(eta, dtype=np.float64)
    _check_shapes(t_ns, eta=eta)
    return _path_layout(len(t_ns), frame_id).fill(stamp=time_parts(stamp_ns), pose_stamp=time_parts(t_ns),
                                                  pose=enu_poses(eta))


@functools.lru_cache(maxsize=16)
def _trajectory_layout(steps: int, frame_id: str, names: tuple[str, ...]) -> CdrLayout:
    bodies = len(names)
    w = CdrWriter()
    w.slot("stamp", "<i4", 2)
    w.string(frame_id)
    w.strings(names)
    w.uint32(steps)
    for _ in range(steps):  # trajectory_msgs/MultiDOFJointTrajectoryPoint
        w.uint32(bodies)
        if bodies:
            w.slot("transforms", "<f8", 7 * bodies)  # Transform = 7 float64, no padding between them
        w.uint32(bodies)
        if bodies:
            w.slot("twists", "<f8", 6 * bodies)  # Twist = 6 float64
        w.uint32(0)  # accelerations: none
        w.slot("time_from_start", "<i4", 2)
    return w.layout()


def candidate_predictions_cdr(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, nu: np.ndarray, frame_id: str,
                              names: Sequence[str]) -> bytes:
    """Serialized MultiDOFJointTrajectory of N bodies (eta, nu (N, H, 3)), as encode_candidate_predictions."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    poses, twists = _check_batch(t_ns, eta, nu, names)
    layout = _trajectory_layout(len(t_ns), frame_id, tuple(names))
    steps, bodies = len(t_ns), len(names)
    return layout.fill(stamp=time_parts(stamp_ns), time_from_start=time_parts(t_ns - int(stamp_ns)),
                       transforms=poses.transpose(1, 0, 2).reshape(steps, 7 * bodies),  # (H, N x 7)
                       twists=twists.transpose(1, 0, 2).reshape(steps, 6 * bodies))  # (H, N x 6)


def predicted_velocities_cdr(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, nu: np.ndarray, frame_id: str,
                             child_frame_id: str) -> bytes:
    """Serialized MultiDOFJointTrajectory of the prediction, byte-equal to rclpy's of encode_predicted_velocities."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    eta, nu = np.asarray(eta, dtype=np.float64), np.asarray(nu, dtype=np.float64)
    _check_shapes(t_ns, eta=eta, nu=nu)
    return candidate_predictions_cdr(stamp_ns, t_ns, eta[None], nu[None], frame_id, [child_frame_id])


def encode_covariance(covariance: np.ndarray, make: c.MakeFn) -> Any:
    """(H, 3, 3) covariances of [x east, y north, yaw] -> std_msgs/Float64MultiArray (steps x 9, row-major)."""
    covariance = _check_covariance(covariance)
    steps = covariance.shape[0]
    dimension = make("std_msgs/msg/MultiArrayDimension")
    layout = make("std_msgs/msg/MultiArrayLayout")(
        dim=[dimension(label=COVARIANCE_LABELS[0], size=steps, stride=steps * 9),
             dimension(label=COVARIANCE_LABELS[1], size=9, stride=9)], data_offset=0)
    return make(COVARIANCE_TYPE)(layout=layout, data=covariance.reshape(-1).tolist())


def _check_covariance(covariance: np.ndarray) -> np.ndarray:
    covariance = np.asarray(covariance, dtype=np.float64)
    if covariance.ndim != 3 or covariance.shape[1:] != (3, 3):
        raise AdapterError(f"covariance must have shape (H, 3, 3), got {covariance.shape}")
    return covariance


@functools.lru_cache(maxsize=16)
def _covariance_layout(steps: int) -> CdrLayout:
    w = CdrWriter()
    w.uint32(2)  # layout.dim
    for label, size, stride in ((COVARIANCE_LABELS[0], steps, steps * 9), (COVARIANCE_LABELS[1], 9, 9)):
        w.string(label)
        w.uint32(size)
        w.uint32(stride)
    w.uint32(0)  # layout.data_offset
    w.sequence("data", "<f8", steps * 9)
    return w.layout()


def covariance_cdr(covariance: np.ndarray) -> bytes:
    """Serialized Float64MultiArray of (H, 3, 3) covariances, byte-equal to rclpy's of encode_covariance."""
    covariance = _check_covariance(covariance)
    return _covariance_layout(covariance.shape[0]).fill(data=covariance.reshape(1, -1))


def current_twist(current_ne: Sequence[float], current_cov: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """(6,) Twist [linear x y z, angular x y z] ENU and (36,) row-major covariance of a current estimate.

    current_ne (2,) toward north / east (m/s); current_cov (3,) P_nn, P_ne, P_ee ((m/s)^2) of the same, NED.
    ENU x = east, y = north: var x = P_ee, var y = P_nn, cov xy = P_ne; z and the angular rates UNKNOWN_VARIANCE.
    """
    c_n, c_e = (float(v) for v in current_ne)
    p_nn, p_ne, p_ee = (float(v) for v in current_cov)
    twist = np.array([c_e, c_n, 0.0, 0.0, 0.0, 0.0])
    covariance = np.diag([0.0, 0.0] + [UNKNOWN_VARIANCE] * 4)  # (6, 6)
    covariance[:2, :2] = [[p_ee, p_ne], [p_ne, p_nn]]
    return twist, covariance.reshape(36)


def encode_current(stamp_ns: int, current_ne: Sequence[float], current_cov: Sequence[float], frame_id: str,
                   make: c.MakeFn) -> Any:
    """geometry_msgs/TwistWithCovarianceStamped of a current estimate (current_twist) in frame_id (ENU)."""
    twist, covariance = current_twist(current_ne, current_cov)
    body = make("geometry_msgs/msg/Twist")(linear=c.vector3(make, *twist[:3]), angular=c.vector3(make, *twist[3:]))
    return make(CURRENT_TYPE)(header=c.header(make, int(stamp_ns), frame_id),
                              twist=make("geometry_msgs/msg/TwistWithCovariance")(twist=body, covariance=covariance))


def decode_current(msg: Any) -> tuple[int, np.ndarray, np.ndarray]:
    """TwistWithCovarianceStamped -> (stamp_ns, current_ne (2,) m/s, its (2, 2) NED covariance)."""
    linear = c.field(msg, "twist.twist.linear", CURRENT_TYPE)
    covariance = np.asarray(c.field(msg, "twist.covariance", CURRENT_TYPE), dtype=np.float64).reshape(6, 6)
    current_ne = np.array([c.field(linear, "y", CURRENT_TYPE), c.field(linear, "x", CURRENT_TYPE)])
    return c.stamp_ns(msg, CURRENT_TYPE), current_ne, covariance[np.ix_([1, 0], [1, 0])]


@functools.lru_cache(maxsize=16)
def _current_layout(frame_id: str) -> CdrLayout:
    w = CdrWriter()
    w.slot("stamp", "<i4", 2)
    w.string(frame_id)
    w.slot("twist", "<f8", 6)  # geometry_msgs/Twist: two Vector3
    w.slot("covariance", "<f8", 36)  # float64[36]: a fixed array, no length
    return w.layout()


def current_cdr(stamp_ns: int, current_ne: Sequence[float], current_cov: Sequence[float], frame_id: str) -> bytes:
    """Serialized TwistWithCovarianceStamped, byte-equal to rclpy's serialisation of encode_current(...)."""
    twist, covariance = current_twist(current_ne, current_cov)
    return _current_layout(frame_id).fill(stamp=time_parts(stamp_ns), twist=twist, covariance=covariance)


class Status(NamedTuple):
    """One diagnostic_msgs/DiagnosticStatus as plain values."""

    level: int  # DiagnosticStatus.OK 0, WARN 1, ERROR 2, STALE 3
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]  # (key, value) pairs


def encode_diagnostics(stamp_ns: int, statuses: Sequence[Status], make: c.MakeFn) -> Any:
    """diagnostic_msgs/DiagnosticArray (header frame_id empty) of `statuses`."""
    status_type, key_value = make("diagnostic_msgs/msg/DiagnosticStatus"), make("diagnostic_msgs/msg/KeyValue")
    return make(DIAGNOSTICS_TYPE)(header=c.header(make, int(stamp_ns), ""), status=[
        status_type(level=bytes([s.level]), name=s.name, message=s.message, hardware_id=s.hardware_id,
                    values=[key_value(key=k, value=v) for k, v in s.values]) for s in statuses])


def diagnostics_cdr(stamp_ns: int, statuses: Sequence[Status]) -> bytes:
    """Serialized DiagnosticArray, byte-equal to rclpy's serialisation of encode_diagnostics (rclpy make)."""
    w = CdrWriter()
    w.slot("stamp", "<i4", 2)
    w.string("")
    w.uint32(len(statuses))
    for status in statuses:
        w.primitive("u1", status.level)  # `byte`
        w.string(status.name)
        w.string(status.message)
        w.string(status.hardware_id)
        w.uint32(len(status.values))
        for key, value in status.values:
            w.string(key)
            w.string(value)
    return w.layout().fill(stamp=time_parts(stamp_ns))

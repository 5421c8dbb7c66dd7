"""The predictor's output messages: predicted path and predicted velocities.

Inputs are marine (eta (H, 3) = [x_n, y_e, psi] NED, nu (H, 3) = [u, v, r] FRD, times in int ns);
messages are REP-103/105:
  nav_msgs/Path: header (stamp = prediction time, frame_id e.g. "odom"); poses[i] stamped with
    the future time t_ns[i], position ENU (x = y_e, y = x_n, z = 0), level orientation from psi.
  trajectory_msgs/MultiDOFJointTrajectory: joint_names = [child_frame_id] (the body frame);
    points[i].transforms[0] the same ENU pose, velocities[0] the body twist FLU (linear.x = u,
    linear.y = -v, angular.z = -r), accelerations empty, time_from_start = t_ns[i] - stamp.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from msg_adapters import _codec as c
from usv_predictor.errors import AdapterError
from usv_predictor.frames import enu_yaw_to_heading, heading_to_enu_yaw, quaternion_to_yaw, yaw_to_quaternion

PATH_TYPE = "nav_msgs/msg/Path"
TRAJECTORY_TYPE = "trajectory_msgs/msg/MultiDOFJointTrajectory"


def _check_shapes(t_ns: np.ndarray, **arrays: np.ndarray) -> None:
    for name, array in arrays.items():
        if array.ndim != 2 or array.shape != (len(t_ns), 3):
            raise AdapterError(f"{name} must have shape ({len(t_ns)}, 3) to match t_ns, got {array.shape}")


def _enu_pose_parts(eta_row: np.ndarray) -> tuple[tuple[float, float], tuple[float, float, float, float]]:
    x_n, y_e, psi = (float(x) for x in eta_row)
    quat = tuple(float(q) for q in yaw_to_quaternion(heading_to_enu_yaw(psi)))
    return (y_e, x_n), quat


def encode_path(stamp_ns: int, t_ns: np.ndarray, eta: np.ndarray, frame_id: str, make: c.MakeFn) -> Any:
    """nav_msgs/Path of the predicted poses eta (H, 3) NED at times t_ns (H,)."""
    t_ns, eta = np.asarray(t_ns, dtype=np.int64), np.asarray(eta, dtype=np.float64)
    _check_shapes(t_ns, eta=eta)
    poses = []
    for t_i, eta_i in zip(t_ns, eta):
        (east, north), quat = _enu_pose_parts(eta_i)
        pose = make("geometry_msgs/msg/Pose")(
            position=c.vector3(make, east, north, 0.0, "geometry_msgs/msg/Point"), orientation=c.quaternion(make, *quat)
        )
        poses.append(make("geometry_msgs/msg/PoseStamped")(header=c.header(make, int(t_i), frame_id), pose=pose))
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
    points = []
    for t_i, eta_i, nu_i in zip(t_ns, eta, nu):
        (east, north), quat = _enu_pose_parts(eta_i)
        u, v, r = (float(x) for x in nu_i)
        transform = make("geometry_msgs/msg/Transform")(
            translation=c.vector3(make, east, north, 0.0), rotation=c.quaternion(make, *quat)
        )
        twist = make("geometry_msgs/msg/Twist")(
            linear=c.vector3(make, u, -v, 0.0), angular=c.vector3(make, 0.0, 0.0, -r)
        )
        points.append(
            make("trajectory_msgs/msg/MultiDOFJointTrajectoryPoint")(
                transforms=[transform],
                velocities=[twist],
                accelerations=[],
                time_from_start=c.time_msg(make, int(t_i) - int(stamp_ns), "builtin_interfaces/msg/Duration"),
            )
        )
    return make(TRAJECTORY_TYPE)(
        header=c.header(make, int(stamp_ns), frame_id), joint_names=[child_frame_id], points=points
    )


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

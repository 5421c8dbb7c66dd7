"""ROS message <-> plain numbers, the one adapter registry. Never imports rclpy.

Roles and their value columns (SI units, marine frames: NED earth, FRD body, heading clockwise
from north) are in ROLE_FIELDS; ROS messages follow REP-103/105 (ENU, FLU, yaw CCW from east) and
the adapters convert between the two with usv_predictor.frames. Time is int nanoseconds.

    adapter = get_adapter("heading", "std_msgs/msg/Float64", units="deg")
    stamp_ns, (psi,) = adapter.decode(msg)           # stamp None for header-less types
    msg = adapter.encode(t_ns, [psi], rosbags_factory(typestore))

decode also accepts a structure of arrays over N messages (numpy leaves) and then returns
(N,) arrays, except for sensor_msgs/JointState (AdapterError "... not vectorisable").
"""
from __future__ import annotations

from typing import Any

from msg_adapters.factories import ColumnarMessage, columnar_factory, rclpy_factory, rosbags_factory
from msg_adapters.registry import ROLE_FIELDS, Adapter
from msg_adapters.standard import ADAPTER_CLASSES
from usv_predictor.errors import AdapterError

__all__ = [
    "ROLE_FIELDS",
    "Adapter",
    "ColumnarMessage",
    "columnar_factory",
    "get_adapter",
    "rclpy_factory",
    "registered",
    "rosbags_factory",
]


def registered() -> list[tuple[str, str]]:
    """Every (role, ros_type) pair an adapter exists for."""
    return list(ADAPTER_CLASSES)


def get_adapter(role: str, ros_type: str, **options: Any) -> Adapter:
    """The adapter converting `ros_type` messages to `role` values, configured by `options`."""
    try:
        adapter_class = ADAPTER_CLASSES[(role, ros_type)]
    except KeyError:
        if role not in ROLE_FIELDS:
            raise AdapterError(f"unknown role {role!r}; roles: {sorted(ROLE_FIELDS)}") from None
        types = [t for r, t in ADAPTER_CLASSES if r == role]
        raise AdapterError(
            f"no adapter for role {role!r} from message type {ros_type!r}; registered types for {role!r}: {types}"
        ) from None
    return adapter_class.build(role, ros_type, options)

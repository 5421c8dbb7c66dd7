"""Shared helpers of the adapters: duck-typed field access and message building.

Every helper works on one message (Python scalars, what rclpy and rosbags expect) AND on a
"structure of arrays" (the same attribute tree whose leaves are numpy arrays over N messages):
decoding uses numpy operations only, and `leaf`/`int_leaf` return Python scalars for 0-d input
and arrays otherwise. Time is int nanoseconds; builtin_interfaces Time is (sec, nanosec) with
nanosec in [0, 1e9) also for negative times (floor division).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from usv_predictor.errors import AdapterError
from usv_predictor.records import NS_PER_S

MakeFn = Callable[[str], Any]
"""make(type_name) -> message class (rosbags dataclass, rclpy class or a columnar builder)."""


def field(msg: object, path: str, ros_type: str) -> Any:
    """Attribute `path` ('a.b.c') of `msg`, or AdapterError naming the type and the field."""
    obj = msg
    for name in path.split("."):
        try:
            obj = getattr(obj, name)
        except AttributeError as err:
            raise AdapterError(
                f"{ros_type}: message of type {type(msg).__name__} has no field {path!r} "
                f"(missing {name!r}); is the topic really a {ros_type}?"
            ) from err
    return obj


def stamp_ns(msg: object, ros_type: str, path: str = "header.stamp") -> int | np.ndarray:
    """Header stamp in int nanoseconds (int for one message, (N,) int64 for columns)."""
    sec = np.asarray(field(msg, f"{path}.sec", ros_type), dtype=np.int64)
    nanosec = np.asarray(field(msg, f"{path}.nanosec", ros_type), dtype=np.int64)
    total = sec * NS_PER_S + nanosec
    return int(total) if total.ndim == 0 else total


def values_out(*columns: Any) -> tuple:
    """Decoded values: tuple of floats for one message, tuple of (N,) float64 arrays for columns."""
    arrays = [np.asarray(c, dtype=np.float64) for c in columns]
    if all(a.ndim == 0 for a in arrays):
        return tuple(float(a) for a in arrays)
    return tuple(np.array(a) for a in np.broadcast_arrays(*arrays))


def leaf(x: Any) -> float | np.ndarray:
    """A float64 message field: Python float for one message, float64 array for columns."""
    a = np.asarray(x, dtype=np.float64)
    return float(a) if a.ndim == 0 else a


def int_leaf(x: Any) -> int | np.ndarray:
    """An integer message field: Python int for one message, int64 array for columns."""
    a = np.asarray(x, dtype=np.int64)
    return int(a) if a.ndim == 0 else a


def column_values(values: Sequence[Any], count: int, ros_type: str) -> list[np.ndarray]:
    """The `count` value columns passed to encode, as float64 arrays (0-d for one message)."""
    if len(values) != count:
        raise AdapterError(f"{ros_type}: encode expects {count} values, got {len(values)}")
    return [np.asarray(v, dtype=np.float64) for v in values]


def time_msg(make: MakeFn, t_ns: Any, type_name: str = "builtin_interfaces/msg/Time") -> Any:
    """builtin_interfaces Time (or Duration) from int nanoseconds."""
    sec, nanosec = np.divmod(np.asarray(t_ns, dtype=np.int64), NS_PER_S)
    return make(type_name)(sec=int_leaf(sec), nanosec=int_leaf(nanosec))


def header(make: MakeFn, t_ns: Any, frame_id: str) -> Any:
    return make("std_msgs/msg/Header")(stamp=time_msg(make, t_ns), frame_id=frame_id)


def vector3(make: MakeFn, x: Any, y: Any, z: Any, type_name: str = "geometry_msgs/msg/Vector3") -> Any:
    return make(type_name)(x=leaf(x), y=leaf(y), z=leaf(z))


def quaternion(make: MakeFn, x: Any, y: Any, z: Any, w: Any) -> Any:
    return make("geometry_msgs/msg/Quaternion")(x=leaf(x), y=leaf(y), z=leaf(z), w=leaf(w))


def diagonal_covariance(diagonal: Sequence[float]) -> np.ndarray:
    """Row-major covariance array (n*n,) with the given diagonal (what ROS covariance fields hold)."""
    return np.diag(np.asarray(diagonal, dtype=np.float64)).ravel()

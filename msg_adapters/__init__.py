"""ROS message <-> plain numbers, the one adapter registry. Never imports rclpy.

Roles and their value columns (SI units, marine frames: NED earth, FRD body, heading clockwise
from north) are in ROLE_FIELDS; ROS messages follow REP-103/105 (ENU, FLU, yaw CCW from east) and
the adapters convert between the two with usv_predictor.frames. Time is int nanoseconds.

    adapter = get_adapter("heading", "std_msgs/msg/Float64", units="deg")
    stamp_ns, (psi,) = adapter.decode(msg)           # stamp None for header-less types
    msg = adapter.encode(t_ns, [psi], rosbags_factory(typestore))

Several roles on one topic (both thrusters in one Float64MultiArray, JointState or Wrench):

    check_shared("thrusters", [port_adapter, starboard_adapter])    # AdapterError if they cannot share it
    msg = encode_shared([port_adapter, starboard_adapter], t_ns, [[c_port], [c_stbd]], make)

decode also accepts a structure of arrays over N messages (numpy leaves) and then returns
(N,) arrays, except for sensor_msgs/JointState (AdapterError "... not vectorisable").
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from msg_adapters.factories import ColumnarMessage, columnar_factory, rclpy_factory, rosbags_factory
from msg_adapters.registry import ROLE_FIELDS, Adapter
from msg_adapters.standard import ADAPTER_CLASSES
from usv_predictor.errors import AdapterError

__all__ = [
    "ROLE_FIELDS",
    "Adapter",
    "ColumnarMessage",
    "check_shared",
    "columnar_factory",
    "encode_shared",
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


def check_shared(topic: str, adapters: Sequence[Adapter]) -> None:
    """AdapterError unless `adapters` (the roles configured on one topic) can share it: one message type that
    carries several values (SHARES_TOPIC), each role reading its own part (slot), agreeing on message-wide options."""
    if len(adapters) < 2:
        return
    roles = [a.role for a in adapters]
    types = sorted({a.ros_type for a in adapters})
    if len(types) > 1:
        raise AdapterError(f"topic {topic!r} carries roles {roles} with different types {types}; one "
                           f"topic has one type")
    if not all(getattr(a, "SHARES_TOPIC", False) for a in adapters):
        raise AdapterError(f"topic {topic!r}: roles {roles} cannot share a {types[0]} topic (it carries one value); "
                           "give each role its own topic, or use a Float64MultiArray, JointState or Wrench")
    slots: dict[object, str] = {}
    for adapter in adapters:
        if adapter.slot in slots:
            raise AdapterError(f"topic {topic!r}: roles {slots[adapter.slot]!r} and {adapter.role!r} read the same "
                               f"part of the message ({adapter.slot!r}); set `index` / `joint` / `field` apart")
        slots[adapter.slot] = adapter.role
    if len({a.message_options for a in adapters}) > 1:
        raise AdapterError(f"topic {topic!r}: roles {roles} need the same message options (for a Wrench: "
                           "surge_full_scale, yaw_full_scale, sign, saturate)")


def encode_shared(adapters: Sequence[Adapter], t_ns: Any, values: Sequence[Sequence[Any]],
                  make: Callable[[str], Any], frame_id: str = "", topic: str = "") -> Any:
    """One message carrying the values of several roles (values[i] for adapters[i]) on one topic."""
    check_shared(topic, adapters)
    if len(adapters) == 1:
        return adapters[0].encode(t_ns, values[0], make, frame_id)
    return type(adapters[0]).encode_shared(adapters, t_ns, values, make, frame_id)

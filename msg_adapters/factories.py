"""make(type_name) -> message class, so one encode() builds rosbags, rclpy or columnar messages.

rosbags: dataclasses from a typestore (no ROS installation needed).
rclpy: the generated classes, imported lazily (e.g. sensor_msgs.msg.Imu); importing a message
package does not import rclpy itself, and this module never does.
columnar: `ColumnarMessage` namespaces whose leaves may be numpy arrays over N messages
("structure of arrays"); what adapters decode in bulk and what bagio serialises in bulk.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

from usv_predictor.errors import AdapterError


def _split_type_name(type_name: str) -> tuple[str, str]:
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(parts):
        raise AdapterError(f"message type {type_name!r} is not of the form 'package/msg/Name'")
    return f"{parts[0]}.{parts[1]}", parts[2]


def rosbags_factory(typestore: Any) -> Callable[[str], type]:
    """make() returning rosbags dataclasses of `typestore` (e.g. get_typestore(Stores.ROS2_JAZZY))."""

    def make(type_name: str) -> type:
        try:
            return typestore.types[type_name]
        except KeyError:
            raise AdapterError(f"message type {type_name!r} is not in the rosbags typestore") from None

    return make


def rclpy_factory() -> Callable[[str], type]:
    """make() returning rclpy message classes, imported on first use."""

    def make(type_name: str) -> type:
        module_name, class_name = _split_type_name(type_name)
        try:
            return getattr(importlib.import_module(module_name), class_name)
        except (ImportError, AttributeError) as err:
            raise AdapterError(
                f"message type {type_name!r}: cannot import {module_name}.{class_name} ({err}); "
                "is its interface package installed and sourced?"
            ) from err

    return make


class ColumnarMessage(SimpleNamespace):
    """One message type's fields as attributes; leaves may be (N, ...) arrays. `__msgtype__` names the type."""


def columnar_factory() -> Callable[[str], Callable[..., ColumnarMessage]]:
    """make() building ColumnarMessage namespaces: encode(t_ns (N,), values of (N,) arrays, make)."""

    def make(type_name: str) -> Callable[..., ColumnarMessage]:
        def build(**fields: Any) -> ColumnarMessage:
            return ColumnarMessage(__msgtype__=type_name, **fields)

        return build

    return make

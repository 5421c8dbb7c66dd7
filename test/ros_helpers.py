"""Shared helpers of the node tests: domain ids, the node harness, /diagnostics lookups (the isolated rclpy
context `ros_context` is a fixture of conftest.py).

Every test process talks on its own ROS_DOMAIN_ID (derived from the xdist worker or the pid, an offset per use) with
discovery on this host only, so parallel runs on one machine do not hear each other.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

import msg_adapters
from usv_predictor.node import node as predictor_node

WAIT_S = 15.0  # upper bound on discovery + a few timer periods (s)
DIAGNOSTICS_RATE_HZ = 20.0  # the harness's /diagnostics rate (default 1 Hz): tests wait on the reports
# plain values (SI, marine frames) of every default input that give a good prediction
GOOD = {"imu": (0.02, 0.0, 0.0, -9.81, math.nan), "velocity": (5.0, 0.1, 0.02), "heading": (0.5,),
        "rudder_angle": (0.1,), "engine_rpm": (650.0,), "gnss": (35.38, 119.56, 0.0)}


def domain_id(offset: int = 0) -> int:
    """A ROS_DOMAIN_ID in 1..200 for this process; different offsets (0..49) give different domains.

    Under pytest-xdist (./run.sh test runs two workers) worker gwK owns the block 50 K + 1 .. 50 K + 50, so
    the workers' nodes never meet (up to four workers); a plain pytest process derives its base from its pid,
    which keeps concurrent runs apart."""
    if not 0 <= offset < 50:
        raise ValueError(f"domain offset {offset}: expected 0..49 (one block per xdist worker)")
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", ...
    base = 50 * int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else 3 * os.getpid()
    return 1 + (base + offset) % 200


def localhost_env(offset: int = 0) -> dict[str, str]:
    """os.environ for a child process on this process's domain (+ offset), discovery on this host only."""
    return {**os.environ, "ROS_DOMAIN_ID": str(domain_id(offset)), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}


def statuses(report: DiagnosticArray) -> dict[str, Any]:
    """{'imu': status, ..., 'model': status} from names like 'predictor: input imu'."""
    return {status.name.split(": ", 1)[1].removeprefix("input "): status for status in report.status}


def values_of(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def level(status: Any) -> int:
    """A DiagnosticStatus level (a one-byte `bytes` in rclpy) as an int."""
    return status.level[0]


class Harness:
    """The node under test (wall clock), a peer node that publishes its inputs, and what comes back."""

    def __init__(self, context: Context, overrides: list[Parameter], peer_name: str = "test_peer",
                 config_path: Any = None) -> None:
        if not any(p.name == "diagnostics_rate_hz" for p in overrides):
            overrides = [*overrides, Parameter("diagnostics_rate_hz", value=DIAGNOSTICS_RATE_HZ)]
        self.node = predictor_node.PredictorNode(config_path=config_path, context=context,
                                                 parameter_overrides=overrides)
        self.peer = Node(peer_name, context=context)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.make = msg_adapters.rclpy_factory()
        self.paths: list[Any] = []
        self.latest: DiagnosticArray | None = None
        self.peer.create_subscription(self.make("nav_msgs/msg/Path"), "predicted_path", self.paths.append, 10)
        self.peer.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.publishers: dict[str, Any] = {}

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        self.latest = msg

    def publish(self, role: str, values: tuple[float, ...], stamp_offset_s: float = 0.0, raw: Any = None) -> None:
        """Encode plain values with the role's configured adapter (or send `raw`) and publish as ROS would."""
        entry = self.node.config.input(role)
        if role not in self.publishers:
            self.publishers[role] = self.peer.create_publisher(self.make(entry.ros_type), entry.topic, 100)
        if raw is None:
            adapter = msg_adapters.get_adapter(entry.role, entry.ros_type, **entry.options)
            stamp = self.peer.get_clock().now().nanoseconds + int(stamp_offset_s * 1e9)
            raw = adapter.encode(stamp, values, self.make, entry.frame_id)
        self.publishers[role].publish(raw)

    def feed(self, skip: tuple[str, ...] = (), **override: tuple[float, ...]) -> None:
        """One sample of every GOOD input (but `skip`), with `override` values per role."""
        for role, values in GOOD.items():
            if role not in skip:
                self.publish(role, override.get(role, values))

    def spin(self, seconds: float, feed: Callable[[], None] | None = None) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            if feed is not None:
                feed()
            self.executor.spin_once(timeout_sec=0.01)

    def spin_until(self, condition: Callable[[dict[str, Any]], bool], feed: Callable[[], None] | None = None) -> dict:
        """Spin (feeding inputs) until the latest /diagnostics satisfies condition; return its statuses."""
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            if feed is not None:
                feed()
            self.executor.spin_once(timeout_sec=0.02)
            if self.latest is not None and condition(statuses(self.latest)):
                return statuses(self.latest)
        last = None if self.latest is None else {k: (level(s), s.message) for k, s in statuses(self.latest).items()}
        pytest.fail(f"no /diagnostics satisfied the condition within {WAIT_S} s; last report: {last}")

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()

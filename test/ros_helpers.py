"""Shared helpers of the node tests: an isolated rclpy context and /diagnostics lookups."""
from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context


@pytest.fixture()
def ros_context(monkeypatch: pytest.MonkeyPatch) -> Iterator[Context]:
    """A private rclpy context on a domain derived from the pid, discovery on this host only."""
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    context = Context()
    rclpy.init(context=context, domain_id=1 + os.getpid() % 100)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def statuses(report: DiagnosticArray) -> dict[str, Any]:
    """{'imu': status, ..., 'model': status} from names like 'predictor: input imu'."""
    return {status.name.split(": ", 1)[1].removeprefix("input "): status for status in report.status}


def values_of(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}

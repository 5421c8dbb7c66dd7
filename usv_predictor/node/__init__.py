"""The online predictor: `node` is the rclpy shell (the package's only rclpy import), `live` the pure
buffers, checks, state and rollout it drives.

`main` is the entry point of `ros2 run usv_predictor predictor` (setup.py: `usv_predictor.node:main`). It
imports the rclpy shell only when called, so `usv_predictor.node.live` stays importable without ROS.
"""
from __future__ import annotations

import signal
from typing import Any, Sequence


class _StoppedEarly(BaseException):
    """SIGTERM or SIGHUP while the shell is being imported: unwinds like Ctrl-C."""


def _stop_early(signum: int, frame: Any) -> None:
    raise _StoppedEarly()


def main(args: Sequence[str] | None = None) -> int:
    """The node's entry point: a stop signal at any moment ends it with exit 0 (node.main's handlers take over once
    it runs; before them, during the imports, these: without them SIGTERM would kill the process as signal 15)."""
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _stop_early)
    try:
        from usv_predictor.node.node import main as node_main  # rclpy, torch: a second or two
    except (KeyboardInterrupt, _StoppedEarly):  # before the node's own handlers exist: a normal end, no traceback
        return 0
    try:
        return node_main(args)
    except _StoppedEarly:  # in the instant before node.main installs its own handlers
        return 0
    finally:
        for sig in (signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_DFL)

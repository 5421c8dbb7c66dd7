"""The online predictor: `node` is the rclpy shell (the package's only rclpy import), `live` the pure
buffers, checks, state and rollout it drives.

`main` is the entry point of `ros2 run usv_predictor predictor` (setup.py: `usv_predictor.node:main`). It
imports the rclpy shell only when called, so `usv_predictor.node.live` stays importable without ROS.
"""
from __future__ import annotations

from typing import Sequence


def main(args: Sequence[str] | None = None) -> int:
    try:
        from usv_predictor.node.node import main as node_main  # rclpy, torch: a second or two
    except KeyboardInterrupt:  # Ctrl-C before the node's own handlers exist: a normal end, no traceback
        return 0
    return node_main(args)

"""The online predictor: `node` is the rclpy shell (the package's only rclpy import), `live` the pure
buffers, checks, state and rollout it drives.

`main` is the entry point of `ros2 run usv_predictor predictor` (setup.py: `usv_predictor.node:main`). It
imports the rclpy shell only when called, so `usv_predictor.node.live` stays importable without ROS.
"""
from __future__ import annotations

import signal
from typing import Any, Sequence

EARLY_STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def main(args: Sequence[str] | None = None) -> int:
    """The node's entry point: a stop signal at any moment ends it with exit 0. During the imports (rclpy, torch,
    numba: seconds) a signal is only noted, never raised into them (an exception thrown through torch's or numba's
    initialisation aborts the process: exit -6); node.main reads the note once its own handlers are installed."""
    noted: list[int] = []

    def note(signum: int, frame: Any) -> None:
        noted.append(signum)

    for sig in EARLY_STOP_SIGNALS:
        signal.signal(sig, note)
    try:
        from usv_predictor.node.node import main as node_main  # rclpy, torch: a second or two
        return node_main(args, stopped_before=noted)
    finally:
        for sig in EARLY_STOP_SIGNALS:
            signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)

"""The online predictor: `node` is the rclpy shell (the package's only rclpy import), `live` the pure
buffers, checks, state and rollout it drives.

`main` is the entry point of `ros2 run usv_predictor predictor` (setup.py: `usv_predictor.node:main`). It
imports the rclpy shell only when called, so `usv_predictor.node.live` stays importable without ROS.
"""
from __future__ import annotations

import os
import signal
from typing import Any, Sequence

EXIT_OK = 0  # stopped by SIGHUP (the terminal went away: a clean stop), or by the context's shutdown elsewhere
EXIT_INTERRUPTED = 130  # stopped by SIGINT (Ctrl-C): 128 + SIGINT, as the replay tool and a shell report it
EXIT_TERMINATED = 143  # stopped by SIGTERM (systemd, docker stop, launch): 128 + SIGTERM
EXIT_CODES = {signal.SIGINT: EXIT_INTERRUPTED, signal.SIGTERM: EXIT_TERMINATED, signal.SIGHUP: EXIT_OK}
STOP_SIGNALS = tuple(EXIT_CODES)  # SIGHUP: the terminal went away, a clean stop too


def main(args: Sequence[str] | None = None) -> int:
    """The node's entry point: a stop signal at any moment ends it, SIGINT with exit 130, SIGTERM 143, SIGHUP 0
    (EXIT_CODES). During the imports (rclpy, torch, numba: seconds on a loaded machine) a stop signal ends the process
    at once with its code (os._exit from the handler: nothing exists yet that needs an end, no ROS context, no file;
    an exception raised into torch's or numba's initialisation would abort it instead, exit -6); node.main installs
    its own handlers once they are done."""

    def stop_now(signum: int, frame: Any) -> None:
        os._exit(EXIT_CODES[signal.Signals(signum)])

    for sig in STOP_SIGNALS:
        signal.signal(sig, stop_now)
    try:
        from usv_predictor.node.node import main as node_main  # rclpy, torch: seconds
        return node_main(args)
    finally:
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.default_int_handler if sig == signal.SIGINT else signal.SIG_DFL)

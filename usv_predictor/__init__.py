"""usv_predictor: online 3-DOF motion prediction for unmanned surface vehicles.

Pure numpy/torch core (frames, dynamics, environment, sensors, simulator), a bag-replay tool
(`usv_predictor.replay`) and an rclpy node (`usv_predictor.node`).
"""
from __future__ import annotations

__version__ = "0.1.0"

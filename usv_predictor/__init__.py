"""usv_predictor: online 3-DOF motion prediction for unmanned surface vehicles.

Folders by layer (a folder imports only those above it; test/test_layers.py checks it): the ground floor
(errors, frames, records, config, atomic), physics/ (vessel, dynamics, environment, actuator layouts, effects,
simulator, manoeuvres, sensors), data/ (recordings, smoother, features, datasets), models/ (the artifact format,
one file per model family), fitting/ (training, identification, hybrid fitting), analysis/ (metrics,
evaluation, diagnosis, plots, reports), node/ (the rclpy node `usv_predictor.node`, its pure live core) and
replay/ (the bag-replay tool `usv_predictor.replay`). msg_adapters/, beside this package, converts ROS messages.
"""
from __future__ import annotations

__version__ = "0.1.0"

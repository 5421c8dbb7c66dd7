"""usv_predictor: online 3-DOF motion prediction for unmanned surface vehicles.

Folders by layer (a folder imports only those above it; test/test_layers.py checks it): the ground floor
(errors, frames, records, config, atomic), physics/ (vessel, dynamics, environment, actuator layouts, effects,
simulator, manoeuvres, sensors), data/ (recordings, smoother, features, datasets), models/ (the artifact format,
one file per model family), fitting/ (training, identification, hybrid fitting), analysis/ (metrics,
evaluation, diagnosis, plots, reports), node/ (the rclpy node `usv_predictor.node`, its pure live core) and
replay/ (the bag-replay tool `usv_predictor.replay`). msg_adapters/, beside this package, converts ROS messages.
"""
from __future__ import annotations

import os as _os

__version__ = "0.1.0"

# One BLAS thread per process. The package's linear algebra is small (least squares over a few thousand rows, dot
# products of ~10^4): OpenBLAS's second thread gains nothing on a quiet machine, and while another process holds the
# other core it turns a 10^4-element dot product from 2 us into ~350 us (docs/kernel.md, "One BLAS thread"). OpenBLAS
# reads this when numpy is first imported, so it acts for the commands and the node, which import this package
# first. A value the user set is kept (OpenBLAS reads it before OMP_NUM_THREADS, which stays torch's).
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

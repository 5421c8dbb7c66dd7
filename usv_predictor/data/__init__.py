"""Data: recordings (aligned, resampled series), the EKF/RTS smoother, model features and datasets."""
from __future__ import annotations

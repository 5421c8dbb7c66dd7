"""Fitting: training the learned model, identifying the grey box, fitting the hybrid's residual."""
from __future__ import annotations

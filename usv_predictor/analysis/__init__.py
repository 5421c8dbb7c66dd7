"""Analysis: naval-architecture metrics, evaluation of models on recordings, diagnosis, plots and reports."""
from __future__ import annotations

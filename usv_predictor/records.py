"""Plain-number records passed between sensors, adapters, bags and models (SI units, named frames).

Time inside is int nanoseconds (t_ns) until the numeric boundary, where it becomes float seconds.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NS_PER_S = 1_000_000_000  # nanoseconds per second


@dataclass(frozen=True)
class Signal:
    """Time-stamped samples of one measured quantity.

    t_ns: (N,) int64 nanoseconds; values: (N, k) float64 in SI units (rpm for engine speed);
    fields: the k column names (see msg_adapters.ROLE_FIELDS for each role's columns and frames).
    """

    t_ns: np.ndarray
    values: np.ndarray
    fields: tuple[str, ...]

    def __post_init__(self) -> None:
        if self.t_ns.ndim != 1 or self.values.ndim != 2:
            raise ValueError(f"Signal needs t_ns (N,) and values (N, k), got {self.t_ns.shape} and {self.values.shape}")
        if len(self.t_ns) != len(self.values) or self.values.shape[1] != len(self.fields):
            raise ValueError(
                f"Signal shapes disagree: t_ns {self.t_ns.shape}, values {self.values.shape}, fields {self.fields}"
            )

    def __len__(self) -> int:
        return len(self.t_ns)

    def column(self, name: str) -> np.ndarray:
        """One column by field name, e.g. signal.column('yaw_rate')."""
        try:
            return self.values[:, self.fields.index(name)]
        except ValueError:
            raise KeyError(f"signal has no field {name!r}; it has {self.fields}") from None

"""Plain-number records passed between sensors, adapters, bags and models (SI units, named frames).

Time inside is int nanoseconds (t_ns) until the numeric boundary, where it becomes float seconds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from usv_predictor.errors import ConfigError

NS_PER_S = 1_000_000_000  # nanoseconds per second
MAX_STEPS = 10**8  # steps any horizon, stride or window may span (over three years at 1 s)


def whole_steps(seconds: float, dt: float, what: str, minimum: int = 1) -> int:
    """round(seconds / dt) steps of dt; ConfigError naming `what` when that is not finite, rounds below `minimum`
    or exceeds MAX_STEPS (a horizon of 1e308 s or 1e-320 s is refused, not turned into an overflow)."""
    ratio = seconds / dt if dt > 0.0 else math.inf
    if not math.isfinite(ratio) or not minimum - 0.5 <= ratio <= MAX_STEPS:
        raise ConfigError(f"{what} {seconds:g} s is {ratio:g} steps of {dt:g} s; expected {minimum} to {MAX_STEPS} "
                          "steps")
    return max(minimum, int(round(ratio)))


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

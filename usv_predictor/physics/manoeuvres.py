"""Standard trial manoeuvres as autopilot programmes (ITTC 7.5-04-02-01, IMO MSC.137(76)).

Every manoeuvre starts from steady straight running at `rpm` and executes after `approach_s`. Rudder angles are
given in degrees, positive to starboard; `side=-1` mirrors a manoeuvre to port.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from usv_predictor.config import Range
from usv_predictor.physics.simulator import Controller


def _check(name: str, **ranges: tuple[float, float, float]) -> None:
    for arg, (value, low, high) in ranges.items():
        Range(low, high, "").check(arg, value, name)


@dataclass(frozen=True)
class TurningCircle:
    rudder_deg: float
    rpm: float
    duration_s: float = 210.0
    approach_s: float = 10.0
    side: int = 1

    @property
    def name(self) -> str:
        return f"turning_circle_{'stbd' if self.side > 0 else 'port'}_{self.rudder_deg:g}deg_{self.rpm:g}rpm"

    def controller(self) -> Controller:
        rudder = math.radians(self.rudder_deg) * self.side

        def command(t: float, psi: float, r: float) -> tuple[float, float]:
            return (rudder if t >= self.approach_s else 0.0), self.rpm

        return command


@dataclass(frozen=True)
class ZigZag:
    """delta/psi zig-zag: reverse the rudder when the heading change reaches the check angle."""

    rudder_deg: float
    check_deg: float
    rpm: float
    duration_s: float = 120.0
    approach_s: float = 5.0
    side: int = 1

    @property
    def name(self) -> str:
        return f"zigzag_{self.rudder_deg:g}_{self.check_deg:g}_{'stbd' if self.side > 0 else 'port'}_{self.rpm:g}rpm"

    def controller(self) -> Controller:
        rudder, check = math.radians(self.rudder_deg), math.radians(self.check_deg)
        state = {"side": self.side, "psi0": None}

        def command(t: float, psi: float, r: float) -> tuple[float, float]:
            if t < self.approach_s:
                return 0.0, self.rpm
            if state["psi0"] is None:
                state["psi0"] = psi
            change = psi - state["psi0"]
            if state["side"] > 0 and change >= check:
                state["side"] = -1
            elif state["side"] < 0 and change <= -check:
                state["side"] = 1
            return state["side"] * rudder, self.rpm

        return command


@dataclass(frozen=True)
class PullOut:
    """Turn with a steady rudder, then return it to zero and watch the yaw rate decay (stability)."""

    rudder_deg: float
    rpm: float
    turn_s: float = 40.0
    duration_s: float = 100.0
    approach_s: float = 5.0
    side: int = 1

    @property
    def name(self) -> str:
        return f"pullout_{'stbd' if self.side > 0 else 'port'}_{self.rudder_deg:g}deg_{self.rpm:g}rpm"

    def controller(self) -> Controller:
        rudder = math.radians(self.rudder_deg) * self.side

        def command(t: float, psi: float, r: float) -> tuple[float, float]:
            on = self.approach_s <= t < self.approach_s + self.turn_s
            return (rudder if on else 0.0), self.rpm

        return command


@dataclass(frozen=True)
class Spiral:
    """Dieudonne spiral: rudder steps from +max to -max and back, each held until the turn is steady."""

    rudder_steps_deg: tuple[float, ...] = (25, 15, 8, 4, 0, -4, -8, -15, -25)
    rpm: float = 650.0
    hold_s: float = 40.0
    approach_s: float = 5.0

    @property
    def name(self) -> str:
        return f"spiral_{self.rpm:g}rpm"

    @property
    def duration_s(self) -> float:
        return self.approach_s + self.hold_s * len(self.rudder_steps_deg)

    def controller(self) -> Controller:
        steps = [math.radians(d) for d in self.rudder_steps_deg]

        def command(t: float, psi: float, r: float) -> tuple[float, float]:
            if t < self.approach_s:
                return 0.0, self.rpm
            k = min(int((t - self.approach_s) // self.hold_s), len(steps) - 1)
            return steps[k], self.rpm

        return command


@dataclass(frozen=True)
class RandomManoeuvre:
    """Persistently exciting programme: random rudder and rpm steps with random hold times (seeded)."""

    seed: int = 0
    rpm: float = 650.0
    rpm_span: float = 150.0  # engine commands in rpm +/- rpm_span (rpm)
    rudder_max_deg: float = 25.0
    hold_min_s: float = 2.0
    hold_max_s: float = 12.0
    duration_s: float = 240.0
    approach_s: float = 5.0
    _table: tuple = field(default=(), repr=False, compare=False)

    @property
    def name(self) -> str:
        return f"random_{self.seed}_{self.rpm:g}rpm"

    def schedule(self) -> np.ndarray:
        """(K, 3) rows of [start time (s), rudder (rad), rpm]; deterministic for the seed."""
        _check(self.name, rudder_max_deg=(self.rudder_max_deg, 0.0, 90.0),
               hold_min_s=(self.hold_min_s, 0.1, self.hold_max_s))
        rng = np.random.default_rng(self.seed)
        rows, t = [], self.approach_s
        while t < self.duration_s:
            rudder = math.radians(rng.uniform(-self.rudder_max_deg, self.rudder_max_deg))
            rpm = self.rpm + rng.uniform(-self.rpm_span, self.rpm_span)
            rows.append((t, rudder, max(rpm, 0.0)))
            t += rng.uniform(self.hold_min_s, self.hold_max_s)
        return np.array(rows)

    def controller(self) -> Controller:
        table = self.schedule()
        starts = table[:, 0]

        def command(t: float, psi: float, r: float) -> tuple[float, float]:
            if t < self.approach_s:
                return 0.0, self.rpm
            k = int(np.searchsorted(starts, t, side="right")) - 1
            return float(table[k, 1]), float(table[k, 2])

        return command


def sea_trial_turns(duration_s: float = 180.0) -> list[TurningCircle]:
    """Seed 000 Table 3: starboard turning tests, rudder 15/20/25 deg x engine 650/700 rpm, 3 min each."""
    return [TurningCircle(rudder, rpm, duration_s=duration_s) for rudder in (15.0, 20.0, 25.0) for rpm in (650.0, 700.0)]


def training_runs() -> list:
    """Zig-zags both ways, a port turn and a persistently exciting random run, for model fitting."""
    return [
        ZigZag(10.0, 10.0, 650.0, duration_s=120.0),
        ZigZag(20.0, 20.0, 700.0, duration_s=120.0, side=-1),
        TurningCircle(20.0, 675.0, duration_s=120.0, side=-1),
        RandomManoeuvre(seed=7, rpm=675.0, duration_s=180.0),
    ]


def diagnosis_runs() -> list:
    """A trial programme that separates hypotheses: turns both ways and zig-zags both ways."""
    return [
        TurningCircle(20.0, 650.0, duration_s=150.0, side=1),
        TurningCircle(20.0, 650.0, duration_s=150.0, side=-1),
        ZigZag(20.0, 20.0, 650.0, duration_s=100.0, side=1),
        ZigZag(20.0, 20.0, 650.0, duration_s=100.0, side=-1),
    ]


PROGRAMMES = {
    "sea_trial": sea_trial_turns,
    "training": training_runs,
    "diagnosis": diagnosis_runs,
}

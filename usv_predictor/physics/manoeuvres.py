"""Standard trial manoeuvres as autopilot programmes (ITTC 7.5-04-02-01, IMO MSC.137(76)).

Every manoeuvre starts from steady straight running at its propulsion command and executes after `approach_s`;
`side=-1` mirrors a manoeuvre to port. An autopilot returns (turn, propulsion) in the layout's steering and
propulsion units (physics/actuators.py), which the layout turns into the boat's commands.

Two families state the commands differently:
  TurningCircle, ZigZag, PullOut, Spiral, RandomManoeuvre   a rudder in degrees and an engine speed in rpm
      (rudder_propeller, rudder_only): the manoeuvres of the shipped bags, names like turning_circle_stbd_20deg_650rpm;
  CommandTurningCircle, CommandZigZag, CommandPullOut, CommandSpiral, CommandRandom   the layout's own inputs
      (turn_input, propulsion_input): a rudder in degrees and a throttle (rudder_throttle), a differential d and a
      throttle p (twin_thrusters: port = p + d/2, starboard = p - d/2), names like turning_circle_stbd_d0.4_p0.6.
      A zig-zag of a twin boat reverses its differential at the check heading.
The factories turning_circle(), zigzag(), ... pick the family of a layout; programmes() the trial programmes.
MANOEUVRE_KINDS is the one record per kind: its data spelling (turning_circle), its `replay simulate --manoeuvre`
spelling (turning-circle) and how it is built, and whether converted public records have it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from usv_predictor.config import Range
from usv_predictor.physics.actuators import ENGINE_RPM, RUDDER_DEG, ActuatorLayout, actuator_layout
from usv_predictor.physics.simulator import Controller


def _check(name: str, **ranges: tuple[float, float, float]) -> None:
    for arg, (value, low, high) in ranges.items():
        Range(low, high, "").check(arg, value, name)


def _side(side: int) -> str:
    return "stbd" if side > 0 else "port"


# ---- the autopilots, shared by both families (turn and propulsion in the layout's units) ------------------

def _held_turn(turn: float, propulsion: float, start_s: float, stop_s: float = math.inf) -> Controller:
    """The turn command between start_s and stop_s, 0 otherwise; the propulsion command throughout."""

    def command(t: float, psi: float, r: float) -> tuple[float, float]:
        return (turn if start_s <= t < stop_s else 0.0), propulsion

    return command


def _zigzag(turn: float, check: float, propulsion: float, approach_s: float, side: int) -> Controller:
    """Reverse the turn command when the heading change from the execute reaches +-check (rad)."""
    state = {"side": side, "psi0": None}

    def command(t: float, psi: float, r: float) -> tuple[float, float]:
        if t < approach_s:
            return 0.0, propulsion
        if state["psi0"] is None:
            state["psi0"] = psi
        change = psi - state["psi0"]
        if state["side"] > 0 and change >= check:
            state["side"] = -1
        elif state["side"] < 0 and change <= -check:
            state["side"] = 1
        return state["side"] * turn, propulsion

    return command


def _steps(steps: list[float], propulsion: float, approach_s: float, hold_s: float) -> Controller:
    """A spiral: each turn command of `steps` held for hold_s after the approach."""

    def command(t: float, psi: float, r: float) -> tuple[float, float]:
        if t < approach_s:
            return 0.0, propulsion
        k = min(int((t - approach_s) // hold_s), len(steps) - 1)
        return steps[k], propulsion

    return command


def _table(table: np.ndarray, propulsion: float, approach_s: float) -> Controller:
    """Rows [start time (s), turn, propulsion] of a random schedule, held from their start."""
    starts = table[:, 0]

    def command(t: float, psi: float, r: float) -> tuple[float, float]:
        if t < approach_s:
            return 0.0, propulsion
        k = int(np.searchsorted(starts, t, side="right")) - 1
        return float(table[k, 1]), float(table[k, 2])

    return command


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

    @property
    def propulsion(self) -> float:
        return self.rpm

    def controller(self) -> Controller:
        return _held_turn(math.radians(self.rudder_deg) * self.side, self.rpm, self.approach_s)


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

    @property
    def propulsion(self) -> float:
        return self.rpm

    def controller(self) -> Controller:
        return _zigzag(math.radians(self.rudder_deg), math.radians(self.check_deg), self.rpm, self.approach_s,
                       self.side)


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

    @property
    def propulsion(self) -> float:
        return self.rpm

    def controller(self) -> Controller:
        return _held_turn(math.radians(self.rudder_deg) * self.side, self.rpm, self.approach_s,
                          self.approach_s + self.turn_s)


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

    @property
    def propulsion(self) -> float:
        return self.rpm

    def controller(self) -> Controller:
        return _steps([math.radians(d) for d in self.rudder_steps_deg], self.rpm, self.approach_s, self.hold_s)


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

    @property
    def propulsion(self) -> float:
        return self.rpm

    def controller(self) -> Controller:
        return _table(self.schedule(), self.rpm, self.approach_s)


# ---- manoeuvres in a layout's own command units -------------------------------------------------------------

def _inputs(layout_name: str) -> ActuatorLayout:
    layout = actuator_layout(layout_name)
    if layout.turn_input is None or layout.propulsion_input is None:
        raise ValueError(f"actuator layout {layout.name} states no turn / propulsion inputs: it cannot be simulated")
    return layout


@dataclass(frozen=True)
class CommandTurningCircle:
    """Turning circle: the turn command held after the approach. turn in the layout's turn_input unit (deg of
    rudder, or a normalised differential), propulsion in its propulsion unit (a normalised throttle)."""

    layout: str
    turn: float
    propulsion: float
    duration_s: float = 210.0
    approach_s: float = 10.0
    side: int = 1

    @property
    def name(self) -> str:
        """turning_circle_stbd_d0.4_p0.6; a circle of no turn is a straight run (straight_p0.6), one at zero
        propulsion a spin on the spot (spin_stbd_d2)."""
        a = _inputs(self.layout)
        if self.turn == 0.0:
            return f"straight_{a.propulsion_input.tag(self.propulsion)}"
        if self.propulsion == 0.0:
            return f"spin_{_side(self.side)}_{a.turn_input.tag(self.turn)}"
        return (f"turning_circle_{_side(self.side)}_{a.turn_input.tag(self.turn)}_"
                f"{a.propulsion_input.tag(self.propulsion)}")

    def controller(self) -> Controller:
        return _held_turn(self.turn * _inputs(self.layout).turn_input.to_command * self.side, self.propulsion,
                          self.approach_s)


@dataclass(frozen=True)
class CommandZigZag:
    """Zig-zag: reverse the turn command (a rudder, or a twin's differential) at the check heading change."""

    layout: str
    turn: float
    check_deg: float
    propulsion: float
    duration_s: float = 120.0
    approach_s: float = 5.0
    side: int = 1

    @property
    def name(self) -> str:
        a = _inputs(self.layout)
        return (f"zigzag_{a.turn_input.tag(self.turn)}_{self.check_deg:g}_{_side(self.side)}_"
                f"{a.propulsion_input.tag(self.propulsion)}")

    def controller(self) -> Controller:
        return _zigzag(self.turn * _inputs(self.layout).turn_input.to_command, math.radians(self.check_deg),
                       self.propulsion, self.approach_s, self.side)


@dataclass(frozen=True)
class CommandPullOut:
    """Turn with a steady turn command, then return it to zero and watch the yaw rate decay."""

    layout: str
    turn: float
    propulsion: float
    turn_s: float = 40.0
    duration_s: float = 100.0
    approach_s: float = 5.0
    side: int = 1

    @property
    def name(self) -> str:
        a = _inputs(self.layout)
        return f"pullout_{_side(self.side)}_{a.turn_input.tag(self.turn)}_{a.propulsion_input.tag(self.propulsion)}"

    def controller(self) -> Controller:
        return _held_turn(self.turn * _inputs(self.layout).turn_input.to_command * self.side, self.propulsion,
                          self.approach_s, self.approach_s + self.turn_s)


@dataclass(frozen=True)
class CommandSpiral:
    """Spiral: turn commands from +max to -max and back (turn_input units), each held until the turn is steady."""

    layout: str
    turn_steps: tuple[float, ...]
    propulsion: float
    hold_s: float = 40.0
    approach_s: float = 5.0

    @property
    def name(self) -> str:
        return f"spiral_{_inputs(self.layout).propulsion_input.tag(self.propulsion)}"

    @property
    def duration_s(self) -> float:
        return self.approach_s + self.hold_s * len(self.turn_steps)

    def controller(self) -> Controller:
        scale = _inputs(self.layout).turn_input.to_command
        return _steps([d * scale for d in self.turn_steps], self.propulsion, self.approach_s, self.hold_s)


@dataclass(frozen=True)
class CommandRandom:
    """Persistently exciting programme: random turn and propulsion steps with random hold times (seeded); the
    propulsion stays in [0, 1]."""

    layout: str
    seed: int = 0
    propulsion: float = 0.6
    propulsion_span: float = 0.2  # propulsion commands in propulsion +/- span (-)
    turn_max: float = 0.5  # largest |turn| (turn_input units)
    hold_min_s: float = 2.0
    hold_max_s: float = 12.0
    duration_s: float = 240.0
    approach_s: float = 5.0

    @property
    def name(self) -> str:
        return f"random_{self.seed}_{_inputs(self.layout).propulsion_input.tag(self.propulsion)}"

    def schedule(self) -> np.ndarray:
        """(K, 3) rows of [start time (s), turn (steering units), propulsion]; deterministic for the seed."""
        _check(self.name, hold_min_s=(self.hold_min_s, 0.1, self.hold_max_s))
        scale = _inputs(self.layout).turn_input.to_command
        rng = np.random.default_rng(self.seed)
        rows, t = [], self.approach_s
        while t < self.duration_s:
            turn = scale * rng.uniform(-self.turn_max, self.turn_max)
            propulsion = self.propulsion + rng.uniform(-self.propulsion_span, self.propulsion_span)
            rows.append((t, turn, min(max(propulsion, 0.0), 1.0)))
            t += rng.uniform(self.hold_min_s, self.hold_max_s)
        return np.array(rows)

    def controller(self) -> Controller:
        return _table(self.schedule(), self.propulsion, self.approach_s)


def _legacy(layout: ActuatorLayout) -> bool:
    """The layout states its manoeuvres by a rudder in degrees and an engine speed in rpm (the first family)."""
    return layout.turn_input is RUDDER_DEG and layout.propulsion_input is ENGINE_RPM


def turning_circle(layout: ActuatorLayout, turn: float, propulsion: float, **extra) -> object:
    """A turning circle of the layout's family (module docstring); turn / propulsion in its input units."""
    if _legacy(layout):
        return TurningCircle(turn, propulsion, **extra)
    return CommandTurningCircle(layout.name, turn, propulsion, **extra)


def zigzag(layout: ActuatorLayout, turn: float, check_deg: float, propulsion: float, **extra) -> object:
    if _legacy(layout):
        return ZigZag(turn, check_deg, propulsion, **extra)
    return CommandZigZag(layout.name, turn, check_deg, propulsion, **extra)


def pullout(layout: ActuatorLayout, turn: float, propulsion: float, **extra) -> object:
    if _legacy(layout):
        return PullOut(turn, propulsion, **extra)
    return CommandPullOut(layout.name, turn, propulsion, **extra)


def spiral(layout: ActuatorLayout, turn_steps: tuple[float, ...], propulsion: float) -> object:
    if _legacy(layout):
        return Spiral(rudder_steps_deg=turn_steps, rpm=propulsion)
    return CommandSpiral(layout.name, turn_steps, propulsion)


def random_manoeuvre(layout: ActuatorLayout, seed: int, propulsion: float, turn_max: float, **extra) -> object:
    if _legacy(layout):
        return RandomManoeuvre(seed=seed, rpm=propulsion, rudder_max_deg=turn_max, **extra)
    return CommandRandom(layout.name, seed=seed, propulsion=propulsion, turn_max=turn_max, **extra)


def _built_turning_circle(layout: ActuatorLayout, turn: float, propulsion: float, side: int, check_deg: float,
                          seed: int, extra: Mapping[str, float]) -> object:
    return turning_circle(layout, turn, propulsion, side=side, **extra)


def _built_zigzag(layout: ActuatorLayout, turn: float, propulsion: float, side: int, check_deg: float, seed: int,
                  extra: Mapping[str, float]) -> object:
    return zigzag(layout, turn, check_deg, propulsion, side=side, **extra)


def _built_pullout(layout: ActuatorLayout, turn: float, propulsion: float, side: int, check_deg: float, seed: int,
                   extra: Mapping[str, float]) -> object:
    return pullout(layout, turn, propulsion, side=side, **extra)


def _built_spiral(layout: ActuatorLayout, turn: float, propulsion: float, side: int, check_deg: float, seed: int,
                  extra: Mapping[str, float]) -> object:
    """Steps of 1, 0.6, 0.3, 0.15 and 0 x turn, then back through the negative ones (its own step durations)."""
    steps = (turn, 0.6 * turn, 0.3 * turn, 0.15 * turn, 0.0)
    return spiral(layout, steps + tuple(-d for d in reversed(steps[:-1])), propulsion)


def _built_random(layout: ActuatorLayout, turn: float, propulsion: float, side: int, check_deg: float, seed: int,
                  extra: Mapping[str, float]) -> object:
    return random_manoeuvre(layout, seed, propulsion, turn, **extra)


@dataclass(frozen=True)
class ManoeuvreKind:
    name: str  # the data spelling: the manoeuvre names' prefix and a bag's custom_data manoeuvre_type
    option: str | None  # the command-line spelling (`replay simulate --manoeuvre`); None: never simulated
    # (layout, turn, propulsion, side, check_deg, seed, extra) -> one manoeuvre of the layout's family, turn and
    # propulsion in the layout's input units, check_deg (deg) a zig-zag's, extra e.g. duration_s; None: not simulated
    build: Callable[..., object] | None
    converted: bool  # a record `replay convert` writes from a public data set may be of this kind


# One record per manoeuvre kind: `replay simulate --manoeuvre` (option), the converted records' manoeuvre_type (name)
MANOEUVRE_KINDS: Mapping[str, ManoeuvreKind] = {k.name: k for k in (
    ManoeuvreKind("turning_circle", "turning-circle", _built_turning_circle, converted=True),
    ManoeuvreKind("zigzag", "zigzag", _built_zigzag, converted=True),
    ManoeuvreKind("pullout", "pullout", _built_pullout, converted=True),
    ManoeuvreKind("spiral", "spiral", _built_spiral, converted=False),
    ManoeuvreKind("random", "random", _built_random, converted=False),
    ManoeuvreKind("path_following", None, None, converted=True),  # the Dalian USV's records (replay/convert)
)}
SIMULATED_OPTIONS = tuple(k.option for k in MANOEUVRE_KINDS.values() if k.option is not None)  # CLI spellings
CONVERTED_KINDS = tuple(k.name for k in MANOEUVRE_KINDS.values() if k.converted)  # data spellings


def simulated_kind(option: str) -> ManoeuvreKind:
    """The kind `replay simulate --manoeuvre OPTION` names; ValueError listing SIMULATED_OPTIONS otherwise."""
    for kind in MANOEUVRE_KINDS.values():
        if kind.option == option and kind.build is not None:
            return kind
    raise ValueError(f"--manoeuvre {option!r}: expected one of {', '.join(SIMULATED_OPTIONS)}")


def sea_trial_turns(duration_s: float = 180.0) -> list[TurningCircle]:
    """Seed 000 Table 3: starboard turning tests, rudder 15/20/25 deg x engine 650/700 rpm, 3 min each."""
    return [TurningCircle(rudder, rpm, duration_s=duration_s) for rudder in (15.0, 20.0, 25.0)
            for rpm in (650.0, 700.0)]


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


def _command_programme(name: str, layout: ActuatorLayout) -> list:
    """The programmes in the layout's own units: its default turn d0 and propulsion p0 (turn_input and
    propulsion_input defaults: a 20 deg rudder or a 0.4 differential, a 0.6 throttle)."""
    d0, p0 = layout.turn_input.default, layout.propulsion_input.default
    if name == "sea_trial":
        return [CommandTurningCircle(layout.name, k * d0, p, duration_s=180.0)
                for k in (0.75, 1.0, 1.25) for p in (p0, p0 + 0.2)]
    if name == "training":
        return [CommandZigZag(layout.name, 0.5 * d0, 10.0, p0, duration_s=120.0),
                CommandZigZag(layout.name, d0, 20.0, p0 + 0.1, duration_s=120.0, side=-1),
                CommandTurningCircle(layout.name, d0, p0 + 0.05, duration_s=120.0, side=-1),
                CommandRandom(layout.name, seed=7, propulsion=p0 + 0.05, turn_max=1.25 * d0, duration_s=180.0)]
    return [CommandTurningCircle(layout.name, d0, p0, duration_s=150.0, side=1),
            CommandTurningCircle(layout.name, d0, p0, duration_s=150.0, side=-1),
            CommandZigZag(layout.name, d0, 20.0, p0, duration_s=100.0, side=1),
            CommandZigZag(layout.name, d0, 20.0, p0, duration_s=100.0, side=-1)]


TWIN_CALM_DAY_THROTTLE = 0.6  # (-) the throttle of the twin calm day's turns and zig-zag, the first straight run's
TWIN_CALM_DAY_HIGH_THROTTLE = 0.9  # (-) the second straight run's throttle (X_u from X_uu)


def twin_calm_day(layout: ActuatorLayout) -> list:
    """docs/your_boat.md "Calm-day trials per layout", twin_thrusters, in this order: turning circles each way at
    differentials 0.4 and 0.8 (throttle 0.6, 90 s), a zig-zag each way (differential 0.4, 20 deg, 100 s), straight
    runs of 60 s at throttles 0.6 and 0.9, a spin each way (differential 2 at throttle 0: one thruster full ahead,
    the other full astern; 40 s after a 5 s approach). The unknown-boat suite's calm day of this layout."""
    p0, p1 = TWIN_CALM_DAY_THROTTLE, TWIN_CALM_DAY_HIGH_THROTTLE
    runs: list = [CommandTurningCircle(layout.name, d, p0, duration_s=90.0, side=side)
                  for d in (0.4, 0.8) for side in (1, -1)]
    runs += [CommandZigZag(layout.name, 0.4, 20.0, p0, duration_s=100.0, side=side) for side in (1, -1)]
    runs += [CommandTurningCircle(layout.name, 0.0, p, duration_s=60.0) for p in (p0, p1)]
    runs += [CommandTurningCircle(layout.name, 2.0, 0.0, duration_s=40.0, approach_s=5.0, side=side)
             for side in (1, -1)]
    return runs


PROGRAMMES: dict[str, Callable[[], list]] = {  # the rudder-and-rpm programmes (the shipped bags')
    "sea_trial": sea_trial_turns,
    "training": training_runs,
    "diagnosis": diagnosis_runs,
}
# Programmes of some layouts only: name -> {layout name: its manoeuvres}
LAYOUT_PROGRAMMES: Mapping[str, Mapping[str, Callable[[ActuatorLayout], list]]] = {
    "calm_day": {"twin_thrusters": twin_calm_day},
}
PROGRAMME_NAMES = tuple(sorted({*PROGRAMMES, *LAYOUT_PROGRAMMES}))  # `replay simulate --programme`


def programme(name: str, layout: ActuatorLayout) -> list:
    """The manoeuvres of trial programme `name` (PROGRAMME_NAMES) for a boat of this layout: the rudder-and-rpm
    ones (seed 000's settings) or the same programme in the layout's own units; a LAYOUT_PROGRAMMES one for its
    layouts only (ValueError naming them otherwise)."""
    if name in LAYOUT_PROGRAMMES:
        of_layout = LAYOUT_PROGRAMMES[name]
        if layout.name not in of_layout:
            raise ValueError(f"programme {name!r} is for actuator layout(s) {', '.join(sorted(of_layout))}, "
                             f"not {layout.name}")
        return of_layout[layout.name](layout)
    if name not in PROGRAMMES:
        raise ValueError(f"unknown programme {name!r}; known: {', '.join(PROGRAMME_NAMES)}")
    return PROGRAMMES[name]() if _legacy(layout) else _command_programme(name, layout)

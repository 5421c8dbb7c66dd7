"""The hidden effects: one Effect record per physical cause, read by the simulator, the grey box, the diagnosis
and the acceptance suite (DESIGN.md "one record per concept": adding a hypothesis = one record here + the
equations of its term in models/greybox.py).

An Effect holds
  name, help      its name in the DESIGN.md diagnosis vocabulary and what it is;
  parameters      its `replay simulate` parameters (EffectParameter; units in the name, directions as compass
                  degrees), each with the simulator field it sets (SimulatorField: a field of Environment,
                  ActuatorFaults or SensorSpec and the unit conversion) and the range the hidden-effect suite
                  draws it from (Uniform, Fixed, or None: left at its default);
  terms           the grey-box terms (Term: GreyBoxRollout attribute, size, scale, bounds, start; SI) fitted
                  when it is a diagnosis hypothesis;
  readout         fitted terms (SI) -> the vocabulary (speeds, compass degrees, ...), their standard errors,
                  the terms a simulated truth implies (the inverse) and estimate-minus-truth errors;
  tolerance       the acceptance suite's absolute error bounds, keyed like the readout's errors;
  layouts         the actuator layouts (physics/actuators.py) it applies to, None for all: a rudder offset needs
                  a rudder, a thruster imbalance two thrusters. The simulator refuses an effect for a vessel it does
                  not apply to; hypothesis_names(layout) and simulated(layout) give the applicable ones;
  step_resolution the share of the model step below which a fitted time (a delay) is not named;
  track_neutral   a sensor bias whose extension moves only the start's yaw rate (the gyro's): the diagnosis asks
                  it not to raise the held-out track error rather than to lower it (analysis/diagnosis.py);
  channels        the diagnosis channels its extension alone moves (a compass offset: the two positions), () for
                  all: the diagnosis measures its evidence and share of the loss on them (analysis/diagnosis.py).

The vocabulary (simulator parameters):
  current              current_speed (m/s), current_to_deg (flows TOWARD), current_turn_rate_deg_s; a change
                       during the run: current_step_time_s (0 = none), current_step_speed (m/s),
                       current_step_to_deg (TOWARD), current_step_ramp_s
  wind                 wind_speed (m/s), wind_from_deg (blows FROM), gust_std (m/s)
  wave_drift           wave_height (m, H_s), wave_from_deg, wave_period_s
  rudder_offset        rudder_offset_deg (true rudder = reported + offset)
  yaw_rate_bias        yaw_rate_bias_deg_s (gyro bias)
  heading_offset       heading_offset_deg (compass misalignment, reported = true + offset)
  actuator_delay       actuator_delay_s (the hull responds this long after the reported rudder/rpm)
  resistance           (diagnosis only: a model error, not simulated)
  propeller_asymmetry  propeller_side_force_pct (transverse propeller force in % of thrust, + to starboard)
  thruster_imbalance   thruster_imbalance_pct (k in %: port delivers (1 + k), starboard (1 - k) of its thrust map;
                       + = the starboard side is weaker, the boat pulls to starboard at equal commands)
plus `none`, the calm-water model, which is no record.

Consumers never bind EFFECTS at import: they read `effects.EFFECTS` (or the functions below) when they run, and
what they derive from it is a RegistryView, so a record added to the registry shows everywhere.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from types import MappingProxyType
from typing import Callable, Iterator, Mapping, Protocol, Sequence, TypeVar

import numpy as np

from usv_predictor.frames import angle_difference_deg, compass_deg
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.sensors import SensorSpec
from usv_predictor.physics.simulator import ActuatorFaults

NONE = "none"  # the calm-water model: a hypothesis and a draw of the suite, but no record
DEG_TO_RAD = math.pi / 180.0  # (rad/deg), exactly what math.radians multiplies by
RAD_TO_DEG = 180.0 / math.pi  # (deg/rad), exactly what math.degrees multiplies by
SIMULATOR_TARGETS = (Environment, ActuatorFaults, SensorSpec)  # the dataclasses an effect parameter can set
CHANNELS = ("u", "v", "r", "x_n", "y_e", "psi")  # the diagnosis' residual channels, in data/segments.SIGMA's order
POSITIONS = (3, 4)  # x_n, y_e among them


# ---- the simulator side ---------------------------------------------------------------------------------

@dataclass(frozen=True)
class SimulatorField:
    """Where a parameter enters the simulator: field `name` of `target`, value = parameter * multiply / divide."""

    target: type  # one of SIMULATOR_TARGETS
    name: str  # its field
    unit: str  # the field's unit
    multiply: float = 1.0  # e.g. DEG_TO_RAD
    divide: float = 1.0  # e.g. 100 for % -> fraction

    def value(self, parameter: float) -> float:
        return parameter * self.multiply / self.divide


@dataclass(frozen=True)
class Uniform:
    """The suite draws the parameter uniformly from [low, high], times a random sign if random_sign."""

    low: float
    high: float
    random_sign: bool = False

    def sample(self, rng: np.random.Generator, sign: float) -> float:
        value = rng.uniform(self.low, self.high)
        return sign * value if self.random_sign else value

    @property
    def extremes(self) -> tuple[float, ...]:
        """The smallest and largest values it can give (both signs if the sign is random)."""
        return (-self.high, -self.low, self.low, self.high) if self.random_sign else (self.low, self.high)


@dataclass(frozen=True)
class Fixed:
    """The suite sets the parameter to this value (no random number is used)."""

    value: float

    def sample(self, rng: np.random.Generator, sign: float) -> float:
        return self.value

    @property
    def extremes(self) -> tuple[float, ...]:
        return (self.value,)


@dataclass(frozen=True)
class EffectParameter:
    """One `replay simulate` parameter of an effect: default and allowed range in `unit`."""

    name: str
    default: float
    low: float
    high: float
    unit: str
    help: str
    sets: SimulatorField  # how the simulator applies it
    draw: Uniform | Fixed | None = None  # the hidden-effect suite's range; None: left at the default

    @property
    def flag(self) -> str:
        """The `replay simulate` option that sets it: current_to_deg -> --current-to."""
        name = self.name.removesuffix("_deg").removesuffix("_deg_s").removesuffix("_s")
        return "--" + name.replace("_", "-")


# ---- the grey-box side ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Term:
    """One parameter block of a hypothesis: the grey-box term, its scale (for conditioning) and bounds (SI)."""

    name: str  # GreyBoxRollout attribute (models/greybox.py gives its equations)
    size: int  # number of values
    scale: float  # typical size, in SI units
    low: float
    high: float
    start: tuple[float, ...]  # initial value of the fit (SI)
    unit: str = ""
    settled: bool = True  # it changes a settled state (u, r at held commands); False: only when a command acts (a
    #                       delay), which the fit check's steady windows cannot see
    probe: float = 0.0  # a 2-D term's magnitude (SI) at which the fit also tries every compass direction before its
    #                     descent (analysis/diagnosis.fit_hypothesis: the loss over a direction has more than one
    #                     minimum); 0: the start alone
    staged: bool = False  # a term that refines another's shape (the waves' head-sea resistance): the fit also descends
    #                       with it held at its start first, then frees it from there, and keeps the lower loss (free
    #                       from the first step it can pull the descent into a poorer basin of the other's direction)

    def __post_init__(self) -> None:
        if len(self.start) != self.size:
            raise ValueError(f"term {self.name}: start {self.start} has {len(self.start)} values, size is {self.size}")
        if self.probe < 0.0 or (self.probe > 0.0 and (self.size != 2 or self.probe > min(-self.low, self.high))):
            raise ValueError(f"term {self.name}: probe {self.probe:g} needs a 2-D term and a magnitude within its "
                             f"bounds [{self.low:g}, {self.high:g}]")


# ---- readouts: grey-box terms (SI) <-> the vocabulary <-> the simulated truth ----------------------------

@dataclass(frozen=True)
class Comparison:
    """error[error_key] = estimate[key] - truth[parameter]; for an angle the absolute wrapped difference (deg)."""

    error_key: str
    key: str  # vocabulary key of the estimate
    parameter: str  # simulator parameter of the truth
    angle: bool = False


class Readout(Protocol):
    terms: tuple[str, ...]  # the grey-box terms it reads
    keys: tuple[str, ...]  # the vocabulary keys it gives
    comparisons: tuple[Comparison, ...]  # against the simulated truth (empty: nothing simulated to compare with)
    error_keys: tuple[str, ...]  # the keys of errors(), those of the effect's tolerance

    def read(self, terms: Mapping[str, Sequence[float]]) -> dict[str, float]: ...

    def uncertainty(self, terms: Mapping[str, Sequence[float]],
                    std: Mapping[str, Sequence[float]]) -> dict[str, float]: ...

    def terms_from_truth(self, parameters: Mapping[str, float]) -> dict[str, tuple[float, ...]]: ...

    def errors(self, found: Mapping[str, float], truth: Mapping[str, float]) -> dict[str, float]: ...


class _Compared:
    """errors() and error_keys from the readout's comparisons."""

    @property
    def error_keys(self) -> tuple[str, ...]:
        return tuple(c.error_key for c in self.comparisons)

    def errors(self, found: Mapping[str, float], truth: Mapping[str, float]) -> dict[str, float]:
        return {c.error_key: abs(angle_difference_deg(found[c.key], truth[c.parameter])) if c.angle
                else found[c.key] - truth[c.parameter] for c in self.comparisons}


@dataclass(frozen=True)
class ScalarReadout(_Compared):
    """A one-value term read as factor * term (rad -> deg: RAD_TO_DEG; fraction -> %: 100; s -> s: 1)."""

    term: str
    key: str  # vocabulary key (unit in the name)
    factor: float
    parameter: str | None = None  # the simulator parameter it estimates (same unit as key); None: not simulated

    @property
    def terms(self) -> tuple[str, ...]:
        return (self.term,)

    @property
    def keys(self) -> tuple[str, ...]:
        return (self.key,)

    @property
    def comparisons(self) -> tuple[Comparison, ...]:
        return () if self.parameter is None else (Comparison(self.key, self.key, self.parameter),)

    def read(self, terms: Mapping[str, Sequence[float]]) -> dict[str, float]:
        return {self.key: self.factor * terms[self.term][0]}

    def uncertainty(self, terms: Mapping[str, Sequence[float]], std: Mapping[str, Sequence[float]]) -> dict[str, float]:
        return {self.key: abs(self.factor) * std[self.term][0]}

    def terms_from_truth(self, parameters: Mapping[str, float]) -> dict[str, tuple[float, ...]]:
        if self.parameter is None:
            return {}
        return {self.term: (parameters[self.parameter] / self.factor,)}


def _direction_sd_deg(spread: float, magnitude: float) -> float:
    """First-order standard error (deg) of the direction of a vector of this magnitude and spread, at most 180."""
    return min(math.degrees(spread / max(magnitude, 1e-9)), 180.0)


@dataclass(frozen=True)
class VelocityReadout(_Compared):
    """A (north, east) velocity term (m/s) read as a speed and a compass direction: where it flows TOWARD
    (toward=True: a current) or where it comes FROM (toward=False: a wind, whose term is the velocity toward)."""

    term: str
    speed_parameter: str  # (m/s)
    direction_parameter: str  # (deg), TOWARD or FROM like the key
    toward: bool

    @property
    def terms(self) -> tuple[str, ...]:
        return (self.term,)

    @property
    def direction_key(self) -> str:
        return "direction_to_deg" if self.toward else "direction_from_deg"

    @property
    def keys(self) -> tuple[str, ...]:
        return ("speed_mps", self.direction_key)

    @property
    def comparisons(self) -> tuple[Comparison, ...]:
        return (Comparison("speed_mps", "speed_mps", self.speed_parameter),
                Comparison("direction_deg", self.direction_key, self.direction_parameter, angle=True))

    def read(self, terms: Mapping[str, Sequence[float]]) -> dict[str, float]:
        n, e = terms[self.term]
        return {"speed_mps": math.hypot(n, e),
                self.direction_key: compass_deg(n, e) if self.toward else compass_deg(-n, -e)}

    def uncertainty(self, terms: Mapping[str, Sequence[float]], std: Mapping[str, Sequence[float]]) -> dict[str, float]:
        spread = math.hypot(*std[self.term])
        return {"speed_mps": spread, self.direction_key: _direction_sd_deg(spread, math.hypot(*terms[self.term]))}

    def terms_from_truth(self, parameters: Mapping[str, float]) -> dict[str, tuple[float, ...]]:
        speed, direction = parameters[self.speed_parameter], math.radians(parameters[self.direction_parameter])
        sign = 1.0 if self.toward else -1.0  # the term is the velocity toward
        return {self.term: (sign * speed * math.cos(direction), sign * speed * math.sin(direction))}


@dataclass(frozen=True)
class WaveReadout(_Compared):
    """The wave term zeta_a^2 (m^2) along the direction the waves come FROM, read as H_s = 2 sqrt(|term|) (m,
    zeta_a = H_s / 2 as in physics/environment.py) and that direction (deg); with a resistance term, also the
    head-sea added-resistance coefficient C_AW (-) it holds as it is (models/greybox.py)."""

    term: str
    height_parameter: str  # H_s (m)
    direction_parameter: str  # waves come FROM (deg)
    resistance_term: str = ""  # C_AW beyond the drift series (-); "": none

    @property
    def terms(self) -> tuple[str, ...]:
        return (self.term, self.resistance_term) if self.resistance_term else (self.term,)

    @property
    def keys(self) -> tuple[str, ...]:
        resistance = ("head_sea_resistance",) if self.resistance_term else ()
        return ("significant_height_m", "direction_from_deg", *resistance)

    @property
    def comparisons(self) -> tuple[Comparison, ...]:
        return (Comparison("significant_height_m", "significant_height_m", self.height_parameter),
                Comparison("direction_deg", "direction_from_deg", self.direction_parameter, angle=True))

    def read(self, terms: Mapping[str, Sequence[float]]) -> dict[str, float]:
        n, e = terms[self.term]
        out = {"significant_height_m": 2.0 * math.sqrt(math.hypot(n, e)), "direction_from_deg": compass_deg(n, e)}
        if self.resistance_term:  # a term not given is zero, as the grey box holds it
            out["head_sea_resistance"] = float(terms.get(self.resistance_term, (0.0,))[0])
        return out

    def uncertainty(self, terms: Mapping[str, Sequence[float]], std: Mapping[str, Sequence[float]]) -> dict[str, float]:
        spread, magnitude = math.hypot(*std[self.term]), math.hypot(*terms[self.term])
        # H_s = 2 sqrt(|w|): dH = d|w| / sqrt(|w|)
        out = {"significant_height_m": spread / max(math.sqrt(magnitude), 1e-9),
               "direction_from_deg": _direction_sd_deg(spread, magnitude)}
        if self.resistance_term in std:
            out["head_sea_resistance"] = float(std[self.resistance_term][0])
        return out

    def terms_from_truth(self, parameters: Mapping[str, float]) -> dict[str, tuple[float, ...]]:
        """The simulator's waves push with its vessel's own drift series: a model of it needs no added resistance."""
        amplitude2 = (parameters[self.height_parameter] / 2.0) ** 2  # zeta_a^2 (m^2)
        direction = math.radians(parameters[self.direction_parameter])
        resistance = {self.resistance_term: (0.0,)} if self.resistance_term else {}
        return {self.term: (amplitude2 * math.cos(direction), amplitude2 * math.sin(direction)), **resistance}


# ---- the record -----------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Effect:
    name: str
    help: str
    terms: tuple[Term, ...]  # grey-box terms fitted for this hypothesis
    readout: Readout
    parameters: tuple[EffectParameter, ...] = ()  # `replay simulate` parameters; () = the simulator cannot make it
    tolerance: Mapping[str, float] = field(default_factory=dict)  # acceptance suite, absolute errors
    not_simulated: str = ""  # why the simulator has no such effect (required when parameters is empty)
    layouts: tuple[str, ...] | None = None  # actuator layouts it applies to; None: every layout
    step_resolution: Mapping[str, float] = field(default_factory=dict)  # vocabulary key (a time, s) -> the share of
    #     the model step dt below which a fitted value is not named: an identified model's own timing errors are of
    #     that size (unresolved)
    track_neutral: bool = False  # a bias of a channel the predicted track is not integrated from (the gyro's): its
    #     extension changes only the start's yaw rate, so it need not lower the held-out track error, only not raise
    #     it by more than analysis/diagnosis.TRACK_NEUTRAL (an unknown boat's -0.488 deg/s gyro bias, found to the
    #     digit with evidence 20: track error 0.465 -> 0.467 m)
    channels: tuple[int, ...] = ()  # the diagnosis channels (CHANNELS) its extension alone moves, () for all: the
    #     others are predicted exactly as without it, so their likelihood is the same with and without it and the
    #     evidence and share of the loss are measured on these (a compass offset rotates the integrated course, not
    #     the body velocities, the yaw rate or the heading the rollout starts from; test_effects.py proves each)

    def __post_init__(self) -> None:
        object.__setattr__(self, "tolerance", MappingProxyType(dict(self.tolerance)))
        object.__setattr__(self, "step_resolution", MappingProxyType(dict(self.step_resolution)))
        if not self.parameters and not self.not_simulated:
            raise ValueError(f"effect {self.name}: no simulator parameters; say why in not_simulated")
        if any(c not in range(len(CHANNELS)) for c in self.channels) or len(set(self.channels)) != len(self.channels):
            raise ValueError(f"effect {self.name}: channels {self.channels} are not distinct indices of {CHANNELS}")

    @property
    def simulated(self) -> bool:
        return bool(self.parameters)

    def applies_to(self, layout: str | None) -> bool:
        """Whether a boat of this actuator layout can have the effect (None: any layout)."""
        return layout is None or self.layouts is None or layout in self.layouts

    def outside_range(self, found: Mapping[str, float]) -> tuple[str, ...]:
        """Why fitted values (vocabulary keys, as the readout reads them) are not physical for this effect: each
        value outside the range of the simulator parameter it estimates (EffectParameter low..high, the range
        `replay simulate` admits; the grey-box terms' bounds are wider, for the fit's conditioning). Directions are
        not checked (every compass direction is physical); () when every value is within, or nothing is simulated."""
        ranges = {p.name: p for p in self.parameters}
        reasons = []
        for c in self.readout.comparisons:
            p = ranges.get(c.parameter)
            if c.angle or p is None or c.key not in found:
                continue
            if not p.low <= found[c.key] <= p.high:
                reasons.append(f"{self.name} {c.key} {found[c.key]:.3g} is outside {p.low:g}..{p.high:g} {p.unit} "
                               f"(the physical range of {p.name})")
        return tuple(reasons)

    def unresolved(self, found: Mapping[str, float], dt: float) -> tuple[str, ...]:
        """Why fitted values (vocabulary keys) cannot be told from zero at model step dt (s): each |value| under its
        step_resolution x dt; () when every value is resolved or the effect has no such limit."""
        return tuple(f"{self.name} {key} {found[key]:.3g} is under {share:g} of the {dt:g} s model step "
                     f"({share * dt:.3g} s), the size of an identified model's own timing error"
                     for key, share in self.step_resolution.items()
                     if key in found and math.isfinite(found[key]) and abs(found[key]) < share * dt)

    def acts_on(self, target: type) -> bool:
        """Whether any of its parameters sets a field of `target` (e.g. Environment: it is part of the sea)."""
        return any(p.sets.target is target for p in self.parameters)


def _registry(*effects: Effect) -> Mapping[str, Effect]:
    names = [e.name for e in effects]
    duplicates = sorted({n for n in names if names.count(n) > 1} | ({NONE} & set(names)))
    if duplicates:
        raise ValueError(f"effect names {duplicates} are taken")
    return MappingProxyType({e.name: e for e in effects})


def sea_parameter(name: str, default: float, low: float, high: float, unit: str, help: str,
                  draw: Uniform | Fixed | None = None) -> EffectParameter:
    """A parameter of the sea: it sets the Environment field of the same name, in the same unit."""
    return EffectParameter(name, default, low, high, unit, help, SimulatorField(Environment, name, unit), draw)


def scalar_effect(name: str, help: str, term: Term, vocabulary: tuple[str, float], tolerance: float,
                  parameter: EffectParameter | None = None, not_simulated: str = "",
                  layouts: tuple[str, ...] | None = None, step_resolution: float = 0.0,
                  track_neutral: bool = False) -> Effect:
    """An effect of one scalar term read as one vocabulary value: vocabulary = (key, factor), see ScalarReadout;
    step_resolution: Effect.step_resolution of that value (0: none); track_neutral: Effect.track_neutral."""
    key, factor = vocabulary
    readout = ScalarReadout(term.name, key, factor, None if parameter is None else parameter.name)
    return Effect(name, help, terms=(term,), readout=readout, parameters=() if parameter is None else (parameter,),
                  tolerance={key: tolerance} if parameter is not None else {}, not_simulated=not_simulated,
                  layouts=layouts, step_resolution={key: step_resolution} if step_resolution else {},
                  track_neutral=track_neutral)


RUDDER_LAYOUTS = ("rudder_propeller", "rudder_throttle", "rudder_only")  # a rudder behind an MMG propeller
# the fit's bound of the head-sea added-resistance coefficient C_AW (-, in 0.5 rho g zeta_a^2 L): total reflection on
# a blunt bow gives B / L (Faltinsen 1990 sec. 5), and measured added resistance peaks at several times its
# short-wave value where the waves are about as long as the hull
WAVE_RESISTANCE_MAX = 2.0


EFFECTS: Mapping[str, Effect] = _registry(
    Effect(
        "current", "a water current: the hull moves with the water, the track drifts toward the current",
        terms=(Term("current_ne", 2, 0.1, -3.0, 3.0, (0.0, 0.0), "m/s"),),  # velocity north/east
        readout=VelocityReadout("current_ne", "current_speed", "current_to_deg", toward=True),
        parameters=(
            sea_parameter("current_speed", 0.3, 0.0, 3.0, "m/s", "current speed", Uniform(0.1, 0.6)),
            sea_parameter("current_to_deg", 90.0, 0.0, 360.0, "deg", "direction the current flows toward",
                          Uniform(0.0, 360.0)),
            sea_parameter("current_turn_rate_deg_s", 0.0, -0.5, 0.5, "deg/s", "slow turning of the current"),
            sea_parameter("current_step_time_s", 0.0, 0.0, 86400.0, "s",
                          "time into the run at which the current changes to the step's speed and direction "
                          "(0: no step)"),
            sea_parameter("current_step_speed", 0.0, 0.0, 3.0, "m/s", "current speed after the step"),
            sea_parameter("current_step_to_deg", 0.0, 0.0, 360.0, "deg",
                          "direction the current flows toward after the step"),
            sea_parameter("current_step_ramp_s", 10.0, 0.1, 600.0, "s",
                          "the step is a linear blend of the two current velocities over this time"),
        ),
        tolerance={"speed_mps": 0.05, "direction_deg": 10.0},  # (m/s), (deg)
    ),
    Effect(
        "wind", "wind: air loads on the superstructure from the apparent wind",
        terms=(Term("wind_ne", 2, 2.0, -40.0, 40.0, (0.5, 0.5), "m/s", probe=8.0),),  # velocity (toward) north/east;
        #     probed at 8 m/s (the middle of the acceptance suite's 5-15 m/s): the air loads' coefficients over the
        #     apparent wind angle give the loss more than one minimum over the direction (the Otter's 7.1 and 7.6 m/s
        #     winds of bench_diagnosis.py, named wave drift before the probe, are named wind with it)
        readout=VelocityReadout("wind_ne", "wind_speed", "wind_from_deg", toward=False),
        parameters=(
            sea_parameter("wind_speed", 8.0, 0.0, 30.0, "m/s", "mean true wind speed", Uniform(5.0, 15.0)),
            sea_parameter("wind_from_deg", 0.0, 0.0, 360.0, "deg", "direction the wind blows from",
                          Uniform(0.0, 360.0)),
            sea_parameter("gust_std", 1.0, 0.0, 10.0, "m/s", "gust standard deviation", Fixed(1.0)),
        ),
        tolerance={"speed_mps": 2.0, "direction_deg": 20.0},  # (m/s), (deg)
    ),
    Effect(
        "wave_drift", "waves: the mean second-order wave drift force and moment",
        terms=(Term("wave_ne", 2, 0.02, -4.0, 4.0, (0.01, 0.01), "m^2", probe=0.25),  # zeta_a^2 along the direction
               #     FROM; probed at 0.25 m^2 (H_s 1 m, within the suite's 0.8-1.5 m): the drift coefficients'
               #     harmonics of the encounter angle give the loss more than one minimum over the direction
               #     (bench_diagnosis.py --vessel otter, draw 19: from the start 0.64 m from 329 deg, loss 677; the
               #     truth 1.17 m from 171 deg, 47.6)
               Term("wave_resistance", 1, 0.1, 0.0, WAVE_RESISTANCE_MAX, (0.0,), "-", staged=True)),  # C_AW beyond
        #     the drift series (models/greybox.py): a description's short-wave drift (physics/empirical.py) has almost
        #     no head-sea surge force, the added resistance of a real bow in waves (docs/results/unknown_boats.md);
        #     staged: free from the probes, one fold of the walkthrough's sea trial ended at C_AW 2 and waves from 83
        #     deg (loss 25.3), held at 0 first at 148 deg (12.1)
        readout=WaveReadout("wave_ne", "wave_height", "wave_from_deg", resistance_term="wave_resistance"),
        parameters=(
            sea_parameter("wave_height", 0.5, 0.0, 4.0, "m", "significant wave height", Uniform(0.8, 1.5)),
            sea_parameter("wave_from_deg", 0.0, 0.0, 360.0, "deg", "direction the waves come from",
                          Uniform(0.0, 360.0)),
            sea_parameter("wave_period_s", 3.0, 1.0, 15.0, "s", "peak period", Fixed(3.0)),
        ),
        tolerance={"significant_height_m": 0.4, "direction_deg": 30.0},  # (m), (deg)
    ),
    scalar_effect("rudder_offset", "a misaligned rudder: the true rudder is the reported one plus an offset",
                  Term("rudder_offset", 1, 0.01, -0.2, 0.2, (0.0,), "rad"), ("offset_deg", RAD_TO_DEG), 0.5,  # (deg)
                  EffectParameter("rudder_offset_deg", 2.0, -10.0, 10.0, "deg", "true minus reported rudder",
                                  SimulatorField(ActuatorFaults, "rudder_offset_rad", "rad", multiply=DEG_TO_RAD),
                                  Uniform(1.0, 4.0, random_sign=True)), layouts=RUDDER_LAYOUTS),
    scalar_effect("yaw_rate_bias", "a gyro bias: the measured yaw rate is the true one plus a constant",
                  Term("yaw_rate_bias", 1, 0.002, -0.1, 0.1, (0.0,), "rad/s"), ("bias_deg_s", RAD_TO_DEG), 0.1,
                  EffectParameter("yaw_rate_bias_deg_s", 0.5, -5.0, 5.0, "deg/s", "gyro bias",  # tolerance (deg/s)
                                  SimulatorField(SensorSpec, "gyro_bias", "rad/s", multiply=DEG_TO_RAD),
                                  Uniform(0.2, 1.0, random_sign=True)), track_neutral=True),
    replace(scalar_effect("heading_offset", "a misaligned compass: the reported heading is the true one plus an offset",
                  Term("heading_offset", 1, 0.01, -0.6, 0.6, (0.0,), "rad"), ("offset_deg", RAD_TO_DEG), 1.0,  # (deg)
                  EffectParameter("heading_offset_deg", 3.0, -30.0, 30.0, "deg", "compass misalignment",
                                  SimulatorField(SensorSpec, "heading_offset", "rad", multiply=DEG_TO_RAD),
                                  Uniform(2.0, 8.0, random_sign=True))), channels=POSITIONS),
    scalar_effect("actuator_delay", "a delay: the hull responds this long after the reported rudder and engine speed",
                  # tolerance (s)
                  Term("actuator_delay", 1, 0.1, 0.0, 5.0, (0.2,), "s", settled=False), ("delay_s", 1.0), 0.2,
                  EffectParameter("actuator_delay_s", 0.5, 0.0, 5.0, "s", "response delay of the hull",
                                  SimulatorField(SensorSpec, "actuator_delay_s", "s"), Uniform(0.3, 1.5)),
                  # a delay under a quarter step is not named: an identified model's timing errors are that size (a
                  # clean small rudder_only boat with searched rudder factors fitted 0.024 s at a 0.25 s step and
                  # named it, docs/results/unknown_boats.md); an exact model would name smaller ones (test_diagnosis.py)
                  step_resolution=0.25),
    scalar_effect("resistance", "a resistance change: fouling, loading or a preset off (relative change of R0)",
                  Term("resistance_change", 1, 0.05, -0.8, 3.0, (0.0,), "-"), ("resistance_change_pct", 100.0), 0.0,
                  not_simulated="a model error, not a hidden effect: simulate it with a vessel whose hull R0 differs"),
    scalar_effect("propeller_asymmetry", "propeller walk: a transverse propeller force in proportion to the thrust",
                  Term("propeller_side_force", 1, 0.01, -0.3, 0.3, (0.0,), "-"),  # side force / thrust
                  ("side_force_pct", 100.0), 0.5,  # tolerance (%)
                  EffectParameter("propeller_side_force_pct", 3.0, -20.0, 20.0, "%",
                                  "transverse propeller force in % of thrust, + to starboard",
                                  SimulatorField(ActuatorFaults, "propeller_side_force", "-", divide=100.0),
                                  Uniform(2.0, 6.0, random_sign=True)), layouts=RUDDER_LAYOUTS),
    scalar_effect("thruster_imbalance", "unequal thrusters: at equal commands the port thruster delivers (1 + k) and "
                  "the starboard one (1 - k) of its thrust map (a fouled or worn propeller, a weak motor or ESC)",
                  Term("thrust_imbalance", 1, 0.02, -0.5, 0.5, (0.0,), "-"),  # k
                  ("imbalance_pct", 100.0), 1.5,  # tolerance (%)
                  EffectParameter("thruster_imbalance_pct", 10.0, -50.0, 50.0, "%",
                                  "thrust imbalance k in %: + = the starboard thruster is weaker",
                                  SimulatorField(ActuatorFaults, "thruster_imbalance", "-", divide=100.0),
                                  Uniform(5.0, 15.0, random_sign=True)), layouts=("twin_thrusters",)),
)


# ---- the online estimator (fitting/online.py) ---------------------------------------------------------------
# The grey-box terms it estimates as states, in its state order (current north/east, gyro bias, resistance change)
ONLINE_TERMS = ("current_ne", "yaw_rate_bias", "resistance_change")
# The terms its float process model takes as the model carries them: a rudder offset, the propeller side force, the
# thrust imbalance, the wind, the wave drift and its head-sea resistance (their equations: physics/dynamics.py, as
# models/greybox.py's)
FIXED_TERMS = ("rudder_offset", "propeller_side_force", "thrust_imbalance", "wind_ne", "wave_ne", "wave_resistance")


# ---- what consumers derive -------------------------------------------------------------------------------

def hypothesis_names(layout: str | None = None) -> tuple[str, ...]:
    """The diagnosis vocabulary: none, then every effect in registry order (only those that apply to `layout`)."""
    return (NONE, *(name for name, effect in EFFECTS.items() if effect.applies_to(layout)))


def simulated(layout: str | None = None) -> dict[str, Effect]:
    """The effects the simulator can make, in registry order (only those that apply to `layout`)."""
    return {name: effect for name, effect in EFFECTS.items() if effect.simulated and effect.applies_to(layout)}


def grey_box_terms() -> dict[str, Term]:
    """Every grey-box term of the registry once, in registry order (effects may share a term of one size)."""
    terms: dict[str, Term] = {}
    for effect in EFFECTS.values():
        for term in effect.terms:
            if term.name in terms and terms[term.name].size != term.size:
                raise ValueError(f"grey-box term {term.name} has size {term.size} in effect {effect.name} "
                                 f"and {terms[term.name].size} elsewhere")
            terms.setdefault(term.name, term)
    return terms


def governed_defaults(target: type) -> dict[str, float]:
    """Defaults of the fields of `target` that some effect parameter sets (the value when the effect is absent)."""
    governed = {p.sets.name for e in EFFECTS.values() for p in e.parameters if p.sets.target is target}
    return {f.name: f.default for f in fields(target) if f.name in governed}


K = TypeVar("K")
V = TypeVar("V")


class RegistryView(Mapping[K, V]):
    """A read-only mapping derived from the registry on every access: what a consumer derives from the records
    (diagnosis.HYPOTHESES, scenario.EFFECTS, hidden_effects.TOLERANCES) never goes stale."""

    def __init__(self, derive: Callable[[], Mapping[K, V]]) -> None:
        self._derive = derive

    def __getitem__(self, key: K) -> V:
        return self._derive()[key]

    def __iter__(self) -> Iterator[K]:
        return iter(self._derive())

    def __len__(self) -> int:
        return len(self._derive())

    def __repr__(self) -> str:
        return f"RegistryView({dict(self._derive())!r})"

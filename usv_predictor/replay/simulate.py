"""Simulated trials as rosbag2 recordings: what `replay simulate` does, from a typed SimulationRequest.

One bag per manoeuvre, named after it, with the default topics of config/predictor.yaml that the vessel's actuator
layout reports (rudder_angle and engine_rpm of a rudder_propeller boat, thruster_port and thruster_starboard of twin
thrusters, ...) plus the ground truth (`ground_truth/odometry`, never used for fitting). The bag's custom_data records
how it was made
(command, vessel, scenario, seed, software version), or with `blind` only a SHA-256 digest of the scenario so
that a tool under test cannot read the answer from it. A trial day starts at EPOCH_NS; the manoeuvres of a
programme follow each other GAP_S apart in time and SPACING_M apart in place, with the approach heading
turned 37 deg each, and a calm-water twin shares its sea bag's seed, time and place.
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from usv_predictor.errors import ConfigError
from usv_predictor.physics.manoeuvres import SIMULATED_OPTIONS
from usv_predictor.records import NS_PER_S

if TYPE_CHECKING:
    from usv_predictor.physics.scenario import Scenario
    from usv_predictor.physics.vessel import Vessel

KINDS = SIMULATED_OPTIONS  # --manoeuvre: the command-line spellings of physics/manoeuvres.MANOEUVRE_KINDS
DEFAULT_MANOEUVRE = "turning-circle"  # neither --programme nor --manoeuvre: one turning circle
SEAS = ("calm", "rizhao")  # calm water, or the seed 000 trial sea (current + wind + waves)
MIN_DT_S, MAX_DT_S = 0.001, 0.2  # s: the integration steps `replay simulate` accepts (RK4 is stable below 0.2 s)
SIDES = ("starboard", "port")
STORAGES = ("sqlite3", "mcap")
EPOCH_NS = 1_622_527_200 * NS_PER_S  # 2021-06-01 06:00 UTC: the simulated trial day starts here
GAP_S = 60.0  # time between consecutive manoeuvres of a programme (s)
SPACING_M = 400.0  # distance between the start points of consecutive manoeuvres (m)
HEADING_STEP_DEG = 37.0  # the approach heading turns this much from one manoeuvre of a programme to the next (deg)


# The command options of `replay simulate` (the layouts' CommandInput records) -> the SimulationRequest field.
OPTION_FIELDS = {"--rudder": "rudder_deg", "--rpm": "rpm", "--differential": "differential", "--throttle": "throttle"}


@dataclass(frozen=True)
class SimulationRequest:
    """What to simulate and where to write it. Values the vessel does not bound are checked here (ConfigError);
    the turn and propulsion commands against the vessel's layout and limits when the manoeuvres are built
    (`manoeuvres`): a rudder layout takes --rudder and --rpm (or --throttle for rudder_throttle), twin thrusters
    --differential and --throttle; None is the layout input's default."""

    output: Path  # directory for the bags
    vessel: Vessel  # the vessel, resolved once by the command (models/loading.resolve_vessel)
    vessel_label: str | None = None  # how the command named it (a preset or a vessel file), recorded in the bags'
    # custom_data `vessel`; None: the vessel's name
    programme: str | None = None  # a trial programme of usv_predictor.physics.manoeuvres.PROGRAMME_NAMES ...
    manoeuvre: str | None = None  # ... or one manoeuvre of KINDS (neither: DEFAULT_MANOEUVRE)
    rudder_deg: float | None = None  # rudder angle (deg; None: 20)
    check_deg: float | None = None  # zig-zag check angle (deg; None: the rudder angle, or 20 for a differential)
    rpm: float | None = None  # engine speed (rpm; None: 650)
    differential: float | None = None  # twin thrusters: port - starboard normalised command (-; None: 0.4)
    throttle: float | None = None  # normalised propulsion command (-; None: 0.6)
    side: str = "starboard"  # first rudder to
    duration_s: float | None = None  # (s; None: the manoeuvre's default)
    heading_deg: float = 0.0  # initial heading (deg clockwise from north)
    sea: str = "calm"  # one of SEAS
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)  # effect -> given parameters (SI
    # units of physics.scenario.EFFECTS; missing ones take their defaults), on top of the sea's
    calm_twin: bool = False  # also write the calm-water twin of each bag into output/calm
    storage: str = "sqlite3"  # rosbag2 storage, one of STORAGES
    compress: bool = True  # zstd-compress the bags
    overwrite: bool = False  # replace existing bags
    blind: bool = False  # record only a digest of the scenario in the bag metadata
    seed: int = 0  # noise, gusts, waves, random manoeuvre
    dt: float = 0.05  # integration step (s)
    command: str = "replay simulate"  # the command line recorded as provenance

    def __post_init__(self) -> None:
        if self.programme and self.manoeuvre:
            raise ConfigError("give either --programme or --manoeuvre, not both")
        if self.manoeuvre is not None and self.manoeuvre not in KINDS:
            raise ConfigError(f"--manoeuvre {self.manoeuvre!r}: expected one of {', '.join(KINDS)}")
        for name, value, allowed in (("--sea", self.sea, SEAS), ("--side", self.side, SIDES),
                                     ("--storage", self.storage, STORAGES)):
            if value not in allowed:
                raise ConfigError(f"{name} {value!r}: expected one of {', '.join(allowed)}")
        if not MIN_DT_S <= self.dt <= MAX_DT_S:  # below: an astronomical number of steps; above: unstable RK4
            raise ConfigError(f"--dt {self.dt:g} s is outside [{MIN_DT_S:g}, {MAX_DT_S:g}] s")
        if self.duration_s is not None and not 1.0 <= self.duration_s <= 3600.0:
            raise ConfigError(f"--duration {self.duration_s:g} s is outside [1, 3600] s")
        if not self.programme and self.manoeuvre == "zigzag" and not 0.0 < self.check_angle_deg <= 90.0:
            raise ConfigError(f"--check {self.check_angle_deg:g} deg is outside (0, 90] deg")

    @property
    def check_angle_deg(self) -> float:
        if self.check_deg is not None:
            return self.check_deg
        return self.rudder_deg if self.rudder_deg is not None else 20.0

    def command_value(self, option: str, default: float) -> float:
        value = getattr(self, OPTION_FIELDS[option])
        return default if value is None else float(value)


def _commands(request: SimulationRequest) -> tuple[float, float]:
    """The request's (turn, propulsion) in the units of its vessel's layout inputs, checked against its limits;
    an option of another layout is refused naming the vessel's layout."""
    vessel = request.vessel
    layout = vessel.actuator_layout
    inputs = (layout.turn_input, layout.propulsion_input)
    if None in inputs:
        raise ConfigError(f"vessel {vessel.name}: actuator layout {layout.name} cannot be simulated")
    own = {i.option for i in inputs}
    given = [option for option, name in OPTION_FIELDS.items() if getattr(request, name) is not None
             and option not in own]
    if given:
        raise ConfigError(f"{' '.join(given)} does not apply to vessel {vessel.name} (actuator layout {layout.name}); "
                          f"it takes {' and '.join(i.option for i in inputs)}")
    values = []
    for i in inputs:
        value = request.command_value(i.option, i.default)
        low, high, closed = i.limits(vessel)
        if not ((low <= value) if closed else (low < value)) or value > high:
            shown = f" {i.unit}" if i.unit == "deg" else ""  # an angle says its unit next to the value
            unit = f" {i.unit}" if i.unit != "-" else ""
            raise ConfigError(f"{i.option} {value:g}{shown} is outside {i.limited_by} {'[' if closed else '('}"
                              f"{low:g}, {high:g}]{unit}")
        values.append(value)
    return values[0], values[1]


def manoeuvres(request: SimulationRequest) -> list:
    """The manoeuvres of the request: its programme, or its one manoeuvre within its vessel's limits, stated in the
    units of the vessel's layout (physics/manoeuvres.py: a rudder and rpm, or the layout's own commands)."""
    from usv_predictor.physics import manoeuvres as mv

    layout = request.vessel.actuator_layout
    turn, propulsion = _commands(request)
    if request.programme:
        if request.programme not in mv.PROGRAMME_NAMES:
            raise ConfigError(f"--programme {request.programme!r}: expected one of {', '.join(mv.PROGRAMME_NAMES)}")
        try:
            return mv.programme(request.programme, layout)
        except ValueError as err:  # a layout programme of another layout
            raise ConfigError(f"--programme {request.programme}: vessel {request.vessel.name}: {err}") from None
    side = 1 if request.side == "starboard" else -1
    extra = {} if request.duration_s is None else {"duration_s": request.duration_s}
    kind = mv.simulated_kind(request.manoeuvre or DEFAULT_MANOEUVRE)
    assert kind.build is not None  # simulated_kind returns simulated kinds only
    return [kind.build(layout, turn, propulsion, side, request.check_angle_deg, request.seed, extra)]


def scenario_effects(sea: str, effects: Mapping[str, Mapping[str, float]]) -> dict[str, dict[str, float]]:
    """The effects of a sea (SEAS) with the given ones added on top (a given parameter replaces the sea's)."""
    from usv_predictor.physics.scenario import RIZHAO_SEA

    chosen = {name: dict(values) for name, values in (RIZHAO_SEA.items() if sea == "rizhao" else ())}
    for name, values in effects.items():
        chosen.setdefault(name, {}).update(values)
    return chosen


def simulate_bag(path: Path, manoeuvre: Any, scenario: Scenario, request: SimulationRequest, *, seed: int, index: int,
                 model: Any = None) -> dict:
    """Simulate one manoeuvre (the index-th of a programme) under `scenario` and write its bag; a summary."""
    from usv_predictor import __version__
    from usv_predictor.config import load_predictor_config
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.sensors import measure
    from usv_predictor.physics.simulator import simulate as integrate
    from usv_predictor.replay.bagio import config_topic_specs, write_bag

    model = model or ManoeuvringModel(request.vessel)
    start_ns = EPOCH_NS + int(index * (GAP_S + 300.0) * NS_PER_S)
    heading = request.heading_deg + HEADING_STEP_DEG * index  # vary the approach heading across a programme
    traj = integrate(model, manoeuvre, scenario.environment, heading_deg=heading, dt=request.dt,
                     faults=scenario.faults, seed=seed, start_ns=start_ns)
    # Manoeuvres of a trial day start at different places, along a line to the north-east.
    shifted = traj.eta.copy()
    shifted[:, 0] += SPACING_M * index
    shifted[:, 1] += SPACING_M * index
    traj = dataclasses.replace(traj, eta=shifted)
    signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=seed + 1)
    specs = config_topic_specs(load_predictor_config(), include_ground_truth=True)
    streams = [(specs[role], signals[role]) for role in specs if role in signals]
    provenance = {"generator": "usv_predictor replay simulate", "version": __version__, "command": request.command,
                  "vessel": scenario.vessel, "manoeuvre": json.dumps(dataclasses.asdict(manoeuvre)),
                  "seed": str(seed), "scenario_sha256": scenario.digest(),
                  "datum": f"{scenario.sensors.datum_lat_deg},{scenario.sensors.datum_lon_deg}"}
    if not request.blind:
        provenance["scenario"] = json.dumps(scenario.describe(), sort_keys=True)
    write_bag(path, streams, storage=request.storage, compress=request.compress, metadata=provenance,
              overwrite=request.overwrite)
    speed = math.hypot(*traj.nu[-1, :2])
    return {"bag": str(path), "manoeuvre": manoeuvre.name, "duration_s": manoeuvre.duration_s,
            "messages": int(sum(len(s) for _, s in streams)), "final_speed_mps": speed,
            "heading_change_deg": math.degrees(traj.psi_unwrapped[-1] - traj.psi_unwrapped[0]),
            "size_bytes": sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())}


def simulate(request: SimulationRequest, progress: Callable[[str], None] = lambda _: None) -> dict:
    """Every bag of the request (and their calm twins); the result of `replay simulate` (bags, scenario, digest)."""
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.scenario import make_scenario
    from usv_predictor.replay.bagio import prepare_outputs

    chosen = manoeuvres(request)
    scenario = make_scenario(request.vessel, scenario_effects(request.sea, request.effects), label=request.vessel_label)
    jobs = [(request.output / m.name, m, scenario) for m in chosen]
    if request.calm_twin:
        jobs += [(request.output / "calm" / m.name, m, scenario.calm_twin()) for m in chosen]
    prepare_outputs(request.output, [p for p, _, _ in jobs], request.overwrite)
    model = ManoeuvringModel(request.vessel)
    results = []
    for k, (path, manoeuvre, scen) in enumerate(jobs):
        index = k % len(chosen)  # a calm twin has the same seed, time and place as its sea bag
        started = time.perf_counter()
        summary = simulate_bag(path, manoeuvre, scen, request, seed=request.seed + 1000 * index, index=index,
                               model=model)
        results.append(summary)
        progress(f"[{k + 1}/{len(jobs)}] {path}  {manoeuvre.duration_s:.0f} s, {summary['messages']} messages, "
                 f"{summary['size_bytes'] / 1e6:.2f} MB ({time.perf_counter() - started:.2f} s)")
    return {"bags": results, "scenario": None if request.blind else scenario.describe(),
            "scenario_sha256": scenario.digest()}

"""Boats the tool has never seen, for the unknown-boat acceptance suite and benchmark, for every actuator layout.

One record per layout (SuiteLayout in SUITE_LAYOUTS): the presets its boats are drawn around (per size class), how
a boat is drawn, the owner's facts `replay vessel init` takes for it, the calm-day trials docs/your_boat.md asks
for, and its effect vocabulary (analysis.hidden_effects.effect_names).

rudder_propeller (and rudder_only, the same boats whose engine speed is not reported): draw_boat(rng) picks a size
class (small 3-6 m, large 12-20 m), a length in it and principal dimensions scaled from a preset (jari_usv: a
single-screw, single-rudder monohull) with a little independent spread, then multiplies every non-dimensional hull
derivative, added mass and propeller/rudder interaction factor of the preset by its own factor U(0.7, 1.3). That is
the TRUTH the simulator runs. What the tool is given is only what an owner knows: the principal dimensions, the
rudder and propeller geometry, the gearbox, the propeller's static thrust at a few engine speeds (a datasheet) and
one straight-running speed at a known engine speed (`OwnerData`, the input of `replay vessel init`,
usv_predictor.physics.empirical). The truth file is never shown to the tool.

Scaling (Froude similarity with the length ratio s = L_pp / L_pp(preset)): lengths x s, areas x s^2, masses x s^3,
times x sqrt(s), angular rates / sqrt(s); the propeller turns at n / sqrt(s) for the same engine speed (gear ratio
engine/propeller = sqrt(s)), so the trial programmes' engine speeds (650-700 rpm, physics/manoeuvres.py) give
Froude-similar speeds on every boat (Fn_L about 0.45, as the preset).

Wave drift: the preset's non-dimensional coefficients C (F = 0.5 rho g zeta_a^2 L [C_X, C_Y, C_N L]) belong to its
own wavelength-to-length ratio in the suite's waves (3 s: lambda 14 m ~ L_pp 13.5 m). A shorter boat in the same
waves sees them longer relative to itself and reflects less (the mean drift falls off as a power of k L in long
waves: e.g. as (k a)^3 on a vertical cylinder of radius a, the long-wave limit of Faltinsen 1990 ch. 5; 0 in the
short-wave limit), so the truth takes C x min(1, s)^2 (WAVE_DRIFT_EXPONENT, between the two). With that exponent
the drift per unit of the boat's weight at a given H_s is the preset's (F / (m g) ~ zeta_a^2 C / L^2): the suite's
0.8-1.5 m waves push every boat as they push the 15 m preset, where the unscaled coefficients pushed a 4 m boat
backward at 12 m/s (boat 21 of seed 2026 once the preset's yaw moment was corrected: its effect day was refused
as implausible velocities and the benchmark stopped). A longer boat keeps the preset's (s >= 1: the short-
wave bound of `vessel init` is 2.4 x above them already).

twin_thrusters: small catamarans (1-3 m) around otter, large catamarans (3-6 m) around wamv, and monohulls (1-6 m)
on otter's hydrodynamics with a monohull's beam (MONOHULL_BEAM_RATIO of the catamaran's; Fossen's Otter
derivatives are rules on the masses, Y_v = -M22 / T_sway and N_r = -M66 / T_yaw with T = 1 s (Fossen 2021 ch. 6),
not a hull form, so they serve a monohull of the same size; its cross-flow drag coefficient is Hoerner's at its
own B / (2 d), empirical.hoerner_cd). The small-craft derivatives are SI, so the Froude scaling takes each its
dimension (SMALL_CRAFT_SCALING: force s^3, speed s^1/2, rate s^-1/2, e.g. N_r (N m s) x s^4.5); then each is x
U(0.7, 1.3), as is the thruster spacing (SPACING_SPREAD, a fraction of the drawn beam) and the thrust map ahead and
astern (one factor each, both thrusters the same: a clean day is `none`). The owner knows the dimensions, the mass,
the hulls (and a catamaran's pontoon beam), the thrusters' spacing and position, their motor lag, the datasheet's
static thrust at TWIN_DATASHEET_COMMANDS and the straight-running speed at TWIN_TRIAL_COMMAND on both thrusters.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
import yaml

from usv_predictor.analysis.hidden_effects import effect_names
from usv_predictor.bounded import load_yaml
from usv_predictor.errors import ConfigError
from usv_predictor.physics import manoeuvres as mv
from usv_predictor.physics.actuators import actuator_layout
from usv_predictor.physics.empirical import OwnerData, hoerner_cd
from usv_predictor.physics.vessel import RHO_WATER, WAVE_DRIFT_SECTION, Vessel, vessel_dir, vessel_from_dict

PRESET = "jari_usv"  # the rudder_propeller class the random hulls are drawn around
SIZE_CLASSES: Mapping[str, tuple[float, float]] = {  # L_pp range (m) of each size class
    "small": (3.0, 6.0),
    "large": (12.0, 20.0),
}
SPREAD = 0.30  # hull derivatives and interaction factors x U(1 - SPREAD, 1 + SPREAD) (-)
SHAPE_SPREAD = 0.10  # B/L, d/L and the block coefficient x U(1 -+ this) around the preset's (-)
WAVE_DRIFT_EXPONENT = 2.0  # the truth's wave-drift coefficients x min(1, s)^this (-): Froude-similar drift per weight
DATASHEET_RPM = (600.0, 1000.0, 1400.0)  # engine speeds (rpm) of the static-thrust points handed to vessel init
TRIAL_RPM = 650.0  # the engine speed of the diagnosis programme: the owner's known straight-running speed (rpm)
# the sections and keys multiplied by their own random factor (non-dimensional, MMG)
PERTURBED: Mapping[str, tuple[str, ...]] = {
    "added_mass": ("m_x", "m_y", "J_z"),
    "hull": ("R0", "X_vv", "X_vr", "X_rr", "X_vvvv", "Y_v", "Y_r", "Y_vvv", "Y_vvr", "Y_vrr", "Y_rrr",
             "N_v", "N_r", "N_vvv", "N_vvr", "N_vrr", "N_rrr"),
    "propeller": ("t_P", "w_P0"),
    "rudder": ("t_R", "a_H", "x_H", "epsilon", "kappa", "l_R", "gamma_R"),  # gamma_R: one factor, both signs
}
# twin_thrusters: the Froude-scaling exponent of each SI small-craft coefficient (value x s^this; force ~ s^3,
# moment ~ s^4, speed ~ s^0.5, yaw rate ~ s^-0.5, mass ~ s^3, inertia ~ s^5), every one also x U(1 -+ SPREAD)
SMALL_CRAFT_SCALING: Mapping[str, float] = {
    "X_udot": 3.0, "Y_vdot": 3.0, "N_rdot": 5.0,  # (kg), (kg), (kg m^2)
    "X_u": 2.5, "X_uu": 2.0, "Y_v": 2.5,  # (N s/m), (N s^2/m^2), (N s/m)
    "Y_r": 3.5, "N_v": 3.5, "N_r": 4.5, "N_rr": 5.0,  # (N s), (N s), (N m s), (N m s^2)
    "cross_flow_cd": 0.0,  # (-)
}
SPACING_SPREAD = 0.15  # thruster spacing / beam x U(1 -+ this) around the preset's (-)
MONOHULL_BEAM_RATIO = 0.6  # a twin-thruster monohull's beam / the catamaran preset's (otter: B/L 0.54 -> 0.32) (-)
TWIN_DATASHEET_COMMANDS = (-1.0, -0.75, -0.5, -0.25, 0.25, 0.5, 0.75, 1.0)  # normalised commands of the datasheet
TWIN_TRIAL_COMMAND = 0.6  # both thrusters: the diagnosis programme's throttle, the owner's known speed (-)


@dataclass(frozen=True)
class SizeClass:
    """One size class of a layout: the preset its boats are drawn around and their length range."""

    preset: str  # config/vessels/<preset>.yaml
    L_pp_m: tuple[float, float]  # length range (m)
    hulls: int = 1  # what the owner tells `vessel init` (--hulls): 1 monohull, 2 catamaran
    beam_ratio: float = 1.0  # the boat's beam / the preset's Froude-scaled beam (a monohull on a catamaran's preset)


@dataclass(frozen=True)
class CalmTrial:
    """One manoeuvre of a calm day the suite simulates itself (its bag's name and the manoeuvre)."""

    bag: str
    manoeuvre: Any  # a physics.manoeuvres manoeuvre of the layout's family


@dataclass(frozen=True)
class UnknownBoat:
    """One random boat: the truth (a vessel description for the simulator) and what its owner knows."""

    name: str
    size_class: str
    scale: float  # L_pp / L_pp of the preset (-)
    truth: dict[str, Any]  # the vessel YAML the simulator runs (never given to the tool)
    factors: dict[str, float]  # "section.key" -> the random factor applied to the preset's value (-)
    owner: OwnerData  # the input of `replay vessel init` (principal dimensions, geometry, datasheet, one speed)
    layout: str = "rudder_propeller"  # the actuator layout (a key of SUITE_LAYOUTS)

    def truth_vessel(self) -> Vessel:
        return vessel_from_dict(self.truth, source=f"unknown boat {self.name}")

    def write_truth(self, path: Path) -> Path:
        """The truth as a vessel YAML the simulator loads (`replay simulate --vessel PATH`)."""
        from usv_predictor.atomic import write_text_atomic

        write_text_atomic(Path(path), yaml.safe_dump(self.truth, sort_keys=False), "truth vessel")
        return Path(path)

    def vessel_init_argv(self, output: Path) -> list[str]:
        """`replay vessel init` arguments giving exactly `owner` (what a user would type): the layout's owner's
        facts (SuiteLayout.owner_options) in their order, then the datasheet's points."""
        o = self.owner
        argv = ["vessel", "init", "--name", o.name, "--layout", o.layout]
        for option, attribute in SUITE_LAYOUTS[self.layout].owner_options:
            value = getattr(o, attribute)
            if value is None:  # not known to this owner (a monohull's pontoon beam)
                continue
            argv += [option, value if isinstance(value, str) else f"{value:.6g}"]
        argv += ["--output", str(output)]
        for command, newtons in o.thrust_points:
            # an astern point as --thrust=-1:-66.7 (argparse reads `--thrust -1:...` as an option)
            point = f"{command:.6g}:{newtons:.6g}"
            argv += [f"--thrust={point}"] if command < 0 else ["--thrust", point]
        return argv


@dataclass(frozen=True)
class SuiteLayout:
    """One actuator layout of the suite: where its boats come from, what their owner knows, which calm day they run
    and which effects they hide."""

    layout: str  # physics/actuators.py layout name
    size_classes: Mapping[str, SizeClass]  # class name -> its preset and lengths
    draw: Callable[[np.random.Generator, SizeClass, float, str, str], tuple[dict[str, Any], dict[str, float]]]
    # (rng, class, L_pp, name, class name) -> (truth, factors); the random numbers after the class and the length
    owner: Callable[[Vessel, SizeClass, Mapping[str, Any], float, str], OwnerData]  # (truth, class, preset, s, name)
    owner_options: tuple[tuple[str, str], ...]  # `vessel init` option -> OwnerData field, in argv order
    trials: str  # the calm day docs/your_boat.md asks for this layout (its words)
    calm_programme: str | None = None  # a `replay simulate --programme` as the calm day ...
    calm_trials: tuple[CalmTrial, ...] = ()  # ... or these manoeuvres (replay.unknown_boats simulates them)
    structure: str = "mmg"  # `identify --structure`
    diagnosable_structures: tuple[str, ...] = ("mmg",)  # the structures `diagnose --model` takes (cv_warning's pick)
    interaction: bool = True  # `identify --interaction` applies (a rudder behind a propeller)
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def effects(self) -> tuple[str, ...]:
        """The hidden effects of the layout: none, then every simulated effect that applies to it."""
        return effect_names(self.layout)


def _preset_raw(name: str) -> dict[str, Any]:
    return load_yaml(vessel_dir() / f"{name}.yaml", "vessel description", ConfigError)


def draw_boat(rng: np.random.Generator, size_class: str | None = None, name: str = "unknown_boat",
              layout: str = "rudder_propeller") -> UnknownBoat:
    """A random boat of `layout` (a key of SUITE_LAYOUTS) and `size_class` (uniform among its classes unless given).

    The random numbers, in order: the class (unless given), the length, the three shape factors (B/L, d/L, C_b),
    then the layout's factors (rudder layouts: one per PERTURBED key in its order; twin_thrusters: one per
    SMALL_CRAFT_SCALING key, then the spacing, the thrust ahead and astern).
    """
    if layout not in SUITE_LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; known: {tuple(SUITE_LAYOUTS)}")
    record = SUITE_LAYOUTS[layout]
    classes = tuple(record.size_classes)
    size_class = size_class or str(rng.choice(classes))
    if size_class not in record.size_classes:
        raise ValueError(f"unknown size class {size_class!r}; known: {classes}")
    cls = record.size_classes[size_class]
    raw = _preset_raw(cls.preset)
    low, high = cls.L_pp_m
    L = float(rng.uniform(low, high))
    s = L / raw["geometry"]["L_pp"]
    truth, factors = record.draw(rng, cls, L, name, size_class)
    vessel = vessel_from_dict(truth, source=f"unknown boat {name}")  # checks it is a physical vessel
    return UnknownBoat(name=name, size_class=size_class, scale=s, truth=truth, factors=factors,
                       owner=record.owner(vessel, cls, raw, s, f"{name}_init"), layout=layout)


def _scaled_geometry(rng: np.random.Generator, g0: Mapping[str, Any], L: float, beam_ratio: float = 1.0
                     ) -> tuple[dict[str, float], float]:
    """The preset's geometry Froude-scaled to L_pp L, with the three shape factors drawn (B/L, d/L, C_b); and s."""
    s = L / g0["L_pp"]
    beam_f, draught_f, cb_f = (float(x) for x in rng.uniform(1 - SHAPE_SPREAD, 1 + SHAPE_SPREAD, 3))
    return {
        "L_pp": L,
        "L_oa": g0["L_oa"] * s,
        "B": g0["B"] * s * beam_f * beam_ratio,
        "d": g0["d"] * s * draught_f,
        "displacement_kg": g0["displacement_kg"] * s**3 * beam_f * draught_f * cb_f,  # (kg) C_b x cb_f
        "x_G": g0["x_G"] * s,
        "k_zz": g0["k_zz"],
    }, s


def _wave_drift(raw: Mapping[str, Any], s: float) -> dict[str, list[float]]:
    wave = min(1.0, s) ** WAVE_DRIFT_EXPONENT  # (-) the module docstring: shorter boats, relatively longer waves
    return {k: [float(c) * wave for c in v] for k, v in raw[WAVE_DRIFT_SECTION].items()}


def _draw_rudder_boat(layout: str) -> Callable[..., tuple[dict[str, Any], dict[str, float]]]:
    """The draw of a rudder-and-propeller boat (module docstring) as `layout` (rudder_propeller, rudder_only)."""

    def draw(rng: np.random.Generator, cls: SizeClass, L: float, name: str, size_class: str
             ) -> tuple[dict[str, Any], dict[str, float]]:
        raw = _preset_raw(cls.preset)
        geometry, s = _scaled_geometry(rng, raw["geometry"], L)
        factors: dict[str, float] = {}
        truth: dict[str, Any] = {key: (dict(value) if isinstance(value, dict) else value)
                                 for key, value in raw.items()}
        for section, keys in PERTURBED.items():
            for key in keys:
                f = float(rng.uniform(1 - SPREAD, 1 + SPREAD))
                factors[f"{section}.{key}"] = f
                targets = ("gamma_R_minus", "gamma_R_plus") if key == "gamma_R" else (key,)
                for target in targets:
                    truth[section][target] = float(raw[section][target]) * f
        root = math.sqrt(s)
        truth["name"] = name
        kind = "rudder-and-propeller boat" if layout == "rudder_propeller" else f"{layout} boat"
        truth["description"] = (f"unknown-boat suite: a {L:.2f} m {size_class} {kind} drawn around "
                                f"{cls.preset} (scale {s:.3f}); the simulator's truth, never given to the tool")
        truth["provenance"] = "usv_predictor.analysis.unknown_boats.draw_boat"
        if layout != raw.get("actuator_layout", "rudder_propeller"):
            truth["actuator_layout"] = layout
        truth["geometry"] = geometry
        truth["propeller"].update(D_P=raw["propeller"]["D_P"] * s, gear_ratio=raw["propeller"]["gear_ratio"] * root)
        truth["rudder"]["A_R"] = raw["rudder"]["A_R"] * s**2
        truth["actuators"].update(
            rudder_rate_deg_s=raw["actuators"]["rudder_rate_deg_s"] / root,
            rudder_time_constant_s=raw["actuators"]["rudder_time_constant_s"] * root,
            engine_time_constant_s=raw["actuators"]["engine_time_constant_s"] * root)
        truth["windage"].update(A_F=raw["windage"]["A_F"] * s**2, A_L=raw["windage"]["A_L"] * s**2)
        truth[WAVE_DRIFT_SECTION] = _wave_drift(raw, s)
        return {k: v for k, v in truth.items() if v is not None}, factors

    return draw


def _draw_twin_boat(rng: np.random.Generator, cls: SizeClass, L: float, name: str, size_class: str
                    ) -> tuple[dict[str, Any], dict[str, float]]:
    """A twin-thruster boat around the class's small-craft preset (module docstring)."""
    raw = _preset_raw(cls.preset)
    geometry, s = _scaled_geometry(rng, raw["geometry"], L, cls.beam_ratio)
    factors: dict[str, float] = {}
    hull = dict(raw["small_craft"])
    if cls.hulls == 1 and _preset_hulls(raw) == 2:  # a monohull: Hoerner's cross-flow drag at its own B / (2 d)
        hull["cross_flow_cd"] = hoerner_cd(geometry["B"] / (2.0 * geometry["d"]))
    for key, exponent in SMALL_CRAFT_SCALING.items():
        f = float(rng.uniform(1 - SPREAD, 1 + SPREAD))
        factors[f"small_craft.{key}"] = f
        hull[key] = float(hull[key]) * s**exponent * f
    spacing_f, ahead_f, astern_f = (float(x) for x in rng.uniform(1 - SPACING_SPREAD, 1 + SPACING_SPREAD, 1).tolist()
                                    + rng.uniform(1 - SPREAD, 1 + SPREAD, 2).tolist())
    factors.update({"thrusters.spacing": spacing_f, "thrusters.forward_N": ahead_f, "thrusters.reverse_N": astern_f})
    t0 = raw["thrusters"]
    spacing = t0["spacing"] / raw["geometry"]["B"] * geometry["B"] * spacing_f

    def thrust_map(m: Mapping[str, Any]) -> dict[str, Any]:
        out = dict(m, forward_N=m["forward_N"] * s**3 * ahead_f, reverse_N=m["reverse_N"] * s**3 * astern_f,
                   time_constant_s=m["time_constant_s"] * math.sqrt(s))
        if m.get("table_command"):  # the table's ahead part x the ahead factor, its astern part x the astern one
            out["table_thrust_N"] = [t * s**3 * (ahead_f if c >= 0.0 else astern_f)
                                     for c, t in zip(m["table_command"], m["table_thrust_N"])]
            out["forward_N"], out["reverse_N"] = out["table_thrust_N"][-1], -out["table_thrust_N"][0]
        return out

    kind = "catamaran" if cls.hulls == 2 else "monohull"
    truth: dict[str, Any] = {
        **{key: (dict(value) if isinstance(value, dict) else value) for key, value in raw.items()},
        "name": name,
        "description": (f"unknown-boat suite: a {L:.2f} m twin-thruster {kind} ({size_class}) drawn around "
                        f"{cls.preset} (scale {s:.3f}); the simulator's truth, never given to the tool"),
        "provenance": "usv_predictor.analysis.unknown_boats.draw_boat",
        "geometry": geometry,
        "small_craft": hull,
        "thrusters": {"spacing": spacing, "x": t0["x"] * s, "port": thrust_map(t0["port"]),
                      "starboard": thrust_map(t0["starboard"])},
    }
    truth["windage"] = dict(raw["windage"], A_F=raw["windage"]["A_F"] * s**2 * cls.beam_ratio,
                            A_L=raw["windage"]["A_L"] * s**2)
    truth[WAVE_DRIFT_SECTION] = _wave_drift(raw, s)
    return {k: v for k, v in truth.items() if v is not None}, factors


def _preset_hulls(raw: Mapping[str, Any]) -> int:
    """The preset's number of hulls: its `vessel init` demihull beam if it is a catamaran (DEMIHULL_BEAM)."""
    return 2 if raw["name"] in DEMIHULL_BEAM else 1


# a catamaran preset's pontoon beam / overall beam: otter's B_pont 0.25 m of 1.08 m (otter.yaml), wamv's 0.3464 m
# float width at its draught of 2.4 m (wamv.yaml cross_flow_cd) (-)
DEMIHULL_BEAM: Mapping[str, float] = {"otter": 0.25 / 1.08, "wamv": 0.3464 / 2.4}


def _preset_freeboard(raw: Mapping[str, Any]) -> float:
    """The preset's height above water implied by its frontal windage area A_F = B x freeboard (m)."""
    return float(raw["windage"]["A_F"]) / float(raw["geometry"]["B"])


def _rudder_owner(truth: Vessel, cls: SizeClass, raw: Mapping[str, Any], s: float, name: str) -> OwnerData:
    return owner_data(truth, freeboard=_preset_freeboard(raw) * s, owner_name=name)


def owner_data(truth: Vessel, freeboard: float, owner_name: str) -> OwnerData:
    """What the owner of `truth` (a rudder boat) knows and hands to `replay vessel init`: dimensions, mass, the
    centre of gravity, rudder and propeller geometry, the gearbox, the engine's limit, a static-thrust datasheet at
    DATASHEET_RPM (T = k0 rho n^2 D^4, n the propeller's rev/s) and the straight-running speed at TRIAL_RPM
    (measured on a calm day: the truth's own steady speed). No hull derivative, added mass or interaction factor."""
    from usv_predictor.physics.dynamics import ManoeuvringModel

    g, p, r, a = truth.geometry, truth.propeller, truth.rudder, truth.actuators
    thrust = tuple((rpm, RHO_WATER * p.k0 * (rpm / 60.0 / p.gear_ratio) ** 2 * p.D_P**4) for rpm in DATASHEET_RPM)
    speed = ManoeuvringModel(truth).straight_speed(TRIAL_RPM)
    return OwnerData(
        name=owner_name, layout=truth.layout, L_pp=g.L_pp, B=g.B, mass_kg=g.displacement_kg, d=g.d, L_oa=g.L_oa,
        x_G=g.x_G, freeboard=freeboard, rudder_area=r.A_R, rudder_span=math.sqrt(r.aspect_ratio * r.A_R),
        rudder_x=r.x_R * g.L_pp, rudder_rate_deg_s=a.rudder_rate_deg_s, rudder_max_deg=a.rudder_max_deg,
        propeller_diameter=p.D_P, propeller_x=p.x_P * g.L_pp, gear_ratio=p.gear_ratio, rpm_max=a.rpm_max,
        engine_time_constant_s=a.engine_time_constant_s, thrust_points=thrust, thrust_unit="rpm",
        speed_m_s=round(float(speed), 3), speed_command=TRIAL_RPM)


def twin_owner_data(truth: Vessel, cls: SizeClass, raw: Mapping[str, Any], s: float, name: str) -> OwnerData:
    """What the owner of a twin-thruster `truth` knows: dimensions, mass, the centre of gravity, the hulls (a
    catamaran's pontoon beam), the thrusters' spacing, position and motor lag, the datasheet's static thrust of one
    thruster at TWIN_DATASHEET_COMMANDS, the straight-running speed at TWIN_TRIAL_COMMAND on both (the truth's own
    steady speed). No hull derivative, added mass or drag coefficient."""
    from usv_predictor.physics.dynamics import ManoeuvringModel

    g, t = truth.geometry, truth.thrusters
    speed = ManoeuvringModel(truth).straight_speed(TWIN_TRIAL_COMMAND)
    demihull = DEMIHULL_BEAM[cls.preset] * g.B if cls.hulls == 2 else None
    return OwnerData(
        name=name, layout=truth.layout, L_pp=g.L_pp, B=g.B, mass_kg=g.displacement_kg, d=g.d, L_oa=g.L_oa,
        x_G=g.x_G, freeboard=_preset_freeboard(raw) * s, hulls=cls.hulls, demihull_beam=demihull,
        engine_time_constant_s=t.port.time_constant_s, thruster_spacing=t.spacing, thruster_x=t.x,
        thrust_points=tuple((c, round(t.port.thrust(c), 4)) for c in TWIN_DATASHEET_COMMANDS),
        thrust_unit="normalised", speed_m_s=round(float(speed), 3), speed_command=TWIN_TRIAL_COMMAND)


_HULL_OPTIONS = (("--lpp", "L_pp"), ("--beam", "B"), ("--mass", "mass_kg"), ("--draught", "d"),
                 ("--length-overall", "L_oa"), ("--x-g", "x_G"), ("--freeboard", "freeboard"))
RUDDER_OWNER_OPTIONS = (*_HULL_OPTIONS, ("--rudder-area", "rudder_area"), ("--rudder-span", "rudder_span"),
                        ("--rudder-x", "rudder_x"), ("--rudder-rate", "rudder_rate_deg_s"),
                        ("--propeller-diameter", "propeller_diameter"), ("--propeller-x", "propeller_x"),
                        ("--gear-ratio", "gear_ratio"), ("--rpm-max", "rpm_max"),
                        ("--engine-time-constant", "engine_time_constant_s"), ("--thrust-unit", "thrust_unit"),
                        ("--speed", "speed_m_s"), ("--at", "speed_command"))
TWIN_OWNER_OPTIONS = (*_HULL_OPTIONS, ("--hulls", "hulls"), ("--demihull-beam", "demihull_beam"),
                      ("--thruster-spacing", "thruster_spacing"),
                      ("--thruster-x", "thruster_x"), ("--engine-time-constant", "engine_time_constant_s"),
                      ("--thrust-unit", "thrust_unit"), ("--speed", "speed_m_s"), ("--at", "speed_command"))


def _straight(layout: str, propulsion: float, duration_s: float) -> Any:
    """A straight run: the turn command held at 0 (a turning circle of no turn), the propulsion at `propulsion`."""
    return mv.turning_circle(actuator_layout(layout), 0.0, propulsion, duration_s=duration_s)


def _rudder_only_trials() -> tuple[CalmTrial, ...]:
    """docs/your_boat.md "Calm-day trials per layout", rudder_only: at the trial engine speed turning circles each
    way at two rudder angles (20 deg and hard over, 35 deg) and a zig-zag each way, straight runs of 60 s at two
    engine speeds."""
    layout = actuator_layout("rudder_only")
    runs = [mv.turning_circle(layout, rudder, TRIAL_RPM, duration_s=120.0, side=side) for rudder in (20.0, 35.0)
            for side in (1, -1)]
    runs += [mv.zigzag(layout, 20.0, 20.0, TRIAL_RPM, duration_s=120.0, side=side) for side in (1, -1)]
    trials = [CalmTrial(m.name, m) for m in runs]
    trials += [CalmTrial(f"straight_{rpm:g}rpm", _straight("rudder_only", rpm, 60.0)) for rpm in (TRIAL_RPM, 700.0)]
    return tuple(trials)


def _twin_trials() -> tuple[CalmTrial, ...]:
    """docs/your_boat.md "Calm-day trials per layout", twin_thrusters: the `calm_day` programme
    (physics/manoeuvres.twin_calm_day), each bag named after its manoeuvre."""
    return tuple(CalmTrial(m.name, m) for m in mv.twin_calm_day(actuator_layout("twin_thrusters")))


_RUDDER_CLASSES = {name: SizeClass(PRESET, lengths) for name, lengths in SIZE_CLASSES.items()}

SUITE_LAYOUTS: Mapping[str, SuiteLayout] = {
    "rudder_propeller": SuiteLayout(
        layout="rudder_propeller", size_classes=_RUDDER_CLASSES, draw=_draw_rudder_boat("rudder_propeller"),
        owner=_rudder_owner, owner_options=RUDDER_OWNER_OPTIONS, calm_programme="training",
        trials="the `training` programme: zig-zags both ways (10/10 deg at 650 rpm, 20/20 deg at 700 rpm), a port "
               "turn at 675 rpm and a random run"),
    "rudder_only": SuiteLayout(
        layout="rudder_only", size_classes=_RUDDER_CLASSES, draw=_draw_rudder_boat("rudder_only"),
        owner=_rudder_owner, owner_options=RUDDER_OWNER_OPTIONS, calm_trials=_rudder_only_trials(),
        trials="turning circles each way at 20 and 35 deg (120 s) and a zig-zag each way (20/20 deg) at the trial "
               "engine speed, straight runs of 60 s at two engine speeds (650 and 700 rpm)"),
    "twin_thrusters": SuiteLayout(
        layout="twin_thrusters",
        size_classes={"small_catamaran": SizeClass("otter", (1.0, 3.0), hulls=2),
                      "large_catamaran": SizeClass("wamv", (3.0, 6.0), hulls=2),
                      "monohull": SizeClass("otter", (1.0, 6.0), hulls=1, beam_ratio=MONOHULL_BEAM_RATIO)},
        draw=_draw_twin_boat, owner=twin_owner_data, owner_options=TWIN_OWNER_OPTIONS, calm_trials=_twin_trials(),
        trials="turning circles each way at differentials 0.4 and 0.8 (throttle 0.6, 90 s), a zig-zag each way "
               "(differential 0.4, 20 deg), straight runs of 60 s at throttles 0.6 and 0.9, a spin each way "
               "(differential 2 at throttle 0: each thruster astern)",
        structure="auto", diagnosable_structures=("diagonal", "coupled"), interaction=False),
}

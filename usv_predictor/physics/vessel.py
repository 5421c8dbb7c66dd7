"""Vessel description: geometry, inertia, hull coefficients, actuators, windage, wave drift.

Presets live in config/vessels/<name>.yaml (never in code); each states its provenance. A vessel names its hull
model (`hull_model`, physics/hulls.py: default mmg) and its actuator layout (`actuator_layout`,
physics/actuators.py: default rudder_propeller); the sections it must have are geometry, windage and wave_drift,
those of its hull model and those of its layout; any other section is refused by name.

MMG sections (added_mass, hull) follow the MMG standard method (Yasukawa & Yoshimura 2015, "Introduction of MMG
standard method for ship maneuvering predictions", J. Mar. Sci. Technol. 20:37-52), non-dimensionalised with
rho, L_pp, d and the speed U: forces X' = X / (0.5 rho L d U^2), moment N' = N / (0.5 rho L^2 d U^2),
mass m' = m / (0.5 rho L^2 d), inertia I' = I / (0.5 rho L^4 d), v' = v_m / U, r' = r L / U.
The small_craft section holds Fossen's dimensional hydrodynamic derivatives (Fossen 2021 ch. 6, SNAME notation):
X = X_u u + X_|u|u |u| u + ..., so damping and added-mass derivatives are NEGATIVE (M_A = -diag(X_udot, Y_vdot,
N_rdot)); the loader refuses a positive one (a magnitude typed where a derivative belongs).

Frames: body x forward, y to starboard, z down (Fossen 2021 sec. 2.2); a thruster at y < 0 is on the port side.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import MISSING, asdict, dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any, Mapping, get_origin, get_type_hints

from usv_predictor.bounded import load_yaml
from usv_predictor.errors import ConfigError
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout, actuator_layout
from usv_predictor.physics.hulls import DEFAULT_HULL_MODEL, HullModel, hull_model

RHO_WATER = 1025.0  # sea water density (kg/m^3)
RHO_AIR = 1.225  # air density at 15 degC (kg/m^3)
GRAVITY = 9.81  # gravitational acceleration (m/s^2)


@dataclass(frozen=True)
class Geometry:
    L_pp: float  # length between perpendiculars (m)
    L_oa: float  # length overall (m)
    B: float  # beam (m)
    d: float  # mean draught (m)
    displacement_kg: float  # mass (kg)
    x_G: float  # longitudinal centre of gravity from midship, + forward (m)
    k_zz: float  # yaw radius of gyration / L_pp (-)


@dataclass(frozen=True)
class AddedMass:
    m_x: float  # surge added mass m_x' (-)
    m_y: float  # sway added mass m_y' (-)
    J_z: float  # yaw added moment of inertia J_z' (-)


@dataclass(frozen=True)
class Hull:
    """MMG hull polynomial (Yasukawa & Yoshimura 2015 eq. 5-7); all non-dimensional."""

    R0: float
    X_vv: float
    X_vr: float
    X_rr: float
    X_vvvv: float
    Y_v: float
    Y_r: float
    Y_vvv: float
    Y_vvr: float
    Y_vrr: float
    Y_rrr: float
    N_v: float
    N_r: float
    N_vvv: float
    N_vvr: float
    N_vrr: float
    N_rrr: float


@dataclass(frozen=True)
class Propeller:
    D_P: float  # propeller diameter (m)
    gear_ratio: float  # engine rpm / propeller rpm (-)
    k0: float  # K_T(J) = k0 + k1 J + k2 J^2 (-)
    k1: float
    k2: float
    t_P: float  # thrust deduction factor (-)
    w_P0: float  # wake fraction at the propeller in straight motion (-)
    x_P: float  # propeller position x_P' = x_P / L_pp (-), negative aft


@dataclass(frozen=True)
class Rudder:
    """Semi-empirical MMG rudder model (Yasukawa & Yoshimura 2015 eq. 13-16, 37-43)."""

    A_R: float  # rudder profile area (m^2)
    aspect_ratio: float  # rudder aspect ratio Lambda (-); f_alpha from Fujii's formula
    t_R: float  # steering resistance deduction factor (-)
    a_H: float  # rudder force increase factor (-)
    x_H: float  # x_H' position of the additional lateral force (-)
    x_R: float  # x_R' rudder position, -0.5 (-)
    epsilon: float  # wake ratio between propeller and rudder (-)
    kappa: float  # propeller slipstream correction (-)
    l_R: float  # l_R' effective longitudinal rudder position (-)
    gamma_R_minus: float  # flow straightening coefficient for beta_R < 0 (-)
    gamma_R_plus: float  # flow straightening coefficient for beta_R > 0 (-)
    eta: float  # propeller diameter / rudder span (-)
    lift_factor: float = 1.0  # (-) the rudder's lift gradient over Fujii's formula: 1 for a description, identified
    #                           from data by fitting/identification.py (identify_interaction)

    @property
    def f_alpha(self) -> float:
        """Rudder lift gradient coefficient: Fujii's 6.13 Lambda / (Lambda + 2.25) times lift_factor."""
        return self.lift_factor * 6.13 * self.aspect_ratio / (self.aspect_ratio + 2.25)


@dataclass(frozen=True)
class Actuators:
    rudder_max_deg: float  # mechanical rudder limit (deg)
    rudder_rate_deg_s: float  # steering gear rate limit (deg/s)
    rudder_time_constant_s: float  # servo first-order time constant (s)
    rpm_min: float  # lowest engine speed accepted (rpm)
    rpm_max: float  # highest engine speed accepted (rpm)
    engine_time_constant_s: float  # engine/propeller first-order lag (s)


@dataclass(frozen=True)
class Windage:
    """Wind loads (seed 000 eq. 12; coefficient shapes of Fossen 2021 eq. 10.40-10.42)."""

    A_F: float  # frontal projected area above water (m^2)
    A_L: float  # lateral projected area above water (m^2)
    c_x: float  # C_X = -c_x cos(gamma) (-)
    c_y: float  # C_Y =  c_y sin(gamma) (-)
    c_n: float  # C_N =  c_n sin(2 gamma) (-)


@dataclass(frozen=True)
class WaveDrift:
    """Mean second-order wave drift, Fourier series in the encounter angle (seed 000 eq. 19).

    F = 0.5 rho g zeta_a^2 L [C_X, C_Y, C_N L], C = a0/2 + sum_n a_n cos(n chi) + b_n sin(n chi),
    chi = wave-from direction - heading (0 = head seas).
    """

    a_x: tuple[float, ...]  # a0, a1, ... for C_X
    b_x: tuple[float, ...]  # b1, b2, ... for C_X
    a_y: tuple[float, ...]
    b_y: tuple[float, ...]
    a_n: tuple[float, ...]
    b_n: tuple[float, ...]


@dataclass(frozen=True)
class SmallCraftHull:
    """Fossen's small-craft hull (Fossen 2021 ch. 6; otter.py): dimensional derivatives in SNAME notation, SI.

    X_H = (X_u + X_uu |u_r|) u_r
    Y_H = Y_v v_r + Y_r r + Y_cf,  N_H = N_v v_r + N_r r + N_rr |r| r + N_cf
    with the strip-theory cross-flow drag (Fossen's crossFlowDrag, C_d from Hoerner's curve at B/2T)
    Y_cf = -0.5 rho d C_d int |v_r + x r| (v_r + x r) dx,  N_cf = -0.5 rho d C_d int x |v_r + x r| (v_r + x r) dx
    over x in [-L/2, L/2] (midpoint rule, dynamics.CROSS_FLOW_STRIPS strips; Fossen's loop takes 21 points of
    width L/20, i.e. 5 % more length). Added mass M_A = -diag(X_udot, Y_vdot, N_rdot).
    """

    X_udot: float  # surge added-mass derivative (kg), <= 0
    Y_vdot: float  # sway added-mass derivative (kg), <= 0
    N_rdot: float  # yaw added-inertia derivative (kg m^2), <= 0
    X_u: float  # linear surge damping (N s/m), <= 0
    X_uu: float  # quadratic surge damping X_|u|u (N s^2/m^2), <= 0
    Y_v: float  # linear sway damping (N s/m), <= 0
    N_r: float  # linear yaw damping (N m s), <= 0
    N_rr: float  # quadratic yaw damping N_|r|r (N m s^2), <= 0
    cross_flow_cd: float  # 2-D cross-flow drag coefficient C_d (-), >= 0; 0 = no cross-flow drag
    Y_r: float = 0.0  # sway force per yaw rate (N s), optional
    N_v: float = 0.0  # yaw moment per sway velocity (N s), optional


@dataclass(frozen=True)
class ThrustMap:
    """Static thrust of one propulsor against its normalised command c in [-1, 1] (+ ahead), and its lag.

    The command first loses its dead band c0: c' = sign(c) (|c| - c0) / (1 - c0) for |c| > c0, else 0 (so +-1
    still gives full thrust). Then either the power law
        T = forward_N c'^e (c' >= 0),  T = -reverse_N |c'|^e (c' < 0)
    (e = 2 for a command proportional to shaft speed: Fossen's T = k n|n| with k_pos, k_neg; e = 1 for a thrust
    command) or, when a table is given, the piecewise-linear curve through (table_command, table_thrust_N) (a
    datasheet curve, e.g. VRX's logistic map or Heron's table). The motor follows the command with a first-order
    lag of time_constant_s (Fossen's otter.py: n_dot = (n_c - n) / T_n); 0 = instantaneous.
    """

    forward_N: float  # thrust at c = +1 (N), > 0
    reverse_N: float  # thrust magnitude at c = -1 (N), >= 0 (a propeller astern is weaker)
    exponent: float  # e of the power law (-), in (0, 4]
    dead_band: float  # c0 (-), in [0, 0.5)
    time_constant_s: float  # first-order motor lag (s), >= 0
    table_command: tuple[float, ...] = ()  # commands (-), strictly increasing from -1 to 1; () = power law
    table_thrust_N: tuple[float, ...] = ()  # thrust at those commands (N), non-decreasing

    def __post_init__(self) -> None:
        if not (self.forward_N > 0.0 and self.reverse_N >= 0.0):
            raise ConfigError(f"forward_N must be > 0 and reverse_N >= 0 (N), got {self.forward_N:g}, "
                              f"{self.reverse_N:g}")
        if not 0.0 < self.exponent <= 4.0:
            raise ConfigError(f"exponent {self.exponent:g} is outside (0, 4]")
        if not 0.0 <= self.dead_band < 0.5:
            raise ConfigError(f"dead_band {self.dead_band:g} is outside [0, 0.5)")
        if self.time_constant_s < 0.0:
            raise ConfigError(f"time_constant_s {self.time_constant_s:g} s must be >= 0")
        c, t = self.table_command, self.table_thrust_N
        if len(c) != len(t):
            raise ConfigError(f"table_command has {len(c)} points, table_thrust_N {len(t)}")
        if c:
            if len(c) < 2 or c[0] != -1.0 or c[-1] != 1.0 or any(b <= a for a, b in zip(c, c[1:])):
                raise ConfigError(f"table_command {list(c)} must increase strictly from -1 to 1")
            if any(b < a for a, b in zip(t, t[1:])):
                raise ConfigError(f"the thrust table {list(t)} is not monotonic (non-decreasing)")
            if t[-1] != self.forward_N or -t[0] != self.reverse_N:
                raise ConfigError(f"forward_N {self.forward_N:g} / reverse_N {self.reverse_N:g} must be the table's "
                                  f"ends {t[-1]:g} / {-t[0]:g} N")

    def effective_command(self, c: float) -> float:
        """The command past the dead band, rescaled to [-1, 1] (c clipped to [-1, 1] first)."""
        c = min(max(c, -1.0), 1.0)
        a = abs(c) - self.dead_band
        if a <= 0.0:
            return 0.0
        a = a / (1.0 - self.dead_band)
        return a if c > 0.0 else -a

    def thrust(self, c: float) -> float:
        """Static thrust (N) at the (lagged) command c (-)."""
        e = self.effective_command(c)
        if self.table_command:
            return table_value(self.table_command, self.table_thrust_N, e)
        return self.forward_N * e**self.exponent if e >= 0.0 else -self.reverse_N * (-e) ** self.exponent


def table_value(xs: tuple[float, ...], ys: tuple[float, ...], x: float) -> float:
    """Piecewise-linear interpolation written as y0 + sum_k s_k clamp(x - x_k, 0, x_k+1 - x_k): the same sum in
    models/greybox.py, so both twins agree to the last bits (x within [xs[0], xs[-1]])."""
    y = ys[0]
    for k in range(len(xs) - 1):
        width = xs[k + 1] - xs[k]
        y += (ys[k + 1] - ys[k]) / width * min(max(x - xs[k], 0.0), width)
    return y


@dataclass(frozen=True)
class Thrusters:
    """Two fixed thrusters pushing along body x, symmetric about the centreline (twin_thrusters layout).

    Forces (Fossen's otter.py tau): X = T_port + T_stbd, Y = 0, N = -y_port T_port - y_stbd T_stbd
    = (spacing / 2) (T_port - T_stbd), the port thruster at y = -spacing/2 (body y to starboard): more port
    thrust turns the bow to starboard. A thrust along x makes no sway force, so `x` does not enter the 3-DOF
    loads; it is kept for the record (and for thrusters that will swivel).
    """

    spacing: float  # distance between the two thrust lines (m), > 0
    x: float  # longitudinal position of the thrusters from midship, + forward (m)
    port: ThrustMap
    starboard: ThrustMap


@dataclass(frozen=True)
class Vessel:
    name: str
    description: str
    provenance: str
    geometry: Geometry
    windage: Windage
    wave_drift: WaveDrift
    added_mass: AddedMass | None = None  # mmg
    hull: Hull | None = None  # mmg
    propeller: Propeller | None = None  # rudder layouts
    rudder: Rudder | None = None  # rudder layouts
    actuators: Actuators | None = None  # rudder layouts
    layout: str = DEFAULT_LAYOUT.name  # actuator layout (physics/actuators.py); YAML key `actuator_layout`
    hull_model_name: str = DEFAULT_HULL_MODEL.name  # hull model (physics/hulls.py); YAML key `hull_model`
    small_craft: SmallCraftHull | None = None  # small_craft
    throttle: ThrustMap | None = None  # rudder_throttle: static thrust of the propeller against its throttle
    thrusters: Thrusters | None = None  # twin_thrusters

    @property
    def actuator_layout(self) -> ActuatorLayout:
        return actuator_layout(self.layout)

    @property
    def hull_model(self) -> HullModel:
        return hull_model(self.hull_model_name)

    @property
    def sections(self) -> tuple[str, ...]:
        """The sections this vessel has: the common ones, its hull model's and its layout's (in that order)."""
        return required_sections(self.hull_model, self.actuator_layout)

    @property
    def mass(self) -> float:
        return self.geometry.displacement_kg

    @property
    def half_rho_l2_d(self) -> float:
        g = self.geometry
        return 0.5 * RHO_WATER * g.L_pp**2 * g.d

    @property
    def inertia_zz(self) -> float:
        """Yaw moment of inertia about the centre of gravity (kg m^2)."""
        return self.mass * (self.geometry.k_zz * self.geometry.L_pp) ** 2

    def added_mass_si(self) -> tuple[float, float, float]:
        """(M_A11 (kg), M_A22 (kg), M_A66 (kg m^2)) of the vessel's hull model, positive."""
        if self.small_craft is not None:
            h = self.small_craft
            return -h.X_udot, -h.Y_vdot, -h.N_rdot
        g, a = self.geometry, self.added_mass
        scale = self.half_rho_l2_d
        return a.m_x * scale, a.m_y * scale, a.J_z * scale * g.L_pp**2

    def mass_matrix(self) -> list[list[float]]:
        """M = M_RB + M_A about midship (MMG eq. 1-3 left-hand sides; Fossen 2021 eq. 6.5), SI units: the rigid
        body from the mass, x_G and k_zz, the added mass of the hull model (diagonal)."""
        g = self.geometry
        m_x, m_y, j_z = self.added_mass_si()
        m = self.mass
        return [
            [m + m_x, 0.0, 0.0],
            [0.0, m + m_y, m * g.x_G],
            [0.0, m * g.x_G, self.inertia_zz + m * g.x_G**2 + j_z],
        ]


WAVE_DRIFT_SECTION = "wave_drift"  # the vessel file's section of the mean wave-drift coefficients (WaveDrift)
# every section a vessel can have: YAML key -> record (those of the hull model and layout are required)
SECTIONS = {
    "geometry": Geometry,
    "added_mass": AddedMass,
    "hull": Hull,
    "propeller": Propeller,
    "rudder": Rudder,
    "actuators": Actuators,
    "windage": Windage,
    WAVE_DRIFT_SECTION: WaveDrift,
    "small_craft": SmallCraftHull,
    "throttle": ThrustMap,
    "thrusters": Thrusters,
}
COMMON_SECTIONS = ("geometry", "windage", WAVE_DRIFT_SECTION)  # every hull model keeps wind and wave drift
TOP_LEVEL_KEYS = ("name", "description", "provenance", "actuator_layout", "hull_model")


def required_sections(hull: HullModel, layout: ActuatorLayout) -> tuple[str, ...]:
    """The sections a vessel of this hull model and layout must have (and the only ones it may have)."""
    return tuple(dict.fromkeys((*COMMON_SECTIONS, *hull.sections, *layout.sections)))


def vessel_dir() -> Path:
    """config/vessels of the source tree or of the installed share/usv_predictor."""
    from usv_predictor.config import package_share_path  # config imports nothing of ours at module level

    return package_share_path("config", "vessels")


def available_vessels() -> list[str]:
    return sorted(p.stem for p in vessel_dir().glob("*.yaml"))


def vessel_preset_exists(name: str) -> bool:
    """True when `name` is a preset here (config/vessels/<name>.yaml), not a path."""
    if Path(name).suffix in (".yaml", ".yml") or not PRESET_NAME.match(name):
        return False
    try:
        return (vessel_dir() / f"{name}.yaml").is_file()
    except ConfigError:
        return False


PRESET_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")  # a preset's file name without .yaml: never a path


def check_vessel_name(name: Any, where: str) -> str:
    """`name` when it is a text that cannot be read as a path (no separator, no leading dot, not ending in .yaml,
    printable); ConfigError naming `where` otherwise. A vessel's name travels in model files: it must never lead
    outside the presets."""
    if not isinstance(name, str) or not name or name.startswith(".") or any(c in name for c in "/\\\0") \
            or Path(name).suffix in (".yaml", ".yml") or not name.isprintable():
        raise ConfigError(f"{where} = {_repr(name)} is not a vessel name (text without path separators, not "
                          "starting with a dot, not a .yaml file name)")
    return name


def load_vessel(name_or_path: str | Path) -> Vessel:
    """Load a preset by name (config/vessels/<name>.yaml) or from a YAML path (a name ending in .yaml/.yml)."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        return load_preset(str(name_or_path))
    return vessel_from_dict(load_yaml(path, "vessel description", ConfigError), source=str(path))


def load_preset(name: str) -> Vessel:
    """The preset config/vessels/<name>.yaml, never a path: what a name read from a file (a model's metadata) may
    load; ConfigError for a name that is no preset name (`../x`, `/tmp/x.yaml`) or no preset here."""
    if not isinstance(name, str) or not PRESET_NAME.match(name) or Path(name).suffix in (".yaml", ".yml"):
        raise ConfigError(f"vessel {_repr(name)} is not a preset name (letters, digits, '_', '.', '-'; no path)")
    path = vessel_dir() / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"unknown vessel preset {name!r}; available: {', '.join(available_vessels())}")
    return vessel_from_dict(load_yaml(path, "vessel description", ConfigError), source=str(path))


def vessel_to_dict(vessel: Vessel) -> dict[str, Any]:
    """The vessel as the plain mapping of a vessel file (YAML keys, sections of its hull model and layout, lists for
    tuples): vessel_from_dict(vessel_to_dict(v)) == v. What a model artifact embeds (models/artifact.py)."""
    out: dict[str, Any] = {"name": vessel.name, "description": vessel.description, "provenance": vessel.provenance,
                           "actuator_layout": vessel.layout, "hull_model": vessel.hull_model_name}
    for key in vessel.sections:
        out[key] = _plain(asdict(getattr(vessel, key)))
    return out


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def description_text(description: Mapping[str, Any]) -> str:
    """The canonical JSON text of a vessel description (sorted keys, no spaces): what is embedded and digested."""
    return json.dumps(description, sort_keys=True, separators=(",", ":"), allow_nan=False)


def description_sha256(description: Mapping[str, Any]) -> str:
    return hashlib.sha256(description_text(description).encode()).hexdigest()


# free text of a vessel file: two descriptions that differ only there describe the same boat
FREE_TEXT_KEYS = ("description", "provenance")


def _flatten(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, Mapping):
        out: dict[str, Any] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}{k}."))
        return out
    return {prefix.rstrip("."): value}


def description_differences(mine: Mapping[str, Any], theirs: Mapping[str, Any],
                            labels: tuple[str, str] = ("model", "given")) -> list[str]:
    """['geometry.L_pp: model 2, given 2.1', ...]: every field (dotted) of two vessel descriptions (vessel_to_dict)
    that differs, numbers to 1e-9 relative; the free text (FREE_TEXT_KEYS) is not compared."""
    a = {k: v for k, v in _flatten(mine).items() if k not in FREE_TEXT_KEYS}
    b = {k: v for k, v in _flatten(theirs).items() if k not in FREE_TEXT_KEYS}
    out = []
    for key in sorted(set(a) | set(b)):
        if key not in a or key not in b:
            out.append(f"{key}: {labels[0]} {_shown(a.get(key))}, {labels[1]} {_shown(b.get(key))}")
        elif not _same_value(a[key], b[key]):
            out.append(f"{key}: {labels[0]} {_shown(a[key])}, {labels[1]} {_shown(b[key])}")
    return out


def _same_value(x: Any, y: Any) -> bool:
    if isinstance(x, list) and isinstance(y, list):
        return len(x) == len(y) and all(_same_value(p, q) for p, q in zip(x, y))
    if _finite(x) and _finite(y):
        return math.isclose(float(x), float(y), rel_tol=1e-9, abs_tol=1e-12)
    return x == y


def _shown(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _record(cls: type, raw: Any, where: str) -> Any:
    """Build dataclass `cls` from a mapping: every field without a default present, no unknown ones; numbers
    finite, lists of numbers as tuples, nested records recursively (ConfigError naming `where`.field)."""
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{where}: expected a mapping")
    hints = get_type_hints(cls)
    names = [f.name for f in fields(cls)]
    optional = {f.name for f in fields(cls) if f.default is not MISSING or f.default_factory is not MISSING}
    missing = [n for n in names if n not in raw and n not in optional]
    extra = [n for n in raw if n not in names]
    if missing or extra:
        raise ConfigError(f"{where}: missing {missing} / unknown {extra}")
    values = {}
    for name in names:
        if name not in raw:
            continue
        value, kind = raw[name], hints[name]
        if is_dataclass(kind):
            values[name] = _record(kind, value, f"{where}.{name}")
            continue
        if get_origin(kind) is tuple:  # tuple[float, ...]: a list of numbers, and only that
            if not isinstance(value, list) or not all(_finite(x) for x in value):
                raise ConfigError(f"{where}.{name} must be a list of finite numbers, got {_repr(value)}")
            values[name] = tuple(float(x) for x in value)
        elif not _finite(value):
            raise ConfigError(f"{where}.{name} must be a finite number, got {_repr(value)}")
        else:
            values[name] = float(value)
    try:
        return cls(**values)
    except ConfigError as err:
        raise ConfigError(f"{where}: {err}") from None


def _repr(value: Any, limit: int = 80) -> str:
    """repr of a value for a message, cut to `limit` characters (a wrong value may be a whole nested document)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... (a {type(value).__name__})"


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def vessel_from_dict(raw: Mapping[str, Any], source: str = "<dict>") -> Vessel:
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{source}: expected a mapping at the top level")
    for key in TOP_LEVEL_KEYS:
        if key in raw and not isinstance(raw[key], str):
            raise ConfigError(f"{source}: {key} must be a text, got {_repr(raw[key])}")
    if "name" in raw:
        check_vessel_name(raw["name"], f"{source}: name")
    layout_name = raw.get("actuator_layout", DEFAULT_LAYOUT.name)
    try:
        layout = actuator_layout(layout_name)
    except ConfigError as err:
        raise ConfigError(f"{source}: actuator_layout: {err}") from None
    try:
        hull = hull_model(raw.get("hull_model", DEFAULT_HULL_MODEL.name))
    except ConfigError as err:
        raise ConfigError(f"{source}: hull_model: {err}") from None
    needed = required_sections(hull, layout)
    for key in needed:
        if not isinstance(raw.get(key), Mapping):
            raise ConfigError(f"{source}: missing section {key!r} (hull model {hull.name}, actuator layout "
                              f"{layout.name} need {', '.join(needed)})")
    unused = [k for k in raw if k in SECTIONS and k not in needed]
    if unused:
        raise ConfigError(f"{source}: section(s) {unused} are not used by hull model {hull.name} and actuator layout "
                          f"{layout.name} (they need {', '.join(needed)})")
    unknown = [k for k in raw if k not in SECTIONS and k not in TOP_LEVEL_KEYS]
    if unknown:
        raise ConfigError(f"{source}: unknown key(s) {unknown}; a vessel has {', '.join(TOP_LEVEL_KEYS)} and sections")
    sections = {key: _record(SECTIONS[key], raw[key], f"{source}: section {key!r}") for key in needed}
    vessel = Vessel(
        name=str(raw.get("name", Path(source).stem)),
        description=str(raw.get("description", "")),
        provenance=str(raw.get("provenance", "")),
        **sections,
        layout=layout.name,
        hull_model_name=hull.name,
    )
    _check_physical(vessel, source)
    return vessel


def _check_physical(v: Vessel, source: str) -> None:
    positive = {
        "geometry.L_pp": v.geometry.L_pp,
        "geometry.B": v.geometry.B,
        "geometry.d": v.geometry.d,
        "geometry.displacement_kg": v.geometry.displacement_kg,
        "geometry.k_zz": v.geometry.k_zz,
    }
    if v.propeller is not None:
        positive["propeller.D_P"] = v.propeller.D_P
    if v.rudder is not None:
        positive["rudder.A_R"] = v.rudder.A_R
    if v.actuators is not None:
        positive.update({"actuators.rudder_max_deg": v.actuators.rudder_max_deg,
                         "actuators.rudder_rate_deg_s": v.actuators.rudder_rate_deg_s,
                         "actuators.rpm_max": v.actuators.rpm_max})
    if v.thrusters is not None:
        positive["thrusters.spacing"] = v.thrusters.spacing
    for name, value in positive.items():
        if value <= 0.0:
            raise ConfigError(f"{source}: {name} must be > 0, got {value}")
    if v.actuators is not None and v.actuators.rpm_min > v.actuators.rpm_max:
        raise ConfigError(f"{source}: actuators.rpm_min > rpm_max")
    if v.propeller is not None and v.throttle is not None and v.propeller.k0 <= 0.0:
        raise ConfigError(f"{source}: propeller.k0 must be > 0 to turn the throttle's static thrust into a speed")
    if v.small_craft is not None:
        h = v.small_craft
        for name in ("X_udot", "Y_vdot", "N_rdot", "X_u", "X_uu", "Y_v", "N_r", "N_rr"):
            if getattr(h, name) > 0.0:
                raise ConfigError(f"{source}: small_craft.{name} = {getattr(h, name):g} must be <= 0 (a hydrodynamic "
                                  f"derivative: added mass and damping are negative)")
        if h.cross_flow_cd < 0.0:
            raise ConfigError(f"{source}: small_craft.cross_flow_cd must be >= 0, got {h.cross_flow_cd:g}")
    ((_, _, _), (_, m22, m23), (_, m32, m33)) = v.mass_matrix()
    if m22 * m33 - m23 * m32 <= 0.0:
        raise ConfigError(f"{source}: the sway-yaw mass matrix [[{m22:g}, {m23:g}], [{m32:g}, {m33:g}]] is not "
                          f"positive definite (x_G, k_zz or the added mass)")

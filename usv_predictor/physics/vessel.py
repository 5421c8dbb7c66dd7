"""Vessel description: geometry, inertia, MMG hull/rudder/propeller coefficients, actuators, windage.

Presets live in config/vessels/<name>.yaml (never in code); each states its provenance. Coefficients
follow the MMG standard method (Yasukawa & Yoshimura 2015, "Introduction of MMG standard method for ship
maneuvering predictions", J. Mar. Sci. Technol. 20:37-52), non-dimensionalised with rho, L_pp, d and the
speed U: forces X' = X / (0.5 rho L d U^2), moment N' = N / (0.5 rho L^2 d U^2), mass m' = m / (0.5 rho L^2 d),
inertia I' = I / (0.5 rho L^4 d), v' = v_m / U, r' = r L / U.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Mapping

import yaml

from usv_predictor.errors import ConfigError
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout, actuator_layout

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

    @property
    def f_alpha(self) -> float:
        """Rudder lift gradient coefficient (Fujii): 6.13 Lambda / (Lambda + 2.25)."""
        return 6.13 * self.aspect_ratio / (self.aspect_ratio + 2.25)


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
class Vessel:
    name: str
    description: str
    provenance: str
    geometry: Geometry
    added_mass: AddedMass
    hull: Hull
    propeller: Propeller
    rudder: Rudder
    actuators: Actuators
    windage: Windage
    wave_drift: WaveDrift
    layout: str = DEFAULT_LAYOUT.name  # actuator layout (physics/actuators.py); YAML key `actuator_layout`

    @property
    def actuator_layout(self) -> ActuatorLayout:
        return actuator_layout(self.layout)

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

    def mass_matrix(self) -> list[list[float]]:
        """M = M_RB + M_A about midship (MMG eq. 1-3 left-hand sides), SI units."""
        g, a = self.geometry, self.added_mass
        scale = self.half_rho_l2_d
        m_x, m_y = a.m_x * scale, a.m_y * scale
        j_z = a.J_z * scale * g.L_pp**2
        m = self.mass
        return [
            [m + m_x, 0.0, 0.0],
            [0.0, m + m_y, m * g.x_G],
            [0.0, m * g.x_G, self.inertia_zz + m * g.x_G**2 + j_z],
        ]


_SECTIONS = {
    "geometry": Geometry,
    "added_mass": AddedMass,
    "hull": Hull,
    "propeller": Propeller,
    "rudder": Rudder,
    "actuators": Actuators,
    "windage": Windage,
    "wave_drift": WaveDrift,
}


def vessel_dir() -> Path:
    """config/vessels of the source tree or of the installed share/usv_predictor."""
    from usv_predictor.config import package_share_path  # config imports nothing of ours at module level

    return package_share_path("config", "vessels")


def available_vessels() -> list[str]:
    return sorted(p.stem for p in vessel_dir().glob("*.yaml"))


def load_vessel(name_or_path: str | Path) -> Vessel:
    """Load a preset by name (config/vessels/<name>.yaml) or from a YAML path."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = vessel_dir() / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ConfigError(
                f"unknown vessel preset {str(name_or_path)!r}; available: {', '.join(available_vessels())}"
            )
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as err:
        raise ConfigError(f"cannot read vessel description {path}: {err}") from err
    return vessel_from_dict(raw, source=str(path))


def vessel_from_dict(raw: Mapping[str, Any], source: str = "<dict>") -> Vessel:
    if not isinstance(raw, Mapping):
        raise ConfigError(f"{source}: expected a mapping at the top level")
    sections = {}
    for key, cls in _SECTIONS.items():
        section = raw.get(key)
        if not isinstance(section, Mapping):
            raise ConfigError(f"{source}: missing section {key!r}")
        names = [f.name for f in fields(cls)]
        missing = [n for n in names if n not in section]
        extra = [n for n in section if n not in names]
        if missing or extra:
            raise ConfigError(f"{source}: section {key!r} missing {missing} / unknown {extra}")
        values = {}
        for name in names:
            value = section[name]
            if isinstance(value, list):
                value = tuple(float(x) for x in value)
            elif not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise ConfigError(f"{source}: {key}.{name} must be a finite number, got {value!r}")
            else:
                value = float(value)
            values[name] = value
        sections[key] = cls(**values)
    layout = raw.get("actuator_layout", DEFAULT_LAYOUT.name)
    try:
        actuator_layout(layout)
    except ConfigError as err:
        raise ConfigError(f"{source}: actuator_layout: {err}") from None
    vessel = Vessel(
        name=str(raw.get("name", Path(source).stem)),
        description=str(raw.get("description", "")),
        provenance=str(raw.get("provenance", "")),
        **sections,
        layout=str(layout),
    )
    _check_physical(vessel, source)
    return vessel


def _check_physical(v: Vessel, source: str) -> None:
    positive = {
        "geometry.L_pp": v.geometry.L_pp,
        "geometry.B": v.geometry.B,
        "geometry.d": v.geometry.d,
        "geometry.displacement_kg": v.geometry.displacement_kg,
        "propeller.D_P": v.propeller.D_P,
        "rudder.A_R": v.rudder.A_R,
        "actuators.rudder_max_deg": v.actuators.rudder_max_deg,
        "actuators.rudder_rate_deg_s": v.actuators.rudder_rate_deg_s,
        "actuators.rpm_max": v.actuators.rpm_max,
    }
    for name, value in positive.items():
        if value <= 0.0:
            raise ConfigError(f"{source}: {name} must be > 0, got {value}")
    if v.actuators.rpm_min > v.actuators.rpm_max:
        raise ConfigError(f"{source}: actuators.rpm_min > rpm_max")

"""3-DOF manoeuvring dynamics in Fossen's matrix form: a hull model, the force model of an actuator layout, wind and
waves.

    M nu_r_dot + C(nu_r) nu_r + D(nu_r) nu_r = tau_act + tau_wind + tau_wave                (Fossen 2021 eq. 6.5)
    eta_dot = R(psi) (nu_r + nu_c)                                                     (Fossen 2021 eq. 2.40)

State (marine convention, SI): [x_n, y_e, psi, u_r, v_r, r, a, b]: eta = [x_n, y_e, psi] (NED), nu_r = [u_r, v_r,
r] the velocity relative to the water in the body frame FRD at midship (body y to starboard), nu_c = R(psi)^T V_c^n
the current in the body frame (seed 000 eq. 20-22), and the two actuator states (a, b) of the layout, named by its
`commands` (physics/actuators.py): rudder_propeller and rudder_only (delta rad, engine speed rpm), rudder_throttle
(delta rad, lagged throttle command -), twin_thrusters (lagged port and starboard commands -: the motor follows its
command with the thrust map's first-order lag, Fossen's otter.py n_dot = (n_c - n) / T_n; thrust = map(level)).
Every force depends on nu_r only, so a uniform current drifts the vessel at exactly V_c.

Hull models (physics/hulls.py, one class here per record, HULL_FORCES):
  mmg          M and C(nu) nu are the left-hand sides of Yasukawa & Yoshimura 2015 eq. 4 (rigid body + added mass
               about midship); D(nu) nu = -[X_H, Y_H, N_H] the MMG hull polynomial (eq. 8; the Munk moment is in
               N_v as in captive-test derivatives).
  small_craft  Fossen 2021 ch. 6 as in his otter.py: M = M_RB + M_A with M_A = -diag(X_udot, Y_vdot, N_rdot);
               C_RB(nu_r) nu_r = [-m (v_r r + x_G r^2), m u_r r, m x_G u_r r] (3-DOF, independent of the linear
               velocity, so the relative-velocity form is exact for an irrotational current) and C_A(nu_r) nu_r =
               [Y_vdot v_r r, -X_udot u_r r, (X_udot - Y_vdot) u_r v_r] (the Munk moment); linear + quadratic
               damping and strip-theory cross-flow drag (vessel.SmallCraftHull).
Actuator force models (physics/actuators.py, one class here per layout, ACTUATOR_FORCES):
  rudder_propeller  the semi-empirical MMG rudder with propeller slipstream (eq. 13-16, 37-43) and the propeller
                    thrust (eq. 10-12) from the engine speed.
  rudder_only       the same (the simulated boat has an engine; its speed is not reported).
  rudder_throttle   the same at the engine speed n whose static thrust rho n^2 D^4 K_T(0) is the thrust map's at
                    the lagged throttle (vessel.ThrustMap; astern gives no thrust: the MMG propeller is ahead only).
  twin_thrusters    X = T_port + T_stbd, N = (b/2) (T_port - T_stbd) (port at y = -b/2), T = thrust map at the
                    lagged command; a thrust imbalance k (thruster_imbalance) multiplies port by (1 + k), starboard
                    by (1 - k): k > 0 is a weaker starboard side, the boat pulls to starboard at equal commands.
tau_wind is seed 000 eq. 12-18 on the apparent wind over ground (the increment over still air), tau_wave the mean
drift of seed 000 eq. 19 (with a head-sea added resistance -0.5 rho g zeta_a^2 L C_AW max(cos chi, 0)^2 in surge when
a model carries one: the grey box's wave_resistance term), for every hull model. N > 0 turns the bow to starboard
(r > 0): positive rudder angles and more port thrust do.

The forces and accelerations are the compiled kernel's (physics/kernel.py: loads, accelerations, with the constants
of kernel_constants), the equations the grey box's rollout integrates too, so the simulator, the grey
box and its torch twin (models/greybox.py, for autograd and the file format) are one model written twice, not three
times; what stays here is the state-level model of the simulator: the actuators' rate limits and lags, straight
running, the turning current's acceleration. ManoeuvringModel(vessel) builds the class of the vessel's hull model and
layout once (a mixin of each) and caches it.
"""
from __future__ import annotations

import math
from abc import ABCMeta, abstractmethod
from dataclasses import dataclass, fields
from typing import Any, ClassVar, NamedTuple

from usv_predictor.errors import ConfigError
from usv_predictor.physics.vessel import (
    GRAVITY,
    RHO_AIR,
    RHO_WATER,
    Hull,
    Propeller,
    Rudder,
    SmallCraftHull,
    ThrustMap,
    Vessel,
)

SPEED_FLOOR = 0.05  # speed below which non-dimensional MMG hull terms are regularised (m/s)
CROSS_FLOW_STRIPS = 20  # strips of the cross-flow drag integral over the length (-), as Fossen's crossFlowDrag


class Forces(NamedTuple):
    """Force decomposition in the body frame at midship: surge X (N), sway Y (N), yaw N (N m).

    steering: the rudder of a rudder layout, the yaw moment of the thrust difference of twin thrusters;
    propulsion: the propeller of a rudder layout, the summed thrust of twin thrusters.
    """

    hull: tuple[float, float, float]
    steering: tuple[float, float, float]
    propulsion: tuple[float, float, float]
    wind: tuple[float, float, float]
    waves: tuple[float, float, float]

    def total(self) -> tuple[float, float, float]:
        h, rd, p, w, wv = self
        return (h[0] + rd[0] + p[0] + w[0] + wv[0], h[1] + rd[1] + p[1] + w[1] + wv[1],
                h[2] + rd[2] + p[2] + w[2] + wv[2])


@dataclass(frozen=True)
class SeaLoads:
    """Environmental inputs at one instant, already resolved (NED, SI)."""

    current_n: float = 0.0  # current velocity north (m/s)
    current_e: float = 0.0  # current velocity east (m/s)
    current_accel_n: float = 0.0  # d/dt of the current north (m/s^2)
    current_accel_e: float = 0.0  # d/dt of the current east (m/s^2)
    wind_speed: float = 0.0  # true wind speed (m/s)
    wind_from: float = 0.0  # direction the wind blows from (rad, clockwise from north)
    wave_amplitude: float = 0.0  # zeta_a for the drift force (m)
    wave_from: float = 0.0  # direction the waves come from (rad)
    wave_resistance: float = 0.0  # head-sea added-resistance coefficient C_AW beyond the drift series (-): a surge
    #                               force -0.5 rho g zeta_a^2 L C_AW max(cos chi, 0)^2 (models/greybox.py)


CALM = SeaLoads()


def fourier_terms(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, tuple[tuple[int, float, float], ...]]:
    """(a0/2, ((n, a_n, b_n), ...)) from the coefficient lists a = (a0, a1, ...), b = (b1, b2, ...)."""
    order = max(len(a) - 1, len(b))
    terms = tuple((n, a[n] if n < len(a) else 0.0, b[n - 1] if n - 1 < len(b) else 0.0) for n in range(1, order + 1))
    return (0.5 * a[0] if a else 0.0), terms


def fourier(series: tuple[float, tuple[tuple[int, float, float], ...]], chi: float) -> float:
    """a0/2 + sum_n a_n cos(n chi) + b_n sin(n chi) (seed 000 eq. 19)."""
    value, terms = series
    for n, a_n, b_n in terms:
        value += a_n * math.cos(n * chi) + b_n * math.sin(n * chi)
    return value


# ---- the constants records: computed once from a Vessel, read by name by both twins -----------------------
# (ManoeuvringModel here, GreyBoxRollout in models/greybox.py: constants_of(vessel) is their one source)

@dataclass(frozen=True)
class SeaConstants:
    """Windage and wave-drift constants (SI), the same for every hull model."""

    wind_x: float  # 0.5 rho_air A_F c_x (kg/m)
    wind_y: float  # 0.5 rho_air A_L c_y (kg/m)
    wind_n: float  # 0.5 rho_air A_L L_oa c_n (kg)
    q_wave: float  # 0.5 rho g L: times zeta_a^2 gives the wave-drift force scale (N/m^2)
    drift_x: tuple[float, tuple[tuple[int, float, float], ...]]  # wave-drift Fourier series (fourier_terms)
    drift_y: tuple[float, tuple[tuple[int, float, float], ...]]
    drift_n: tuple[float, tuple[tuple[int, float, float], ...]]

    @classmethod
    def of(cls, vessel: Vessel) -> "SeaConstants":
        g, w, d = vessel.geometry, vessel.windage, vessel.wave_drift
        return cls(
            wind_x=0.5 * RHO_AIR * w.A_F * w.c_x, wind_y=0.5 * RHO_AIR * w.A_L * w.c_y,
            wind_n=0.5 * RHO_AIR * w.A_L * g.L_oa * w.c_n, q_wave=0.5 * RHO_WATER * GRAVITY * g.L_pp,
            drift_x=fourier_terms(d.a_x, d.b_x), drift_y=fourier_terms(d.a_y, d.b_y),
            drift_n=fourier_terms(d.a_n, d.b_n),
        )


def _mass_constants(vessel: Vessel) -> dict[str, float]:
    """The rigid body and the mass matrix M = M_RB + M_A about midship (Vessel.mass_matrix) in SI units."""
    ((m11, _, _), (_, m22, m23), (_, m32, m33)) = vessel.mass_matrix()
    return dict(L=vessel.geometry.L_pp, m=vessel.mass, x_G=vessel.geometry.x_G, m11=m11, m22=m22, m23=m23, m32=m32,
                m33=m33, det_vr=m22 * m33 - m23 * m32)


@dataclass(frozen=True)
class HullConstants:
    """The MMG hull: rigid body and added mass (M), the force scale and the hull polynomial, SI units."""

    L: float  # length between perpendiculars L_pp (m)
    m: float  # mass (kg)
    x_G: float  # centre of gravity from midship, + forward (m)
    m11: float  # M = M_RB + M_A about midship (kg, kg m, kg m^2), MMG eq. 1-3 left-hand sides
    m22: float
    m23: float
    m32: float
    m33: float
    det_vr: float  # m22 m33 - m23 m32 (kg^2 m^2)
    q_force: float  # 0.5 rho L d: times U^2 gives the hull force scale (kg/m)
    hull: Hull  # MMG hull polynomial coefficients (-): the identifiable hull coefficients

    @classmethod
    def of(cls, vessel: Vessel) -> "HullConstants":
        g = vessel.geometry
        return cls(**_mass_constants(vessel), q_force=0.5 * RHO_WATER * g.L_pp * g.d, hull=vessel.hull)


@dataclass(frozen=True)
class SmallCraftConstants:
    """Fossen's small-craft hull (vessel.SmallCraftHull) in SI units, with the mass matrix and cross-flow strips."""

    L: float  # length (m)
    m: float  # mass (kg)
    x_G: float  # centre of gravity from midship, + forward (m)
    m11: float  # M = M_RB + M_A about midship (kg, kg m, kg m^2)
    m22: float
    m23: float
    m32: float
    m33: float
    det_vr: float  # m22 m33 - m23 m32 (kg^2 m^2)
    munk: float  # Y_vdot - X_udot (kg): the added-mass yaw moment is munk u_r v_r (N m)
    m33_rigid: float  # I_z + m x_G^2 (kg m^2): m33 = m33_rigid - N_rdot (the torch twin adds the fitted N_rdot)
    small_craft: SmallCraftHull  # the derivatives (SI): the identifiable hull coefficients
    half_rho_d: float  # 0.5 rho d (kg/m^2)
    cross_flow: float  # half_rho_d C_d (kg/m^2): times the strip integral of |w| w (m^3/s^2) gives N
    strip_x: tuple[float, ...]  # strip centres from midship (m), midpoint rule over [-L/2, L/2]
    strip_dx: float  # strip width L / CROSS_FLOW_STRIPS (m)

    @classmethod
    def of(cls, vessel: Vessel) -> "SmallCraftConstants":
        g, h = vessel.geometry, vessel.small_craft
        dx = g.L_pp / CROSS_FLOW_STRIPS
        half_rho_d = 0.5 * RHO_WATER * g.d
        return cls(**_mass_constants(vessel), munk=h.Y_vdot - h.X_udot,
                   m33_rigid=vessel.inertia_zz + vessel.mass * g.x_G**2, small_craft=h, half_rho_d=half_rho_d,
                   cross_flow=half_rho_d * h.cross_flow_cd,
                   strip_x=tuple(-0.5 * g.L_pp + (k + 0.5) * dx for k in range(CROSS_FLOW_STRIPS)), strip_dx=dx)


@dataclass(frozen=True)
class RudderPropellerConstants:
    """The propeller, rudder and actuator constants of the rudder layouts.

    The vessel file's propeller and rudder sections as they are (their fields become the attributes of the
    same names), plus what is derived from them in SI units.
    """

    propeller: Propeller  # D_P (m), gear_ratio, K_T(J) coefficients, t_P, w_P0, x_P' (-)
    rudder: Rudder  # A_R (m^2), interaction factors, non-dimensional positions (-)
    f_alpha: float  # rudder lift gradient (Fujii) (-)
    x_H_m: float  # position of the additional lateral force x_H' L (m)
    x_R_m: float  # rudder position x_R' L (m)
    l_R_m: float  # effective longitudinal rudder position l_R' L (m)
    rudder_max: float  # mechanical rudder limit (rad)
    rudder_rate: float  # steering gear rate limit (rad/s)
    t_rudder: float  # steering gear time constant (s)
    t_engine: float  # engine time constant (s)

    @classmethod
    def of(cls, vessel: Vessel) -> "RudderPropellerConstants":
        g, rd, a = vessel.geometry, vessel.rudder, vessel.actuators
        return cls(
            propeller=vessel.propeller, rudder=rd, f_alpha=rd.f_alpha, x_H_m=rd.x_H * g.L_pp, x_R_m=rd.x_R * g.L_pp,
            l_R_m=rd.l_R * g.L_pp, rudder_max=math.radians(a.rudder_max_deg),
            rudder_rate=math.radians(a.rudder_rate_deg_s), t_rudder=a.rudder_time_constant_s,
            t_engine=a.engine_time_constant_s,
        )


@dataclass(frozen=True)
class ThrottleConstants:
    """The throttle of rudder_throttle: its thrust map and the propeller's static-thrust factor."""

    throttle: ThrustMap  # static thrust (N) against the normalised throttle, with the motor lag
    static_thrust: float  # rho D^4 K_T(0) (kg m): T0 = static_thrust n^2 for n in rev/s
    rpm_per_rev_s: float  # 60 gear_ratio: engine rpm per propeller rev/s (rpm s)

    @classmethod
    def of(cls, vessel: Vessel) -> "ThrottleConstants":
        p = vessel.propeller
        return cls(throttle=vessel.throttle, static_thrust=RHO_WATER * p.D_P**4 * p.k0,
                   rpm_per_rev_s=60.0 * p.gear_ratio)


@dataclass(frozen=True)
class TwinThrusterConstants:
    """The two fixed thrusters of twin_thrusters (vessel.Thrusters)."""

    half_spacing: float  # b/2: lever arm of each thrust about the centreline (m)
    port: ThrustMap  # thrust (N) against the port command, with its motor lag
    starboard: ThrustMap

    @classmethod
    def of(cls, vessel: Vessel) -> "TwinThrusterConstants":
        t = vessel.thrusters
        return cls(half_spacing=0.5 * t.spacing, port=t.port, starboard=t.starboard)


OPENED = (Propeller, Rudder)  # records whose fields constants_of lists under their own names


def constants_of(vessel: Vessel, records: tuple[type, ...] | None = None) -> dict[str, object]:
    """Every constant of the vessel's equations of motion by name: the records of its hull model and of its
    layout's force model and SeaConstants (or only `records`), with the vessel sections in OPENED (propeller,
    rudder) opened into their fields. The hull coefficients stay one record under the hull model's section name
    (`hull`, `small_craft`), thrust maps one record each."""
    out: dict[str, object] = {}
    for record_type in model_class(vessel).constants if records is None else records:
        record = record_type.of(vessel)
        for f in fields(record):
            value = getattr(record, f.name)
            if isinstance(value, OPENED):
                out.update({g.name: getattr(value, g.name) for g in fields(value)})
            else:
                out[f.name] = value
    return out


def kernel_constants(vessel: Vessel, dt: float = 0.5, substeps: int = 1) -> tuple[Any, Any]:
    """(ki, p) of a Vessel's calm-water equations (the float model's, physics/dynamics.ManoeuvringModel; the torch
    twin's module is packed from its attributes by models/kernel_rollout.py, which holds the same values: both come
    from dynamics.constants_of), every term zero."""
    import numpy as np

    from usv_predictor.physics import kernel as kn

    pk = kn.Packer()
    ki = pk.ki
    ki[kn.K_HULL] = {"mmg": kn.MMG, "small_craft": kn.SMALL_CRAFT}[vessel.hull_model_name]
    layout = {"rudder_propeller": kn.RUDDER_PROPELLER, "rudder_throttle": kn.RUDDER_THROTTLE,
              "rudder_only": kn.RUDDER_ONLY, "twin_thrusters": kn.TWIN_THRUSTERS}[vessel.layout]
    ki[kn.K_LAYOUT], ki[kn.K_SUBSTEPS] = layout, int(substeps)
    sea = SeaConstants.of(vessel)
    pk.set("dt", dt)
    pk.set("L_sea", vessel.geometry.L_pp)
    for name in ("wind_x", "wind_y", "wind_n", "q_wave"):
        pk.set(name, getattr(sea, name))
    hull_record = HullConstants if ki[kn.K_HULL] == kn.MMG else SmallCraftConstants
    hull = hull_record.of(vessel)
    for name in kn.MASS_CONSTANTS:
        pk.set(name, getattr(hull, name))
    section = getattr(vessel, vessel.hull_model.coefficients)
    names = [f.name for f in fields(section)]
    pk.append(kn.K_O_HULL, [float(getattr(section, n)) for n in names])
    tables = [[[half_a0, 0.0, 0.0]] + [[float(n), a, b] for n, a, b in terms]
              for half_a0, terms in (sea.drift_x, sea.drift_y, sea.drift_n)]
    drift = kn.fourier_tables(tables)
    ki[kn.K_DRIFT_ROWS] = drift.shape[1]
    pk.append(kn.K_O_DRIFT, drift)
    strips: list[float] = []
    if ki[kn.K_HULL] == kn.MMG:
        pk.set("q_force", hull.q_force)
        pk.set("speed_floor", SPEED_FLOOR)
    else:
        for name in ("m33_rigid", "half_rho_d", "strip_dx"):
            pk.set(name, getattr(hull, name))
        strips = list(hull.strip_x)
        for k, name in enumerate(kn.SMALL_CRAFT_INDICES):
            ki[kn.K_XUD + k] = names.index(name)
    ki[kn.K_N_STRIPS] = len(strips)
    pk.append(kn.K_O_STRIPS, strips)
    h = dt / substeps
    lags = np.zeros((2, 3))
    maps = []
    if layout == kn.TWIN_THRUSTERS:
        twin = TwinThrusterConstants.of(vessel)
        pk.set("half_spacing", twin.half_spacing)
        maps = [kn.thrust_map_spec(twin.port), kn.thrust_map_spec(twin.starboard)]
        times = [twin.port.time_constant_s, twin.starboard.time_constant_s]
        lags[:, :] = np.stack([times, kn.lag_factors(times, 0.5 * h), kn.lag_factors(times, h)], axis=1)
    else:
        rudder = constants_of(vessel, (RudderPropellerConstants,))
        for name in kn.RUDDER_CONSTANTS:
            pk.set(name, rudder[name])
        pk.set("rho", RHO_WATER)
        pk.set("L_act", vessel.geometry.L_pp)
        if layout == kn.RUDDER_THROTTLE:
            throttle = ThrottleConstants.of(vessel)
            pk.set("static_thrust", throttle.static_thrust)
            pk.set("rpm_per_rev_s", throttle.rpm_per_rev_s)
            maps = [kn.thrust_map_spec(throttle.throttle)]
            t = throttle.throttle.time_constant_s
            lags[0] = [t, *kn.lag_factors([t], 0.5 * h), *kn.lag_factors([t], h)]
    flat, ki[kn.K_MAP_WIDTH], (ki[kn.K_MAP_N0], ki[kn.K_MAP_N1]) = kn.thrust_maps(maps)
    pk.append(kn.K_O_MAPS, flat)
    pk.append(kn.K_O_LAG, lags)
    pk.append(kn.K_O_COEF, np.zeros(kn.N_POLY))
    ki[kn.K_MEMBERS] = 1
    return ki, pk.constants()


# ---- the float model ------------------------------------------------------------------------------------

class ManoeuvringModel(metaclass=ABCMeta):
    """The vessel's equations of motion, with every constant precomputed in SI units (constants_of).

    ManoeuvringModel(vessel) is an instance of the class that combines the vessel's hull model (HULL_FORCES) and
    its layout's force model (ACTUATOR_FORCES) with this base; see the module docstring for the equations. The
    abstract methods are what a hull model or a force model supplies: a combination that misses one cannot be
    instantiated (TypeError naming it).
    """

    constants: ClassVar[tuple[type, ...]] = ()  # the constants records of the combined class
    munk: float = 0.0  # (kg) -C_A(nu_r) nu_r in yaw = munk u_r v_r: the small-craft hull's Munk moment (MMG: in N_v)

    def __new__(cls, vessel: Vessel, *args: Any, **kwargs: Any) -> "ManoeuvringModel":
        return super().__new__(model_class(vessel) if cls is ManoeuvringModel else cls)

    def __init__(self, vessel: Vessel, propeller_side_force: float = 0.0, thrust_imbalance: float = 0.0) -> None:
        """propeller_side_force: transverse propeller force / thrust (-), + to starboard at the propeller
        (the 'paddle-wheel' effect of a single screw, or a bent shaft); 0 for a symmetric propulsor.
        thrust_imbalance: k (-), the port thruster delivers (1 + k), the starboard one (1 - k) of its map's thrust
        (k > 0: the starboard side is weaker). Each acts only in the layouts that have the propulsor."""
        self.vessel = vessel
        self.propeller_side_force = float(propeller_side_force)
        self.thrust_imbalance = float(thrust_imbalance)
        for name, value in constants_of(vessel).items():  # attributes: the state-level equations read self.<name>
            setattr(self, name, value)
        self._packed: tuple[Any, Any, Any] | None = None  # (kernel module, ki, p): built on first use (numba)

    def _kernel(self) -> tuple[Any, Any, Any]:
        """The compiled equations of this vessel (physics/kernel.py, the torch twin's kernel) with its force faults:
        (the kernel module, ki, p)."""
        if self._packed is None:
            from usv_predictor.physics import kernel

            ki, p = kernel_constants(self.vessel)
            p[kernel.T_SIDE_FORCE] = self.propeller_side_force
            p[kernel.T_THRUST_IMBALANCE] = self.thrust_imbalance
            self._packed = (kernel, ki, p)
        return self._packed

    def _sea(self, sea: SeaLoads, current: bool = True) -> tuple[float, ...]:
        """The kernel's sea tuple, every element a float: the compiled functions are typed by their arguments, and an
        int where a float was would compile another specialisation (seconds, holding the GIL) in mid-run."""
        kernel = self._kernel()[0]
        return kernel.sea_tuple(*map(float, (self.q_wave, sea.current_n if current else 0.0,
                                             sea.current_e if current else 0.0, sea.wind_speed, sea.wind_from,
                                             sea.wave_amplitude, sea.wave_from, sea.wave_resistance)))

    def __reduce__(self) -> tuple:
        """Pickled as the arguments that rebuild it (its class is made per hull model and layout)."""
        return ManoeuvringModel, (self.vessel, self.propeller_side_force, self.thrust_imbalance)

    def with_faults(self, propeller_side_force: float, thrust_imbalance: float) -> "ManoeuvringModel":
        """This model, or one of the same vessel with these force faults."""
        if (propeller_side_force, thrust_imbalance) == (self.propeller_side_force, self.thrust_imbalance):
            return self
        return ManoeuvringModel(self.vessel, propeller_side_force=propeller_side_force,
                                thrust_imbalance=thrust_imbalance)

    # ---- forces: the compiled kernel's (physics/kernel.py) -----------------------------------------------------
    def loads(self, u_r: float, v_r: float, r: float, psi: float, u: float, v: float,
              a: float, b: float, sea: SeaLoads = CALM) -> Forces:
        """All forces and moments at midship for relative (u_r, v_r) and over-ground (u, v) velocities and the
        actuator levels (a, b) of the layout (delta rad and rpm for rudder_propeller)."""
        kernel, ki, p = self._kernel()
        f = kernel.loads(ki, p, self._sea(CALM), *map(float, (psi, u_r, v_r, r, a, b)))
        wind, waves = self.environment_loads(psi, u, v, sea)
        return Forces((f[0], f[1], f[2]), (f[3], f[4], f[5]), (f[6], f[7], f[8]), wind, waves)

    def hull_loads(self, u_r: float, v_r: float, r: float) -> tuple[float, float, float]:
        """(X_H (N), Y_H (N), N_H (N m)) of the hull at midship for the water-relative velocities."""
        kernel, ki, p = self._kernel()
        return kernel.loads(ki, p, self._sea(CALM), 0.0, *map(float, (u_r, v_r, r)), 0.0, 0.0)[0:3]

    def actuator_loads(self, u_r: float, v_r: float, r: float, a: float, b: float
                       ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(steering, propulsion) loads (X (N), Y (N), N (N m)) each, at the actuator levels (a, b)."""
        kernel, ki, p = self._kernel()
        f = kernel.loads(ki, p, self._sea(CALM), 0.0, *map(float, (u_r, v_r, r, a, b)))
        return (f[3], f[4], f[5]), (f[6], f[7], f[8])

    def actuator_loads_many(self, nu: Any, levels: Any) -> tuple[Any, Any]:
        """(steering (T, 3), propulsion (T, 3)) loads at the water-relative velocities nu (T, 3) and the actuator
        levels (T, 2): actuator_loads of every sample in one kernel call."""
        import numpy as np

        kernel, ki, p = self._kernel()
        plain = ("C", "W")  # float64, C-contiguous, writable: the kernel's one compiled signature
        out = kernel.actuator_loads_many(ki, p, np.require(nu, np.float64, plain),
                                         np.require(levels, np.float64, plain), np.empty((len(nu), 6)))
        return out[:, 0:3], out[:, 3:6]

    def environment_loads(self, psi: float, u: float, v: float, sea: SeaLoads
                          ) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
        """(wind, waves) loads at heading psi and over-ground velocity (u, v): the apparent wind over ground (seed 000
        eq. 13-18) as the increment over still air (the still-air drag of the boat's own motion is part of the
        calm-water resistance, as in trial analysis, ITTC 7.5-04-01-01.1: zero without wind, and a current alone
        still drifts the boat exactly), and the mean wave drift (eq. 19)."""
        kernel, ki, p = self._kernel()
        f = kernel.loads(ki, p, self._sea(sea, current=False), float(psi), float(u), float(v), 0.0, 0.0, 0.0)
        return (f[9], f[10], f[11]), (f[12], f[13], f[14])

    # ---- equations of motion ------------------------------------------------------------------------
    def accelerations(self, psi: float, u_r: float, v_r: float, r: float, a: float, b: float,
                      sea: SeaLoads = CALM) -> tuple[float, float, float]:
        """nu_r_dot = M^-1 (tau - C(nu_r) nu_r - M_RB R^T dV_c/dt) at the actuator levels (a, b): the kernel's
        equations (physics/kernel.accelerations), the twin of models/greybox.py's."""
        kernel, ki, p = self._kernel()
        return kernel.accelerations(ki, p, self._sea(sea), *map(float, (psi, u_r, v_r, r, a, b, sea.current_accel_n,
                                                                       sea.current_accel_e)))

    def derivative(self, state: list[float], cmd_a: float, cmd_b: float, sea: SeaLoads) -> list[float]:
        """d/dt of [x_n, y_e, psi, u_r, v_r, r, a, b] for the commands (cmd_a, cmd_b) of the layout's `commands`."""
        _, _, psi, u_r, v_r, r, a, b = state
        c, s = math.cos(psi), math.sin(psi)
        u = u_r + sea.current_n * c + sea.current_e * s
        v = v_r - sea.current_n * s + sea.current_e * c
        u_dot, v_dot, r_dot = self.accelerations(psi, u_r, v_r, r, a, b, sea)
        a_dot, b_dot = self.actuator_rates(a, b, cmd_a, cmd_b)
        return [u * c - v * s, u * s + v * c, r, u_dot, v_dot, r_dot, a_dot, b_dot]

    def straight_speed(self, command: float, tol: float = 1e-6) -> float:
        """Steady straight-running speed through the water (m/s) where thrust balances resistance, for the
        propulsion command of the layout (rpm; a normalised throttle; both thrusters' command); 0 when the
        command does not drive the boat ahead."""
        a, b = self.initial_actuators(command)
        low, high = 0.0, 60.0
        if self.accelerations(0.0, 1e-3, 0.0, 0.0, a, b)[0] <= 0.0:
            return 0.0
        while high - low > tol:
            mid = 0.5 * (low + high)
            if self.accelerations(0.0, mid, 0.0, 0.0, a, b)[0] > 0.0:
                low = mid
            else:
                high = mid
        return 0.5 * (low + high)

    def initial_state(self, command: float, heading_rad: float) -> list[float]:
        """Steady straight running at the propulsion command: [x_n, y_e, psi, u_r, v_r, r, a, b]."""
        return [0.0, 0.0, heading_rad, self.straight_speed(command), 0.0, 0.0, *self.initial_actuators(command)]

    def actuator_levels(self, states: Any, commands: Any) -> Any:
        """(N, 2) actuator levels the forces act with, from the states and commands (N, 2): the states (a layout
        with an instantaneous motor overrides it)."""
        return states

    # ---- supplied by the hull model and the actuator force model (their forces are the kernel's) ---------------
    @abstractmethod
    def resistance_coefficients(self) -> tuple[float, float]:
        """(r1 (N s/m), r2 (N s^2/m^2)) of the straight-running resistance R(u) = r1 u + r2 u^2 of the hull."""

    @abstractmethod
    def actuator_rates(self, a: float, b: float, cmd_a: float, cmd_b: float) -> tuple[float, float]:
        """(da/dt, db/dt) of the actuator levels toward the commands (the layout's rate limits and motor lags)."""

    @abstractmethod
    def initial_actuators(self, command: float) -> tuple[float, float]:
        """(a, b) actuator levels of steady straight running at the propulsion command."""


# ---- hull models ----------------------------------------------------------------------------------------

class MmgHullForces:
    """The MMG hull polynomial (Yasukawa & Yoshimura 2015 eq. 5-8), regularised below SPEED_FLOOR."""

    constants = (HullConstants,)

    def resistance_coefficients(self) -> tuple[float, float]:
        return 0.0, self.q_force * self.hull.R0  # X_H = -0.5 rho L d R0 u^2 at v = r = 0


class SmallCraftHullForces:
    """Fossen's small-craft hull (vessel.SmallCraftHull): damping derivatives, cross-flow drag, Munk moment."""

    constants = (SmallCraftConstants,)

    def resistance_coefficients(self) -> tuple[float, float]:
        h = self.small_craft
        return -h.X_u, -h.X_uu


# ---- actuator force models ------------------------------------------------------------------------------

class RudderPropellerForces:
    """MMG propeller (eq. 10-12) and rudder with slipstream (eq. 13-16, 37-43) from (delta rad, engine rpm)."""

    constants = (RudderPropellerConstants,)

    def actuator_rates(self, delta: float, rpm: float, delta_cmd: float, rpm_cmd: float) -> tuple[float, float]:
        """Steering gear: first-order servo with rate limit; engine: first-order lag."""
        delta_cmd = min(max(delta_cmd, -self.rudder_max), self.rudder_max)
        delta_dot = (delta_cmd - delta) / self.t_rudder
        delta_dot = min(max(delta_dot, -self.rudder_rate), self.rudder_rate)
        return delta_dot, (rpm_cmd - rpm) / self.t_engine

    def initial_actuators(self, command: float) -> tuple[float, float]:
        return 0.0, command  # rudder amidships, the engine at the commanded speed

    def engine_speed_for(self, speed: float, resistance_change: float = 0.0, surge_force: float = 0.0) -> float:
        """The engine speed (rpm) that holds `speed` (m/s, through the water) in straight running: the inverse of
        straight_speed, in closed form. Straight (v = r = delta = 0): beta_P = 0, u_P = u (1 - w_P0), and
        (1 - t_P) rho (k0 D^4 n^2 + k1 D^3 u_P n + k2 D^2 u_P^2) = (1 + resistance_change) (r1 u + r2 u^2) - X_sea,
        a quadratic in n (rev/s) whose positive root is taken; 0 for speed <= 0. surge_force X_sea (N): the sea's
        surge force in that straight running (wind and waves; models/greybox.py RudderOnlyModule.begin's)."""
        if speed <= 0.0:
            return 0.0
        r1, r2 = self.resistance_coefficients()
        u_p = speed * (1.0 - self.w_P0)
        scale = (1.0 - self.t_P) * RHO_WATER
        qa = scale * self.k0 * self.D_P**4
        qb = scale * self.k1 * self.D_P**3 * u_p
        qc = scale * self.k2 * self.D_P**2 * u_p * u_p - ((1.0 + resistance_change) * (r1 * speed + r2 * speed * speed)
                                                         - surge_force)
        n = (-qb + math.sqrt(max(qb * qb - 4.0 * qa * qc, 0.0))) / (2.0 * qa)
        return max(n, 0.0) * 60.0 * self.gear_ratio


class RudderThrottleForces(RudderPropellerForces):
    """The rudder-propeller forces at the engine speed of the thrust map's static thrust at the lagged throttle."""

    constants = (RudderPropellerConstants, ThrottleConstants)

    def engine_speed(self, level: float) -> float:
        """Engine speed (rpm) whose static thrust rho n^2 D^4 K_T(0) is the throttle map's at `level` (0 astern): the
        conversion the kernel's rudder_throttle forces make (physics/kernel._actuator_forces)."""
        thrust = self.throttle.thrust(level)
        return math.sqrt(thrust / self.static_thrust) * self.rpm_per_rev_s if thrust > 0.0 else 0.0

    def actuator_rates(self, delta: float, level: float, delta_cmd: float, throttle_cmd: float) -> tuple[float, float]:
        delta_dot, _ = RudderPropellerForces.actuator_rates(self, delta, 0.0, delta_cmd, 0.0)
        lag = self.throttle.time_constant_s
        return delta_dot, (throttle_cmd - level) / lag if lag > 0.0 else 0.0

    def derivative(self, state: list[float], cmd_a: float, cmd_b: float, sea: SeaLoads) -> list[float]:
        if self.throttle.time_constant_s > 0.0:
            return ManoeuvringModel.derivative(self, state, cmd_a, cmd_b, sea)
        return ManoeuvringModel.derivative(self, [*state[:7], cmd_b], cmd_a, cmd_b, sea)  # instantaneous motor

    def actuator_levels(self, states: Any, commands: Any) -> Any:
        if self.throttle.time_constant_s > 0.0:
            return states
        levels = states.copy()
        levels[:, 1] = commands[:, 1]
        return levels


class TwinThrusterForces:
    """Two fixed thrusters: X = T_p + T_s, N = (b/2)(T_p - T_s), each thrust its map's at the lagged command."""

    constants = (TwinThrusterConstants,)

    def actuator_rates(self, port: float, starboard: float, cmd_p: float, cmd_s: float) -> tuple[float, float]:
        lag_p, lag_s = self.port.time_constant_s, self.starboard.time_constant_s
        return ((cmd_p - port) / lag_p if lag_p > 0.0 else 0.0), ((cmd_s - starboard) / lag_s if lag_s > 0.0 else 0.0)

    def derivative(self, state: list[float], cmd_a: float, cmd_b: float, sea: SeaLoads) -> list[float]:
        if self.port.time_constant_s > 0.0 and self.starboard.time_constant_s > 0.0:
            return ManoeuvringModel.derivative(self, state, cmd_a, cmd_b, sea)
        # an instantaneous motor (time constant 0, e.g. VRX's thrusters): its level is the command
        port = state[6] if self.port.time_constant_s > 0.0 else cmd_a
        starboard = state[7] if self.starboard.time_constant_s > 0.0 else cmd_b
        return ManoeuvringModel.derivative(self, [*state[:6], port, starboard], cmd_a, cmd_b, sea)

    def actuator_levels(self, states: Any, commands: Any) -> Any:
        levels = states.copy()
        for k, side in enumerate((self.port, self.starboard)):
            if side.time_constant_s == 0.0:
                levels[:, k] = commands[:, k]
        return levels

    def initial_actuators(self, command: float) -> tuple[float, float]:
        return command, command  # both thrusters at the command


HULL_FORCES: dict[str, type] = {  # hull model (physics/hulls.py) -> its equations
    "mmg": MmgHullForces,
    "small_craft": SmallCraftHullForces,
}
ACTUATOR_FORCES: dict[str, type] = {  # actuator layout (physics/actuators.py) -> its force model
    "rudder_propeller": RudderPropellerForces,
    "rudder_only": RudderPropellerForces,
    "rudder_throttle": RudderThrottleForces,
    "twin_thrusters": TwinThrusterForces,
}
_CLASSES: dict[tuple[str, str], type] = {}


def model_class(vessel: Vessel) -> type:
    """The ManoeuvringModel class of the vessel's hull model and layout (built once, cached)."""
    key = (vessel.hull_model_name, vessel.layout)
    if key not in _CLASSES:
        try:
            hull, forces = HULL_FORCES[key[0]], ACTUATOR_FORCES[key[1]]
        except KeyError as err:
            raise ConfigError(f"vessel {vessel.name}: no equations for {err.args[0]!r} in physics/dynamics.py "
                              f"(hull models {sorted(HULL_FORCES)}, layouts {sorted(ACTUATOR_FORCES)})") from None
        name = f"ManoeuvringModel[{key[0]}, {key[1]}]"
        _CLASSES[key] = type(name, (forces, hull, ManoeuvringModel),
                             {"constants": (*hull.constants, *forces.constants, SeaConstants), "__module__": __name__})
    return _CLASSES[key]

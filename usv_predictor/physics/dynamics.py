"""3-DOF manoeuvring dynamics in Fossen's matrix form with MMG force models.

    M nu_r_dot + C(nu_r) nu_r + D(nu_r) nu_r = tau_R + tau_P + tau_wind + tau_wave      (Fossen 2021 eq. 6.5)
    eta_dot = R(psi) (nu_r + nu_c)                                                     (Fossen 2021 eq. 2.40)

State (marine convention, SI): eta = [x_n, y_e, psi] (NED), nu_r = [u_r, v_r, r] = velocity relative to the
water in the body frame FRD at midship, nu_c = R(psi)^T V_c^n the current in the body frame (seed 000 eq. 20-22).
Because the hydrodynamic forces depend on nu_r only, a uniform current drifts the vessel at exactly V_c.
M and C(nu) are the left-hand sides of Yasukawa & Yoshimura 2015 eq. 4 (rigid body + added mass about midship);
D(nu) nu = -[X_H, Y_H, N_H] is the MMG hull polynomial (eq. 8; linear + nonlinear damping, the Munk moment is in
N_v as in captive-test derivatives); tau_R is the semi-empirical rudder model with propeller slipstream
(eq. 13-16, 37-43), tau_P the propeller thrust from rpm (eq. 10-12); tau_wind is seed 000 eq. 12-18 on the
apparent wind over ground
(the increment over still air); tau_wave the mean drift of seed 000 eq. 19.
Positive rudder angle delta turns the vessel to starboard (r > 0).

Everything is plain Python float arithmetic: one derivative is a few microseconds, which beats numpy on
scalars by an order of magnitude (see benchmarks/bench_simulator.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

from usv_predictor.physics.vessel import GRAVITY, RHO_AIR, RHO_WATER, Hull, Propeller, Rudder, Vessel

SPEED_FLOOR = 0.05  # speed below which non-dimensional hull terms are regularised (m/s)


class Forces(NamedTuple):
    """Force decomposition in the body frame at midship: surge X (N), sway Y (N), yaw N (N m)."""

    hull: tuple[float, float, float]
    rudder: tuple[float, float, float]
    propeller: tuple[float, float, float]
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


@dataclass(frozen=True)
class HullConstants:
    """The rigid body, added mass, hull, windage and wave-drift constants of a vessel in SI units.

    Computed once from a Vessel; both twins of the physics (ManoeuvringModel here, GreyBoxRollout in torch)
    read their constants from this record and its actuator twin (RudderPropellerConstants), field by field
    under the same names, so they cannot drift apart.
    """

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
    hull: Hull  # MMG hull polynomial coefficients (-)
    wind_x: float  # 0.5 rho_air A_F c_x (kg/m)
    wind_y: float  # 0.5 rho_air A_L c_y (kg/m)
    wind_n: float  # 0.5 rho_air A_L L_oa c_n (kg)
    q_wave: float  # 0.5 rho g L: times zeta_a^2 gives the wave-drift force scale (N/m^2)
    drift_x: tuple[float, tuple[tuple[int, float, float], ...]]  # wave-drift Fourier series (fourier_terms)
    drift_y: tuple[float, tuple[tuple[int, float, float], ...]]
    drift_n: tuple[float, tuple[tuple[int, float, float], ...]]

    @classmethod
    def of(cls, vessel: Vessel) -> "HullConstants":
        g, w, d = vessel.geometry, vessel.windage, vessel.wave_drift
        ((m11, _, _), (_, m22, m23), (_, m32, m33)) = vessel.mass_matrix()
        return cls(
            L=g.L_pp, m=vessel.mass, x_G=g.x_G, m11=m11, m22=m22, m23=m23, m32=m32, m33=m33,
            det_vr=m22 * m33 - m23 * m32, q_force=0.5 * RHO_WATER * g.L_pp * g.d, hull=vessel.hull,
            wind_x=0.5 * RHO_AIR * w.A_F * w.c_x, wind_y=0.5 * RHO_AIR * w.A_L * w.c_y,
            wind_n=0.5 * RHO_AIR * w.A_L * g.L_oa * w.c_n, q_wave=0.5 * RHO_WATER * GRAVITY * g.L_pp,
            drift_x=fourier_terms(d.a_x, d.b_x), drift_y=fourier_terms(d.a_y, d.b_y), drift_n=fourier_terms(d.a_n, d.b_n),
        )


@dataclass(frozen=True)
class RudderPropellerConstants:
    """The propeller, rudder and actuator constants of the rudder_propeller layout (see HullConstants).

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


def constants_of(vessel: Vessel) -> dict[str, object]:
    """Every constant of the vessel's equations of motion by name: HullConstants and its actuator constants,
    with the vessel sections they carry (propeller, rudder; not the hull polynomial) opened into their fields."""
    out: dict[str, object] = {}
    for record in (HullConstants.of(vessel), RudderPropellerConstants.of(vessel)):
        for f in fields(record):
            value = getattr(record, f.name)
            if isinstance(value, (Propeller, Rudder)):
                out.update({g.name: getattr(value, g.name) for g in fields(value)})
            else:
                out[f.name] = value
    return out


class ManoeuvringModel:
    """The vessel's equations of motion, with every constant precomputed in SI units (constants_of)."""

    def __init__(self, vessel: Vessel, propeller_side_force: float = 0.0) -> None:
        """propeller_side_force: transverse propeller force / thrust (-), + to starboard at the propeller
        (the 'paddle-wheel' effect of a single screw, or a bent shaft); 0 for a symmetric propulsor."""
        self.vessel = vessel
        self.propeller_side_force = float(propeller_side_force)
        for name, value in constants_of(vessel).items():  # attributes: the float hot path reads self.<name>
            setattr(self, name, value)

    # ---- forces -------------------------------------------------------------------------------------
    def propeller(self, u_r: float, v_r: float, r: float, rpm: float) -> tuple[float, float, float, float]:
        """Returns (X_P (N), u_P inflow (m/s), K_T (-), n_P (rev/s)); MMG eq. 10-12 with w_P = w_P0 exp(-4 beta_P^2)."""
        speed = math.sqrt(u_r * u_r + v_r * v_r) + 1e-9
        beta_p = math.atan2(-v_r, max(u_r, 1e-9)) - self.x_P * r * self.L / speed  # beta - x_P' r'
        w_p = self.w_P0 * math.exp(-4.0 * beta_p * beta_p)
        u_p = u_r * (1.0 - w_p)
        n_p = rpm / 60.0 / self.gear_ratio
        if n_p <= 1e-6:
            return 0.0, u_p, 0.0, 0.0
        j = u_p / (n_p * self.D_P)
        k_t = self.k0 + self.k1 * j + self.k2 * j * j
        thrust = RHO_WATER * n_p * n_p * self.D_P**4 * k_t
        return (1.0 - self.t_P) * thrust, u_p, k_t, n_p

    def loads(self, u_r: float, v_r: float, r: float, psi: float, u: float, v: float,
              delta: float, rpm: float, sea: SeaLoads = CALM) -> Forces:
        """All forces and moments at midship for relative (u_r, v_r) and over-ground (u, v) velocities."""
        h = self.hull
        L = self.L
        speed = math.sqrt(u_r * u_r + v_r * v_r)
        U = max(speed, SPEED_FLOOR)
        vp = v_r / U
        rp = r * L / U
        q = self.q_force * U * U
        x_h = q * (-h.R0 * (u_r * abs(u_r) / (U * U)) + h.X_vv * vp * vp + h.X_vr * vp * rp + h.X_rr * rp * rp
                   + h.X_vvvv * vp**4)
        y_h = q * (h.Y_v * vp + h.Y_r * rp + h.Y_vvv * vp**3 + h.Y_vvr * vp * vp * rp + h.Y_vrr * vp * rp * rp
                   + h.Y_rrr * rp**3)
        n_h = q * L * (h.N_v * vp + h.N_r * rp + h.N_vvv * vp**3 + h.N_vvr * vp * vp * rp
                       + h.N_vrr * vp * rp * rp + h.N_rrr * rp**3)

        x_p, u_p, k_t, n_p = self.propeller(u_r, v_r, r, rpm)

        # rudder inflow with propeller slipstream (MMG eq. 38, written without the 1/J^2 singularity)
        slip = math.sqrt(u_p * u_p + 8.0 * max(k_t, 0.0) * n_p * n_p * self.D_P**2 / math.pi)
        u_rudder = self.epsilon * math.sqrt(
            self.eta * (u_p + self.kappa * (slip - u_p)) ** 2 + (1.0 - self.eta) * u_p * u_p
        )
        beta_r = -(v_r + self.l_R_m * r)  # U * beta_R (m/s)
        gamma = self.gamma_R_minus if beta_r < 0.0 else self.gamma_R_plus
        v_rudder = gamma * beta_r
        alpha_r = delta - math.atan2(v_rudder, max(u_rudder, 1e-9))
        f_n = 0.5 * RHO_WATER * self.A_R * (u_rudder * u_rudder + v_rudder * v_rudder) * self.f_alpha * math.sin(alpha_r)
        x_r = -(1.0 - self.t_R) * f_n * math.sin(delta)
        y_r = -(1.0 + self.a_H) * f_n * math.cos(delta)
        n_r = -(self.x_R_m + self.a_H * self.x_H_m) * f_n * math.cos(delta)

        wind = (0.0, 0.0, 0.0)
        if sea.wind_speed > 0.0:
            # apparent wind over ground (seed 000 eq. 13-18); the still-air drag of the boat's own motion is
            # part of the calm-water resistance R0 (as in trial analysis, ITTC 7.5-04-01-01.1), so the load is
            # the increment over still air: zero without wind, and a current alone still drifts the boat exactly
            c, s = math.cos(psi), math.sin(psi)
            w_n, w_e = -sea.wind_speed * math.cos(sea.wind_from), -sea.wind_speed * math.sin(sea.wind_from)
            wind_now = self._air_load(u - (w_n * c + w_e * s), v - (-w_n * s + w_e * c))
            still = self._air_load(u, v)
            wind = (wind_now[0] - still[0], wind_now[1] - still[1], wind_now[2] - still[2])

        waves = (0.0, 0.0, 0.0)
        if sea.wave_amplitude > 0.0:
            chi = sea.wave_from - psi  # 0 = head seas
            qw = self.q_wave * sea.wave_amplitude**2
            waves = (qw * fourier(self.drift_x, chi), qw * fourier(self.drift_y, chi),
                     qw * L * fourier(self.drift_n, chi))
        y_p = self.propeller_side_force * x_p / (1.0 - self.t_P)  # share of the thrust, at the propeller
        return Forces((x_h, y_h, n_h), (x_r, y_r, n_r), (x_p, y_p, y_p * self.x_P * L), wind, waves)

    def _air_load(self, u_rw: float, v_rw: float) -> tuple[float, float, float]:
        """Air load for the apparent wind (u_rw, v_rw) in the body frame (seed 000 eq. 12-14)."""
        v2 = u_rw * u_rw + v_rw * v_rw
        gamma = -math.atan2(v_rw, u_rw)
        return (-self.wind_x * v2 * math.cos(gamma), self.wind_y * v2 * math.sin(gamma),
                self.wind_n * v2 * math.sin(2.0 * gamma))

    # ---- equations of motion ------------------------------------------------------------------------
    def accelerations(self, psi: float, u_r: float, v_r: float, r: float, delta: float, rpm: float,
                      sea: SeaLoads = CALM) -> tuple[float, float, float]:
        """nu_r_dot = M^-1 (tau - C(nu_r) nu_r - M_RB R^T dV_c/dt)."""
        c, s = math.cos(psi), math.sin(psi)
        u = u_r + sea.current_n * c + sea.current_e * s
        v = v_r - sea.current_n * s + sea.current_e * c
        x, y, n = self.loads(u_r, v_r, r, psi, u, v, delta, rpm, sea).total()
        m, x_g = self.m, self.x_G
        # Coriolis and centripetal terms of MMG eq. 4 (Fossen's C(nu) nu)
        rhs_x = x + self.m22 * v_r * r + x_g * m * r * r
        rhs_y = y - self.m11 * u_r * r
        rhs_n = n - x_g * m * u_r * r
        if sea.current_accel_n or sea.current_accel_e:
            # a turning current accelerates the water; the rigid body feels it (Fossen 2021 sec. 10.3)
            a_u = sea.current_accel_n * c + sea.current_accel_e * s
            a_v = -sea.current_accel_n * s + sea.current_accel_e * c
            rhs_x -= m * a_u
            rhs_y -= m * a_v
            rhs_n -= m * x_g * a_v
        u_dot = rhs_x / self.m11
        v_dot = (self.m33 * rhs_y - self.m23 * rhs_n) / self.det_vr
        r_dot = (self.m22 * rhs_n - self.m32 * rhs_y) / self.det_vr
        return u_dot, v_dot, r_dot

    def actuator_rates(self, delta: float, rpm: float, delta_cmd: float, rpm_cmd: float) -> tuple[float, float]:
        """Steering gear: first-order servo with rate limit; engine: first-order lag."""
        delta_cmd = min(max(delta_cmd, -self.rudder_max), self.rudder_max)
        delta_dot = (delta_cmd - delta) / self.t_rudder
        delta_dot = min(max(delta_dot, -self.rudder_rate), self.rudder_rate)
        return delta_dot, (rpm_cmd - rpm) / self.t_engine

    def derivative(self, state: list[float], delta_cmd: float, rpm_cmd: float, sea: SeaLoads) -> list[float]:
        """d/dt of [x_n, y_e, psi, u_r, v_r, r, delta, rpm]."""
        _, _, psi, u_r, v_r, r, delta, rpm = state
        c, s = math.cos(psi), math.sin(psi)
        u = u_r + sea.current_n * c + sea.current_e * s
        v = v_r - sea.current_n * s + sea.current_e * c
        u_dot, v_dot, r_dot = self.accelerations(psi, u_r, v_r, r, delta, rpm, sea)
        delta_dot, rpm_dot = self.actuator_rates(delta, rpm, delta_cmd, rpm_cmd)
        return [u * c - v * s, u * s + v * c, r, u_dot, v_dot, r_dot, delta_dot, rpm_dot]

    def straight_speed(self, rpm: float, tol: float = 1e-6) -> float:
        """Steady straight-running speed through the water (m/s) where thrust balances resistance."""
        low, high = 0.0, 60.0
        if self.accelerations(0.0, 1e-3, 0.0, 0.0, 0.0, rpm)[0] <= 0.0:
            return 0.0
        while high - low > tol:
            mid = 0.5 * (low + high)
            if self.accelerations(0.0, mid, 0.0, 0.0, 0.0, rpm)[0] > 0.0:
                low = mid
            else:
                high = mid
        return 0.5 * (low + high)

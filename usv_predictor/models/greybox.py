"""The manoeuvring model as a batched, differentiable, TorchScript-able closed-loop rollout.

Same equations as usv_predictor.physics.dynamics (a hull model + the force model of the vessel's actuator layout +
wind + waves, seed 000 eq. 12-22 for the sea), written once more in torch because the two serve different needs:
the float version simulates one boat at 100 Hz output in well under a second, this one rolls out hundreds of
segments at once and gives gradients for identification and diagnosis. test_greybox.py proves they agree, for
every hull model and layout. Both read their constants from the records of physics/dynamics.py (constants_of):
the rollout the mass matrix and the sea, its two submodules those of the hull model (HULL_MODULES) and of the
layout's force model (ACTUATOR_MODULES), one registry line each.

Interface (the model artifact's, see usv_predictor/models/artifact.py):
    forward(state (B, 4) [u, v, r, psi] as MEASURED, controls (B, H, C) as REPORTED, the columns of the vessel's
            actuator layout: [delta rad, rpm], [delta, throttle], [delta], [port, starboard] ...,
            reference (B, 4) | None [u, v, r, psi] as MEASURED in the straight running whose engine setting the
            prediction holds: rudder_only only, the others ignore it; None = the start state)
      -> (1, B, H, 6) [u, v, r, x_n, y_e, psi] as they will be MEASURED at dt, 2 dt, ... H dt,
         positions relative to the start (NED, m), psi continuous.
controls[:, k] is the reported control at step k; between samples the controls move linearly (first-order
hold: the rudder of a recording changes during a step, and holding it would lag the response by half a step);
the last sample is held. RK4 with `substeps` per step. A control that reports an actuator state (a rudder angle,
an engine speed) is the actuator's level; one that reports a command (a throttle, a thruster command) drives a
first-order motor lag of the thrust map's time constant, solved exactly for the linear command of each substep
(y(t) = c(t) - T c' + (y0 - c0 + T c') exp(-t/T); no stiffness, any T >= 0), starting at the first reported
command (steady running). rudder_only has no propulsion control: its engine speed is `engine_speed_rpm`, or, when
that is 0, the speed that holds the water speed of the `reference` state in straight running (the closed-form
inverse of straight_speed, dynamics.RudderPropellerForces.engine_speed_for), held over the horizon. The reference is
the straight running of the manoeuvre (replay: its approach, data.recording.approach_state: a boat slows down in a
turn at the same engine setting, so the engine speed of a start inside a turn would run slow); without one, the start
state. Its water speed is its surge less the current term along its heading (the engine holds a speed through the
water; the current's share of the measured speed over ground is the current's), and the thrust balances the hull's
resistance less the surge force of the wind and wave terms at the reference's heading (a head sea slows the approach
at the same engine setting: the engine speed is not the calm-water one of that slower speed).

Extension terms (all zero for the calm-water model; one attribute per Term of the effect records in
usv_predictor.physics.effects, which say which diagnosis hypothesis fits them; their equations are here):
    current_ne (2,) current velocity north/east (m/s);     wind_ne (2,) wind velocity (toward) north/east (m/s)
    wave_ne (2,) zeta_a^2 (m^2) along the direction the waves come FROM;
    wave_resistance (1,) C_AW (-), the head-sea added resistance beyond the drift series: a surge force
        -0.5 rho g zeta_a^2 L C_AW max(cos chi, 0)^2 (chi = wave direction FROM - heading): the short-wave drift of a
        transverse wall at the bow (Faltinsen 1990 sec. 5, as physics/empirical.short_wave_drift: the force of a lit
        wall goes with sin^2 of the incidence), the head-sea resistance a description's waterline lacks;
    rudder_offset (rad, true - reported)
    yaw_rate_bias (rad/s, measured - true); heading_offset (rad, measured - true);
    actuator_delay (s, the hull feels the reported controls this much later);
    resistance_change (-, relative change of the calm-water resistance: R0 of the MMG hull, X_u and X_uu of the
        small-craft hull: fouling, loading, a preset off);
    propeller_side_force (-, transverse propeller force / thrust, + to starboard: propeller walk; rudder layouts);
    thrust_imbalance (-, k: port thruster (1 + k), starboard (1 - k) of its map; + = starboard weaker; twins).
A term acts only where its layout has the part (effects.Effect.layouts); the others leave the prediction alone.
"""
from __future__ import annotations

import math
from dataclasses import asdict, fields, replace
from typing import Any, Dict, List, Mapping, Optional, Tuple

import numpy as np
import torch
from torch import Tensor, nn

from usv_predictor.data.recording import APPROACH_S
from usv_predictor.physics import dynamics, effects
from usv_predictor.physics.dynamics import SPEED_FLOOR, SeaConstants, constants_of
from usv_predictor.physics.kernel import lag_factors, thrust_map_spec
from usv_predictor.physics.vessel import RHO_WATER, Hull, Propeller, Rudder, Thrusters, ThrustMap, Vessel

HULL_NAMES = tuple(f.name for f in fields(Hull))  # the MMG hull's coefficients, R0 ... N_rrr (vessel.Hull)


def _fourier_table(series: tuple[float, tuple[tuple[int, float, float], ...]]) -> List[List[float]]:
    """[[a0/2, 0, 0], [n, a_n, b_n], ...] for TorchScript (no nested tuples of mixed types)."""
    half_a0, terms = series
    return [[half_a0, 0.0, 0.0]] + [[float(n), a, b] for n, a, b in terms]


def _set_constants(module: nn.Module, constants: Mapping[str, object]) -> None:
    """The constants as module attributes (TorchScript-typable: floats, lists); records are left to the module."""
    for name, value in constants.items():
        if name.startswith("drift_"):
            setattr(module, name, _fourier_table(value))
        elif isinstance(value, tuple):
            setattr(module, name, [float(x) for x in value])
        elif isinstance(value, (int, float)):
            setattr(module, name, float(value))


def hull_coefficients(vessel: Vessel) -> Tuple[Tuple[str, ...], Tuple[float, ...]]:
    """(names, values) of the vessel's identifiable hull coefficients: the fields of its hull model's section."""
    section = getattr(vessel, vessel.hull_model.coefficients)
    names = tuple(f.name for f in fields(section))
    return names, tuple(float(getattr(section, n)) for n in names)


# ---- hull models (dynamics.MmgHullForces, dynamics.SmallCraftHullForces) ----------------------------------------

class MmgHullModule(nn.Module):
    """The MMG hull polynomial; h = the 17 coefficients of vessel.Hull in HULL_NAMES order (the rollout's `hull`
    unbound: a list of 0-dim tensors, GreyBoxRollout.hull_list)."""

    def __init__(self, vessel: Vessel) -> None:
        super().__init__()
        self.speed_floor = SPEED_FLOOR
        _set_constants(self, constants_of(vessel, dynamics.MmgHullForces.constants))

    def forces(self, h: List[Tensor], u_r: Tensor, v_r: Tensor, r: Tensor, resistance_change: Tensor) -> List[Tensor]:
        L = self.L
        U = torch.clamp(torch.sqrt(u_r * u_r + v_r * v_r), min=self.speed_floor)
        vp = v_r / U
        rp = r * L / U
        q = self.q_force * U * U
        x_h = q * (-h[0] * (1.0 + resistance_change[0]) * u_r * torch.abs(u_r) / (U * U) + h[1] * vp * vp
                   + h[2] * vp * rp + h[3] * rp * rp + h[4] * vp ** 4)
        y_h = q * (h[5] * vp + h[6] * rp + h[7] * vp ** 3 + h[8] * vp * vp * rp + h[9] * vp * rp * rp
                   + h[10] * rp ** 3)
        n_h = q * L * (h[11] * vp + h[12] * rp + h[13] * vp ** 3 + h[14] * vp * vp * rp + h[15] * vp * rp * rp
                       + h[16] * rp ** 3)
        return [x_h, y_h, n_h]

    def solve(self, h: List[Tensor], x: Tensor, y: Tensor, n: Tensor, u_r: Tensor, v_r: Tensor,
              r: Tensor) -> List[Tensor]:
        """nu_r_dot = M^-1 (tau - C(nu_r) nu_r) with MMG's Coriolis terms (no Munk moment: it is in N_v)."""
        rhs_x = x + self.m22 * v_r * r + self.x_G * self.m * r * r
        rhs_y = y - self.m11 * u_r * r
        rhs_n = n - self.x_G * self.m * u_r * r
        return [rhs_x / self.m11, (self.m33 * rhs_y - self.m23 * rhs_n) / self.det_vr,
                (self.m22 * rhs_n - self.m32 * rhs_y) / self.det_vr]

    def resistance(self, h: List[Tensor], resistance_change: Tensor) -> List[Tensor]:
        """[r1 (N s/m), r2 (N s^2/m^2)] of the straight-running resistance R = r1 u + r2 u^2."""
        return [torch.zeros_like(h[0]), self.q_force * h[0] * (1.0 + resistance_change[0])]


class SmallCraftHullModule(nn.Module):
    """Fossen's small-craft hull; h = the coefficients of vessel.SmallCraftHull in its field order (indexed by
    name below). The mass matrix follows the fitted added mass."""

    def __init__(self, vessel: Vessel) -> None:
        super().__init__()
        _set_constants(self, constants_of(vessel, dynamics.SmallCraftHullForces.constants))
        self.register_buffer("strips", torch.tensor(self.strip_x, dtype=torch.float64), persistent=False)  # (S,)
        names, _ = hull_coefficients(vessel)
        (self.i_xud, self.i_yvd, self.i_nrd, self.i_xu, self.i_xuu, self.i_yv, self.i_yr, self.i_nv, self.i_nr,
         self.i_nrr, self.i_cd) = (names.index(n) for n in ("X_udot", "Y_vdot", "N_rdot", "X_u", "X_uu", "Y_v", "Y_r",
                                                           "N_v", "N_r", "N_rr", "cross_flow_cd"))

    def forces(self, h: List[Tensor], u_r: Tensor, v_r: Tensor, r: Tensor, resistance_change: Tensor) -> List[Tensor]:
        w = v_r[:, None] + self.strips[None, :] * r[:, None]  # (B, S) relative cross-flow velocity along the hull
        f = torch.abs(w) * w  # (B, S)
        cross = -self.half_rho_d * h[self.i_cd] * self.strip_dx
        y_cf = cross * torch.sum(f, dim=1)
        n_cf = cross * torch.sum(self.strips[None, :] * f, dim=1)
        x_h = (1.0 + resistance_change[0]) * ((h[self.i_xu] + h[self.i_xuu] * torch.abs(u_r)) * u_r)
        y_h = h[self.i_yv] * v_r + h[self.i_yr] * r + y_cf
        n_h = h[self.i_nv] * v_r + h[self.i_nr] * r + h[self.i_nrr] * torch.abs(r) * r + n_cf
        return [x_h, y_h, n_h]

    def solve(self, h: List[Tensor], x: Tensor, y: Tensor, n: Tensor, u_r: Tensor, v_r: Tensor,
              r: Tensor) -> List[Tensor]:
        """nu_r_dot = M^-1 (tau - C_RB(nu_r) nu_r - C_A(nu_r) nu_r), M with the fitted added mass; the yaw row has
        the Munk moment (Y_vdot - X_udot) u_r v_r."""
        m11 = self.m - h[self.i_xud]
        m22 = self.m - h[self.i_yvd]
        m33 = self.m33_rigid - h[self.i_nrd]
        det = m22 * m33 - self.m23 * self.m32
        rhs_x = x + m22 * v_r * r + self.x_G * self.m * r * r
        rhs_y = y - m11 * u_r * r
        rhs_n = n - self.x_G * self.m * u_r * r + (h[self.i_yvd] - h[self.i_xud]) * u_r * v_r
        return [rhs_x / m11, (m33 * rhs_y - self.m23 * rhs_n) / det, (m22 * rhs_n - self.m32 * rhs_y) / det]

    def resistance(self, h: List[Tensor], resistance_change: Tensor) -> List[Tensor]:
        return [-h[self.i_xu] * (1.0 + resistance_change[0]), -h[self.i_xuu] * (1.0 + resistance_change[0])]


# ---- actuator force models (dynamics.RudderPropellerForces, RudderThrottleForces, TwinThrusterForces) ----------

class CommandLag(nn.Module):
    """Exact first-order lags of the reported command columns over one substep of length h (time constants T,
    0 = instantaneous): the level at the substep's start, middle and end for a linear command u0 -> u2."""

    def __init__(self, time_constants: List[float], h: float) -> None:
        super().__init__()
        self.h = h  # (s)
        as64 = dict(dtype=torch.float64)
        self.register_buffer("t", torch.tensor(time_constants, **as64), persistent=False)  # (K,) (s)
        self.register_buffer("e_half", torch.tensor(lag_factors(time_constants, 0.5 * h), **as64), persistent=False)
        self.register_buffer("e_full", torch.tensor(lag_factors(time_constants, h), **as64), persistent=False)

    def levels(self, y0: Tensor, u0: Tensor, u1: Tensor, u2: Tensor) -> List[Tensor]:
        """(B, K) levels at 0, h/2, h for the (B, K) commands u0, u1, u2 and the (B, K) level y0 at 0."""
        drift = self.t * (u2 - u0) / self.h  # T dc/dt: how far a lag trails a ramp
        start = y0 - u0 + drift
        return [y0, u1 - drift + start * self.e_half, u2 - drift + start * self.e_full]


def _thrust(level: Tensor, spec: List[float], table_x: List[float], table_y: List[float]) -> Tensor:
    """vessel.ThrustMap.thrust in torch: dead band, then the power law or the piecewise-linear table."""
    c = torch.clamp(level, min=-1.0, max=1.0)
    a = torch.clamp(torch.abs(c) - spec[3], min=0.0) / (1.0 - spec[3])
    e = torch.where(c > 0.0, a, -a)
    if spec[4] > 0.0:
        y = torch.full_like(e, table_y[0])
        for k in range(len(table_x) - 1):
            width = table_x[k + 1] - table_x[k]
            y = y + (table_y[k + 1] - table_y[k]) / width * torch.clamp(e - table_x[k], min=0.0, max=width)
        return y
    return torch.where(e >= 0.0, spec[0] * torch.pow(torch.clamp(e, min=0.0), spec[2]),
                       -spec[1] * torch.pow(torch.clamp(-e, min=0.0), spec[2]))


class RudderPropellerModule(nn.Module):
    """MMG propeller and rudder from the levels (delta rad, engine rpm); controls [delta, rpm] are both levels."""

    def __init__(self, vessel: Vessel, h: float) -> None:
        super().__init__()
        self.rho = RHO_WATER
        self.pi = math.pi
        _set_constants(self, constants_of(vessel, dynamics.RudderPropellerForces.constants))
        self.L = vessel.geometry.L_pp

    def begin(self, u_r0: Tensor, controls: Tensor, resistance: List[Tensor], engine_speed_rpm: Tensor) -> Tensor:
        """(B, K) what the layout carries over the rollout (nothing here). resistance: [r1, r2, X_sea] of the straight
        running at u_r0 (rudder_only's engine speed; hull resistance r1 u + r2 u^2, the sea's surge force N)."""
        return torch.zeros_like(controls[:, 0, :1])

    def stage(self, u0: Tensor, u1: Tensor, u2: Tensor, carry: Tensor, rudder_offset: Tensor) -> List[Tensor]:
        """[a0, b0, a1, b1, a2, b2, carry]: the levels at the substep's start, middle and end."""
        return [u0[:, 0] + rudder_offset[0], u0[:, 1], u1[:, 0] + rudder_offset[0], u1[:, 1],
                u2[:, 0] + rudder_offset[0], u2[:, 1], carry]

    def engine_speed(self, level: Tensor) -> Tensor:
        return level

    def forces(self, u_r: Tensor, v_r: Tensor, r: Tensor, delta: Tensor, level: Tensor, side_force: Tensor,
               imbalance: Tensor) -> List[Tensor]:
        """[X, Y, N] of the rudder, then of the propeller (dynamics.RudderPropellerForces.actuator_loads)."""
        rpm = self.engine_speed(level)
        L = self.L
        speed = torch.sqrt(u_r * u_r + v_r * v_r) + 1e-9
        beta_p = torch.atan2(-v_r, torch.clamp(u_r, min=1e-9)) - self.x_P * r * L / speed
        u_p = u_r * (1.0 - self.w_P0 * torch.exp(-4.0 * beta_p * beta_p))
        n_p = torch.clamp(rpm / 60.0 / self.gear_ratio, min=1e-6)
        j = u_p / (n_p * self.D_P)
        k_t = self.k0 + self.k1 * j + self.k2 * j * j
        running = (rpm / 60.0 / self.gear_ratio > 1e-6).to(u_r.dtype)
        x_p = running * (1.0 - self.t_P) * self.rho * n_p * n_p * self.D_P ** 4 * k_t
        slip = torch.sqrt(u_p * u_p + running * 8.0 * torch.clamp(k_t, min=0.0) * n_p * n_p * self.D_P ** 2 / self.pi)
        u_rud = self.epsilon * torch.sqrt(self.eta * (u_p + self.kappa * (slip - u_p)) ** 2
                                          + (1.0 - self.eta) * u_p * u_p)
        beta_r = -(v_r + self.l_R_m * r)
        v_rud = torch.where(beta_r < 0.0, self.gamma_R_minus * beta_r, self.gamma_R_plus * beta_r)
        alpha = delta - torch.atan2(v_rud, torch.clamp(u_rud, min=1e-9))
        f_n = 0.5 * self.rho * self.A_R * (u_rud * u_rud + v_rud * v_rud) * self.f_alpha * torch.sin(alpha)
        cos_d = torch.cos(delta)
        x_r = -(1.0 - self.t_R) * f_n * torch.sin(delta)
        y_r = -(1.0 + self.a_H) * f_n * cos_d
        n_r = -(self.x_R_m + self.a_H * self.x_H_m) * f_n * cos_d
        y_p = side_force[0] * x_p / (1.0 - self.t_P)
        return [x_r, y_r, n_r, x_p, y_p, y_p * self.x_P * L]


class RudderThrottleModule(RudderPropellerModule):
    """rudder_throttle: controls [delta, throttle]; the throttle command is lagged, its map's static thrust is the
    engine speed's (dynamics.RudderThrottleForces.engine_speed)."""

    def __init__(self, vessel: Vessel, h: float) -> None:
        super().__init__(vessel, h)
        _set_constants(self, constants_of(vessel, (dynamics.ThrottleConstants,)))
        self.lag = CommandLag([vessel.throttle.time_constant_s], h)
        self.map, self.table_x, self.table_y = thrust_map_spec(vessel.throttle)

    def begin(self, u_r0: Tensor, controls: Tensor, resistance: List[Tensor], engine_speed_rpm: Tensor) -> Tensor:
        return controls[:, 0, 1:2]  # (B, 1) the motor at the first reported throttle

    def stage(self, u0: Tensor, u1: Tensor, u2: Tensor, carry: Tensor, rudder_offset: Tensor) -> List[Tensor]:
        y = self.lag.levels(carry, u0[:, 1:2], u1[:, 1:2], u2[:, 1:2])
        return [u0[:, 0] + rudder_offset[0], y[0][:, 0], u1[:, 0] + rudder_offset[0], y[1][:, 0],
                u2[:, 0] + rudder_offset[0], y[2][:, 0], y[2]]

    def engine_speed(self, level: Tensor) -> Tensor:
        thrust = torch.clamp(_thrust(level, self.map, self.table_x, self.table_y), min=0.0)
        return torch.sqrt(thrust / self.static_thrust) * self.rpm_per_rev_s


class RudderOnlyModule(RudderPropellerModule):
    """rudder_only: controls [delta]; the engine speed is engine_speed_rpm, or (0) the one that holds the water speed
    u_r0 of the reference state (the start state without one) in straight running against the hull's resistance and
    the sea terms' surge force there (dynamics.RudderPropellerForces.engine_speed_for in calm water), held over the
    horizon."""

    def begin(self, u_r0: Tensor, controls: Tensor, resistance: List[Tensor], engine_speed_rpm: Tensor) -> Tensor:
        speed = torch.clamp(u_r0, min=0.0)
        u_p = speed * (1.0 - self.w_P0)
        scale = (1.0 - self.t_P) * self.rho
        qa = scale * self.k0 * self.D_P ** 4
        qb = scale * self.k1 * self.D_P ** 3 * u_p
        # thrust = resistance - the sea's surge force (resistance[2], N; wind and waves of the rollout's terms)
        qc = scale * self.k2 * self.D_P ** 2 * u_p * u_p - (resistance[0] * speed + resistance[1] * speed * speed
                                                            - resistance[2])
        n = (-qb + torch.sqrt(torch.clamp(qb * qb - 4.0 * qa * qc, min=0.0))) / (2.0 * qa)
        rpm = torch.clamp(n, min=0.0) * 60.0 * self.gear_ratio
        rpm = torch.where(engine_speed_rpm[0] > 0.0, torch.ones_like(rpm) * engine_speed_rpm[0], rpm)
        return rpm[:, None]  # (B, 1)

    def stage(self, u0: Tensor, u1: Tensor, u2: Tensor, carry: Tensor, rudder_offset: Tensor) -> List[Tensor]:
        rpm = carry[:, 0]
        return [u0[:, 0] + rudder_offset[0], rpm, u1[:, 0] + rudder_offset[0], rpm, u2[:, 0] + rudder_offset[0], rpm,
                carry]


class TwinThrusterModule(nn.Module):
    """twin_thrusters: controls [port, starboard] commands, each lagged and mapped to thrust; X = T_p + T_s,
    N = (b/2) (T_p - T_s) with (1 + k) T_p, (1 - k) T_s for the thrust imbalance k."""

    def __init__(self, vessel: Vessel, h: float) -> None:
        super().__init__()
        _set_constants(self, constants_of(vessel, dynamics.TwinThrusterForces.constants))
        t = vessel.thrusters
        self.lag = CommandLag([t.port.time_constant_s, t.starboard.time_constant_s], h)
        self.port, self.port_x, self.port_y = thrust_map_spec(t.port)
        self.starboard, self.starboard_x, self.starboard_y = thrust_map_spec(t.starboard)

    def begin(self, u_r0: Tensor, controls: Tensor, resistance: List[Tensor], engine_speed_rpm: Tensor) -> Tensor:
        return controls[:, 0, :]  # (B, 2) the motors at the first reported commands

    def stage(self, u0: Tensor, u1: Tensor, u2: Tensor, carry: Tensor, rudder_offset: Tensor) -> List[Tensor]:
        y = self.lag.levels(carry, u0, u1, u2)
        return [y[0][:, 0], y[0][:, 1], y[1][:, 0], y[1][:, 1], y[2][:, 0], y[2][:, 1], y[2]]

    def forces(self, u_r: Tensor, v_r: Tensor, r: Tensor, port: Tensor, starboard: Tensor, side_force: Tensor,
               imbalance: Tensor) -> List[Tensor]:
        t_p = (1.0 + imbalance[0]) * _thrust(port, self.port, self.port_x, self.port_y)
        t_s = (1.0 - imbalance[0]) * _thrust(starboard, self.starboard, self.starboard_x, self.starboard_y)
        zero = torch.zeros_like(u_r)
        return [zero, zero, self.half_spacing * (t_p - t_s), t_p + t_s, zero, zero]


HULL_MODULES: Dict[str, type] = {  # hull model (physics/hulls.py) -> its torch equations
    "mmg": MmgHullModule,
    "small_craft": SmallCraftHullModule,
}
ACTUATOR_MODULES: Dict[str, type] = {  # actuator layout (physics/actuators.py) -> its torch force model
    "rudder_propeller": RudderPropellerModule,
    "rudder_throttle": RudderThrottleModule,
    "rudder_only": RudderOnlyModule,
    "twin_thrusters": TwinThrusterModule,
}


class GreyBoxRollout(nn.Module):
    __annotations__ = {"drift_harmonics": List[List[float]]}  # TorchScript: the list may be empty

    def __init__(self, vessel: Vessel, dt: float, substeps: int = 2) -> None:
        super().__init__()
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.n_controls = len(vessel.actuator_layout.controls)
        # the SI constants of the equations of motion, from the records both twins read (physics/dynamics.py):
        # the mass matrix and the sea here, the hull model's and the layout's in the two submodules
        self.L = vessel.geometry.L_pp  # (m), the wave-drift moment arm
        _set_constants(self, constants_of(vessel, (SeaConstants,)))
        # the wave-drift harmonics any of the three series uses: [n, its cos needed, its sin needed] (_drift)
        series = (self.drift_x, self.drift_y, self.drift_n)
        self.drift_harmonics = [[float(n), float(any(len(t) > n and t[n][1] != 0.0 for t in series)),
                                 float(any(len(t) > n and t[n][2] != 0.0 for t in series))]
                                for n in range(1, max(len(t) for t in series))]
        self.hull_forces = HULL_MODULES[vessel.hull_model_name](vessel)
        self.actuator_forces = ACTUATOR_MODULES[vessel.layout](vessel, self.dt / self.substeps)
        names, values = hull_coefficients(vessel)
        self.hull_names = names  # the identifiable hull coefficients (a tensor: identification and diagnosis set it)
        self.hull = nn.Parameter(torch.tensor(values, dtype=torch.float64), requires_grad=False)
        # rudder_only: the engine speed held over a prediction (rpm); 0 = from the water speed of the reference state
        self.engine_speed_rpm = nn.Parameter(torch.zeros(1, dtype=torch.float64), requires_grad=False)
        # the extension terms of the effect records, all zero: current_ne, wind_ne, wave_ne, rudder_offset, ...
        terms = effects.grey_box_terms()
        self.term_names = tuple(terms)
        for term in terms.values():
            setattr(self, term.name, nn.Parameter(torch.zeros(term.size, dtype=torch.float64), requires_grad=False))

    # ---- forces ---------------------------------------------------------------------------------
    def _drift(self, chi: Tensor) -> List[Tensor]:
        """The wave-drift Fourier series [C_x, C_y, C_n] at (B,) chi (seed 000 eq. 19): a0/2 + sum a_n cos(n chi) +
        b_n sin(n chi), each harmonic's cos and sin computed once for the three series (drift_harmonics), a zero
        coefficient's term left out (it adds 0)."""
        cos: List[Tensor] = []
        sin: List[Tensor] = []
        for harmonic in self.drift_harmonics:  # [n, cos needed, sin needed]
            angle = chi if harmonic[0] == 1.0 else harmonic[0] * chi
            cos.append(torch.cos(angle) if harmonic[1] > 0.0 else chi)
            sin.append(torch.sin(angle) if harmonic[2] > 0.0 else chi)
        out: List[Tensor] = []
        for table in (self.drift_x, self.drift_y, self.drift_n):
            value = torch.full_like(chi, table[0][0])
            for k, row in enumerate(table[1:]):
                if row[1] != 0.0:
                    value = value + row[1] * cos[k]
                if row[2] != 0.0:
                    value = value + row[2] * sin[k]
            out.append(value)
        return out

    def _air_load(self, u_rw: Tensor, v_rw: Tensor) -> List[Tensor]:
        v2 = u_rw * u_rw + v_rw * v_rw
        gamma = -torch.atan2(v_rw, u_rw)
        return [-self.wind_x * v2 * torch.cos(gamma), self.wind_y * v2 * torch.sin(gamma),
                self.wind_n * v2 * torch.sin(2.0 * gamma)]

    def _accelerations(self, psi: Tensor, u_r: Tensor, v_r: Tensor, r: Tensor, a: Tensor, b: Tensor) -> List[Tensor]:
        """[u_r_dot, v_r_dot, r_dot] for (B,) tensors at the actuator levels a, b (delta rad and rpm for
        rudder_propeller; dynamics.ManoeuvringModel.accelerations)."""
        return self._accelerations_with(self.hull_list(), self._sea_terms(), psi, u_r, v_r, r, a, b)

    def _accelerations_with(self, hull: List[Tensor], sea: List[Tensor], psi: Tensor, u_r: Tensor, v_r: Tensor,
                            r: Tensor, a: Tensor, b: Tensor) -> List[Tensor]:
        """_accelerations with the hull coefficients unbound (hull_list) and the sea terms' values (_sea_terms)
        given: a rollout that holds them computes them once (fit_check's causes, CausesRollout)."""
        h = self.hull_forces.forces(hull, u_r, v_r, r, self.resistance_change)
        act = self.actuator_forces.forces(u_r, v_r, r, a, b, self.propeller_side_force, self.thrust_imbalance)
        loads = self._sea_loads_with(sea, psi, u_r, v_r)
        x = h[0] + act[0] + act[3] + loads[0]
        y = h[1] + act[1] + act[4] + loads[1]
        n = h[2] + act[2] + act[5] + loads[2]
        return self.hull_forces.solve(hull, x, y, n, u_r, v_r, r)

    def hull_list(self) -> List[Tensor]:
        """The hull coefficients as a list of 0-dim tensors (one unbind, no select per coefficient and use)."""
        return self.hull.unbind(0)

    def _sea_terms(self) -> List[Tensor]:
        """What the sea loads take from the extension terms, the same over a rollout: [current north, east (m/s),
        wind north, east (m/s), q_wave zeta_a^2 (N), the direction the waves come from (rad), q_wave zeta_a^2 C_AW
        (N)], each 0-dim, or (B,) when the terms are set per row."""
        amp = torch.sqrt(self.wave_ne[0] ** 2 + self.wave_ne[1] ** 2 + 1e-30)  # finite gradient at zero
        drift = self.q_wave * amp
        return [self.current_ne[0], self.current_ne[1], self.wind_ne[0], self.wind_ne[1], drift,
                torch.atan2(self.wave_ne[1], self.wave_ne[0]), drift * self.wave_resistance[0]]

    def _sea_loads(self, psi: Tensor, u_r: Tensor, v_r: Tensor) -> List[Tensor]:
        """[X, Y, N] of the sea terms on (B,) heading psi and water velocity u_r, v_r: the wind over the still-air
        drag (seed 000 eq. 12-18) and the mean wave drift (eq. 19) with its head-sea added resistance."""
        return self._sea_loads_with(self._sea_terms(), psi, u_r, v_r)

    def _sea_loads_with(self, sea: List[Tensor], psi: Tensor, u_r: Tensor, v_r: Tensor) -> List[Tensor]:
        """_sea_loads with the sea terms' values given (_sea_terms)."""
        L = self.L
        # sea: apparent wind over ground, mean wave drift
        c, s = torch.cos(psi), torch.sin(psi)
        u_g = u_r + sea[0] * c + sea[1] * s
        v_g = v_r - sea[0] * s + sea[1] * c
        wind = self._air_load(u_g - (sea[2] * c + sea[3] * s), v_g - (-sea[2] * s + sea[3] * c))
        still = self._air_load(u_g, v_g)  # still-air drag is in the resistance: the load is the increment (dynamics.py)
        x_w, y_w, n_w = wind[0] - still[0], wind[1] - still[1], wind[2] - still[2]
        chi = sea[5] - psi
        qw = sea[4]
        drift = self._drift(chi)
        head = torch.clamp(torch.cos(chi), min=0.0)
        x_wv = qw * drift[0] - sea[6] * head * head
        y_wv = qw * drift[1]
        n_wv = qw * L * drift[2]
        return [x_w + x_wv, y_w + y_wv, n_w + n_wv]

    def _derivative(self, s: List[Tensor], a: Tensor, b: Tensor) -> List[Tensor]:
        """d/dt of [x_n, y_e, psi, u_r, v_r, r]; positions move with the current (over ground)."""
        psi, u_r, v_r, r = s[2], s[3], s[4], s[5]
        c, sn = torch.cos(psi), torch.sin(psi)
        u = u_r + self.current_ne[0] * c + self.current_ne[1] * sn
        v = v_r - self.current_ne[0] * sn + self.current_ne[1] * c
        acc = self._model_accelerations(psi, u_r, v_r, r, a, b)
        return [u * c - v * sn, u * sn + v * c, r, acc[0], acc[1], acc[2]]

    def _model_accelerations(self, psi: Tensor, u_r: Tensor, v_r: Tensor, r: Tensor, a: Tensor,
                             b: Tensor) -> List[Tensor]:
        """The accelerations the rollout integrates; a hybrid model adds its learned residual here."""
        return self._accelerations(psi, u_r, v_r, r, a, b)

    def _delayed(self, controls: Tensor) -> Tensor:
        """Controls shifted later by actuator_delay (linear interpolation, the first value held before)."""
        steps = controls.shape[1]
        shift = self.actuator_delay[0] / self.dt
        index = torch.arange(steps, dtype=controls.dtype, device=controls.device) - shift
        index = torch.clamp(index, min=0.0, max=float(steps - 1))
        low = torch.floor(index).detach()
        frac = index - low
        lo = low.long()
        hi = torch.clamp(lo + 1, max=steps - 1)
        return controls[:, lo] * (1.0 - frac)[None, :, None] + controls[:, hi] * frac[None, :, None]

    def forward(self, state: Tensor, controls: Tensor, reference: Optional[Tensor] = None) -> Tensor:
        return self._rollout(state, controls, reference).unsqueeze(0)  # (1, B, H, 6)

    def _start(self, state: Tensor, controls: Tensor,
               reference: Optional[Tensor]) -> Tuple[Tensor, List[Tensor], Tensor]:
        """(controls (B, H, C) in float64 as the hull feels them, the start [x_n, y_e, psi, u_r, v_r, r] (B,) each,
        the layout's carry (B, K)): what a rollout starts from (_rollout's first part, shared with fit_check's)."""
        state = state.to(torch.float64)  # (B, 4) measured u, v, r, psi
        controls = controls.to(torch.float64)  # (B, H, C) reported controls of the actuator layout
        if controls.dim() != 3 or controls.shape[2] != self.n_controls:
            raise ValueError(f"controls must be (B, H, {self.n_controls}), the vessel's actuator layout")
        if float(self.actuator_delay[0]) != 0.0 or self.actuator_delay.requires_grad:
            controls = self._delayed(controls)
        psi0 = state[:, 3] - self.heading_offset[0]
        c, s = torch.cos(psi0), torch.sin(psi0)
        zeros = torch.zeros_like(psi0)
        x: List[Tensor] = [zeros, zeros, psi0,
                           state[:, 0] - (self.current_ne[0] * c + self.current_ne[1] * s),
                           state[:, 1] - (-self.current_ne[0] * s + self.current_ne[1] * c),
                           state[:, 2] - self.yaw_rate_bias[0]]
        held = x[3]  # (B,) the water speed whose straight running sets rudder_only's engine speed: the start's ...
        psi_held = psi0
        if reference is not None:  # ... or the reference state's (module docstring)
            ref = reference.to(torch.float64)  # (B, 4) measured u, v, r, psi
            psi_held = ref[:, 3] - self.heading_offset[0]
            held = ref[:, 0] - (self.current_ne[0] * torch.cos(psi_held) + self.current_ne[1] * torch.sin(psi_held))
        resistance = self.hull_forces.resistance(self.hull_list(), self.resistance_change)
        # the sea's surge force in that straight running (wind, waves): the engine holds the speed against it too
        sea_x = self._sea_loads(psi_held, held, torch.zeros_like(held))[0]  # (B,) N
        carry = self.actuator_forces.begin(held, controls, [resistance[0], resistance[1], sea_x],
                                           self.engine_speed_rpm)  # (B, K)
        return controls, x, carry

    def _stage(self, c0: Tensor, dc: Tensor, j: int, carry: Tensor) -> List[Tensor]:
        """The actuator levels of substep j of a step whose reported controls go from c0 to c0 + dc (B, C) (first-order
        hold), at RK4's three stages (the substep's start, middle, end): actuator_forces.stage's [a, b] x 3 and the
        carry at the end (shared by _rollout and fit_check's causes' rollout)."""
        a0 = float(j) / self.substeps
        a1 = (float(j) + 0.5) / self.substeps
        a2 = (float(j) + 1.0) / self.substeps
        return self.actuator_forces.stage(c0 + a0 * dc, c0 + a1 * dc, c0 + a2 * dc, carry, self.rudder_offset)

    def _rollout(self, state: Tensor, controls: Tensor, reference: Optional[Tensor] = None) -> Tensor:
        """(B, H, 6) [u, v, r, x_n, y_e, psi] as measured (the module docstring's interface without the ensemble
        axis)."""
        controls, x, carry = self._start(state, controls, reference)
        h = self.dt / self.substeps
        outputs: List[Tensor] = []
        steps = controls.shape[1]
        for k in range(steps):
            # first-order hold: the reported controls are samples, the actuators move between them
            c0 = controls[:, k]
            dc = controls[:, min(k + 1, steps - 1)] - c0
            for j in range(self.substeps):
                lv = self._stage(c0, dc, j, carry)
                k1 = self._derivative(x, lv[0], lv[1])
                k2 = self._derivative([p + 0.5 * h * q for p, q in zip(x, k1)], lv[2], lv[3])
                k3 = self._derivative([p + 0.5 * h * q for p, q in zip(x, k2)], lv[2], lv[3])
                k4 = self._derivative([p + h * q for p, q in zip(x, k3)], lv[4], lv[5])
                x = [p + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for p, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
                carry = lv[6]
            c, s = torch.cos(x[2]), torch.sin(x[2])
            u_g = x[3] + self.current_ne[0] * c + self.current_ne[1] * s
            v_g = x[4] - self.current_ne[0] * s + self.current_ne[1] * c
            outputs.append(torch.stack([u_g, v_g, x[5] + self.yaw_rate_bias[0], x[0], x[1],
                                        x[2] + self.heading_offset[0]], dim=-1))
        return torch.stack(outputs, dim=1)  # (B, H, 6)

    @torch.jit.ignore
    def terms(self) -> Dict[str, List[float]]:
        return {name: getattr(self, name).detach().tolist() for name in self.term_names}


class GreyBoxPredictor:
    """A GreyBoxRollout behind the artifact's predict/metadata interface (numpy in, numpy out), predicting with the
    compiled kernel (models/kernel_rollout.KernelRollout, which re-reads the rollout's terms at every call), or with
    the rollout itself where the kernel cannot run it (inference_note says which and why)."""

    def __init__(self, rollout: GreyBoxRollout, metadata: Dict[str, object], vessel: Vessel | None = None) -> None:
        from usv_predictor.models.kernel_rollout import KERNEL_FORM, KernelRollout, KernelUnavailable

        self.rollout = rollout
        self.metadata = dict(metadata)
        self.embedded_vessel = vessel  # the vessel it was built from (models/loading.model_vessel)
        try:
            self.kernel: Optional[KernelRollout] = KernelRollout(rollout, live=True)
            self.inference_note = KERNEL_FORM
        except KernelUnavailable as err:
            self.kernel, self.inference_note = None, f"the torch rollout ({err})"

    accepts_reference = True  # predict takes the reference state of rudder_only's engine speed (module docstring)

    def predict(self, state, controls, reference=None):  # (B, 4), (B, H, C), (B, 4) | None -> (1, B, H, 6)
        if self.kernel is not None:
            return self.kernel.rollout(np.asarray(state, dtype=np.float64), np.asarray(controls, dtype=np.float64),
                                       None if reference is None else np.asarray(reference, dtype=np.float64))
        with torch.no_grad():
            return self.rollout(torch.as_tensor(state, dtype=torch.float64),
                                torch.as_tensor(controls, dtype=torch.float64),
                                None if reference is None else torch.as_tensor(reference, dtype=torch.float64)).numpy()


def engine_speed_metadata(vessel: Vessel, rollout: GreyBoxRollout) -> Dict[str, object]:
    """{"engine_speed": how the artifact holds its engine speed} for a layout that reports no propulsion
    (rudder_only), {} for the others: what a user of the file (the node, another tool) must pass to get replay's
    predictions (module docstring)."""
    if vessel.actuator_layout.propulsion:
        return {}
    fixed = float(rollout.engine_speed_rpm.detach()[0])
    return {"engine_speed": {
        "held_rpm": fixed if fixed > 0.0 else None,
        "rule": "held over a prediction: held_rpm when set, else the engine speed that holds the water speed of the "
                "reference state in straight running against the calm-water resistance less the surge force of the "
                "model's wind and wave terms at the reference heading",
        "reference": "forward's third argument (B, 4) [u, v, r, psi] as measured; replay evaluate, diagnose and the "
                     "fit check pass the manoeuvre's approach (medians over its straight running before the first "
                     "turn command, at least approach_s); the predictor node the latest straight running it has seen "
                     "(node/live.ApproachTracker); without one the start state",
        "approach_s": APPROACH_S}}


def greybox_metadata(vessel: Vessel, rollout: GreyBoxRollout, *, model_type: str = "greybox",
                     training_data_sha256: str = "", horizon_steps: int = 120, training: Dict[str, object] | None = None
                     ) -> Dict[str, object]:
    """The artifact metadata of a grey box (usv_predictor/models/artifact.py REQUIRED_KEYS)."""
    from usv_predictor.models.artifact import UNITS

    layout = vessel.actuator_layout
    return {
        "model_type": model_type, "feature_set": "physics", "feature_names": [],
        "state_layout": ["u", "v", "r", "psi"], "control_layout": list(layout.control_names),
        "actuator_layout": layout.name, "hull_model": vessel.hull_model_name,
        "output_layout": ["u", "v", "r", "x_n", "y_e", "psi"], "dt": rollout.dt, "horizon_steps": int(horizon_steps),
        "normalisation": {}, "vessel": vessel.name, "training_data_sha256": training_data_sha256,
        "ensemble_size": 1,
        "architecture": {"structure": vessel.hull_model.structure, "substeps": rollout.substeps,
                         "hull": dict(zip(rollout.hull_names, rollout.hull.detach().tolist())),
                         "terms": rollout.terms()},
        "training": dict(training or {}), "units": dict(UNITS), **engine_speed_metadata(vessel, rollout),
    }


def greybox_predictor(vessel: Vessel, dt: float, substeps: int = 2) -> GreyBoxPredictor:
    """The calm-water grey box of a vessel as a predictor (the physics baseline of evaluations)."""
    rollout = GreyBoxRollout(vessel, dt=dt, substeps=substeps)
    label = f"physics (calm-water {vessel.hull_model.label} grey box of the preset)"
    meta = greybox_metadata(vessel, rollout, model_type=label)
    meta["model_id"] = f"physics-{vessel.name}"
    return GreyBoxPredictor(rollout, meta, vessel)


def hull_from_metadata(meta: Mapping[str, Any]) -> dict[str, float] | None:
    """The hull coefficients of a grey-box artifact's metadata, for either hull model (the fields of its hull model's
    section: vessel.Hull of the MMG hull, vessel.SmallCraftHull of the small-craft one; an identification's actuator
    gains come along under their section-qualified names, e.g. thrusters.port.forward_N): from `replay identify`
    (identification.coefficients) or from `replay diagnose --export` (architecture.hull); None for anything the
    plain grey box cannot carry (Abkowitz structure, extra terms, a learned residual, another family)."""
    ident = meta.get("identification")
    arch = meta.get("architecture")
    if isinstance(ident, dict):
        residual = arch.get("residual", "ZeroResidual") if isinstance(arch, dict) else "ZeroResidual"
        if ident.get("structure") == "abkowitz" or ident.get("extra_terms") or residual != "ZeroResidual":
            return None
        return {c["name"]: c["estimate"] for c in ident.get("coefficients", []) if isinstance(c, dict)}
    return arch.get("hull") if isinstance(arch, dict) and isinstance(arch.get("hull"), dict) else None


def _thrust_map(raw: Mapping[str, Any]) -> ThrustMap:
    return ThrustMap(**{k: tuple(float(x) for x in v) if isinstance(v, (list, tuple)) else float(v)
                        for k, v in raw.items()})


def actuator_sections_metadata(vessel: Vessel) -> Dict[str, Any]:
    """The vessel's identifiable actuator sections as plain data (artifact metadata): thrusters, throttle, rudder and
    propeller (their interaction factors: fitting/interaction.py)."""
    out: Dict[str, Any] = {}
    if vessel.thrusters is not None:
        t = vessel.thrusters
        out["thrusters"] = {"spacing": t.spacing, "x": t.x, "port": asdict(t.port), "starboard": asdict(t.starboard)}
    if vessel.throttle is not None:
        out["throttle"] = asdict(vessel.throttle)
    if vessel.rudder is not None and vessel.propeller is not None:  # the interaction factors identify may set
        out["rudder"] = asdict(vessel.rudder)
        out["propeller"] = asdict(vessel.propeller)
    return out


def vessel_from_metadata(meta: Mapping[str, Any], preset: Vessel) -> Vessel | None:
    """The calm-water vessel a grey-box artifact describes: `preset` (the vessel file it was made with) with the
    artifact's hull coefficients and, when the metadata carry them (an identification of thrusters or a throttle),
    its actuator sections; None when hull_from_metadata refuses the artifact. ValueError naming the difference when
    the artifact's hull model or actuator layout is not the preset's, or a hull coefficient is missing."""
    hull = hull_from_metadata(meta)
    if hull is None:
        return None
    for key, mine in (("hull_model", preset.hull_model_name), ("actuator_layout", preset.layout)):
        theirs = meta.get(key) or (meta.get("identification") or {}).get(key)
        if theirs is not None and theirs != mine:
            raise ValueError(f"the model's {key} is {theirs!r}, the vessel {preset.name}'s is {mine!r}")
    names, _ = hull_coefficients(preset)
    missing = [n for n in names if n not in hull and preset.hull_model_name == "mmg"]
    if missing:
        raise ValueError(f"hull coefficients {missing} missing from its metadata")
    section = preset.hull_model.coefficients
    vessel = replace(preset, **{section: replace(getattr(preset, section),
                                                 **{n: float(hull[n]) for n in names if n in hull})})
    sections = (meta.get("identification") or {}).get("actuator_sections") or {}
    if "thrusters" in sections and vessel.thrusters is not None:
        t = sections["thrusters"]
        vessel = replace(vessel, thrusters=Thrusters(float(t["spacing"]), float(t["x"]), _thrust_map(t["port"]),
                                                     _thrust_map(t["starboard"])))
    if "throttle" in sections and vessel.throttle is not None:
        vessel = replace(vessel, throttle=_thrust_map(sections["throttle"]))
    if "rudder" in sections and vessel.rudder is not None:
        vessel = replace(vessel, rudder=Rudder(**{k: float(v) for k, v in sections["rudder"].items()}))
    if "propeller" in sections and vessel.propeller is not None:
        vessel = replace(vessel, propeller=Propeller(**{k: float(v) for k, v in sections["propeller"].items()}))
    return vessel

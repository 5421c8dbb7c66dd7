"""The MMG manoeuvring model as a batched, differentiable, TorchScript-able closed-loop rollout.

Same equations as usv_predictor.physics.dynamics (Yasukawa & Yoshimura 2015 in Fossen's matrix form, seed 000
eq. 12-22 for the sea), written once more in torch because the two serve different needs: the float
version simulates one boat at 100 Hz output in well under a second, this one rolls out hundreds of
segments at once and gives gradients for identification and diagnosis. test_greybox.py proves they agree.

Interface (the model artifact's, see usv_predictor/models/artifact.py):
    forward(state (B, 4) [u, v, r, psi] as MEASURED, controls (B, H, 2) [delta rad, rpm] as REPORTED)
      -> (1, B, H, 6) [u, v, r, x_n, y_e, psi] as they will be MEASURED at dt, 2 dt, ... H dt,
         positions relative to the start (NED, m), psi continuous.
controls[:, k] is the reported control at step k; between samples the actuators move linearly (first-order
hold: the rudder of a recording changes during a step, and holding it would lag the response by half a step);
the last sample is held. RK4 with `substeps` per step.

Extension terms (all zero for the calm-water model; one attribute per Term of the effect records in
usv_predictor.physics.effects, which say which diagnosis hypothesis fits them; their equations are here):
    current_ne (2,) current velocity north/east (m/s);     wind_ne (2,) wind velocity (toward) north/east (m/s)
    wave_ne (2,) zeta_a^2 (m^2) along the direction the waves come FROM; rudder_offset (rad, true - reported)
    yaw_rate_bias (rad/s, measured - true); heading_offset (rad, measured - true);
    actuator_delay (s, the hull feels the reported controls this much later);
    resistance_change (-, relative change of the calm-water resistance R0: fouling, loading, a preset off);
    propeller_side_force (-, transverse propeller force / thrust, + to starboard: propeller walk).
"""
from __future__ import annotations

import math
from typing import Any, Dict, List, Mapping

import torch
from torch import Tensor, nn

from usv_predictor.physics import effects
from usv_predictor.physics.dynamics import SPEED_FLOOR, constants_of
from usv_predictor.physics.vessel import RHO_WATER, Vessel

HULL_NAMES = ("R0", "X_vv", "X_vr", "X_rr", "X_vvvv", "Y_v", "Y_r", "Y_vvv", "Y_vvr", "Y_vrr", "Y_rrr",
              "N_v", "N_r", "N_vvv", "N_vvr", "N_vrr", "N_rrr")


def _fourier_table(series: tuple[float, tuple[tuple[int, float, float], ...]]) -> List[List[float]]:
    """[[a0/2, 0, 0], [n, a_n, b_n], ...] for TorchScript (no nested tuples of mixed types)."""
    half_a0, terms = series
    return [[half_a0, 0.0, 0.0]] + [[float(n), a, b] for n, a, b in terms]


class GreyBoxRollout(nn.Module):
    def __init__(self, vessel: Vessel, dt: float, substeps: int = 2) -> None:
        super().__init__()
        self.dt = float(dt)
        # module constants as attributes: TorchScript does not capture Python globals
        self.speed_floor = SPEED_FLOOR
        self.rho = RHO_WATER
        self.pi = math.pi
        self.substeps = int(substeps)
        # the SI constants of the equations of motion, from the one record both twins read (physics/dynamics.py)
        for name, value in constants_of(vessel).items():
            if name == "hull":
                continue  # a tensor below: identification and diagnosis set it
            setattr(self, name, _fourier_table(value) if name.startswith("drift_") else value)
        h = vessel.hull
        self.hull = nn.Parameter(torch.tensor([getattr(h, n) for n in HULL_NAMES], dtype=torch.float64),
                                 requires_grad=False)
        # the extension terms of the effect records, all zero: current_ne, wind_ne, wave_ne, rudder_offset, ...
        terms = effects.grey_box_terms()
        self.term_names = tuple(terms)
        for term in terms.values():
            setattr(self, term.name, nn.Parameter(torch.zeros(term.size, dtype=torch.float64), requires_grad=False))

    # ---- forces ---------------------------------------------------------------------------------
    def _fourier(self, table: List[List[float]], chi: Tensor) -> Tensor:
        value = torch.full_like(chi, table[0][0])
        for row in table[1:]:
            value = value + row[1] * torch.cos(row[0] * chi) + row[2] * torch.sin(row[0] * chi)
        return value

    def _air_load(self, u_rw: Tensor, v_rw: Tensor) -> List[Tensor]:
        v2 = u_rw * u_rw + v_rw * v_rw
        gamma = -torch.atan2(v_rw, u_rw)
        return [-self.wind_x * v2 * torch.cos(gamma), self.wind_y * v2 * torch.sin(gamma),
                self.wind_n * v2 * torch.sin(2.0 * gamma)]

    def _accelerations(self, psi: Tensor, u_r: Tensor, v_r: Tensor, r: Tensor, delta: Tensor,
                       rpm: Tensor) -> List[Tensor]:
        """[u_r_dot, v_r_dot, r_dot] for (B,) tensors (dynamics.ManoeuvringModel.accelerations)."""
        h = self.hull
        L = self.L
        U = torch.clamp(torch.sqrt(u_r * u_r + v_r * v_r), min=self.speed_floor)
        vp = v_r / U
        rp = r * L / U
        q = self.q_force * U * U
        x_h = q * (-h[0] * (1.0 + self.resistance_change[0]) * u_r * torch.abs(u_r) / (U * U) + h[1] * vp * vp + h[2] * vp * rp + h[3] * rp * rp
                   + h[4] * vp ** 4)
        y_h = q * (h[5] * vp + h[6] * rp + h[7] * vp ** 3 + h[8] * vp * vp * rp + h[9] * vp * rp * rp
                   + h[10] * rp ** 3)
        n_h = q * L * (h[11] * vp + h[12] * rp + h[13] * vp ** 3 + h[14] * vp * vp * rp + h[15] * vp * rp * rp
                       + h[16] * rp ** 3)
        # propeller
        speed = torch.sqrt(u_r * u_r + v_r * v_r) + 1e-9
        beta_p = torch.atan2(-v_r, torch.clamp(u_r, min=1e-9)) - self.x_P * r * L / speed
        u_p = u_r * (1.0 - self.w_P0 * torch.exp(-4.0 * beta_p * beta_p))
        n_p = torch.clamp(rpm / 60.0 / self.gear_ratio, min=1e-6)
        j = u_p / (n_p * self.D_P)
        k_t = self.k0 + self.k1 * j + self.k2 * j * j
        running = (rpm / 60.0 / self.gear_ratio > 1e-6).to(u_r.dtype)
        x_p = running * (1.0 - self.t_P) * self.rho * n_p * n_p * self.D_P ** 4 * k_t
        # rudder
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
        # sea: apparent wind over ground, mean wave drift
        c, s = torch.cos(psi), torch.sin(psi)
        u_g = u_r + self.current_ne[0] * c + self.current_ne[1] * s
        v_g = v_r - self.current_ne[0] * s + self.current_ne[1] * c
        wind = self._air_load(u_g - (self.wind_ne[0] * c + self.wind_ne[1] * s),
                              v_g - (-self.wind_ne[0] * s + self.wind_ne[1] * c))
        still = self._air_load(u_g, v_g)  # still-air drag is in R0: the load is the increment (dynamics.py)
        x_w, y_w, n_w = wind[0] - still[0], wind[1] - still[1], wind[2] - still[2]
        amp = torch.sqrt(self.wave_ne[0] ** 2 + self.wave_ne[1] ** 2 + 1e-30)  # finite gradient at zero
        chi = torch.atan2(self.wave_ne[1], self.wave_ne[0]) - psi
        qw = self.q_wave * amp
        x_wv = qw * self._fourier(self.drift_x, chi)
        y_wv = qw * self._fourier(self.drift_y, chi)
        n_wv = qw * L * self._fourier(self.drift_n, chi)
        y_p = self.propeller_side_force[0] * x_p / (1.0 - self.t_P)
        x = x_h + x_r + x_p + x_w + x_wv
        y = y_h + y_r + y_p + y_w + y_wv
        n = n_h + n_r + y_p * self.x_P * L + n_w + n_wv
        rhs_x = x + self.m22 * v_r * r + self.x_G * self.m * r * r
        rhs_y = y - self.m11 * u_r * r
        rhs_n = n - self.x_G * self.m * u_r * r
        return [rhs_x / self.m11, (self.m33 * rhs_y - self.m23 * rhs_n) / self.det_vr,
                (self.m22 * rhs_n - self.m32 * rhs_y) / self.det_vr]

    def _derivative(self, s: List[Tensor], delta: Tensor, rpm: Tensor) -> List[Tensor]:
        """d/dt of [x_n, y_e, psi, u_r, v_r, r]; positions move with the current (over ground)."""
        psi, u_r, v_r, r = s[2], s[3], s[4], s[5]
        c, sn = torch.cos(psi), torch.sin(psi)
        u = u_r + self.current_ne[0] * c + self.current_ne[1] * sn
        v = v_r - self.current_ne[0] * sn + self.current_ne[1] * c
        acc = self._model_accelerations(psi, u_r, v_r, r, delta, rpm)
        return [u * c - v * sn, u * sn + v * c, r, acc[0], acc[1], acc[2]]

    def _model_accelerations(self, psi: Tensor, u_r: Tensor, v_r: Tensor, r: Tensor, delta: Tensor,
                             rpm: Tensor) -> List[Tensor]:
        """The accelerations the rollout integrates; a hybrid model adds its learned residual here."""
        return self._accelerations(psi, u_r, v_r, r, delta, rpm)

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

    def forward(self, state: Tensor, controls: Tensor) -> Tensor:
        state = state.to(torch.float64)  # (B, 4) measured u, v, r, psi
        controls = controls.to(torch.float64)  # (B, H, 2) reported delta, rpm
        if float(self.actuator_delay[0]) != 0.0 or self.actuator_delay.requires_grad:
            controls = self._delayed(controls)
        psi0 = state[:, 3] - self.heading_offset[0]
        c, s = torch.cos(psi0), torch.sin(psi0)
        zeros = torch.zeros_like(psi0)
        x: List[Tensor] = [zeros, zeros, psi0,
                           state[:, 0] - (self.current_ne[0] * c + self.current_ne[1] * s),
                           state[:, 1] - (-self.current_ne[0] * s + self.current_ne[1] * c),
                           state[:, 2] - self.yaw_rate_bias[0]]
        h = self.dt / self.substeps
        outputs: List[Tensor] = []
        steps = controls.shape[1]
        for k in range(steps):
            # first-order hold: the reported controls are samples, the actuators move between them
            c0 = controls[:, k]
            dc = controls[:, min(k + 1, steps - 1)] - c0
            for j in range(self.substeps):
                a0 = float(j) / self.substeps
                a1 = (float(j) + 0.5) / self.substeps
                a2 = (float(j) + 1.0) / self.substeps
                u0 = c0 + a0 * dc
                u1 = c0 + a1 * dc
                u2 = c0 + a2 * dc
                d0, d1, d2 = u0[:, 0] + self.rudder_offset[0], u1[:, 0] + self.rudder_offset[0], u2[:, 0] + self.rudder_offset[0]
                k1 = self._derivative(x, d0, u0[:, 1])
                k2 = self._derivative([a + 0.5 * h * b for a, b in zip(x, k1)], d1, u1[:, 1])
                k3 = self._derivative([a + 0.5 * h * b for a, b in zip(x, k2)], d1, u1[:, 1])
                k4 = self._derivative([a + h * b for a, b in zip(x, k3)], d2, u2[:, 1])
                x = [a + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
            c, s = torch.cos(x[2]), torch.sin(x[2])
            u_g = x[3] + self.current_ne[0] * c + self.current_ne[1] * s
            v_g = x[4] - self.current_ne[0] * s + self.current_ne[1] * c
            outputs.append(torch.stack([u_g, v_g, x[5] + self.yaw_rate_bias[0], x[0], x[1],
                                        x[2] + self.heading_offset[0]], dim=-1))
        return torch.stack(outputs, dim=1).unsqueeze(0)  # (1, B, H, 6)

    @torch.jit.ignore
    def terms(self) -> Dict[str, List[float]]:
        return {name: getattr(self, name).detach().tolist() for name in self.term_names}


class GreyBoxPredictor:
    """A GreyBoxRollout behind the artifact's predict/metadata interface (numpy in, numpy out)."""

    def __init__(self, rollout: GreyBoxRollout, metadata: Dict[str, object]) -> None:
        self.rollout = rollout
        self.metadata = dict(metadata)

    def predict(self, state, controls):  # (B, 4), (B, H, 2) -> (1, B, H, 6)
        with torch.no_grad():
            return self.rollout(torch.as_tensor(state, dtype=torch.float64),
                                torch.as_tensor(controls, dtype=torch.float64)).numpy()


def greybox_metadata(vessel: Vessel, rollout: GreyBoxRollout, *, model_type: str = "greybox",
                     training_data_sha256: str = "", horizon_steps: int = 120, training: Dict[str, object] | None = None
                     ) -> Dict[str, object]:
    """The artifact metadata of a grey box (usv_predictor/models/artifact.py REQUIRED_KEYS)."""
    from usv_predictor.models.artifact import UNITS

    return {
        "model_type": model_type, "feature_set": "physics", "feature_names": [],
        "state_layout": ["u", "v", "r", "psi"], "control_layout": ["delta", "rpm"],
        "output_layout": ["u", "v", "r", "x_n", "y_e", "psi"], "dt": rollout.dt, "horizon_steps": int(horizon_steps),
        "normalisation": {}, "vessel": vessel.name, "training_data_sha256": training_data_sha256,
        "ensemble_size": 1,
        "architecture": {"structure": "MMG (Yasukawa & Yoshimura 2015)", "substeps": rollout.substeps,
                         "hull": dict(zip(HULL_NAMES, rollout.hull.detach().tolist())), "terms": rollout.terms()},
        "training": dict(training or {}), "units": dict(UNITS),
    }


def greybox_predictor(vessel: Vessel, dt: float, substeps: int = 2) -> GreyBoxPredictor:
    """The calm-water grey box of a vessel as a predictor (the physics baseline of evaluations)."""
    rollout = GreyBoxRollout(vessel, dt=dt, substeps=substeps)
    meta = greybox_metadata(vessel, rollout, model_type="physics (calm-water MMG grey box of the preset)")
    meta["model_id"] = f"physics-{vessel.name}"
    return GreyBoxPredictor(rollout, meta)


def hull_from_metadata(meta: Mapping[str, Any]) -> dict[str, float] | None:
    """The MMG hull derivatives of a grey-box artifact's metadata: from `replay identify`
    (identification.coefficients) or from `replay diagnose --export` (architecture.hull); None for anything
    the plain grey box cannot carry (Abkowitz structure, extra terms, a learned residual, another family)."""
    ident = meta.get("identification")
    arch = meta.get("architecture")
    if isinstance(ident, dict):
        residual = arch.get("residual", "ZeroResidual") if isinstance(arch, dict) else "ZeroResidual"
        if ident.get("structure") != "mmg" or ident.get("extra_terms") or residual != "ZeroResidual":
            return None
        return {c["name"]: c["estimate"] for c in ident.get("coefficients", []) if isinstance(c, dict)}
    return arch.get("hull") if isinstance(arch, dict) and isinstance(arch.get("hull"), dict) else None

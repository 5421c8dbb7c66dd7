"""Grey box + residual: the identified MMG model with extra acceleration terms, one TorchScript rollout.

    nu_dot = f_MMG(nu, a, b; identified hull)  +  g(psi, u_r, v_r, r, a, b)                (seed 001 sec. 1, hybrid)

a, b are the actuator levels of the layout (delta rad and rpm for a rudder boat, the lagged port / starboard commands
of twins). g is one of
    PolynomialResidual    the Abkowitz-type terms beyond the MMG hull (identification.EXTRA_NAMES), as forces
                          turned into accelerations by M^-1 of the vessel (Yasukawa & Yoshimura 2015 eq. 4);
    GeneralisingResidual  the generalising hybrid: an ensemble of E small MLPs on features that generalise
                          (GENERALISING_FEATURES: the non-dimensional drift and yaw rate v' = v_r / U, r' = r L / U,
                          the speed U / U_ref, the actuator levels, and sin / cos psi for the sea, as seed 000's NTF
                          features, eq. 25-26), whose output is a non-dimensional acceleration scaled back by U^2 / L
                          (surge, sway) and U^2 / L^2 (yaw), so it is a force coefficient as the hull's are; it is
                          BOUNDED (bound * tanh, the bound set from the residuals of the identification data) and it
                          fades to zero outside the region of the data it was fitted on (support envelope: a Gaussian
                          fall-off, SUPPORT_WIDTH training standard deviations wide, of each feature's distance beyond
                          its training range), so where data is thin the physics alone predicts;
    SumResidual           two of them added (the Abkowitz terms of an identification + the learned residual).
ResidualGreyBox keeps GreyBoxRollout's forward interface (the model artifact's):
    forward(state (B, 4) [u, v, r, psi], controls (B, H, C), reference (B, 4) | None) -> (E, B, H, 6)
E = `members`: an ensemble residual runs as ONE rollout of E x B rows (member e owns rows e B .. e B + B - 1), so the
ensemble costs one grey-box rollout with a wider batch. It is exported through
usv_predictor.models.artifact.export_module with model_type "greybox" (polynomial residual) or "hybrid" (learned
residual); building and training them: usv_predictor.fitting.hybrid_fit.
"""
from __future__ import annotations

import math
from typing import List, Mapping, Optional

import torch
from torch import Tensor, nn

from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.physics.dynamics import HullConstants
from usv_predictor.physics.vessel import Vessel

GENERALISING_FEATURES = ("v_prime", "r_prime", "speed_ratio", "level_a", "level_b", "sin_psi", "cos_psi")
SPEED_FLOOR_RATIO = 0.05  # (-) U below this fraction of U_ref is taken as this (the scaling U^2 stays finite)
SUPPORT_WIDTH = 0.5  # (training std) the envelope falls to exp(-1/2) this far beyond a feature's training range
EXTRA_NAMES = ("X_du", "Y_0", "Y_duv", "Y_dur", "N_0", "N_duv", "N_dur")  # abkowitz terms beyond the MMG hull


class ZeroResidual(nn.Module):
    def forward(self, psi: Tensor, u: Tensor, v: Tensor, r: Tensor, delta: Tensor, rpm: Tensor) -> Tensor:
        return torch.zeros(u.shape[0], 3, dtype=u.dtype, device=u.device)  # (B, 3)


class PolynomialResidual(nn.Module):
    """Abkowitz-type extra hull terms [X_du, Y_0, Y_duv, Y_dur, N_0, N_duv, N_dur] -> accelerations."""

    def __init__(self, vessel: Vessel, terms: Mapping[str, float], u0: float) -> None:
        super().__init__()
        self.coef = nn.Parameter(torch.tensor([float(terms.get(n, 0.0)) for n in EXTRA_NAMES], dtype=torch.float64),
                                 requires_grad=False)
        self.u0 = float(u0)
        constants = HullConstants.of(vessel)  # the grey box's own record: the same L, q_force and mass matrix
        for name in ("L", "q_force", "m11", "m22", "m23", "m32", "m33"):
            setattr(self, name, getattr(constants, name))

    def forward(self, psi: Tensor, u: Tensor, v: Tensor, r: Tensor, delta: Tensor, rpm: Tensor) -> Tensor:
        c = self.coef
        U = torch.clamp(torch.sqrt(u * u + v * v), min=1e-3)
        vp, rp, du = v / U, r * self.L / U, (u - self.u0) / U
        q = self.q_force * U * U
        x = q * c[0] * du
        y = q * (c[1] + c[2] * du * vp + c[3] * du * rp)
        n = q * self.L * (c[4] + c[5] * du * vp + c[6] * du * rp)
        det = self.m22 * self.m33 - self.m23 * self.m32
        return torch.stack([x / self.m11, (self.m33 * y - self.m23 * n) / det,
                            (self.m22 * n - self.m32 * y) / det], dim=-1)  # (B, 3)


class GeneralisingResidual(nn.Module):
    """E members' bounded residual accelerations on features that generalise (module docstring).

    Per member e and sample: z = (features - in_mean) / in_std (F,), h = tanh(W_k h + b_k) over `layers` hidden
    layers, a' = bound * tanh(W_out h + b_out) * envelope(z) (3,) non-dimensional, and the accelerations
    [a'_0 U^2 / L, a'_1 U^2 / L, a'_2 U^2 / L^2]. The output layer starts at zero: an untrained residual is the grey
    box.
    The members' weights are stacked (E, ., .) and applied with one batched matmul per layer."""

    def __init__(self, L: float, u_ref: float, members: int = 5, hidden: int = 32, layers: int = 2) -> None:
        super().__init__()
        if members < 1 or hidden < 1 or layers < 1:
            raise ValueError(f"GeneralisingResidual: members, hidden and layers must be >= 1, got {members}, {hidden}, "
                             f"{layers}")
        self.L = float(L)  # (m)
        self.u_ref = float(u_ref)  # (m/s) the reference speed of speed_ratio (the data's median speed)
        self.members = int(members)
        self.speed_floor = SPEED_FLOOR_RATIO * self.u_ref  # (m/s)
        self.support_width = SUPPORT_WIDTH  # (training std)
        width = len(GENERALISING_FEATURES)
        widths = [width] + [hidden] * layers
        scale = [1.0 / math.sqrt(a) for a in widths[:-1]]
        self.weights = nn.ParameterList([nn.Parameter(torch.randn(members, a, b, dtype=torch.float64) * s)
                                         for a, b, s in zip(widths[:-1], widths[1:], scale)])  # (E, in, out)
        self.biases = nn.ParameterList([nn.Parameter(torch.zeros(members, 1, b, dtype=torch.float64))
                                        for b in widths[1:]])  # (E, 1, out)
        self.head_weight = nn.Parameter(torch.zeros(members, hidden, 3, dtype=torch.float64))  # (E, hidden, 3)
        self.head_bias = nn.Parameter(torch.zeros(members, 1, 3, dtype=torch.float64))  # (E, 1, 3)
        # set from the identification data by fitting.hybrid_fit (fixed in training)
        self.in_mean = nn.Parameter(torch.zeros(width, dtype=torch.float64), requires_grad=False)  # (F,)
        self.in_std = nn.Parameter(torch.ones(width, dtype=torch.float64), requires_grad=False)  # (F,)
        self.z_low = nn.Parameter(torch.full((width,), -math.inf, dtype=torch.float64), requires_grad=False)  # (F,)
        self.z_high = nn.Parameter(torch.full((width,), math.inf, dtype=torch.float64), requires_grad=False)  # (F,)
        self.bound = nn.Parameter(torch.ones(3, dtype=torch.float64), requires_grad=False)  # (3,) non-dimensional

    def features(self, psi: Tensor, u: Tensor, v: Tensor, r: Tensor, a: Tensor, b: Tensor) -> Tensor:
        """(N, F) GENERALISING_FEATURES from (N,) water-relative velocities, heading and actuator levels."""
        speed = torch.clamp(torch.sqrt(u * u + v * v), min=self.speed_floor)
        return torch.stack([v / speed, r * self.L / speed, speed / self.u_ref, a, b, torch.sin(psi), torch.cos(psi)],
                           dim=-1)

    def envelope(self, z: Tensor) -> Tensor:
        """(..., 1) 1 inside the training range of every feature, a Gaussian fall-off beyond it."""
        beyond = torch.relu(z - self.z_high) + torch.relu(self.z_low - z)  # (..., F) in training std
        return torch.exp(-0.5 * (beyond / self.support_width).pow(2).sum(dim=-1, keepdim=True))

    def nondimensional(self, x: Tensor) -> Tensor:
        """(E, B, 3) bounded non-dimensional residual of each member from (E, B, F) features."""
        z = (x - self.in_mean) / self.in_std  # (E, B, F)
        h = z
        for weight, bias in zip(self.weights, self.biases):
            h = torch.tanh(torch.baddbmm(bias, h, weight))  # (E, B, hidden)
        out = self.bound * torch.tanh(torch.baddbmm(self.head_bias, h, self.head_weight))  # (E, B, 3)
        return out * self.envelope(z)

    def forward(self, psi: Tensor, u: Tensor, v: Tensor, r: Tensor, a: Tensor, b: Tensor) -> Tensor:
        x = self.features(psi, u, v, r, a, b)  # (E B, F), member-major rows
        rows = x.shape[0] // self.members
        nd = self.nondimensional(x.reshape(self.members, rows, x.shape[1])).reshape(-1, 3)  # (E B, 3)
        q = x[:, 2:3] * self.u_ref  # (E B, 1) the (floored) speed U
        q = q * q / self.L
        return torch.cat([nd[:, 0:2] * q, nd[:, 2:3] * q / self.L], dim=1)  # (E B, 3) m/s^2, m/s^2, rad/s^2


class SumResidual(nn.Module):
    """first + second (e.g. the identification's Abkowitz terms and a learned residual)."""

    def __init__(self, first: nn.Module, second: nn.Module) -> None:
        super().__init__()
        self.first = first
        self.second = second

    def forward(self, psi: Tensor, u: Tensor, v: Tensor, r: Tensor, a: Tensor, b: Tensor) -> Tensor:
        return self.first(psi, u, v, r, a, b) + self.second(psi, u, v, r, a, b)


class ResidualGreyBox(GreyBoxRollout):
    """GreyBoxRollout whose accelerations get `residual` added (module docstring); `members` > 1 for an ensemble
    residual (GeneralisingResidual), rolled out as one batch of members x B rows."""

    def __init__(self, vessel: Vessel, dt: float, residual: nn.Module, substeps: int = 2, members: int = 1) -> None:
        super().__init__(vessel, dt, substeps)
        self.residual = residual
        self.members = int(members)

    def _model_accelerations(self, psi: Tensor, u_r: Tensor, v_r: Tensor, r: Tensor, delta: Tensor,
                             rpm: Tensor) -> List[Tensor]:
        acc = self._accelerations(psi, u_r, v_r, r, delta, rpm)
        extra = self.residual(psi, u_r, v_r, r, delta, rpm)  # (B, 3)
        return [acc[0] + extra[:, 0], acc[1] + extra[:, 1], acc[2] + extra[:, 2]]

    def forward(self, state: Tensor, controls: Tensor, reference: Optional[Tensor] = None) -> Tensor:
        rows = state.shape[0]
        if self.members == 1:
            return self._rollout(state, controls, reference).unsqueeze(0)  # (1, B, H, 6)
        if reference is not None:
            reference = reference.repeat(self.members, 1)  # (E B, 4)
        out = self._rollout(state.repeat(self.members, 1), controls.repeat(self.members, 1, 1),
                            reference)  # (E B, H, 6)
        return out.reshape(self.members, rows, out.shape[1], out.shape[2])  # (E, B, H, 6)

    def water_velocities(self, psi: Tensor, nu: Tensor) -> Tensor:
        """(N, 3) [u_r, v_r, r]: the measured (N, 3) [u, v, r] over ground less the model's current (the
        current_ne term, turned into the body frame at the (N,) heading psi; zero on a calm-water grey box)."""
        nu = nu.to(torch.float64)
        c, s = torch.cos(psi), torch.sin(psi)
        u_c = self.current_ne[0] * c + self.current_ne[1] * s  # (N,) the current along the body's x ...
        v_c = -self.current_ne[0] * s + self.current_ne[1] * c  # (N,) ... and y axis
        return torch.stack([nu[:, 0] - u_c, nu[:, 1] - v_c, nu[:, 2]], dim=-1)

    def accelerations_at(self, psi: Tensor, nu: Tensor, controls: Tensor) -> Tensor:
        """(N, 3) the model's d/dt of the measured [u, v, r] over ground at (N,) heading psi, (N, 3) nu over ground
        and (N, 2) actuator levels: the accelerations of the water-relative velocities (hull, actuators, the sea's
        loads at that heading, the residual) plus the turning of the current in the body frame,
            d/dt (u - u_r) = r (v - v_r),   d/dt (v - v_r) = -r (u - u_r)
        (u - u_r = c_n cos psi + c_e sin psi, v - v_r = -c_n sin psi + c_e cos psi). With no extension term it is
        accelerations(nu, controls) at any heading. The actuator stage's terms (rudder_offset, actuator_delay) and
        the sensors' (yaw_rate_bias, heading_offset) act in the rollout only, not here."""
        psi = psi.to(torch.float64)
        controls = controls.to(torch.float64)
        water = self.water_velocities(psi, nu)  # (N, 3)
        zero = torch.zeros_like(psi)
        d = self._derivative([zero, zero, psi, water[:, 0], water[:, 1], water[:, 2]], controls[:, 0], controls[:, 1])
        r = water[:, 2]
        return torch.stack([d[3] + r * (nu[:, 1] - water[:, 1]), d[4] - r * (nu[:, 0] - water[:, 0]), d[5]], dim=-1)

    def accelerations(self, nu: Tensor, controls: Tensor) -> Tensor:
        """(N, 3) model accelerations at (N, 3) nu and (N, 2) actuator levels (heading 0: calm water; a single-member
        residual)."""
        nu = nu.to(torch.float64)
        controls = controls.to(torch.float64)
        zero = torch.zeros_like(nu[:, 0])
        d = self._derivative([zero, zero, zero, nu[:, 0], nu[:, 1], nu[:, 2]], controls[:, 0], controls[:, 1])
        return torch.stack(d[3:], dim=-1)

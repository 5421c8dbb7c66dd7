"""Grey box + residual: the identified MMG model with extra acceleration terms, one TorchScript rollout.

    nu_dot = f_MMG(nu, delta, rpm; identified hull)  +  g(u, v, r, delta, rpm)             (seed 001 sec. 1, hybrid)

g is one of
    PolynomialResidual  the Abkowitz-type terms beyond the MMG hull (identification.EXTRA_NAMES), as forces
                        turned into accelerations by M^-1 of the vessel (Yasukawa & Yoshimura 2015 eq. 4);
    MlpResidual         a small MLP on normalised [u, v, r, delta, rpm], trained on the residual accelerations
                        nu_dot(smoothed) - f_MMG (what the grey box misses), tanh hidden layers so it stays bounded
                        away from the data.
ResidualGreyBox keeps GreyBoxRollout's forward interface (the model artifact's):
    forward(state (B, 4) [u, v, r, psi], controls (B, H, 2) [delta, rpm]) -> (1, B, H, 6)
and is exported through usv_predictor.models.artifact.export_module with model_type "greybox" (polynomial residual) or
"hybrid" (MLP residual); building and training them: usv_predictor.fitting.hybrid_fit.
"""
from __future__ import annotations

from typing import List, Mapping

import torch
from torch import Tensor, nn

from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.physics.dynamics import HullConstants
from usv_predictor.physics.vessel import Vessel

RESIDUAL_INPUTS = ("u", "v", "r", "delta", "rpm")
EXTRA_NAMES = ("X_du", "Y_0", "Y_duv", "Y_dur", "N_0", "N_duv", "N_dur")  # abkowitz terms beyond the MMG hull


class ZeroResidual(nn.Module):
    def forward(self, u: Tensor, v: Tensor, r: Tensor, delta: Tensor, rpm: Tensor) -> Tensor:
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

    def forward(self, u: Tensor, v: Tensor, r: Tensor, delta: Tensor, rpm: Tensor) -> Tensor:
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


class MlpResidual(nn.Module):
    """Residual accelerations from normalised [u, v, r, delta, rpm] (tanh MLP, output in target units)."""

    def __init__(self, hidden: int = 32, layers: int = 2) -> None:
        super().__init__()
        widths = [len(RESIDUAL_INPUTS)] + [hidden] * layers
        blocks: List[nn.Module] = []
        for a, b in zip(widths[:-1], widths[1:]):
            blocks += [nn.Linear(a, b), nn.Tanh()]
        self.body = nn.Sequential(*blocks)
        self.head = nn.Linear(widths[-1], 3)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)  # starts as the pure grey box
        self.in_mean = nn.Parameter(torch.zeros(len(RESIDUAL_INPUTS), dtype=torch.float64), requires_grad=False)
        self.in_std = nn.Parameter(torch.ones(len(RESIDUAL_INPUTS), dtype=torch.float64), requires_grad=False)
        self.out_std = nn.Parameter(torch.ones(3, dtype=torch.float64), requires_grad=False)
        self.double()

    def forward(self, u: Tensor, v: Tensor, r: Tensor, delta: Tensor, rpm: Tensor) -> Tensor:
        x = (torch.stack([u, v, r, delta, rpm], dim=-1) - self.in_mean) / self.in_std  # (B, 5)
        return self.head(self.body(x)) * self.out_std  # (B, 3)


class ResidualGreyBox(GreyBoxRollout):
    """GreyBoxRollout whose accelerations get `residual` added (module docstring)."""

    def __init__(self, vessel: Vessel, dt: float, residual: nn.Module, substeps: int = 2) -> None:
        super().__init__(vessel, dt, substeps)
        self.residual = residual

    def _model_accelerations(self, psi: Tensor, u_r: Tensor, v_r: Tensor, r: Tensor, delta: Tensor,
                             rpm: Tensor) -> List[Tensor]:
        acc = self._accelerations(psi, u_r, v_r, r, delta, rpm)
        extra = self.residual(u_r, v_r, r, delta, rpm)  # (B, 3)
        return [acc[0] + extra[:, 0], acc[1] + extra[:, 1], acc[2] + extra[:, 2]]

    def accelerations(self, nu: Tensor, controls: Tensor) -> Tensor:
        """(N, 3) model accelerations at (N, 3) nu and (N, 2) controls (heading irrelevant in calm water)."""
        nu = nu.to(torch.float64)
        controls = controls.to(torch.float64)
        zero = torch.zeros_like(nu[:, 0])
        d = self._derivative([zero, zero, zero, nu[:, 0], nu[:, 1], nu[:, 2]], controls[:, 0], controls[:, 1])
        return torch.stack(d[3:], dim=-1)

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
and is exported through usv_predictor.artifact.export_module with model_type "greybox" (polynomial residual) or
"hybrid" (MLP residual); see export_identified().
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, List, Mapping, Sequence

import numpy as np
import torch
from torch import Tensor, nn

from usv_predictor.artifact import OUTPUT_LAYOUT, UNITS, ModelArtifact, export_module
from usv_predictor.dynamics import ManoeuvringModel
from usv_predictor.errors import ModelError
from usv_predictor.features import CONTROL_NAMES, STATE_NAMES
from usv_predictor.greybox import GreyBoxRollout
from usv_predictor.identification import EXTRA_NAMES, ForceData, IdentificationResult
from usv_predictor.vessel import RHO_WATER, Vessel

RESIDUAL_INPUTS = ("u", "v", "r", "delta", "rpm")


class ZeroResidual(nn.Module):
    def forward(self, u: Tensor, v: Tensor, r: Tensor, delta: Tensor, rpm: Tensor) -> Tensor:
        return torch.zeros(u.shape[0], 3, dtype=u.dtype, device=u.device)  # (B, 3)


class PolynomialResidual(nn.Module):
    """Abkowitz-type extra hull terms [X_du, Y_0, Y_duv, Y_dur, N_0, N_duv, N_dur] -> accelerations."""

    def __init__(self, vessel: Vessel, terms: Mapping[str, float], u0: float) -> None:
        super().__init__()
        m = ManoeuvringModel(vessel)
        self.coef = nn.Parameter(torch.tensor([float(terms.get(n, 0.0)) for n in EXTRA_NAMES], dtype=torch.float64),
                                 requires_grad=False)
        self.u0 = float(u0)
        self.L = m.L
        self.q_force = 0.5 * RHO_WATER * vessel.geometry.L_pp * vessel.geometry.d
        self.m11, self.m22, self.m23, self.m32, self.m33 = m.m11, m.m22, m.m23, m.m32, m.m33

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


# ------------------------------------------------------------------------------------------ building and training


def greybox_module(result: IdentificationResult, dt: float, substeps: int = 2) -> ResidualGreyBox:
    """The identified grey box (with the abkowitz terms when that structure was chosen)."""
    residual: nn.Module = (PolynomialResidual(result.vessel, result.extra_terms, result.fit.u0)
                           if result.extra_terms else ZeroResidual())
    return ResidualGreyBox(result.vessel, dt, residual, substeps)


@dataclass(frozen=True)
class HybridTraining:
    epochs: int = 600
    hidden: int = 32
    layers: int = 2
    learning_rate: float = 3e-3
    weight_decay: float = 1e-4
    seed: int = 0


def residual_targets(module: ResidualGreyBox, data: Sequence[ForceData]) -> tuple[np.ndarray, np.ndarray]:
    """(inputs (N, 5) [u, v, r, delta, rpm], residual accelerations (N, 3)) over the kept samples."""
    nu = np.vstack([d.nu[d.keep] for d in data])
    controls = np.vstack([d.controls[d.keep] for d in data])
    measured = np.vstack([d.nu_dot[d.keep] for d in data])
    with torch.no_grad():
        model = module.accelerations(torch.from_numpy(nu), torch.from_numpy(controls)).numpy()
    return np.column_stack([nu, controls]), measured - model


def train_hybrid(result: IdentificationResult, dt: float, config: HybridTraining = HybridTraining(),
                 substeps: int = 2) -> tuple[ResidualGreyBox, dict[str, Any]]:
    """Grey box + MLP trained (full batch Adam, MSE in target-std units) on the residual accelerations."""
    torch.manual_seed(config.seed)
    base = greybox_module(result, dt, substeps)
    inputs, targets = residual_targets(base, result.data)
    if len(inputs) < 50:
        raise ModelError(f"hybrid: only {len(inputs)} samples to learn the residual from (need >= 50)")
    mlp = MlpResidual(config.hidden, config.layers)
    with torch.no_grad():
        mlp.in_mean.copy_(torch.from_numpy(inputs.mean(axis=0)))
        mlp.in_std.copy_(torch.from_numpy(np.maximum(inputs.std(axis=0), 1e-6)))
        mlp.out_std.copy_(torch.from_numpy(np.maximum(targets.std(axis=0), 1e-9)))
    x = torch.from_numpy(inputs)
    y = torch.from_numpy(targets)
    trainable = [p for p in mlp.parameters() if p.requires_grad]
    optimiser = torch.optim.Adam(trainable, lr=config.learning_rate, weight_decay=config.weight_decay)
    cols = (x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4])
    before = float(((y / mlp.out_std) ** 2).mean())
    loss = torch.tensor(before)
    for _ in range(config.epochs):
        optimiser.zero_grad()
        loss = (((mlp(*cols) - y) / mlp.out_std) ** 2).mean()
        loss.backward()
        optimiser.step()
    module = ResidualGreyBox(result.vessel, dt, mlp, substeps)
    info = {"samples": len(inputs), "epochs": config.epochs, "hidden": config.hidden, "layers": config.layers,
            "residual_nmse_before": before, "residual_nmse_after": float(loss.detach()),
            "residual_std": targets.std(axis=0).tolist()}
    return module, info


def export_identified(path: str, module: ResidualGreyBox, result: IdentificationResult, *, dt: float,
                      training_data_sha256: str, model_type: str = "greybox", hybrid: Mapping[str, Any] | None = None,
                      horizon_steps: int = 120, extra: Mapping[str, Any] | None = None) -> ModelArtifact:
    """One TorchScript file with the identification in its metadata (coefficients, CIs, structure, digest)."""
    if model_type not in ("greybox", "hybrid"):
        raise ModelError(f"model_type {model_type!r}: expected 'greybox' or 'hybrid'")
    metadata = {
        "model_type": model_type,
        "feature_set": "MMG grey box" + (" + MLP residual" if model_type == "hybrid" else ""),
        "feature_names": list(RESIDUAL_INPUTS),
        "state_layout": list(STATE_NAMES),
        "control_layout": list(CONTROL_NAMES),
        "output_layout": list(OUTPUT_LAYOUT),
        "dt": float(dt),
        "horizon_steps": int(horizon_steps),
        "normalisation": {},
        "vessel": result.vessel.name.removesuffix("_identified"),
        "training_data_sha256": training_data_sha256,
        "ensemble_size": 1,
        "architecture": {"structure": result.structure, "substeps": module.substeps,
                         "residual": type(module.residual).__name__, **dict(hybrid or {})},
        "training": {"method": "inverse-dynamics regression (EKF/RTS accelerations)", "prior": result.fit.prior_policy},
        "identification": result.to_json(),
        "units": UNITS,
        "dtype": "float64",
        **dict(extra or {}),
    }
    return export_module(path, module, metadata)

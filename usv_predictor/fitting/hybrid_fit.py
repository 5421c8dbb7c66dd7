"""Building the identified grey box and fitting the hybrid's learned residual (models/hybrid.py).

    greybox_module      the identified MMG grey box (+ the Abkowitz polynomial terms when that structure won)
    train_hybrid        grey box + MlpResidual trained on the residual accelerations nu_dot(smoothed) - f_MMG
    export_identified   one TorchScript artifact with the identification in its metadata
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from usv_predictor.data.features import STATE_NAMES
from usv_predictor.errors import ModelError
from usv_predictor.fitting.identification import ForceData, IdentificationResult
from usv_predictor.models.artifact import OUTPUT_LAYOUT, UNITS, ModelArtifact, export_module
from usv_predictor.models.greybox import actuator_sections_metadata, engine_speed_metadata, hull_coefficients
from usv_predictor.models.hybrid import MlpResidual, PolynomialResidual, ResidualGreyBox, ZeroResidual


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
    """(inputs (N, 5) [u, v, r, a, b], residual accelerations (N, 3)) over the kept samples; a, b the actuator
    levels of the layout (delta and rpm of a rudder boat, the lagged port and starboard commands of twins)."""
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
    """One TorchScript file with the identification in its metadata (coefficients, CIs, structure, digest) and the
    vessel file identified (result.prior) embedded."""
    if model_type not in ("greybox", "hybrid"):
        raise ModelError(f"model_type {model_type!r}: expected 'greybox' or 'hybrid'")
    vessel = result.vessel
    layout = vessel.actuator_layout
    identification = result.to_json()
    identification["actuator_sections"] = actuator_sections_metadata(vessel)  # the identified thrust maps, in full
    names, values = hull_coefficients(vessel)
    metadata = {
        "model_type": model_type,
        "feature_set": f"{vessel.hull_model.label} grey box" + (" + MLP residual" if model_type == "hybrid" else ""),
        "feature_names": ["u", "v", "r", *layout.commands],  # the residual's inputs (the state and actuator levels)
        "state_layout": list(STATE_NAMES),
        "control_layout": list(layout.control_names),
        "actuator_layout": layout.name,
        "hull_model": vessel.hull_model_name,
        "output_layout": list(OUTPUT_LAYOUT),
        "dt": float(dt),
        "horizon_steps": int(horizon_steps),
        "normalisation": {},
        "vessel": vessel.name.removesuffix("_identified"),
        "training_data_sha256": training_data_sha256,
        "ensemble_size": 1,
        "architecture": {"structure": result.structure, "hull_structure": vessel.hull_model.structure,
                         "substeps": module.substeps, "residual": type(module.residual).__name__,
                         "hull": dict(zip(names, values)), **dict(hybrid or {})},
        "training": {"method": "inverse-dynamics regression (EKF/RTS accelerations)", "prior": result.fit.prior_policy},
        "identification": identification,
        "units": UNITS,
        "dtype": "float64",
        **engine_speed_metadata(vessel, module),  # rudder_only: how the engine speed is held (identification's
        #                                           per-manoeuvre estimates: identification.actuators)
        **dict(extra or {}),
    }
    return export_module(path, module, metadata, vessel=result.prior)

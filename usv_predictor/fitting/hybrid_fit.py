"""Building the identified grey box and fitting the hybrid's learned residual (models/hybrid.py).

    greybox_module      the identified MMG grey box (+ the Abkowitz polynomial terms when that structure won)
    train_hybrid        grey box + GeneralisingResidual (an ensemble), trained by a multi-step (rollout) loss with
                        early stopping on manoeuvres held out whole, and pulled toward zero (issue 15)
    export_identified   one TorchScript artifact with the identification in its metadata

The hybrid's training (train_hybrid):
  1. the residual's feature normalisation, the training range of every feature (its support envelope) and the
     bound of its non-dimensional output come from the identification data: the one-step residual accelerations
     nu_dot(smoothed) - f_grey box (residual_targets) made non-dimensional by U^2 / L (U^2 / L^2 for yaw); the bound
     is BOUND_MARGIN x their 99.5th percentile, so the learned term can never exceed what the data showed;
  2. loss of member e = mean over its segments (data/segments.py: horizon_s rollouts from measured states with the
     recorded controls, seed 000's multi-step loss, Fig. 3, here through the grey box) of the squared residuals of
     u, v, r, the track and the heading in noise units (SIGMA)  +  zero_weight x mean (a' / bound)^2 over the
     one-step samples (regularisation toward the pure grey box); each member trains on its own bootstrap of the
     training segments and starts from its own random hidden weights (the ensemble's spread);
  3. early stopping per member on the same loss over whole held-out manoeuvres (data.dataset.split_by_manoeuvre):
     the weights of the epoch with the lowest validation loss are kept.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from usv_predictor.data.dataset import split_by_manoeuvre
from usv_predictor.data.features import STATE_NAMES
from usv_predictor.data.recording import Recording
from usv_predictor.data.segments import Segments, make_segments
from usv_predictor.errors import DiagnosisError, ModelError
from usv_predictor.fitting.identification import ForceData, IdentificationResult
from usv_predictor.fitting.training import reproducible
from usv_predictor.models.artifact import OUTPUT_LAYOUT, UNITS, ModelArtifact, export_module
from usv_predictor.models.greybox import actuator_sections_metadata, engine_speed_metadata, hull_coefficients
from usv_predictor.models.hybrid import (GENERALISING_FEATURES, GeneralisingResidual, PolynomialResidual,
                                         ResidualGreyBox, SumResidual, ZeroResidual)

BOUND_MARGIN = 1.5  # (-) the learned residual's bound over the 99.5th percentile of the data's residuals
MIN_SAMPLES = 50  # one-step samples the residual's statistics need


def greybox_module(result: IdentificationResult, dt: float, substeps: int = 2) -> ResidualGreyBox:
    """The identified grey box (with the abkowitz terms when that structure was chosen)."""
    residual: nn.Module = (PolynomialResidual(result.vessel, result.extra_terms, result.fit.u0)
                           if result.extra_terms else ZeroResidual())
    return ResidualGreyBox(result.vessel, dt, residual, substeps)


@dataclass(frozen=True)
class HybridTraining:
    members: int = 5  # ensemble members (spread)
    hidden: int = 32
    layers: int = 2
    epochs: int = 150  # at most; early stopping keeps the best
    patience: int = 30  # epochs without a better validation loss before a member stops improving
    learning_rate: float = 3e-3
    weight_decay: float = 1e-4
    horizon_s: float = 20.0  # (s) the multi-step loss' segments (the diagnosis' horizon)
    stride_s: float = 5.0  # (s) between segment starts
    zero_weight: float = 0.1  # (-) weight of the pull toward zero (step 2 of the module docstring)
    val_fraction: float = 0.25  # of the manoeuvres, held out whole for early stopping (none with one manoeuvre)
    validation: tuple[str, ...] = ()  # glob patterns of manoeuvres held out for early stopping (instead of the fraction)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("members", "hidden", "layers", "epochs", "patience"):
            if getattr(self, name) < 1:
                raise ModelError(f"hybrid training: {name} must be >= 1, got {getattr(self, name)}")
        for name in ("learning_rate", "horizon_s", "stride_s"):
            if not getattr(self, name) > 0.0:
                raise ModelError(f"hybrid training: {name} must be > 0, got {getattr(self, name)}")


def residual_targets(module: ResidualGreyBox, data: Sequence[ForceData]) -> tuple[np.ndarray, np.ndarray]:
    """(inputs (N, 5) [u, v, r, a, b], residual accelerations (N, 3)) over the kept samples; a, b the actuator
    levels of the layout (delta and rpm of a rudder boat, the lagged port and starboard commands of twins)."""
    nu = np.vstack([d.nu[d.keep] for d in data])
    controls = np.vstack([d.controls[d.keep] for d in data])
    measured = np.vstack([d.nu_dot[d.keep] for d in data])
    with torch.no_grad():
        model = module.accelerations(torch.from_numpy(nu), torch.from_numpy(controls)).numpy()
    return np.column_stack([nu, controls]), measured - model


def _residual_statistics(residual: GeneralisingResidual, base: ResidualGreyBox, data: Sequence[ForceData],
                         recordings: Sequence[Recording]) -> torch.Tensor:
    """Set the residual's normalisation, training range and bound from the identification data (step 1); returns
    the (N, F) features of the one-step samples (for the pull toward zero)."""
    psi_of = {rec.name: rec.psi for rec in recordings}
    for d in data:
        if d.name not in psi_of or len(psi_of[d.name]) != len(d.keep):
            raise ModelError(f"hybrid: the identification's manoeuvre {d.name!r} is not among the recordings given "
                             f"(or has another length): train the residual on the recordings that were identified")
    psi = np.concatenate([psi_of[d.name][d.keep] for d in data])  # (N,) heading of the one-step samples
    inputs, targets = residual_targets(base, data)  # (N, 5) [u, v, r, a, b], (N, 3)
    if len(inputs) < MIN_SAMPLES:
        raise ModelError(f"hybrid: only {len(inputs)} samples to learn the residual from (need >= {MIN_SAMPLES})")
    x = residual.features(*(torch.from_numpy(c) for c in (psi, *inputs.T)))  # (N, F)
    speed = x[:, 2:3].numpy() * residual.u_ref  # (N, 1) floored U
    nondim = targets * residual.L / speed ** 2  # (N, 3): u_dot L / U^2, v_dot L / U^2, then r_dot L / U^2 ...
    nondim[:, 2] *= residual.L  # ... r_dot L^2 / U^2
    with torch.no_grad():
        mean, std = x.mean(dim=0), x.std(dim=0).clamp(min=1e-6)
        residual.in_mean.copy_(mean)
        residual.in_std.copy_(std)
        z = (x - mean) / std
        residual.z_low.copy_(z.min(dim=0).values)
        residual.z_high.copy_(z.max(dim=0).values)
        residual.bound.copy_(torch.from_numpy(BOUND_MARGIN * np.maximum(np.percentile(np.abs(nondim), 99.5, axis=0),
                                                                         1e-9)))
    return x


def _split_segments(recordings: Sequence[Recording], config: HybridTraining) -> tuple[Segments, Segments | None,
                                                                                    dict[str, str]]:
    """Training and validation segments (data/segments.py), whole manoeuvres apart (none held out with one)."""
    names = [rec.name for rec in recordings]
    fraction = config.val_fraction if len(set(names)) > 1 and not config.validation else 0.0
    split = split_by_manoeuvre(names, val_fraction=fraction, seed=config.seed, val=config.validation)
    parts: dict[str, Segments | None] = {}
    for part in ("train", "val"):
        chosen = [rec for rec in recordings if split[rec.name] == part]
        try:
            parts[part] = make_segments(chosen, config.horizon_s, config.stride_s) if chosen else None
        except DiagnosisError as err:
            raise ModelError(f"hybrid: {part} manoeuvres {[r.name for r in chosen]}: {err}") from err
    if parts["train"] is None:
        raise ModelError("hybrid: no manoeuvre left to train on")
    return parts["train"], parts["val"], split


def _segment_losses(module: ResidualGreyBox, seg: Segments, weights: torch.Tensor | None = None) -> torch.Tensor:
    """(E,) each member's mean squared weighted residual (noise units, data/segments.SIGMA) of its rollouts over the
    segments: velocities, track and heading; `weights` (E, N) resample the segments per member."""
    predicted = module(seg.state, seg.controls, seg.reference)  # (E, N, H, 6)
    r = (predicted - seg.target) * seg.weight  # (E, N, H, 6)
    per_segment = (r * r).sum(dim=(2, 3)) / torch.count_nonzero(seg.weight, dim=(1, 2)).clamp(min=1)  # (E, N)
    if weights is None:
        return per_segment.mean(dim=1)
    return (per_segment * weights).sum(dim=1) / weights.sum(dim=1)


def train_hybrid(result: IdentificationResult, recordings: Sequence[Recording], dt: float,
                 config: HybridTraining = HybridTraining(), substeps: int = 2,
                 progress: Callable[[str], None] = lambda _: None) -> tuple[ResidualGreyBox, dict[str, Any]]:
    """The identified grey box + a GeneralisingResidual ensemble trained as the module docstring says; `recordings`
    are the identification's, at the model step dt (their names split training and validation manoeuvres)."""
    base = greybox_module(result, dt, substeps)
    train, val, split = _split_segments(recordings, config)
    speeds = np.hypot(*np.vstack([d.nu[d.keep] for d in result.data])[:, :2].T)
    u_ref = float(np.median(speeds)) if len(speeds) else 1.0
    with reproducible(config.seed, torch.get_num_threads()):
        learned = GeneralisingResidual(result.vessel.geometry.L_pp, max(u_ref, 0.1), config.members, config.hidden,
                                       config.layers)
        x_samples = _residual_statistics(learned, base, result.data, recordings)
        residual = SumResidual(base.residual, learned)
        module = ResidualGreyBox(result.vessel, dt, residual, substeps, members=config.members)
        bootstrap = torch.from_numpy(np.random.default_rng(config.seed).poisson(1.0, (config.members, len(train)))
                                     .astype(np.float64)) + 1e-3  # (E, N) each member's resampling of the segments
        trainable = [p for p in learned.parameters() if p.requires_grad]
        optimiser = torch.optim.Adam(trainable, lr=config.learning_rate, weight_decay=config.weight_decay)
        samples = x_samples.unsqueeze(0).expand(config.members, -1, -1)  # (E, N, F)
        best = [float("inf")] * config.members
        best_epoch = [0] * config.members
        best_state = [p.detach().clone() for p in trainable]
        history = []
        stale = 0
        for epoch in range(1, config.epochs + 1):
            optimiser.zero_grad()
            fit = _segment_losses(module, train, bootstrap)  # (E,)
            zero = ((learned.nondimensional(samples) / learned.bound) ** 2).sum(dim=-1).mean(dim=-1)  # (E,)
            (fit + config.zero_weight * zero).sum().backward()
            optimiser.step()
            fit = fit.detach()
            with torch.no_grad():
                monitor = (_segment_losses(module, val) if val is not None
                           else _segment_losses(module, train) + config.zero_weight * zero)  # (E,)
            history.append((fit.tolist(), monitor.tolist()))
            improved = False
            for e in range(config.members):
                if float(monitor[e]) < best[e]:
                    best[e], best_epoch[e], improved = float(monitor[e]), epoch, True
                    for keep, p in zip(best_state, trainable):
                        keep[e].copy_(p.detach()[e])
            stale = 0 if improved else stale + 1
            if epoch % 10 == 0 or epoch == 1:
                progress(f"  hybrid epoch {epoch}: train {float(fit.mean()):.4g}, "
                         f"{'val' if val is not None else 'train'} {float(monitor.mean()):.4g}")
            if stale >= config.patience:
                break
        with torch.no_grad():
            for keep, p in zip(best_state, trainable):
                p.copy_(keep)
            grey = _segment_losses(ResidualGreyBox(result.vessel, dt, base.residual, substeps),
                                   val if val is not None else train)
    info = {"residual": "GeneralisingResidual", "features": list(GENERALISING_FEATURES), "members": config.members,
            "hidden": config.hidden, "layers": config.layers, "u_ref_mps": learned.u_ref,
            "bound": learned.bound.tolist(), "horizon_s": config.horizon_s, "zero_weight": config.zero_weight,
            "epochs_run": len(history), "best_epoch": best_epoch,
            "monitor": "val" if val is not None else "train",
            "val_manoeuvres": sorted({n for n, s in split.items() if s == "val"}),
            "loss_best": best, "loss_grey_box": float(grey[0]), "segments_train": len(train),
            "segments_val": len(val) if val is not None else 0}
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
        "feature_set": f"{vessel.hull_model.label} grey box" + (" + learned residual" if model_type == "hybrid" else ""),
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
        "ensemble_size": int(getattr(module, "members", 1)),
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

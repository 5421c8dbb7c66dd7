"""Building the identified grey box and fitting the hybrid's learned residual (models/hybrid.py).

    greybox_module      the identified MMG grey box (+ the Abkowitz polynomial terms when that structure won)
    base_from_artifact  a grey box read back from its artifact (`replay identify`, or `replay diagnose --export`:
                        the calm-water model extended with the diagnosed causes, e.g. current + wave drift), with its
                        extension terms, checked to roll out exactly as the file does
    train_hybrid        grey box + GeneralisingResidual (an ensemble), trained by a multi-step (rollout) loss with
                        early stopping on manoeuvres held out whole, and pulled toward zero
    train_residual      the same on any grey box (train_hybrid's work): on an extended grey box the physics carries
                        the sea (the current moves the boat, the wave drift pushes it) and the residual only what the
                        extension leaves, its bound set from what the extension leaves (step 1)
    export_identified   one TorchScript artifact with the identification in its metadata
    export_on_base      one TorchScript artifact of a hybrid on a base artifact, with the base's metadata

The hybrid's training (train_hybrid):
  1. the residual's feature normalisation, the training range of every feature (its support envelope) and the
     bound of its non-dimensional output come from the identification data: the one-step residual accelerations
     nu_dot(smoothed) - f_grey box (residual_targets; the grey box at the sample's heading with its extension terms,
     features of the velocities through the water) made non-dimensional by U^2 / L (U^2 / L^2 for yaw); the bound
     is BOUND_MARGIN x the 99.5th percentile of their running mean over bound_window_s (10 s: what persists, the
     part a residual of the state can explain; per sample, the first-order wave motion of a sea trial set a bound 10
     times larger), so the learned term can never exceed what the data showed the base leaves (an extension that
     explains the sea leaves less: on the shipped sea trial a bound 2-5 times tighter than the calm-water model's);
  2. loss of member e = mean over its segments (data/segments.py: horizon_s rollouts from measured states with the
     recorded controls, seed 000's multi-step loss, Fig. 3, here through the grey box) of the squared residuals of
     u, v, r, the track and the heading in noise units (SIGMA)  +  zero_weight x mean (a' / bound)^2 over the
     one-step samples (regularisation toward the pure grey box); each member trains on its own bootstrap of the
     training segments and starts from its own random hidden weights (the ensemble's spread);
  3. early stopping per member on the same loss over whole held-out manoeuvres (data.dataset.split_by_manoeuvre):
     the weights of the epoch with the lowest validation loss are kept, the untrained residual (epoch 0: the base
     alone) among them, so a member whose learned term never predicts the held-out manoeuvres better than its base
     keeps none (best_epoch 0).
  4. a non-finite loss stops the training (errors.TrainingDiverged naming the epoch, the member, the loss and the
     likely cause): before the first step, a base whose rollouts diverge on some segments (a residual bounded by what
     the data showed cannot make an unstable grey box stable, and a NaN gradient would poison every weight) or one-
     step samples that are not finite; after it, the learned term driving the rollout unstable (the learning rate).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from usv_predictor.data.dataset import split_by_manoeuvre
from usv_predictor.data.features import STATE_NAMES
from usv_predictor.data.recording import Recording
from usv_predictor.data.segments import Segments, make_segments, weighted_residuals
from usv_predictor.errors import DiagnosisError, ModelError, TrainingDiverged
from usv_predictor.fitting.identification import ForceData, IdentificationResult
from usv_predictor.fitting.training import reproducible
from usv_predictor.models.artifact import OUTPUT_LAYOUT, UNITS, ModelArtifact, export_module
from usv_predictor.models.families import MODEL_FAMILIES, family_name
from usv_predictor.models.greybox import (actuator_sections_metadata, engine_speed_metadata, hull_coefficients,
                                          vessel_from_metadata)
from usv_predictor.physics.vessel import Vessel
from usv_predictor.models.hybrid import (GENERALISING_FEATURES, GeneralisingResidual, PolynomialResidual,
                                         ResidualGreyBox, SumResidual, ZeroResidual)

BOUND_MARGIN = 1.5  # (-) the learned residual's bound over the 99.5th percentile of the data's residuals
MIN_SAMPLES = 50  # one-step samples the residual's statistics need


def greybox_module(result: IdentificationResult, dt: float, substeps: int = 2) -> ResidualGreyBox:
    """The identified grey box (with the abkowitz terms when that structure was chosen)."""
    residual: nn.Module = (PolynomialResidual(result.vessel, result.extra_terms, result.fit.u0)
                           if result.extra_terms else ZeroResidual())
    return ResidualGreyBox(result.vessel, dt, residual, substeps)


BASE_CHECK_STEPS = 50  # model steps of the probe rollout that proves a rebuilt base equals its artifact


def base_from_artifact(artifact: ModelArtifact, preset: Vessel, probe: Recording, *,
                       source: str = "--base") -> tuple[Vessel, ResidualGreyBox]:
    """(the vessel, the grey box) of a grey-box artifact (`replay identify --structure mmg`, or `replay diagnose
    --export`: the calm-water model with the diagnosed causes' terms), `preset` the vessel file it was made with.
    The hull comes from the metadata (models.greybox.vessel_from_metadata), the extension terms (current_ne,
    wave_ne, ...) and the held engine speed from the file's module; the rebuilt grey box must roll out the first
    BASE_CHECK_STEPS steps of `probe` (a recording at the model's step: its first state, its controls) as the file
    does (to 1e-9), else ModelError: a base it cannot rebuild is refused, never approximated.
    A learned model, a hybrid or an Abkowitz grey box is refused by name (ModelError)."""
    meta = artifact.metadata
    family = MODEL_FAMILIES.get(family_name(str(meta.get("model_type", ""))))
    try:
        vessel = vessel_from_metadata(meta, preset) if family is not None and family.physics else None
    except ValueError as err:
        raise ModelError(f"{source} {artifact.path}: {err}") from None
    if vessel is None:
        raise ModelError(f"{source} {artifact.path}: a hybrid's base must be a grey box without learned or extra terms "
                         f"(`replay identify --structure mmg`, or its `replay diagnose --export` extension), not "
                         f"model_type {meta.get('model_type')!r}")
    substeps = int((meta.get("architecture") or {}).get("substeps", 2))
    base = with_terms(ResidualGreyBox(vessel, float(meta["dt"]), ZeroResidual(), substeps), artifact.module)
    steps = min(BASE_CHECK_STEPS, len(probe))
    state = torch.from_numpy(np.asarray(probe.state()[:1], dtype=np.float64))  # (1, 4)
    controls = torch.from_numpy(np.asarray(probe.controls[None, :steps], dtype=np.float64))  # (1, H, C)
    with torch.no_grad():
        mine = base(state, controls)[0]  # (1, H, 6)
        theirs = artifact.module(state, controls, None)[0]  # (1, H, 6)
    if theirs.shape != mine.shape or not torch.allclose(mine, theirs, rtol=0.0, atol=1e-9):
        raise ModelError(f"{source} {artifact.path}: its grey box could not be rebuilt from its metadata (the rebuilt "
                         f"rollout differs from the file's by {float((mine - theirs).abs().max()):.3g}): an extension "
                         f"term this version does not know?")
    return vessel, base


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
    bound_window_s: float = 10.0  # (s) the bound is taken from the one-step residuals averaged over this window
    #                               (step 1: what persists, not the waves' first-order oscillation; 0: per sample)
    val_fraction: float = 0.25  # of the manoeuvres, held out whole for early stopping (none with one manoeuvre)
    # glob patterns of manoeuvres held out for early stopping (instead of the fraction)
    validation: tuple[str, ...] = ()
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("members", "hidden", "layers", "epochs", "patience"):
            if getattr(self, name) < 1:
                raise ModelError(f"hybrid training: {name} must be >= 1, got {getattr(self, name)}")
        for name in ("learning_rate", "horizon_s", "stride_s"):
            if not getattr(self, name) > 0.0:
                raise ModelError(f"hybrid training: {name} must be > 0, got {getattr(self, name)}")
        if not self.bound_window_s >= 0.0:
            raise ModelError(f"hybrid training: bound_window_s must be >= 0, got {self.bound_window_s}")


def residual_targets(module: ResidualGreyBox, data: Sequence[ForceData],
                     psi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(inputs (N, 5) [u, v, r, a, b], residual accelerations (N, 3)) over the kept samples; a, b the actuator
    levels of the layout (delta and rpm of a rudder boat, the lagged port and starboard commands of twins).
    psi (N,): the samples' headings, for a grey box with extension terms (ResidualGreyBox.accelerations_at: its
    current and sea loads; u, v are then through the water); None: calm water (heading 0, u, v over ground)."""
    nu = np.vstack([d.nu[d.keep] for d in data])
    controls = np.vstack([d.controls[d.keep] for d in data])
    measured = np.vstack([d.nu_dot[d.keep] for d in data])
    with torch.no_grad():
        if psi is None:
            model = module.accelerations(torch.from_numpy(nu), torch.from_numpy(controls)).numpy()
            velocities = nu
        else:
            heading = torch.from_numpy(np.asarray(psi, dtype=np.float64))
            model = module.accelerations_at(heading, torch.from_numpy(nu), torch.from_numpy(controls)).numpy()
            velocities = module.water_velocities(heading, torch.from_numpy(nu)).numpy()
    return np.column_stack([velocities, controls]), measured - model


def running_mean(values: np.ndarray, groups: np.ndarray, width: int) -> np.ndarray:
    """(N, K) centred running mean of `width` samples of (N, K) values within each run of equal (N,) groups (a
    manoeuvre's kept samples); the window shrinks at a run's ends (same length out)."""
    out = np.empty_like(values)
    for g in np.unique(groups):
        rows = np.flatnonzero(groups == g)
        v = values[rows]
        csum = np.vstack([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
        half = max(width, 1) // 2
        lo = np.clip(np.arange(len(v)) - half, 0, len(v))
        hi = np.clip(np.arange(len(v)) + half + 1, 0, len(v))
        out[rows] = (csum[hi] - csum[lo]) / (hi - lo)[:, None]
    return out


def _residual_statistics(residual: GeneralisingResidual, base: ResidualGreyBox, data: Sequence[ForceData],
                         recordings: Sequence[Recording], bound_window_s: float = 0.0) -> torch.Tensor:
    """Set the residual's normalisation, training range and bound from the identification data (step 1); returns
    the (N, F) features of the one-step samples (for the pull toward zero)."""
    psi_of = {rec.name: rec.psi for rec in recordings}
    for d in data:
        if d.name not in psi_of or len(psi_of[d.name]) != len(d.keep):
            raise ModelError(f"hybrid: the identification's manoeuvre {d.name!r} is not among the recordings given "
                             f"(or has another length): train the residual on the recordings that were identified")
    psi = np.concatenate([psi_of[d.name][d.keep] for d in data])  # (N,) heading of the one-step samples
    inputs, targets = residual_targets(base, data, psi)  # (N, 5) [u_r, v_r, r, a, b], (N, 3)
    if len(inputs) < MIN_SAMPLES:
        raise ModelError(f"hybrid: only {len(inputs)} samples to learn the residual from (need >= {MIN_SAMPLES})")
    x = residual.features(*(torch.from_numpy(c) for c in (psi, *inputs.T)))  # (N, F)
    speed = x[:, 2:3].numpy() * residual.u_ref  # (N, 1) floored U
    nondim = targets * residual.L / speed ** 2  # (N, 3): u_dot L / U^2, v_dot L / U^2, then r_dot L / U^2 ...
    nondim[:, 2] *= residual.L  # ... r_dot L^2 / U^2
    if bound_window_s > 0.0:  # the systematic part: the waves' first-order oscillation averages out
        groups = np.concatenate([np.full(int(d.keep.sum()), k) for k, d in enumerate(data)])
        widths = {round(bound_window_s / float(np.median(np.diff(d.t_s)))) for d in data if len(d.t_s) > 1}
        nondim = running_mean(nondim, groups, max(widths, default=1))
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


def _segment_losses(module: ResidualGreyBox, seg: Segments, weights: torch.Tensor | None = None,
                    predicted: torch.Tensor | None = None) -> torch.Tensor:
    """(E,) each member's mean squared weighted residual (noise units, data/segments.SIGMA) of its rollouts over the
    segments: velocities, track and heading; `weights` (E, N) resample the segments per member; `predicted` the
    rollouts when already made (else the module's own, differentiable)."""
    if predicted is None:
        predicted = module(seg.state, seg.controls, seg.reference)  # (E, N, H, 6)
    r = weighted_residuals(predicted, seg)  # (E, N, H, 6)
    per_segment = (r * r).sum(dim=(2, 3)) / torch.count_nonzero(seg.weight, dim=(1, 2)).clamp(min=1)  # (E, N)
    if weights is None:
        return per_segment.mean(dim=1)
    return (per_segment * weights).sum(dim=1) / weights.sum(dim=1)


def _monitored_losses(module: ResidualGreyBox, seg: Segments) -> torch.Tensor:
    """(E,) _segment_losses without gradients, the rollouts on the compiled kernel (models/kernel_rollout, built from
    the module's weights as they are now: equal to the module's rollout to rounding, test_kernel.py) where it can run
    the module, on the module itself otherwise: the early-stopping monitor of every epoch and the scores either side
    of the training, a third of a training's rollouts."""
    from usv_predictor.models.kernel_rollout import KernelRollout, KernelUnavailable

    with torch.no_grad():
        try:
            predicted = KernelRollout(module)(seg.state, seg.controls, seg.reference)  # (E, N, H, 6)
        except KernelUnavailable:
            predicted = None
        return _segment_losses(module, seg, predicted=predicted)


def _diverging_segments(module: ResidualGreyBox, seg: Segments) -> int:
    """How many segments the module's rollout leaves without a finite loss in some member (NaN/inf, or so large
    that its square overflows)."""
    with torch.no_grad():
        r = weighted_residuals(module(seg.state, seg.controls, seg.reference), seg)  # (E, N, H, 6)
        per_segment = (r * r).sum(dim=(2, 3))  # (E, N)
    return int((~torch.isfinite(per_segment)).any(dim=0).sum())


def _check_loss(losses: torch.Tensor, zero: torch.Tensor, epoch: int, what: str, base: ResidualGreyBox,
                seg: Segments, config: HybridTraining) -> None:
    """TrainingDiverged naming the epoch, the member, the loss and its likely cause when a member's `losses` (E,) or
    pull toward zero `zero` (E,) is not finite (module docstring, step 4)."""
    bad = ~(torch.isfinite(losses) & torch.isfinite(zero))
    if not bool(bad.any()):
        return
    member = int(torch.nonzero(bad)[0, 0])
    value = float(losses[member]) if not math.isfinite(float(losses[member])) else float(zero[member])
    where = f"hybrid: the {what} loss of member {member} is {value} at epoch {epoch}"
    if not math.isfinite(float(zero[member])):
        raise TrainingDiverged(f"{where}: the one-step samples' residual features are not finite (NaN/inf in the "
                               "identification data)")
    diverging = _diverging_segments(base, seg)
    if diverging:
        raise TrainingDiverged(f"{where}: the grey box alone diverges (NaN/inf loss) on {diverging} of {len(seg)} "
                               f"{what} segments; a residual cannot be trained on a base that diverges (an unstable "
                               "identified hull: check its signs, e.g. N_r < 0, or identify on more manoeuvres)")
    raise TrainingDiverged(f"{where}: the learned residual drove the rollout unstable (the grey box alone rolls out "
                           f"every segment); lower the learning rate (now {config.learning_rate:g})")


def train_hybrid(result: IdentificationResult, recordings: Sequence[Recording], dt: float,
                 config: HybridTraining = HybridTraining(), substeps: int = 2,
                 progress: Callable[[str], None] = lambda _: None) -> tuple[ResidualGreyBox, dict[str, Any]]:
    """The identified grey box + a GeneralisingResidual ensemble trained as the module docstring says; `recordings`
    are the identification's, at the model step dt (their names split training and validation manoeuvres)."""
    return train_residual(greybox_module(result, dt, substeps), result.vessel, result.data, recordings, dt, config,
                          progress=progress)


def with_terms(module: ResidualGreyBox, source: nn.Module) -> ResidualGreyBox:
    """`module` with the extension terms (current_ne, wave_ne, ... : physics.effects) of `source` copied in."""
    with torch.no_grad():
        for name in module.term_names:
            getattr(module, name).copy_(getattr(source, name).detach().reshape(getattr(module, name).shape))
        module.engine_speed_rpm.copy_(source.engine_speed_rpm.detach())
    return module


def train_residual(base: ResidualGreyBox, vessel: Vessel, data: Sequence[ForceData], recordings: Sequence[Recording],
                   dt: float, config: HybridTraining = HybridTraining(),
                   progress: Callable[[str], None] = lambda _: None) -> tuple[ResidualGreyBox, dict[str, Any]]:
    """`base` (a grey box of `vessel`, with its extension terms: greybox_module or base_from_artifact) + a
    GeneralisingResidual ensemble trained as the module docstring says on the one-step `data` (the smoothed
    inverse dynamics of `recordings`: identification.prepare) and the multi-step segments of `recordings`, at the
    model step dt (their names split training and validation manoeuvres). The hybrid keeps the base's terms."""
    substeps = base.substeps
    train, val, split = _split_segments(recordings, config)
    speeds = np.hypot(*np.vstack([d.nu[d.keep] for d in data])[:, :2].T)
    u_ref = float(np.median(speeds)) if len(speeds) else 1.0
    with reproducible(config.seed, torch.get_num_threads()):
        learned = GeneralisingResidual(vessel.geometry.L_pp, max(u_ref, 0.1), config.members, config.hidden,
                                       config.layers)
        x_samples = _residual_statistics(learned, base, data, recordings, config.bound_window_s)
        residual = SumResidual(base.residual, learned)
        module = with_terms(ResidualGreyBox(vessel, dt, residual, substeps, members=config.members), base)
        bootstrap = torch.from_numpy(np.random.default_rng(config.seed).poisson(1.0, (config.members, len(train)))
                                     .astype(np.float64)) + 1e-3  # (E, N) each member's resampling of the segments
        trainable = [p for p in learned.parameters() if p.requires_grad]
        optimiser = torch.optim.Adam(trainable, lr=config.learning_rate, weight_decay=config.weight_decay)
        samples = x_samples.unsqueeze(0).expand(config.members, -1, -1)  # (E, N, F)
        with torch.no_grad():  # epoch 0, the untrained residual (zero: the base itself) is a candidate too, so a
            #                    member keeps no learned term that does not beat its base on the held-out manoeuvres
            zero = ((learned.nondimensional(samples) / learned.bound) ** 2).sum(dim=-1).mean(dim=-1)  # (E,)
            _check_loss(_monitored_losses(module, train), zero, 0, "training", base, train, config)
            monitor = (_monitored_losses(module, val) if val is not None
                       else _monitored_losses(module, train) + config.zero_weight * zero)  # (E,)
            if val is not None:
                _check_loss(monitor, zero, 0, "validation", base, val, config)
        best = [float(x) for x in monitor]
        best_epoch = [0] * config.members
        best_state = [p.detach().clone() for p in trainable]
        history = []
        stale = 0
        for epoch in range(1, config.epochs + 1):
            optimiser.zero_grad()
            fit = _segment_losses(module, train, bootstrap)  # (E,)
            zero = ((learned.nondimensional(samples) / learned.bound) ** 2).sum(dim=-1).mean(dim=-1)  # (E,)
            _check_loss(fit.detach(), zero.detach(), epoch, "training", base, train, config)
            (fit + config.zero_weight * zero).sum().backward()
            optimiser.step()
            fit = fit.detach()
            monitor = (_monitored_losses(module, val) if val is not None
                       else _monitored_losses(module, train) + config.zero_weight * zero.detach())  # (E,)
            _check_loss(monitor, zero.detach(), epoch, "validation" if val is not None else "training", base,
                        val if val is not None else train, config)
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
            grey = _monitored_losses(base, val if val is not None else train)
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
        "feature_set": f"{vessel.hull_model.label} grey box"
                + (" + learned residual" if model_type == "hybrid" else ""),
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


def hybrid_model_type(base_model_type: str) -> str:
    """The model_type of a hybrid on a base of `base_model_type`: 'greybox+current+wave_drift' ->
    'hybrid+current+wave_drift' (the family hybrid, the base's diagnosed causes kept: models/families.py)."""
    _, plus, causes = base_model_type.partition("+")
    return "hybrid" + plus + causes


def export_on_base(path: str, module: ResidualGreyBox, base: ModelArtifact, *, vessel: Vessel | None,
                   training_data_sha256: str, hybrid: Mapping[str, Any]) -> ModelArtifact:
    """One TorchScript file of a hybrid trained on the grey box of the artifact `base` (base_from_artifact): the
    base's metadata (hull, terms, identification or diagnosis, engine speed) with model_type hybrid[+causes], the
    residual's record under architecture and the base's model_id and training under training.base; `vessel` the
    description to embed (None: the base's)."""
    meta = {key: value for key, value in base.metadata.items()
            if key not in ("model_id", "format", "software_version", "created_utc")}
    causes = str(base.metadata.get("model_type", "greybox"))
    meta.update({
        "model_type": hybrid_model_type(causes),
        "feature_set": f"{meta.get('feature_set', 'physics')} + learned residual",
        "training_data_sha256": training_data_sha256,
        "ensemble_size": int(module.members),
        "architecture": {**dict(base.metadata.get("architecture") or {}), "residual": type(module.residual).__name__,
                         "terms": module.terms(), **dict(hybrid)},
        "training": {"method": "learned residual (fitting.hybrid_fit.train_residual) on the grey box of "
                               f"{base.path.name} ({causes})",
                     "base": {"model_id": base.model_id, "model_type": causes,
                              "training": base.metadata.get("training")}},
    })  # the base's engine_speed record stays true: with_terms copied its held engine speed
    return export_module(path, module, meta, vessel=vessel or base.embedded_vessel)

"""The extension of last resort: when no physical hypothesis explains what the calm-water model gets wrong,
the learned residual, named as such (`unexplained`) and with its measured gain.

`diagnose` names a physical cause when one lowers the held-out loss and track error (analysis/diagnosis.py). When none
does, its answer is `model_mismatch` (the calm-water model leaves errors no hypothesis explains) or `inconclusive` (a
candidate explains the loss but not the tracks), and the loop "extend the model, measure the gain" would end
empty-handed. Then, and only then, the grey box + GeneralisingResidual hybrid (models/hybrid.py, trained by
fitting.hybrid_fit.train_hybrid: features that generalise, multi-step loss, bounded, pulled toward zero, an ensemble)
is fitted on top of the calm-water model and measured exactly as a cause is:

  - on the diagnosis' two folds by manoeuvre, the residual of each fold trained on the OTHER fold's manoeuvres only
    (early stopping on one of them held out whole), and scored on the held-out fold's segments (the ensemble mean):
    held-out loss L (noise units), evidence 0.5 n_eff ln(L_calm / L), share of the calm-water loss removed, and the
    held-out track error at the segment end, with the thresholds a cause needs (EVIDENCE_CAUSE, MIN_GAIN,
    MIN_TRACK_GAIN of analysis/diagnosis.py);
  - and the open-loop position error after 30 s of analysis.evaluation on the held-out manoeuvres (the metric a named
    cause's extension must lower, diagnosis.GAIN_METRIC), against the calm-water model's.

The answer becomes `unexplained` with these gains only when every test passes; otherwise the earlier answer stays
(its message says what the residual achieved). A physical cause that is named is never replaced: the residual is not
tried then. The residual's own numbers (bounds, epochs, members) are reported; its features, not a physical parameter,
carry what it learned, so `parameters` stays empty. A calm-water model that diverges on the data has no residual to
learn (it is not tried).

Cost: two trainings of UNEXPLAINED_TRAINING (3 members, <= 60 epochs) on half the manoeuvres each, plus one on all of
them for --export; the segments are the diagnosis' (its horizon and stride).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from usv_predictor.analysis import diagnosis as dg
from usv_predictor.data.recording import Recording
from usv_predictor.errors import ConfigError, DatasetError, DiagnosisError, ModelError
from usv_predictor.fitting import hybrid_fit
from usv_predictor.fitting import identification as ident
from usv_predictor.physics.vessel import Vessel

UNEXPLAINED_TRAINING = hybrid_fit.HybridTraining(members=3, hidden=16, layers=2, epochs=60, patience=15,
                                                 learning_rate=1e-2)  # the few members and epochs of last resort
REPLACES = (dg.MODEL_MISMATCH, dg.INCONCLUSIVE)  # the answers the residual may replace (no physical cause named)
REMEDY = ("the learned residual (`--export` writes it: a hybrid for the node) predicts better than the calm-water "
          "model, but names no physical cause: look for one the vocabulary lacks (an effect record, "
          "physics/effects.py), or identify the boat again (docs/your_boat.md)")


@dataclass(frozen=True)
class UnexplainedGain:
    """The learned residual's measured gain on the diagnosis' held-out manoeuvres (module docstring)."""

    accepted: bool  # every test passed: the answer is `unexplained`
    heldout_loss: float  # mean over both folds' held-out segments (noise units), the ensemble mean's
    calm_water_loss: float  # the calm-water model's, on the same segments
    gain: float  # share of the calm-water model's held-out loss removed
    evidence: float  # 0.5 n_eff ln(L_calm / L)
    heldout_track_error_m: float  # mean position error at the held-out segments' end (m)
    calm_water_track_error_m: float
    track_gain: float  # share of the calm-water model's held-out track error removed
    open_loop_30s_m: float | None  # analysis.evaluation's mean position error after 30 s on the held-out manoeuvres
    calm_water_open_loop_30s_m: float | None
    replaced: str  # the answer it replaces (model_mismatch or inconclusive), or would have
    reasons: tuple[str, ...]  # why it is not accepted (empty when accepted)
    training: tuple[dict[str, Any], ...] = field(default_factory=tuple)  # train_hybrid's info per fold

    @property
    def open_loop_gain(self) -> float | None:
        before, after = self.calm_water_open_loop_30s_m, self.open_loop_30s_m
        return None if before is None or after is None or not before > 0 else 1.0 - after / before

    def to_json(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "reasons": list(self.reasons), "training": list(self.training),
                "open_loop_gain": self.open_loop_gain}


class _EnsembleMean(torch.nn.Module):
    """A hybrid ensemble (E, B, H, 6) behind the diagnosis' rollout interface: (ensemble mean (B, H, 6),)."""

    def __init__(self, module: torch.nn.Module) -> None:
        super().__init__()
        self.module = module

    def forward(self, state: torch.Tensor, controls: torch.Tensor,
                reference: torch.Tensor | None = None) -> tuple[torch.Tensor]:
        return (self.module(state, controls, reference).mean(dim=0),)


def _finite_mean(values: np.ndarray) -> float:
    """Mean of the finite values (a segment without a fix at its end has no track error); NaN when none is."""
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if len(finite) else float("nan")


def calm_water_identification(vessel: Vessel, recordings: Sequence[Recording],
                              description: Vessel | None = None) -> ident.IdentificationResult:
    """The calm-water model as an identification result that holds every coefficient (nothing re-identified): what
    train_hybrid and export_identified take; its data are the recordings' inverse dynamics (identification.prepare),
    from which the residual's normalisation, support and bound come."""
    data = tuple(ident.prepare(vessel, recordings))
    speeds = np.hypot(*np.vstack([d.nu[d.keep] for d in data])[:, :2].T)
    fit = ident.HullFit(vessel.hull_model.structure, "held (the calm-water model of diagnose)", (), (),
                        float(np.median(speeds)) if len(speeds) else 1.0)
    return ident.IdentificationResult(vessel, fit, (), {}, data,
                                      ("calm-water model of `replay diagnose`, not re-identified: the learned residual "
                                       "of last resort (diagnosis `unexplained`) is trained on top of it",),
                                      prior=description or vessel, trials=_trials(vessel))


def _trials(vessel: Vessel) -> Mapping[str, str]:
    """The table of the trials that would determine the coefficients of the vessel's hull model
    (fitting/hull_models.HULL_FITS; the MMG hull's for a hull model identification does not know)."""
    from usv_predictor.fitting.hull_models import HULL_FITS

    known = HULL_FITS.get(vessel.hull_model_name)
    return known.would_determine if known is not None else ident.WOULD_DETERMINE


def _train(vessel: Vessel, recordings: Sequence[Recording], dt: float, config: hybrid_fit.HybridTraining,
           progress: Callable[[str], None]) -> tuple[torch.nn.Module, dict[str, Any], ident.IdentificationResult]:
    result = calm_water_identification(vessel, recordings)
    module, info = hybrid_fit.train_hybrid(result, recordings, dt, config, substeps=1, progress=progress)
    return module, info, result


def measure_unexplained(recordings: Sequence[Recording], vessel: Vessel, diagnosis: dg.Diagnosis, *, dt: float,
                        horizon_s: float, stride_s: float, segments: dg.Segments,
                        config: hybrid_fit.HybridTraining | None = None,
                        progress: Callable[[str], None] = lambda _: None) -> UnexplainedGain | None:
    """The learned residual's gain on the diagnosis' held-out folds (module docstring); None when it cannot be
    trained on these data (the reason is reported by progress). config: None = UNEXPLAINED_TRAINING (its horizon and
    stride replaced by the diagnosis')."""
    from usv_predictor.analysis import evaluation
    from usv_predictor.models.greybox import GreyBoxPredictor, GreyBoxRollout, greybox_metadata

    names = [r.name for r in recordings]
    calm_rollout = dg.compiled_rollout(vessel, dt)  # the diagnosis' calm-water model (one RK4 substep per dt)
    dg.set_terms(calm_rollout, {})
    calm_eval = GreyBoxRollout(vessel, dt=dt, substeps=1)
    calm_predictor = GreyBoxPredictor(calm_eval, {**greybox_metadata(vessel, calm_eval), "model_id": "calm-water"})
    losses, tracks, calm_losses, calm_tracks, infos = [], [], [], [], []
    before, after = [], []
    for fit_fold, test_fold in ((0, 1), (1, 0)):
        fit_names, test_names = diagnosis.folds[fit_fold], diagnosis.folds[test_fold]
        fitted = [recordings[names.index(n)] for n in fit_names]
        held_out = [recordings[names.index(n)] for n in test_names]
        progress(f"unexplained: training the learned residual on {', '.join(fit_names)}; held out: "
                 f"{', '.join(test_names)}")
        try:
            module, info, _ = _train(vessel, fitted, dt, dataclasses.replace(config or UNEXPLAINED_TRAINING,
                                                                             horizon_s=horizon_s, stride_s=stride_s),
                                     progress)
        except (ModelError, DatasetError, ConfigError, DiagnosisError) as err:
            progress(f"unexplained: no learned residual ({err})")
            return None
        infos.append(info)
        held = segments.select(np.isin(segments.recording, [names.index(n) for n in test_names]))
        loss_, track_ = dg.segment_scores(_EnsembleMean(module), held)
        calm_loss, calm_track = dg.segment_scores(calm_rollout, held)
        losses.append(loss_)
        tracks.append(track_)
        calm_losses.append(calm_loss)
        calm_tracks.append(calm_track)
        predictor = GreyBoxPredictor(module, {**greybox_metadata(vessel, module, model_type="hybrid"),
                                              "ensemble_size": module.members, "model_id": "unexplained"})
        before += evaluation.evaluate(calm_predictor, held_out, horizons_s=(30.0,)).recordings
        after += evaluation.evaluate(predictor, held_out, horizons_s=(30.0,)).recordings
    loss, calm = np.concatenate(losses), np.concatenate(calm_losses)
    track, calm_track = np.concatenate(tracks), np.concatenate(calm_tracks)
    mean, calm_mean = float(loss.mean()), float(calm.mean())
    evidence = (dg.log_evidence(dg.effective_segments(len(loss), stride_s, horizon_s), mean, calm_mean)
                if math.isfinite(mean) else -math.inf)
    gain = 1.0 - mean / calm_mean if calm_mean > 0 else float("nan")
    track_after, track_before = _finite_mean(track), _finite_mean(calm_track)
    track_gain = 1.0 - track_after / track_before if track_before > 0 else float("nan")
    loop_before = evaluation.summarise(before, (30.0,)).get(dg.GAIN_METRIC)
    loop_after = evaluation.summarise(after, (30.0,)).get(dg.GAIN_METRIC)
    reasons = []
    went = [e for e in after if e.diverged_at_s is not None]
    if went:  # its closed loop has no metric left to compare: that is the answer
        reasons.append(f"its rollout diverges (NaN/inf) on {len(went)} held-out manoeuvre(s), the first "
                       f"{went[0].name} at {went[0].diverged_at_s:.1f} s")
    if not (evidence >= dg.EVIDENCE_CAUSE and gain >= dg.MIN_GAIN):
        reasons.append(f"it removes {gain * 100:.1f} % of the calm-water model's held-out loss with evidence "
                       f"{evidence:.1f} (an extension needs >= {dg.MIN_GAIN * 100:.0f} % and >= {dg.EVIDENCE_CAUSE:g})")
    if math.isfinite(track_gain) and not track_gain > dg.MIN_TRACK_GAIN:
        reasons.append(f"it does not lower the held-out track error after {horizon_s:g} s ({track_before:.3g} -> "
                       f"{track_after:.3g} m)")
    if loop_before is not None and loop_after is not None and not loop_after < loop_before:
        reasons.append(f"it does not lower the held-out open-loop position error after 30 s ({loop_before:.3g} -> "
                       f"{loop_after:.3g} m)")
    return UnexplainedGain(not reasons, mean, calm_mean, gain, evidence, track_after, track_before, track_gain,
                           loop_after, loop_before, diagnosis.cause, tuple(reasons), tuple(infos))


def unexplained_answer(diagnosis: dg.Diagnosis, found: UnexplainedGain, horizon_s: float) -> dg.Diagnosis:
    """`diagnosis` answered `unexplained` with the residual's gain (found.accepted), or kept with what the residual
    achieved appended to its message (not accepted)."""
    achieved = (f"a learned residual (grey box + GeneralisingResidual) removes {found.gain * 100:.0f} % of the "
                f"calm-water model's held-out loss (evidence {found.evidence:.1f}) and {found.track_gain * 100:.0f} % "
                f"of its held-out track error after {horizon_s:g} s ({found.calm_water_track_error_m:.3g} -> "
                f"{found.heldout_track_error_m:.3g} m)")
    if found.open_loop_30s_m is not None and found.calm_water_open_loop_30s_m is not None:
        achieved += (f", open-loop position error after 30 s {found.calm_water_open_loop_30s_m:.3g} -> "
                     f"{found.open_loop_30s_m:.3g} m")
    if not found.accepted:
        return dataclasses.replace(diagnosis, message=f"{diagnosis.message}; the extension of last resort was tried: "
                                                      f"{achieved}, not enough: {'; '.join(found.reasons)}")
    message = (f"{dg.UNEXPLAINED}: no physical hypothesis explains what the calm-water model gets wrong (the answer "
               f"would be {diagnosis.message}); the extension of last resort: {achieved}; {REMEDY}")
    return dataclasses.replace(diagnosis, cause=dg.UNEXPLAINED, parameters={}, uncertainty={}, message=message,
                               confounded_with=(), additional_causes=())


def export_unexplained(path: Path, vessel: Vessel, recordings: Sequence[Recording], dt: float, *, horizon_s: float,
                       stride_s: float, description: Vessel | None = None,
                       config: hybrid_fit.HybridTraining | None = None,
                       progress: Callable[[str], None] = lambda _: None):
    """The hybrid (calm-water model + learned residual) trained on every manoeuvre, as a model artifact (config: None =
    UNEXPLAINED_TRAINING)."""
    result = calm_water_identification(vessel, recordings, description)
    module, info = hybrid_fit.train_hybrid(result, recordings, dt,
                                           dataclasses.replace(config or UNEXPLAINED_TRAINING, horizon_s=horizon_s,
                                                               stride_s=stride_s),
                                           substeps=1, progress=progress)
    return hybrid_fit.export_identified(str(path), module, result, dt=dt,
                                        training_data_sha256=ident.data_digest(recordings), model_type="hybrid",
                                        hybrid={**info, "diagnosis": dg.UNEXPLAINED})

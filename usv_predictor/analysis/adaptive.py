"""Adaptive prediction: the online estimator (fitting/online.py) run over a recording, its live estimate put into
the grey box's terms before each open-loop prediction (`replay evaluate --adaptive`; the node will do the same per
cycle).

How the live estimate reaches a model:
  grey box, extended grey box (`replay diagnose --export`), hybrid (`replay identify --hybrid`): the TorchScript
      module's term parameters current_ne (2,), yaw_rate_bias (1,), resistance_change (1,) (models/greybox.py) are
      set to the estimate before the rollout (a copy_ into the parameter: no recompilation, microseconds) and put
      back afterwards, so the model object is left as it was. The terms enter physically: the start state through
      the water is the measured one minus the current, the gyro bias is taken off, the track drifts with the
      current, the resistance change acts on the surge. The filter's process model is the artifact's own vessel
      (its identified hull from the metadata) with the artifact's other terms (rudder offset, wind, waves,
      propeller side force) as they are; the artifact's current, bias and resistance are the prior means.
  a learned model (DNN) without these parameters: NOT applied. Its training sea is in its weights (seed 000's
      NTF features learn the drift of the day), so adding the estimated current to its track would count the
      current twice; whether it predicts through the water cannot be proven from the file. The estimate is still
      computed and reported, with `applied: false` and the reason.
"""
from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from usv_predictor.analysis import evaluation
from usv_predictor.data.recording import Recording
from usv_predictor.fitting.online import TERMS, OnlineConfig, OnlineEstimate, OnlineEstimator
from usv_predictor.models.loading import check_dt
from usv_predictor.physics import effects
from usv_predictor.physics.vessel import Vessel

NOT_APPLIED = ("not applied: a learned model has no physical current term; its training sea is in its weights, so "
               "adding the estimate to its track would count the current twice")


@dataclass(frozen=True)
class AdaptiveRecording:
    """The online estimate along one recording and the adaptive open-loop errors."""

    name: str
    applied: bool
    open_loop: evaluation.OpenLoop | None
    estimates: tuple[OnlineEstimate, ...]
    t_s: np.ndarray  # (T,) s since the recording's start

    def to_json(self, dt: float) -> dict[str, Any]:
        last = self.estimates[-1] if self.estimates else None
        converged = [e.converged for e in self.estimates]
        return {
            "name": self.name, "applied": self.applied,
            "open_loop": None if self.open_loop is None else self.open_loop.to_json(dt),
            "final_estimate": None if last is None else last.to_json(),
            "converged_fraction": float(np.mean(converged)) if converged else None,
            "first_converged_s": next((float(t) for t, c in zip(self.t_s, converged) if c), None),
        }


def module_of(model: Any) -> Any:
    """The torch module behind a model (ModelArtifact.module, GreyBoxPredictor.rollout), or None."""
    return getattr(model, "module", None) or getattr(model, "rollout", None)


def model_terms(model: Any) -> dict[str, list[float]] | None:
    """The grey-box terms (models/greybox.py names, SI) the model carries; None when it has no current term (a
    learned model: the estimate is not applied)."""
    module = module_of(model)
    if module is None or not hasattr(module, effects.ONLINE_TERMS[0]):  # no current term
        return None
    out = {}
    for name in effects.grey_box_terms():
        if hasattr(module, name):
            out[name] = [float(x) for x in getattr(module, name).detach().reshape(-1).tolist()]
    return out


def set_terms(model: Any, terms: Mapping[str, Sequence[float]]) -> None:
    """Write grey-box terms into the model's parameters (torch.no_grad copy_, shapes kept)."""
    import torch

    module = module_of(model)
    with torch.no_grad():
        for name, values in terms.items():
            parameter = getattr(module, name)
            parameter.copy_(torch.tensor(list(values), dtype=parameter.dtype).reshape(parameter.shape))


def model_vessel(model: Any, vessel: Vessel | None = None) -> Vessel:
    """The vessel of the model's grey box: `vessel`, else the model's own (models/loading.resolve_vessel: the
    description the artifact embeds or the preset its metadata names; ConfigError when it has neither), with the hull
    coefficients the metadata carries (identified or diagnosed), where they are that vessel's hull model's."""
    from usv_predictor.models.greybox import hull_from_metadata
    from usv_predictor.models.loading import resolve_vessel

    meta = dict(model.metadata)
    base = vessel if vessel is not None else resolve_vessel(model=model)
    hull = hull_from_metadata(meta) if meta.get("feature_set") == "physics" else None
    if not hull:
        return base
    section_name = base.hull_model.coefficients
    section = getattr(base, section_name)
    known = {k: float(v) for k, v in hull.items() if hasattr(section, k)}
    return replace(base, **{section_name: replace(section, **known)})


def estimator_for(model: Any, vessel: Vessel | None = None, config: OnlineConfig | None = None
                  ) -> OnlineEstimator:
    """The online estimator of a model: its grey box's vessel (model_vessel) and terms (prior means and fixed
    terms)."""
    return OnlineEstimator(model_vessel(model, vessel), config, model_terms(model) or {})


def adaptive_open_loop(model: Any, recording: Recording, reference: str = "gnss",
                       horizons_s: Sequence[float] = evaluation.DEFAULT_HORIZONS_S, stride_s: float = 5.0,
                       config: OnlineConfig | None = None, vessel: Vessel | None = None) -> AdaptiveRecording:
    """evaluation.open_loop with the live estimate: the same windows and the same held reference (a rudder_only
    layout's approach, evaluation.held_reference, given to every rollout by evaluation.windowed_open_loop); the
    estimator runs causally over the recording (OnlineEstimator.run_recording: its process model holds the engine
    speed of the same approach, of the measured track); before the rollout from sample k the model's terms are set
    to the estimate after sample k (when the model has them). vessel: the grey box's (model_vessel; None: the
    model's own)."""
    check_dt(model, recording.dt, f"recording {recording.name}")
    estimator = estimator_for(model, vessel, config)  # vessel None: the model's own (model_vessel)
    estimates = tuple(estimator.run_recording(recording))
    original = model_terms(model)

    def predict(starts: np.ndarray, states: np.ndarray, controls: np.ndarray, held: np.ndarray | None
                ) -> np.ndarray:  # -> (E, B, H, 6)
        if original is None:
            return evaluation.rollout(model, states, controls, held)
        with per_start_terms(model, [live_terms(estimates[k], original) for k in starts]):
            return evaluation.rollout(model, states, controls, held)

    loop = evaluation.windowed_open_loop(recording, evaluation.reference_tracks(recording, reference), horizons_s,
                                         stride_s, predict)
    return AdaptiveRecording(recording.name, original is not None, loop, estimates, recording.t_s - recording.t_s[0])


@contextlib.contextmanager
def per_start_terms(model: Any, terms: Sequence[Mapping[str, Sequence[float]]]) -> Iterator[None]:
    """Within the block the model's term parameters hold one column per batch element: (size, B) instead of
    (size,). The grey box indexes its terms as term[i], which is then (B,) and broadcasts against the (B,) state,
    so element b is predicted exactly as with its own terms set by set_terms (test_online.py proves it equal):
    every start point of a recording in one rollout. The original parameters are put back afterwards."""
    import torch
    from torch import nn

    module = module_of(model)
    names = sorted({name for t in terms for name in t})
    originals = {name: getattr(module, name) for name in names}
    try:
        with torch.no_grad():
            for name in names:
                columns = torch.tensor([list(t[name]) for t in terms], dtype=torch.float64).T  # (size, B)
                setattr(module, name, nn.Parameter(columns.contiguous(), requires_grad=False))
        yield
    finally:
        for name, parameter in originals.items():
            setattr(module, name, parameter)


def live_terms(estimate: OnlineEstimate, original: Mapping[str, Sequence[float]]) -> dict[str, list[float]]:
    """The model's terms with the estimated ones replaced (current_ne, yaw_rate_bias, resistance_change);
    before the filter has started (no finite estimate) the model's own."""
    out = {name: list(original[name]) for name in TERMS if name in original}
    if all(math.isfinite(x) for x in estimate.state):
        out.update({name: values for name, values in estimate.terms().items() if name in original})
    return out


def summarise(adaptive: Sequence[AdaptiveRecording], horizons_s: Sequence[float]) -> dict[str, Any]:
    """Pooled adaptive open-loop errors over every start point, like evaluation.summarise."""
    out: dict[str, Any] = {"applied": bool(adaptive) and all(a.applied for a in adaptive)}
    if adaptive and not adaptive[0].applied:
        out["reason"] = NOT_APPLIED
    out.update(evaluation.pooled_open_loop([a.open_loop for a in adaptive], horizons_s))
    return out

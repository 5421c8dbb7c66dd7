"""One diagnosis run: the calm-water model, the named cause, what the model gets wrong, the gain, the outputs.

    calm_water_model   the calm-water model of a diagnosis: a vessel preset, or the identified hull (and thrust maps)
                       of a grey-box artifact (`replay identify`: an MMG or a small-craft hull; or an earlier
                       `replay diagnose --export`) on the vessel it embeds
    run_diagnosis      diagnose + discrepancy + held-out gain + export + report (usv_predictor.analysis.diagnosis),
                       with the segments and the scripted grey box built once and shared by every step

The result is the JSON of `replay diagnose` (keys in its module docstring).
"""
from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from usv_predictor.analysis import diagnosis as dg
from usv_predictor.analysis.diagnosis_steps import DiagnosisSteps
from usv_predictor.analysis.diagnosis_unexplained import (REPLACES, export_unexplained, measure_unexplained,
                                                          unexplained_answer)
from usv_predictor.atomic import finite_or_none
from usv_predictor.data.recording import Recording
from usv_predictor.errors import DatasetError, ModelError
from usv_predictor.models.families import MODEL_FAMILIES, family_name
from usv_predictor.models.greybox import hull_from_metadata, vessel_from_metadata
from usv_predictor.physics.vessel import Vessel



@dataclasses.dataclass(frozen=True)
class DiagnosisOptions:
    """What a diagnosis run tries and writes (run_diagnosis)."""

    hypotheses: tuple[str, ...] | None = None  # the causes tried (None: every hypothesis of the layout)
    max_causes: int = 2  # at most this many causes named together (>= 1)
    gain: bool = True  # measure the extended model on held-out manoeuvres, withdraw a cause that does not help
    export: Path | None = None  # write the extended model (TorchScript artifact) there; None: no file
    report: Path | None = None  # write report.md + plots into this directory; None: no report
    fit_check: bool = True  # refuse a calm-water model that does not fit the bags at all (analysis/fit_check.py)
    unexplained: bool = True  # with gain: try the learned residual of last resort when no physical cause is named
    wave_filter: str = "auto"  # filter the residuals' wave-frequency motion: by the detector (auto), on, off
    #                            (data/wave_motion.py)


class CalmWater(NamedTuple):
    vessel: Vessel  # the calm-water model's vessel (a preset, or one with an artifact's identified hull)
    source: str  # "preset" or "identified (<model_id>)"
    description: Vessel  # the vessel file it was made from (what an exported extension embeds)


def calm_water_model(vessel: str | Path | None, model: Path | None, config: Path | None = None) -> CalmWater:
    """The calm-water model of a diagnosis, what `replay diagnose` resolves at its boundary (its vessel by
    models/loading.resolve_vessel, once).

    vessel: a preset name or vessel file (None: the model's vessel, the description it embeds or the preset it names;
    without a model the predictor config's); model: a grey-box artifact whose identified hull replaces the vessel's
    (ModelError when it carries anything else, or when `vessel` differs from the description it embeds).
    """
    from usv_predictor.models.loading import resolve_vessel

    if model is None:
        preset = resolve_vessel(vessel, config_path=config)
        return CalmWater(preset, "preset", preset)
    from usv_predictor.models.artifact import load_artifact

    artifact = load_artifact(model)
    meta = artifact.metadata
    hull = hull_from_metadata(meta)
    family = MODEL_FAMILIES.get(family_name(str(meta.get("model_type", ""))))
    if family is None or not family.physics or hull is None:
        raise ModelError(f"model {model}: diagnose needs a grey box without learned or extra terms "
                         f"(`replay identify --structure mmg`, or a small-craft structure), not model_type "
                         f"{meta.get('model_type')!r}; compare other models with `replay evaluate`")
    preset = resolve_vessel(vessel, model=artifact, source=f"model {model}")
    try:
        identified = vessel_from_metadata(meta, preset)
    except ValueError as err:
        raise ModelError(f"model {model}: {err}") from None
    assert identified is not None  # hull_from_metadata accepted it above
    return CalmWater(identified, f"identified ({meta.get('model_id')})", preset)


def calm_water_vessel(vessel: str | Path | None, model: Path | None, config: Path | None = None) -> tuple[Vessel, str]:
    """(the calm-water vessel, where it comes from): calm_water_model without the description."""
    calm = calm_water_model(vessel, model, config)
    return calm.vessel, calm.source


def run_diagnosis(recordings: Sequence[Recording], vessel: Vessel, source: str, *, dt: float, horizon_s: float = 20.0,
                  stride_s: float = 5.0, options: DiagnosisOptions = DiagnosisOptions(),
                  progress: Callable[[str], None] = lambda _: None, suited_steps: DiagnosisSteps | None = None,
                  description: Vessel | None = None) -> dict[str, Any]:
    """Diagnose `recordings` (resampled at dt) against the calm-water `vessel` (from `source`), in segments of
    horizon_s every stride_s (s), trying and writing what `options` say (DiagnosisOptions, the fields below).

    suited_steps: the steps that suit the vessel (analysis.diagnosis_steps), recorded in the JSON's `steps` with
    the ones used (they differ where the caller gave its own). description: the vessel file the calm-water model
    was made from, embedded in the exported extension (None: `vessel`).
    fit_check: refuse (FitCheckError, one line) a calm-water model that does not fit the bags at all
    (analysis/fit_check.py); False: proceed, the failed check then makes the answer model_mismatch.
    gain: also evaluate the extended model on held-out manoeuvres (when a cause is named) and withdraw the cause
    when its extension does not lower the held-out 30 s position error; export: write the extended model
    (TorchScript artifact) there; report: write report.md + plots into that directory.
    unexplained (with gain): when no physical cause is named (model_mismatch, inconclusive), try the learned residual
    of last resort and answer `unexplained` when it lowers the held-out loss and track error
    (analysis/diagnosis_unexplained.py); --export then writes that hybrid.
    """
    hypotheses, max_causes, gain, export, report = (options.hypotheses, options.max_causes, options.gain,
                                                    options.export, options.report)
    fit_check, unexplained = options.fit_check, options.unexplained
    if not recordings:
        raise DatasetError("no usable recording in the bags (see the warnings above)")
    missing = [r.name for r in recordings if vessel.layout == "rudder_propeller" and not (r.controls[:, 1] > 0).any()]
    if missing:
        raise DatasetError(f"no engine speed in {missing}: the calm-water model needs rudder and rpm; "
                           f"record engine_rpm")
    progress(f"diagnosing {len(recordings)} manoeuvre(s) against the {source} calm-water model of {vessel.name}")
    if max_causes < 1:
        raise DatasetError(f"--max-causes {max_causes} must be >= 1")
    dg.check_data(recordings)  # its refusals come before those of the segments, as in dg.diagnose
    from usv_predictor.analysis.fit_check import check_fit, require_fit
    from usv_predictor.models.loading import physics_predictor

    named = f"the preset {vessel.name}" if source == "preset" else f"the {source} calm-water model of {vessel.name}"
    fitted = check_fit(physics_predictor(vessel, dt), recordings, vessel=vessel, label=named)
    progress(fitted.summary())
    if fit_check:
        require_fit(fitted)
    # built once: diagnose, discrepancy and gain share the segments (with the wave filter the detector decides) ...
    segments, waves = dg.diagnosis_segments(recordings, horizon_s, stride_s, options.wave_filter)
    progress(waves.describe())
    rollout = dg.compiled_rollout(vessel, dt)  # ... the segments and the compiled grey box
    result = dg.diagnose(recordings, vessel, hypotheses=hypotheses, horizon_s=horizon_s, stride_s=stride_s,
                         max_causes=max_causes, progress=progress, segments=segments, rollout=rollout,
                         fit_mismatch="; ".join(fitted.reasons))
    if waves.applied:
        result = dataclasses.replace(result, notes=(*result.notes, waves.describe()))
    calm_fit = result.calm_water_fit
    # a calm-water model that diverges on the data (diagnose: model_mismatch) has no discrepancy to describe
    diverged = calm_fit is not None and not math.isfinite(calm_fit.heldout_loss)
    discrepancy = None if diverged else dg.discrepancy(rollout, segments, recordings)
    rejected = None
    if result.hypotheses and gain:
        progress("measuring the gain on held-out manoeuvres")
        measured = dg.measure_gain(recordings, vessel, result, horizon_s=horizon_s, segment_stride_s=stride_s,
                                   segments=segments, rollout=rollout)
        before = measured["baseline"].get(dg.GAIN_METRIC)
        after = measured["extended"].get(dg.GAIN_METRIC)
        # the track rule of naming them (diagnosis.lowers_track) on the measured 30 s open-loop error; a gain that is
        # not finite (an extension that diverges, a zero baseline) withdraws them too
        gain = None if before is None or after is None else (1.0 - after / before if before > 0.0 else -math.inf)
        if gain is not None and not (math.isfinite(gain) and dg.lowers_track(gain, result.hypotheses)):
            rejected = {"causes": list(result.hypotheses), "baseline": measured["baseline"],
                        "extended": measured["extended"], "gain": measured["relative_improvement"]}
            result = dg.withdraw_causes(result,
                                        f"the extension with {'+'.join(result.hypotheses)} "
                                        f"{dg.track_rule_failed(result.hypotheses)} the held-out "
                                        f"open-loop position error after 30 s ({before:.3g} -> {after:.3g} m)",
                                        rollout, segments)
            measured = None
    else:
        measured = None
    last_resort = None
    if (unexplained and gain and result.cause in REPLACES and calm_fit is not None
            and math.isfinite(calm_fit.heldout_loss)):
        progress(f"no physical cause named ({result.cause}): trying the learned residual of last resort")
        last_resort = measure_unexplained(recordings, vessel, result, dt=dt, horizon_s=horizon_s, stride_s=stride_s,
                                          segments=segments, progress=progress)
        if last_resort is not None:
            result = unexplained_answer(result, last_resort, horizon_s)
    progress(f"cause: {result.cause} {result.parameters} — {result.message}")
    calm = result.calm_water_fit
    out: dict[str, Any] = {
        # a parameter at its bound has an undefined (infinite) standard error: null, like a diverged fit's figures
        "cause": result.cause, "parameters": _undefined_as_null(result.parameters),
        "uncertainty": _undefined_as_null(result.uncertainty),
        "confounded_with": list(result.confounded_with), "message": result.message, "notes": list(result.notes),
        "additional_causes": [_undefined_as_null(dataclasses.asdict(a)) for a in result.additional_causes],
        "dropped_causes": list(result.dropped_causes),
        "further_candidate": (_undefined_as_null({**dataclasses.asdict(result.further_candidate),
                                                  "reason": result.further_candidate_reason})
                              if result.further_candidate is not None else None),
        # a hypothesis whose fit diverged has a non-finite held-out loss and evidence: written as null (undefined)
        "evidence": [_undefined_as_null(dataclasses.asdict(e)) for e in result.evidence],
        "folds": [list(f) for f in result.folds], "discrepancy": discrepancy,
        "calm_water_fit": _undefined_as_null(dataclasses.asdict(calm)) if calm is not None else None,
        "fit_check": fitted.to_json(), "wave_filter": waves.to_json(),
        "mismatch_reasons": list(result.mismatch_reasons),
        "best_environmental_cause": result.best_environmental_cause, "rejected_extension": rejected,
        "inconclusive": ({"candidate": result.candidate, "parameters": result.candidate_parameters,
                          "reasons": list(result.inconclusive_reasons)} if result.cause == dg.INCONCLUSIVE else None),
        "unexplained": _undefined_as_null(last_resort.to_json()) if last_resort is not None else None,
        "calm_water_model": {"vessel": vessel.name, "source": source},
        "recordings": [{"name": r.name, "source": r.source, "duration_s": r.duration_s} for r in recordings],
        "seconds": result.seconds,
        "steps": {"dt_s": dt, "horizon_s": horizon_s, "stride_s": stride_s,
                  "suited": None if suited_steps is None else suited_steps.to_json()},
    }
    if measured is not None:
        out.update(baseline=measured["baseline"], extended=measured["extended"], gain=measured["relative_improvement"])
        per_recording = measured["per_recording"]
    else:
        out.update(baseline=None, extended=None, gain={})
        per_recording = None
    if export is not None and result.cause == dg.UNEXPLAINED:
        artifact = export_unexplained(export, vessel, recordings, dt, horizon_s=horizon_s, stride_s=stride_s,
                                      description=description, progress=progress)
        out["exported_model"] = {"path": str(export), "model_id": artifact.model_id}
        progress(f"hybrid (calm-water model + learned residual of last resort) written to {export} "
                 f"({artifact.model_id})")
    elif export is not None and result.cause == dg.MODEL_MISMATCH:
        out["exported_model"] = None
        progress(f"no model written to {export}: the calm-water model does not fit ({dg.MODEL_MISMATCH}); {dg.REMEDY}")
    elif export is not None and result.cause == dg.INCONCLUSIVE:
        out["exported_model"] = None
        progress(f"no model written to {export}: no cause named ({dg.INCONCLUSIVE}); {dg.INCONCLUSIVE_REMEDY}")
    elif export is not None:
        artifact = dg.export_extended(export, vessel, result, dt, description=description)
        out["exported_model"] = {"path": str(export), "model_id": artifact.model_id}
        progress(f"extended model written to {export} ({artifact.model_id})")
    if report is not None:
        from usv_predictor.analysis.diagnosis_report import write_report

        out["report"] = str(write_report(report, out, recordings, vessel, result, per_recording))
        progress(f"report written to {out['report']}")
    return out


def _undefined_as_null(value: Any) -> Any:
    """A record's numbers with the non-finite ones (a diverged fit's loss, evidence, parameters) as None (JSON null)."""
    if isinstance(value, dict):
        return {k: _undefined_as_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_undefined_as_null(v) for v in value]
    if isinstance(value, float):
        return finite_or_none(value)
    return value

"""Bags -> an identified grey box: what `replay identify` does (usv_predictor.fitting.identification on the bags'
recordings, export through usv_predictor.fitting.hybrid_fit, validation and report on request)."""
from __future__ import annotations

import glob
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from usv_predictor.errors import BagError, DatasetError


def identification_recordings(paths: Sequence[Path], dt: float, progress: Callable[[str], None] = lambda _: None) -> list:
    """The recordings of `paths` at step dt; a bag without engine speed is a DatasetError saying why it matters."""
    from usv_predictor.replay.recordings import load_recordings

    try:
        return load_recordings(paths, dt, progress=progress)
    except BagError as err:
        if "engine_rpm" in str(err):
            raise DatasetError(f"identification needs the engine speed (engine_rpm): without it the propeller thrust "
                               f"and the rudder inflow are unknown, so R0 and every speed-dependent hull term cannot be "
                               f"separated from them ({err})") from err
        raise


def identify_bags(bags: Sequence[Path], output: Path, *, vessel: str, structure: str = "auto", prior: str = "none",
                  hybrid: bool = False, dt: float = 0.2, validation: str | None = None, report: Path | None = None,
                  progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Identify the hull of preset `vessel` from `bags` (structure mmg / abkowitz / auto, prior none / fix / ridge),
    export the grey box (with hybrid: plus an MLP residual) to `output`; validation: a glob of bags only
    evaluated; report: a directory for summary.md and the force plots. The result of `replay identify`."""
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.fitting import hybrid_fit, identification
    from usv_predictor.physics.vessel import load_vessel

    preset = load_vessel(vessel)
    recordings = identification_recordings(list(bags), dt, progress)
    if not recordings:
        raise DatasetError(f"no usable recordings in {[str(b) for b in bags]}")
    result = identification.identify(preset, recordings, structure=structure, prior=prior, progress=progress)
    from usv_predictor.fitting.candidates import candidate_scores, cv_warning

    candidates = candidate_scores(preset, list(result.data), result)
    warning = cv_warning(candidates)
    if warning:
        progress(f"warning: {warning}")
    digest = identification.data_digest(recordings)
    hybrid_info = None
    if hybrid:
        progress("training the MLP residual")
        module, hybrid_info = hybrid_fit.train_hybrid(result, dt)
    else:
        module = hybrid_fit.greybox_module(result, dt)
    artifact = hybrid_fit.export_identified(str(output), module, result, dt=dt, training_data_sha256=digest,
                                            model_type="hybrid" if hybrid else "greybox", hybrid=hybrid_info)
    progress(f"wrote {output} (model {artifact.model_id}, {artifact.metadata['model_type']}, structure "
             f"{result.structure})")
    out: dict[str, Any] = {"model": str(output), "model_id": artifact.model_id,
                           "model_type": artifact.metadata["model_type"], "training_data_sha256": digest,
                           "identification": result.to_json(), "hybrid": hybrid_info,
                           "cv_candidates": [c.to_json() for c in candidates], "cv_warning": warning}
    if validation:
        paths = sorted(Path(p) for p in glob.glob(validation))
        if not paths:
            raise DatasetError(f"--val {validation!r} matches no bag")
        out["validation"] = evaluate(artifact, identification_recordings(paths, dt, progress), progress=progress).to_json()
    for c in result.fit.coefficients():
        progress(f"  {c.name:7s} {c.estimate:+.5f}  [{c.ci95[0]:+.5f}, {c.ci95[1]:+.5f}]  prior {c.prior:+.5f}  "
                 f"{c.status}")
    if report is not None:
        from usv_predictor.analysis.reports import write_identification_report

        out["report"] = str(write_identification_report(report, result, out))
    return out

"""Bags -> an identified grey box: what `replay identify` does (usv_predictor.fitting.identification on the bags'
recordings, export through usv_predictor.fitting.hybrid_fit, validation and report on request)."""
from __future__ import annotations

import glob
from collections.abc import Callable, Sequence
from pathlib import Path
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from usv_predictor.errors import BagError, DatasetError

if TYPE_CHECKING:
    from usv_predictor.fitting.hybrid_fit import HybridTraining
    from usv_predictor.physics.vessel import Vessel


def identification_recordings(paths: Sequence[Path], dt: float, progress: Callable[[str], None] = lambda _: None,
                               config: Path | None = None, *, layout: Any = None, blocks: int = 1,
                               scale: float = 1.0, vessel_name: str = "") -> list:
    """The recordings of `paths` at step dt (topics of `config`, default the shipped predictor.yaml), read with the
    vessel's actuator `layout` (physics/actuators.py; None: rudder_propeller); a bag without engine speed is a
    DatasetError saying why it matters. blocks > 1 cuts each recording into that many contiguous pieces of equal
    length, NAME~1, NAME~2, ... (blocked cross-validation of a single long record: each piece is held out in turn).
    scale: Froude scale L_bags / L_vessel (replay.recordings.load_recordings; 1: none). vessel_name: the vessel they
    are read as (load_recordings)."""
    from usv_predictor.physics.actuators import DEFAULT_LAYOUT
    from usv_predictor.replay.recordings import Pieces, load_recordings, slice_recording

    if blocks < 1:
        raise DatasetError(f"--blocks {blocks}: expected a whole number >= 1")
    try:
        recordings = load_recordings(paths, dt, config_path=config, progress=progress, layout=layout or DEFAULT_LAYOUT,
                                     pieces=Pieces(scale=scale), vessel_name=vessel_name)
    except BagError as err:
        if "engine_rpm" in str(err):
            raise DatasetError(f"identification needs the engine speed (engine_rpm): without it the propeller thrust "
                               f"and the rudder inflow are unknown, so R0 and every speed-dependent hull "
                               f"term cannot be "
                               f"separated from them ({err}); a vessel file of layout rudder_only identifies what such "
                               "a record supports") from err
        raise
    if blocks == 1:
        return recordings
    pieces = []
    for rec in recordings:
        bounds = np.linspace(0, len(rec), blocks + 1).round().astype(int)
        pieces += [slice_recording(rec, int(a), int(b), f"{rec.name}~{k + 1}")
                   for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]
    return pieces


@dataclass(frozen=True)
class IdentifyRequest:
    """What `replay identify` identifies from which bags, how, and what it writes (option combinations checked)."""

    bags: tuple[Path, ...]  # bag files or directories of bags
    output: Path  # the grey-box (or hybrid) artifact written
    structure: str = "auto"  # mmg / abkowitz / diagonal / coupled / auto (fitting/identification.py)
    prior: str = "none"  # none / fix / ridge: what a coefficient the data leave undetermined becomes
    hybrid: HybridTraining | None = None  # also train a learned residual so (fitting.hybrid_fit); None: grey box only
    dt: float = 0.2  # the model's step (s)
    validation: str | None = None  # a glob of bags only evaluated; None: no validation
    report: Path | None = None  # a directory for summary.md and the force plots; None: no report
    blocks: int = 1  # pieces per recording for blocked cross-validation of a single long record
    config: Path | None = None  # predictor.yaml whose topics are read; None: the shipped one
    scale: float = 1.0  # Froude scale L_bags / L_vessel, the bags scaled to the vessel's size (1: none)
    base: Path | None = None  # with hybrid: a grey-box artifact whose hull and terms are kept (hybrid_on_base)
    interaction: str | None = None  # identify / fix a rudder boat's interaction factors (None: identify)
    output_error: bool = False  # the output-error fit and stability check after the force fit (fitting/output_error.py)

    def __post_init__(self) -> None:
        if self.base is not None:
            if self.hybrid is None:
                raise DatasetError("--base MODEL is the grey box a learned residual is added to: it needs --hybrid")
            if (self.structure != "auto" or self.prior != "none" or self.blocks != 1 or self.report is not None
                    or self.interaction is not None):
                raise DatasetError("--base MODEL keeps the base's hull (nothing is identified): --structure, --prior, "
                                   "--blocks, --report and --interaction do not apply")


def identification_vessel(request: IdentifyRequest, vessel: str | Path | None) -> tuple[Vessel, Any]:
    """(the vessel identified, the base artifact or None): what `replay identify` resolves at its boundary.

    vessel: a preset name or vessel file (models/loading.resolve_vessel); without --base it is required; with
    --base, None is the vessel the base embeds, and a different one is a ModelError naming the fields. The base is
    loaded once (its dt checked against the request's)."""
    from usv_predictor.models.loading import check_dt, load_model, resolve_vessel

    if request.base is None:
        if vessel is None:
            raise DatasetError("--vessel is required (the vessel file whose hull is identified), unless --base gives "
                               "it")
        return resolve_vessel(vessel), None
    artifact = load_model(str(request.base), option="--base", physics=False)
    check_dt(artifact, request.dt, f"--dt for --base {request.base}")
    return resolve_vessel(vessel, model=artifact, source=f"--base {request.base}"), artifact


def identify_bags(request: IdentifyRequest, vessel: Vessel, base: Any = None,
                  progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Identify the hull (and what the layout lets the data set: thrust gains, engine speeds) of `vessel` from the
    request's bags, read with its actuator layout, export the grey box (with a hybrid training: plus a learned
    residual trained so) to the request's output, validate and report on request (IdentifyRequest's fields).
    base: the loaded base artifact of request.base (identification_vessel), whose hull and extension terms are kept,
    the residual trained on top of them (hybrid_on_base); the hull is then not identified again. The result of
    `replay identify`."""
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.fitting import hull_models, hybrid_fit, identification

    r = request
    bags, output, structure, prior, hybrid, dt = r.bags, r.output, r.structure, r.prior, r.hybrid, r.dt
    validation, report, blocks, config, scale, interaction = (r.validation, r.report, r.blocks, r.config, r.scale,
                                                              r.interaction)
    if base is not None:
        return hybrid_on_base(request, base, vessel, progress=progress)
    preset = vessel
    layout = preset.actuator_layout
    recordings = identification_recordings(list(bags), dt, progress, config, layout=layout, blocks=blocks,
                                           scale=scale, vessel_name=preset.name)
    if not recordings:
        raise DatasetError(f"no usable recordings in {[str(b) for b in bags]}")
    result = hull_models.identify(preset, recordings, structure=structure, prior=prior,
                                  interaction=interaction or "identify", progress=progress,
                                  output_error=r.output_error)
    from usv_predictor.fitting.candidates import candidate_scores, cv_warning

    candidates = candidate_scores(preset, list(result.data), result)
    warning = cv_warning(candidates)
    if warning:
        progress(f"warning: {warning}")
    digest = identification.data_digest(recordings)
    hybrid_info = None
    if hybrid is not None:
        progress(f"training the learned residual ({hybrid.members} members, multi-step loss, held-out manoeuvres)")
        module, hybrid_info = hybrid_fit.train_hybrid(result, recordings, dt, hybrid, progress=progress)
    else:
        module = hybrid_fit.greybox_module(result, dt)
    artifact = hybrid_fit.export_identified(str(output), module, result, dt=dt, training_data_sha256=digest,
                                            model_type="hybrid" if hybrid is not None else "greybox",
                                            hybrid=hybrid_info)
    progress(f"wrote {output} (model {artifact.model_id}, {artifact.metadata['model_type']}, structure "
             f"{result.structure})")
    out: dict[str, Any] = {"model": str(output), "model_id": artifact.model_id,
                           "model_type": artifact.metadata["model_type"], "training_data_sha256": digest,
                           "identification": result.to_json(), "hybrid": hybrid_info,
                           "cv_candidates": [c.to_json() for c in candidates], "cv_warning": warning,
                           "froude_scale": scale}
    if validation:
        paths = sorted(Path(p) for p in glob.glob(validation))
        if not paths:
            raise DatasetError(f"--val {validation!r} matches no bag")
        out["validation"] = evaluate(artifact, identification_recordings(paths, dt, progress, config, layout=layout,
                                                                         scale=scale, vessel_name=preset.name),
                                     progress=progress).to_json()
    for c in result.coefficients():
        progress(f"  {c.name:7s} {c.estimate:+.5g}  [{c.ci95[0]:+.5g}, {c.ci95[1]:+.5g}]  prior {c.prior:+.5g}  "
                 f"{c.status}")
    if result.held_message():  # JSON: identification.held[] (name, value, how, would_determine)
        progress(result.held_message())
    if report is not None:
        from usv_predictor.analysis.reports import write_identification_report

        out["report"] = str(write_identification_report(report, result, out))
    return out


def hybrid_on_base(request: IdentifyRequest, artifact: Any, vessel: Vessel,
                   progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """`replay identify --hybrid --base MODEL`: the grey box of MODEL (`artifact`, loaded from request.base;
    fitting.hybrid_fit.base_from_artifact: e.g. `replay diagnose --export`'s calm-water model + current + wave drift)
    + a learned residual trained on `bags` (fitting.hybrid_fit.train_residual), written to `output` (model_type
    hybrid[+the base's causes]). vessel: the vessel file, checked against the one MODEL embeds
    (identification_vessel); dt is the base's step. The JSON of `replay identify` with the base's record instead of
    an identification."""
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.fitting import hybrid_fit, identification

    bags, output, hybrid, dt, validation = request.bags, request.output, request.hybrid, request.dt, request.validation
    config, scale, base, preset = request.config, request.scale, request.base, vessel
    assert hybrid is not None  # IdentifyRequest: --base needs --hybrid
    layout = preset.actuator_layout
    recordings = identification_recordings(list(bags), dt, progress, config, layout=layout, scale=scale,
                                           vessel_name=preset.name)
    if not recordings:
        raise DatasetError(f"no usable recordings in {[str(b) for b in bags]}")
    identified, grey = hybrid_fit.base_from_artifact(artifact, preset, recordings[0], source=f"--base {base}")
    progress(f"base {base}: {artifact.metadata['model_type']} ({artifact.model_id}), terms "
             + ", ".join(f"{k} {[round(x, 4) for x in v]}" for k, v in grey.terms().items() if any(v)))
    data = identification.prepare(identified, recordings, progress=progress)
    progress(f"training the learned residual ({hybrid.members} members, multi-step loss, held-out manoeuvres) on "
             f"the base")
    module, info = hybrid_fit.train_residual(grey, identified, data, recordings, dt, hybrid, progress=progress)
    digest = identification.data_digest(recordings)
    out_artifact = hybrid_fit.export_on_base(str(output), module, artifact, vessel=preset,
                                             training_data_sha256=digest, hybrid=info)
    progress(f"wrote {output} (model {out_artifact.model_id}, {out_artifact.metadata['model_type']})")
    out: dict[str, Any] = {"model": str(output), "model_id": out_artifact.model_id,
                           "model_type": out_artifact.metadata["model_type"], "training_data_sha256": digest,
                           "base": {"model": str(base), "model_id": artifact.model_id,
                                    "model_type": artifact.metadata["model_type"], "terms": grey.terms()},
                           "hybrid": info, "froude_scale": scale}
    if validation:
        paths = sorted(Path(p) for p in glob.glob(validation))
        if not paths:
            raise DatasetError(f"--val {validation!r} matches no bag")
        out["validation"] = evaluate(out_artifact, identification_recordings(paths, dt, progress, config,
                                                                             layout=layout, scale=scale,
                                                                             vessel_name=preset.name),
                                     progress=progress).to_json()
    return out

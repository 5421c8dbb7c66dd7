"""Bags -> a diagnosis: what `replay diagnose` does (usv_predictor.analysis.diagnosis_run on the bags' recordings)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from usv_predictor.analysis.diagnosis_run import CalmWater, DiagnosisOptions


@dataclass(frozen=True)
class DiagnoseRequest:
    """Which bags `replay diagnose` reads, at what step and scale, and what the diagnosis tries (options)."""

    bags: tuple[Path, ...]  # bag files or directories of bags
    dt: float | None = None  # the model's step (s); None: what suits the calm-water vessel (analysis.diagnosis_steps)
    horizon_s: float | None = None  # the segments' length (s); None: what suits the vessel
    stride_s: float | None = None  # time between segment starts (s); None: what suits the vessel
    include_calm: bool = False  # also read the calm/ twins under bag directories
    config: Path | None = None  # predictor.yaml whose topics are read; None: the shipped one
    scale: float = 1.0  # Froude scale L_bags / L_vessel: the bags scaled to the calm-water vessel's size (1: none)
    options: DiagnosisOptions = field(default_factory=DiagnosisOptions)  # hypotheses, gain, export, report, ...


def diagnose_bags(request: DiagnoseRequest, calm: CalmWater,
                  progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """The calm-water model `calm` (analysis.diagnosis_run.calm_water_model: a preset or vessel file, or a grey-box
    artifact's identified hull on the vessel it embeds), the bags' recordings at its step (topics of the request's
    config, Froude-scaled by its scale: replay.recordings.load_recordings), and the diagnosis run on them
    (run_diagnosis)."""
    from usv_predictor.analysis.diagnosis_run import run_diagnosis
    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps
    from usv_predictor.replay.recordings import Pieces, load_recordings

    calm_water, source, description = calm
    suited = diagnosis_steps(calm_water)
    dt = suited.dt if request.dt is None else request.dt
    horizon_s = suited.horizon_s if request.horizon_s is None else request.horizon_s
    stride_s = suited.stride_s if request.stride_s is None else request.stride_s
    progress(f"model step {dt:g} s, segments of {horizon_s:g} s every {stride_s:g} s ({suited.reason})")
    recordings = load_recordings(list(request.bags), dt, config_path=request.config,
                                 pieces=Pieces(include_calm=request.include_calm, horizon_s=horizon_s,
                                               scale=request.scale),
                                 progress=progress, layout=calm_water.actuator_layout, vessel_name=description.name)
    result = run_diagnosis(recordings, calm_water, source, dt=dt, horizon_s=horizon_s, stride_s=stride_s,
                           options=request.options, progress=progress, suited_steps=suited, description=description)
    result["froude_scale"] = request.scale
    return result

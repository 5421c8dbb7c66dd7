"""Bags -> a diagnosis: what `replay diagnose` does (usv_predictor.analysis.diagnosis_run on the bags' recordings)."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any


def diagnose_bags(bags: Sequence[Path], *, vessel: str | None = None, model: Path | None = None,
                  dt: float | None = None, hypotheses: Sequence[str] | None = None, max_causes: int = 2,
                  horizon_s: float | None = None, stride_s: float | None = None, gain: bool = True, export: Path
                  | None = None, report: Path | None = None,
                  include_calm: bool = False, config: Path | None = None, fit_check: bool = True, scale: float = 1.0,
                  unexplained: bool = True, progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """The calm-water model (preset or vessel file `vessel`, or grey-box artifact `model` on the vessel it embeds), the
    bags' recordings at step dt
    (topics of the predictor config `config`), and the diagnosis run on them (run_diagnosis: the arguments).
    dt, horizon_s, stride_s: None = what suits the calm-water vessel (analysis.diagnosis_steps). scale: Froude scale
    L_bags / L_vessel, the bags scaled to the calm-water vessel's size (replay.recordings.load_recordings; 1: none)."""
    from usv_predictor.analysis.diagnosis_run import calm_water_model, run_diagnosis
    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps
    from usv_predictor.replay.recordings import load_recordings

    calm_water, source, description = calm_water_model(vessel, model, config)
    suited = diagnosis_steps(calm_water)
    dt = suited.dt if dt is None else dt
    horizon_s = suited.horizon_s if horizon_s is None else horizon_s
    stride_s = suited.stride_s if stride_s is None else stride_s
    progress(f"model step {dt:g} s, segments of {horizon_s:g} s every {stride_s:g} s ({suited.reason})")
    recordings = load_recordings(bags, dt, config_path=config, include_calm=include_calm, horizon_s=horizon_s,
                                 progress=progress, layout=calm_water.actuator_layout, scale=scale)
    result = run_diagnosis(recordings, calm_water, source, dt=dt, hypotheses=hypotheses, max_causes=max_causes,
                           horizon_s=horizon_s, stride_s=stride_s, gain=gain, export=export, report=report,
                           fit_check=fit_check, progress=progress, suited_steps=suited, description=description,
                           unexplained=unexplained)
    result["froude_scale"] = scale
    return result

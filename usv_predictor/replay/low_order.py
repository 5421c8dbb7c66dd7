"""Bags -> the low-order model, or the better of it and the grey box: `replay identify --family nomoto | auto`.

    nomoto  the low-order model (models/nomoto.py) fitted by output error to every recording (fitting/nomoto_fit.py)
            and exported, with its coefficients' 95 % intervals and what would determine the loose ones
    auto    each recording cut at its middle; the grey box (replay.identify's identification, the same structure,
            prior, interaction and blocks; a single recording's first half in at least 2 pieces, for its CV) and
            the low-order model fitted on the first halves, both predicting the held-out second halves open loop
            (starts every HELD_OUT_STRIDE_S, errors at HELD_OUT_HORIZONS_S); the one with the smaller error at the
            longest horizon that fits (then the shorter; a model whose rollout is not finite, or that cannot be
            identified, loses) is identified again on all the data and exported, the errors of both printed with
            the reason
"""
from __future__ import annotations

import math
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from usv_predictor.errors import DatasetError, ModelError, NotIdentifiableError

FAMILIES = ("greybox", "nomoto", "auto")  # what `replay identify --family` takes; greybox: replay.identify
HELD_OUT_HORIZONS_S = (10.0, 30.0)  # (s) the open-loop horizons the choice compares
HELD_OUT_STRIDE_S = 5.0  # (s) between the held-out starts (as `replay evaluate`)


@dataclass(frozen=True)
class LowOrderRequest:
    """What `replay identify --family nomoto|auto` was asked (the grey-box options apply to auto's grey box)."""

    bags: tuple[Path, ...]
    output: Path
    vessel: str
    family: str = "nomoto"  # "nomoto" or "auto"
    order: int = 1  # the low-order model's yaw order (1 or 2)
    dt: float = 0.2  # (s)
    structure: str = "auto"
    prior: str = "none"
    interaction: str | None = None
    blocks: int = 1
    config: Path | None = None
    scale: float = 1.0

    def __post_init__(self) -> None:
        if self.family not in ("nomoto", "auto"):
            raise DatasetError(f"--family {self.family!r}: expected nomoto or auto here (greybox: replay.identify)")
        if self.order not in (1, 2):
            raise DatasetError(f"--order {self.order}: expected 1 or 2")


def identify_low_order(request: LowOrderRequest, progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """The result of `replay identify --family nomoto|auto` (module docstring)."""
    from usv_predictor.models.loading import resolve_vessel
    from usv_predictor.replay.identify import identification_recordings

    vessel = resolve_vessel(request.vessel, option="--vessel")
    recordings = identification_recordings(list(request.bags), request.dt, progress, request.config,
                                           layout=vessel.actuator_layout, scale=request.scale)
    if not recordings:
        raise DatasetError(f"no usable recordings in {[str(b) for b in request.bags]}")
    if request.family == "nomoto":
        return _export_nomoto(request, vessel, recordings, progress)
    return _auto(request, vessel, recordings, progress)


def _export_nomoto(request: LowOrderRequest, vessel: Any, recordings: Sequence[Any],
                   progress: Callable[[str], None]) -> dict[str, Any]:
    from usv_predictor.fitting.identification import data_digest
    from usv_predictor.fitting.nomoto_fit import NomotoFitOptions, fit_nomoto
    from usv_predictor.models.nomoto import describe, export_nomoto

    fit = fit_nomoto(recordings, NomotoFitOptions(order=request.order), progress=progress)
    digest = data_digest(recordings)
    artifact = export_nomoto(str(request.output), fit.coefficients, vessel, request.dt, training_data_sha256=digest,
                             identification=fit.to_json())
    progress(f"wrote {request.output} (model {artifact.model_id}, nomoto order {request.order})")
    progress(describe(fit.coefficients, fit.intervals()))
    for note in fit.notes:
        progress(f"  {note}")
    turns = steady_turns(fit, recordings)
    for side, turn in turns["sides"].items():
        interval = "" if None in turn["radius_ci95_m"] else " [{:.3g}, {:.3g}]".format(*turn["radius_ci95_m"])
        radius = "none (no turn)" if turn["radius_m"] is None else f"{turn['radius_m']:.3g} m{interval}"
        progress(f"  steady turn at the data's {turns['command']:.4g} turn command to {side}: radius {radius}, drift "
                 f"angle {turn['drift_deg']:.1f} deg (speed set point {turns['speed_set_point_mps']:.3g} m/s)")
    return {"model": str(request.output), "model_id": artifact.model_id, "model_type": "nomoto", "family": "nomoto",
            "training_data_sha256": digest, "identification": fit.to_json(), "steady_turns": turns,
            "froude_scale": request.scale}


def steady_turns(fit: Any, recordings: Sequence[Any]) -> dict[str, Any]:
    """The steady turn both ways (NomotoFit.turning_circle, radius with its 95 % interval) at the 95th percentile of
    the data's |turn command| about its offset, at the data's speed set point (the median approach speed, or u_0 + u_p
    times the median propulsion level) and median propulsion level: what a turning test at that command would show if
    the yaw response stayed linear there."""
    import numpy as np

    from usv_predictor.data.recording import held_reference

    c = fit.coefficients
    level = float(np.nanmedian(np.concatenate([r.controls @ fit.propulsion_w for r in recordings])))
    offset = c.s_0 + c.s_p * level
    steering = np.concatenate([r.controls @ fit.steering_w for r in recordings]) - offset
    command = float(np.nanpercentile(np.abs(steering), 95))
    if c.speed_mode == "command":
        u_c = c.u_0 + c.u_p * level
    else:
        approaches = [held_reference(r) for r in recordings]
        speeds = [a[0] for a in approaches if a is not None] or [float(np.nanmedian(r.nu[:, 0])) for r in recordings]
        u_c = float(np.median(speeds))
    sides = {}
    for side, sign in (("starboard", 1.0), ("port", -1.0)):
        turn = fit.turning_circle(offset + sign * command, u_c, level)
        sides[side] = {k: (None if isinstance(v, float) and not math.isfinite(v) else  # JSON: no NaN or inf
                           [x if math.isfinite(x) else None for x in v] if isinstance(v, tuple) else v)
                       for k, v in turn.items()}
    return {"command": command, "speed_set_point_mps": u_c, "propulsion_level": level, "sides": sides}


def halves(recordings: Sequence[Any]) -> tuple[list[Any], list[Any]]:
    """(first halves, second halves) of the recordings, each cut at its middle sample."""
    from usv_predictor.replay.recordings import slice_recording

    first, second = [], []
    for rec in recordings:
        middle = len(rec) // 2
        first.append(slice_recording(rec, 0, middle, f"{rec.name}~first_half"))
        second.append(slice_recording(rec, middle, len(rec), f"{rec.name}~second_half"))
    return first, second


def _pieces(recordings: Sequence[Any], blocks: int) -> list[Any]:
    from usv_predictor.replay.recordings import slice_recording

    if blocks == 1:
        return list(recordings)
    out = []
    for rec in recordings:
        bounds = [round(k * len(rec) / blocks) for k in range(blocks + 1)]
        out += [slice_recording(rec, a, b, f"{rec.name}~{k + 1}") for k, (a, b) in enumerate(zip(bounds[:-1],
                                                                                                   bounds[1:]))]
    return out


def held_out_errors(model: Any, held_out: Sequence[Any]) -> dict[str, Any]:
    """{"open_loop_m": {"10s": mean position error (m), ...}, "diverged": rollouts not finite} on the held-out data."""
    from usv_predictor.analysis.evaluation import evaluate

    result = evaluate(model, list(held_out), "gnss", HELD_OUT_HORIZONS_S, HELD_OUT_STRIDE_S)
    summary = result.summary
    errors = {f"{h:g}s": summary.get(f"mean_position_error_after_{h:g}s_m") for h in HELD_OUT_HORIZONS_S}
    return {"open_loop_m": errors, "diverged": int(summary.get("open_loop_diverged_windows") or 0)}


def choose(candidates: dict[str, dict[str, Any]]) -> tuple[str, str]:
    """(family, why): the candidate with the smaller held-out error at the longest horizon both have, then the
    shorter; a refused candidate or one whose rollouts diverged loses."""
    def score(name: str) -> tuple[float, ...]:
        c = candidates[name]
        if "refused" in c or c.get("diverged", 0) > 0:
            return (math.inf,) * len(HELD_OUT_HORIZONS_S)
        values = [c["open_loop_m"].get(f"{h:g}s") for h in reversed(HELD_OUT_HORIZONS_S)]
        return tuple(math.inf if v is None or not math.isfinite(v) else float(v) for v in values)

    names = sorted(candidates, key=score)
    best, other = names[0], names[1]
    if not any(math.isfinite(x) for x in score(best)):
        reasons = "; ".join(f"{n}: {candidates[n].get('refused', 'its rollouts diverged')}" for n in names)
        raise NotIdentifiableError(f"--family auto: no family predicts the held-out halves ({reasons})")

    def shown(name: str) -> str:
        c = candidates[name]
        if "refused" in c:
            return f"{name} refused ({c['refused']})"
        errors = " / ".join("-" if v is None else f"{v:.2f}" for v in c["open_loop_m"].values())
        extra = f", {c['diverged']} rollouts diverged" if c.get("diverged") else ""
        return f"{name} {errors} m{extra}"

    horizons = " / ".join(f"{h:g}" for h in HELD_OUT_HORIZONS_S)
    why = (f"{best} predicts the held-out halves better: open-loop error at {horizons} s {shown(best)}; "
           f"{shown(other)}")
    return best, why


def compare_families(request: LowOrderRequest, vessel: Any, recordings: Sequence[Any],
                     progress: Callable[[str], None] = lambda _: None) -> tuple[str, str, dict[str, dict[str, Any]]]:
    """(chosen family, why, each candidate's held-out errors or refusal): the grey box and the low-order model fitted
    on the first halves of `recordings`, scored on the second halves (module docstring)."""
    from usv_predictor.fitting import hull_models, hybrid_fit
    from usv_predictor.fitting.nomoto_fit import NomotoFitOptions, fit_nomoto
    from usv_predictor.models.artifact import load_artifact
    from usv_predictor.models.loading import with_fused_rollout
    from usv_predictor.models.nomoto import export_nomoto

    first, second = halves(recordings)
    candidates: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="identify-auto-") as scratch:
        progress("auto: the grey box on the first half of each recording")
        try:
            blocks = max(request.blocks, 2) if len(first) == 1 else request.blocks  # its CV needs two pieces
            result = hull_models.identify(vessel, _pieces(first, blocks), structure=request.structure,
                                          prior=request.prior, interaction=request.interaction or "identify",
                                          progress=progress)
            path = Path(scratch) / "greybox.pt"
            hybrid_fit.export_identified(str(path), hybrid_fit.greybox_module(result, request.dt), result,
                                         dt=request.dt, training_data_sha256="")
            candidates["greybox"] = held_out_errors(with_fused_rollout(load_artifact(path)), second)
        except (NotIdentifiableError, DatasetError, ModelError) as err:
            candidates["greybox"] = {"refused": str(err).splitlines()[0]}
        progress(f"auto: the low-order model (Nomoto order {request.order}) on the first half of each recording")
        try:
            fit = fit_nomoto(first, NomotoFitOptions(order=request.order, intervals=False), progress=progress)
            path = Path(scratch) / "nomoto.pt"
            export_nomoto(str(path), fit.coefficients, vessel, request.dt, training_data_sha256="",
                          identification=fit.to_json())
            candidates["nomoto"] = held_out_errors(with_fused_rollout(load_artifact(path)), second)
        except (NotIdentifiableError, DatasetError, ModelError) as err:
            candidates["nomoto"] = {"refused": str(err).splitlines()[0]}
    chosen, why = choose(candidates)
    return chosen, why, candidates


def _auto(request: LowOrderRequest, vessel: Any, recordings: Sequence[Any],
          progress: Callable[[str], None]) -> dict[str, Any]:
    from usv_predictor.replay.identify import IdentifyRequest, identify_bags

    chosen, why, candidates = compare_families(request, vessel, recordings, progress)
    progress(f"auto: {why}; {chosen} identified again on all the data")
    if chosen == "greybox":
        grey = IdentifyRequest(bags=tuple(request.bags), output=Path(request.output), structure=request.structure,
                               prior=request.prior, dt=request.dt, blocks=request.blocks, config=request.config,
                               scale=request.scale, interaction=request.interaction)
        out = identify_bags(grey, vessel, progress=progress)
        out["family"] = "greybox"
    else:
        out = _export_nomoto(request, vessel, recordings, progress)
    out["choice"] = {"chosen": chosen, "why": why, "held_out": candidates,
                     "horizons_s": list(HELD_OUT_HORIZONS_S), "stride_s": HELD_OUT_STRIDE_S,
                     "split": "each recording's first half fitted, its second half predicted"}
    return out

"""`replay diagnose`: what the calm-water model gets wrong on measured bags, the named cause, the extended
model and its measured gain on held-out manoeuvres (usv_predictor.analysis.diagnosis).

JSON result: cause, parameters (DESIGN.md vocabulary and units), uncertainty, confounded_with, additional_causes
(further causes added one at a time while the evidence holds, with their parameters), evidence (every
hypothesis: held-out loss, gain, log-likelihood evidence, per-fold parameters), discrepancy (what the calm-water
model gets wrong), baseline / extended / gain (evaluation metrics on held-out manoeuvres), notes.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

NAME = "diagnose"
HELP = "name the physical cause of what the calm-water model gets wrong, extend the model, measure the gain"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from usv_predictor.physics.effects import hypothesis_names

    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG", help="bags or directories of bags (a trial programme)")
    parser.add_argument("--vessel", default=None, help="vessel preset of the calm-water model (default: config's vessel)")
    parser.add_argument("--model", type=Path, default=None, metavar="M",
                        help="a grey-box model artifact (from `replay identify`) as the calm-water model instead of the preset")
    parser.add_argument("--dt", type=float, default=0.5, help="model step (s, default 0.5)")
    parser.add_argument("--hypotheses", nargs="+", default=None, metavar="H",
                        help=f"hypotheses to test (default: all of {' '.join(hypothesis_names())})")
    parser.add_argument("--max-causes", type=int, default=2,
                        help="name up to this many causes, added one at a time while each passes the evidence test "
                             "(default 2)")
    parser.add_argument("--horizon", type=float, default=20.0, help="segment horizon (s, default 20)")
    parser.add_argument("--stride", type=float, default=5.0, help="time between segment starts (s, default 5)")
    parser.add_argument("--no-gain", action="store_true", help="skip the held-out evaluation of the extended model")
    parser.add_argument("--export", type=Path, default=None, metavar="PATH",
                        help="write the extended model (TorchScript artifact) for the node")
    parser.add_argument("--report", type=Path, default=None, metavar="DIR", help="write report.md + plots into DIR")
    parser.add_argument("--include-calm", action="store_true", help="also read calm/ twins under bag directories")
    parser.add_argument("--config", type=Path, default=None, help="predictor.yaml with the topics (default: shipped)")


def _log(message: str) -> None:
    print(message, file=sys.stderr)


def baseline_vessel(args: argparse.Namespace):
    """The calm-water model: a vessel preset, or the identified hull of a grey-box artifact."""
    from usv_predictor.config import load_predictor_config
    from usv_predictor.errors import ModelError
    from usv_predictor.models.greybox import HULL_NAMES
    from usv_predictor.physics.vessel import load_vessel

    if args.model is None:
        return load_vessel(args.vessel or load_predictor_config(args.config).vessel), "preset"
    from usv_predictor.models.artifact import load_artifact

    artifact = load_artifact(args.model)
    meta = artifact.metadata
    hull = _hull_of(meta)
    if not str(meta.get("model_type", "")).startswith("greybox") or hull is None:
        raise ModelError(f"model {args.model}: diagnose needs an MMG grey box without learned or extra terms "
                         f"(`replay identify --structure mmg`), not model_type {meta.get('model_type')!r}; "
                         "compare other models with `replay evaluate`")
    vessel = load_vessel(args.vessel or str(meta.get("vessel")))
    missing = [n for n in HULL_NAMES if n not in hull]
    if missing:
        raise ModelError(f"model {args.model}: hull coefficients {missing} missing from its metadata")
    vessel = dataclasses.replace(vessel, hull=dataclasses.replace(vessel.hull, **{n: float(hull[n]) for n in HULL_NAMES}))
    return vessel, f"identified ({meta.get('model_id')})"


def _hull_of(meta: dict) -> dict | None:
    """The MMG hull derivatives of a grey-box artifact: from `replay identify` (identification.coefficients)
    or from `replay diagnose --export` (architecture.hull); None for anything the grey box cannot carry."""
    ident = meta.get("identification")
    arch = meta.get("architecture")
    if isinstance(ident, dict):
        residual = arch.get("residual", "ZeroResidual") if isinstance(arch, dict) else "ZeroResidual"
        if ident.get("structure") != "mmg" or ident.get("extra_terms") or residual != "ZeroResidual":
            return None
        return {c["name"]: c["estimate"] for c in ident.get("coefficients", []) if isinstance(c, dict)}
    return arch.get("hull") if isinstance(arch, dict) and isinstance(arch.get("hull"), dict) else None


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.analysis import diagnosis as dg
    from usv_predictor.errors import DatasetError
    from usv_predictor.replay.recordings import load_recordings

    vessel, source = baseline_vessel(args)
    recordings = load_recordings(args.bags, args.dt, config_path=args.config, include_calm=args.include_calm,
                                 horizon_s=args.horizon, progress=_log)
    if not recordings:
        raise DatasetError("no usable recording in the bags (see the warnings above)")
    missing = [r.name for r in recordings if not (r.controls[:, 1] > 0).any()]
    if missing:
        raise DatasetError(f"no engine speed in {missing}: the calm-water model needs rudder and rpm; record engine_rpm")
    _log(f"diagnosing {len(recordings)} manoeuvre(s) against the {source} calm-water model of {vessel.name}")
    if args.max_causes < 1:
        raise DatasetError(f"--max-causes {args.max_causes} must be >= 1")
    result = dg.diagnose(recordings, vessel, hypotheses=args.hypotheses, horizon_s=args.horizon, stride_s=args.stride,
                         max_causes=args.max_causes, progress=_log)
    seg = dg.make_segments(recordings, args.horizon, args.stride)
    discrepancy = dg.discrepancy(dg.scripted_rollout(vessel, args.dt), seg, recordings)
    _log(f"cause: {result.cause} {result.parameters} — {result.message}")
    out = {
        "cause": result.cause, "parameters": result.parameters, "uncertainty": result.uncertainty,
        "confounded_with": list(result.confounded_with), "message": result.message, "notes": list(result.notes),
        "additional_causes": [dataclasses.asdict(a) for a in result.additional_causes],
        "evidence": [dataclasses.asdict(e) for e in result.evidence],
        "folds": [list(f) for f in result.folds], "discrepancy": discrepancy,
        "calm_water_model": {"vessel": vessel.name, "source": source},
        "recordings": [{"name": r.name, "source": r.source, "duration_s": r.duration_s} for r in recordings],
        "seconds": result.seconds,
    }
    if result.cause != "none" and not args.no_gain:
        _log("measuring the gain on held-out manoeuvres")
        gain = dg.measure_gain(recordings, vessel, result, horizon_s=args.horizon, segment_stride_s=args.stride)
        out.update(baseline=gain["baseline"], extended=gain["extended"], gain=gain["relative_improvement"])
        per_recording = gain["per_recording"]
    else:
        out.update(baseline=None, extended=None, gain={})
        per_recording = None
    if args.export is not None:
        artifact = dg.export_extended(args.export, vessel, result, args.dt)
        out["exported_model"] = {"path": str(args.export), "model_id": artifact.model_id}
        _log(f"extended model written to {args.export} ({artifact.model_id})")
    if args.report is not None:
        from usv_predictor.analysis.diagnosis_report import write_report

        out["report"] = str(write_report(args.report, out, recordings, vessel, result, per_recording))
        _log(f"report written to {out['report']}")
    return out

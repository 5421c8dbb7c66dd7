"""`replay evaluate [BAGS...]`: a model on recorded manoeuvres, scored like seed 000 Tables 7-8.

With no bags it evaluates on the shipped sea-trial bags (bags/sea_trial, not their calm twins); with no
--model it uses the shipped model (models/default.pt). `--model physics[:VESSEL]` evaluates the calm-water
manoeuvring model of a vessel preset instead: the physics baseline a learned model must beat at sea.
Prints one row per test (turning radius eq. 29, drift direction eq. 28, drift distance eq. 27, open-loop error),
writes the full result with --json and, with --output DIR, evaluation.json plus the time series
(evaluation_series.npz) that `replay report DIR/evaluation.json` draws from. Bags are only read.
"""
from __future__ import annotations

import argparse
import datetime
import math
import sys
from pathlib import Path
from typing import Any

NAME = "evaluate"
HELP = "evaluate a model on bags: closed-loop tracks, turning-circle and zig-zag metrics, open-loop errors"
EVALUATION_FILE = "evaluation.json"
SERIES_FILE = "evaluation_series.npz"
PHYSICS = "physics"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="*", type=Path, metavar="BAG",
                        help="bags or directories of bags (default: the shipped bags/sea_trial, calm twins skipped)")
    add_model_arguments(parser)
    parser.add_argument("--output", type=Path, default=None, metavar="DIR",
                        help=f"write {EVALUATION_FILE} and {SERIES_FILE} (time series for `replay report`) into DIR")


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Options shared with `replay report` (which can evaluate bags itself)."""
    parser.add_argument("--model", default=None, metavar="M",
                        help="model artifact (.pt), or 'physics[:VESSEL]' for the calm-water physics baseline "
                             "(default: the shipped models/default.pt)")
    parser.add_argument("--dt", type=float, default=None,
                        help="step (s) to resample the bags at; must equal the model's dt (default: the model's)")
    parser.add_argument("--reference", choices=("gnss", "truth"), default="gnss",
                        help="compare with the measured GNSS track and states (default) or the ground truth of "
                             "simulated bags")
    parser.add_argument("--horizons", type=float, nargs="+", default=[10.0, 30.0, 60.0], metavar="S",
                        help="open-loop horizons (s, default 10 30 60)")
    parser.add_argument("--stride", type=float, default=5.0, metavar="S",
                        help="time between open-loop start points (s, default 5)")
    parser.add_argument("--include-calm", action="store_true", help="also read calm/ twins under bag directories")


def _log(message: str) -> None:
    print(message, file=sys.stderr)


# ------------------------------------------------------------------ model and data


def default_model_path() -> Path:
    """The shipped model; ModelError saying where it was looked for when there is none yet."""
    from usv_predictor.config import package_share_path, share_roots
    from usv_predictor.errors import ConfigError, ModelError

    try:
        return package_share_path("models", "default.pt")
    except ConfigError as err:
        looked = ", ".join(str(root / "models" / "default.pt") for root in share_roots())
        raise ModelError(f"no shipped model: models/default.pt does not exist (looked in {looked}); train one with "
                         "`replay train`, pass --model PATH, or --model physics for the physics baseline") from err


def load_model(spec: str | None, dt: float | None) -> Any:
    """The model named by --model, checked against --dt (ModelError naming the file and what differs)."""
    from usv_predictor.analysis import evaluation
    from usv_predictor.config import load_predictor_config
    from usv_predictor.errors import ModelError

    if spec is not None and (spec == PHYSICS or spec.startswith(PHYSICS + ":")):
        cfg = load_predictor_config()
        vessel = spec.partition(":")[2] or cfg.vessel
        return evaluation.physics_predictor(vessel, dt if dt is not None else cfg.dt)
    path = default_model_path() if spec is None else Path(spec)
    if not path.is_file():
        raise ModelError(f"--model {path}: no such model file")
    try:
        from usv_predictor.models.artifact import load_artifact
    except ImportError as err:
        raise ModelError(f"{path}: cannot load model artifacts, usv_predictor.models.artifact is unavailable ({err})") from err
    model = load_artifact(path)
    if dt is not None:
        evaluation.check_dt(model, dt, f"--dt for {path}")
    return model


def default_bags() -> list[Path]:
    from usv_predictor.config import package_share_path
    from usv_predictor.errors import BagError, ConfigError

    try:
        return [package_share_path("bags", "sea_trial")]
    except ConfigError as err:
        raise BagError(f"no bags given and the shipped bags/sea_trial is missing: {err}") from err


def run_evaluation(args: argparse.Namespace) -> tuple[Any, list[Path]]:
    """(EvaluationResult, bag arguments) for the command-line options shared by evaluate and report."""
    import numpy as np

    from usv_predictor.analysis import evaluation
    from usv_predictor.errors import BagError
    from usv_predictor.replay.recordings import load_recordings

    if args.stride <= 0.0 or any(h <= 0.0 for h in args.horizons):
        raise evaluation.EvaluationError("--stride and --horizons must be positive (s)")
    model = load_model(args.model, args.dt)
    dt = evaluation.model_dt(model)
    bags = list(args.bags) or default_bags()
    _log(f"model {model.metadata.get('model_id', '?')} ({model.metadata.get('model_type', '?')}), dt {dt:g} s; "
         f"reading {', '.join(map(str, bags))}")
    recordings = load_recordings(bags, dt, include_calm=args.include_calm, warn=lambda m: _log(f"warning: {m}"),
                                 progress=_log)
    if not recordings:
        raise BagError(f"no usable recording in {', '.join(map(str, bags))} (see the warnings above)")
    result = evaluation.evaluate(model, recordings, args.reference, tuple(args.horizons), args.stride, progress=_log)
    from usv_predictor import __version__

    result.extra.update({
        "generated_utc": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "software_version": __version__,
        "model_source": args.model or str(default_model_path()),
        "data": {"bags": [str(b) for b in bags], "dt_s": dt, "reference": args.reference,
                 "recordings": [{"name": r.name, "source": r.source, "duration_s": r.duration_s,
                                 "has_gnss": bool(np.isfinite(r.position).any()),
                                 "has_truth": r.truth is not None} for r in recordings]},
    })
    return result, bags


# ------------------------------------------------------------------ output


def _cell(value: float | None, digits: int = 2, suffix: str = "") -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}{suffix}"


def format_table(result: dict) -> str:
    """Seed 000 Tables 7-8 per test (one row each): radius, drift direction, drift distance, open-loop error."""
    horizons = result.get("open_loop_horizons_s", [])
    mid = f"{horizons[len(horizons) // 2]:g}" if horizons else None
    head = (f"{'test':<36} {'kind':<15} | {'radius m':>8} {'pred':>7} {'err':>8} | {'drift deg':>9} {'pred':>7}"
            f" {'err':>7} | {'drift m':>7} {'pred':>6} {'err':>8}" + (f" | OL {mid} s m" if mid else ""))
    lines = [f"model {result['model'].get('model_id', '?')} ({result['model'].get('model_type', '?')}), "
             f"reference {result['reference']}", head, "-" * len(head)]
    for rec in result["recordings"]:
        row = f"{rec['name'][-36:]:<36} {rec['manoeuvre']['kind']:<15} |"
        turning = rec.get("turning")
        if turning:
            m, p, e = turning["measured"], turning["predicted"], turning["errors"]
            row += (f" {_cell(m['turning_radius_m']):>8} {_cell(p['turning_radius_m']):>7}"
                    f" {_cell(e['turning_radius_rel_pct'], 2, '%'):>8} |"
                    f" {_cell(m['drift_direction_deg']):>9} {_cell(p['drift_direction_deg']):>7}"
                    f" {_cell(e['drift_direction_abs_deg']):>7} |"
                    f" {_cell(m['drift_distance_m']):>7} {_cell(p['drift_distance_m']):>6}"
                    f" {_cell(e['drift_distance_rel_pct'], 2, '%'):>8}")
        else:
            row += f" {'':>8} {'':>7} {'':>8} | {'':>9} {'':>7} {'':>7} | {'':>7} {'':>6} {'':>8}"
        if mid:
            loop = rec.get("open_loop") or {}
            row += f" | {_cell(loop.get(f'position_error_after_{mid}s_m')):>9}"
        lines.append(row)
    s = result["summary"]
    lines.append("-" * len(head))
    lines.append(f"max |rel. error| radius {_cell(s.get('max_abs_turning_radius_rel_error_pct'), 2, '%')}, "
                 f"max |error| drift direction {_cell(s.get('max_abs_drift_direction_error_deg'), 2, ' deg')}, "
                 f"max |rel. error| drift distance {_cell(s.get('max_abs_drift_distance_rel_error_pct'), 2, '%')}")
    lines.append("mean open-loop position error: " + ", ".join(
        f"{h:g} s {_cell(s.get(f'mean_position_error_after_{h:g}s_m'), 2, ' m')}" for h in horizons))
    return "\n".join(lines)


def write_series_atomic(path: Path, arrays: dict) -> None:
    """np.savez to a temporary file beside `path`, then os.replace."""
    import numpy as np

    from usv_predictor.atomic import atomic_open

    with atomic_open(path, "wb") as out:
        np.savez_compressed(out, **arrays)


def save_evaluation(result: Any, directory: Path) -> dict:
    """DIR/evaluation.json + DIR/evaluation_series.npz; returns the JSON written."""
    from usv_predictor.analysis.evaluation import series_arrays
    from usv_predictor.replay.cli import write_json_atomic

    write_series_atomic(directory / SERIES_FILE, series_arrays(result))
    data = dict(result.to_json(), series_file=SERIES_FILE)
    write_json_atomic(directory / EVALUATION_FILE, data)
    return data


def run(args: argparse.Namespace) -> dict:
    result, _ = run_evaluation(args)
    data = result.to_json()
    if args.output is not None:
        data = save_evaluation(result, args.output)
        _log(f"wrote {args.output / EVALUATION_FILE} and {args.output / SERIES_FILE}")
    from usv_predictor.replay.cli import _jsonable

    print(format_table(_jsonable(data)))
    return data

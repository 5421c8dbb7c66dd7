"""`replay evaluate [BAGS...]`: a model on recorded manoeuvres, scored like seed 000 Tables 7-8.

With no bags it evaluates on the shipped sea-trial bags (bags/sea_trial, not their calm twins); with no
--model it uses the shipped model (models/default.pt). `--model physics[:VESSEL]` evaluates the calm-water
manoeuvring model of a vessel preset instead: the physics baseline a learned model must beat at sea.
Prints one row per test (turning radius eq. 29, drift direction eq. 28, drift distance eq. 27, open-loop error),
writes the full result with --json and, with --output DIR, evaluation.json plus the time series
(evaluation_series.npz) that `replay report DIR/evaluation.json` draws from. Bags are only read.
A model that does not fit the bags at all (its steady speed or yaw rate at the recorded commands, or its length
scale: usv_predictor.analysis.fit_check) is refused in one line (exit 2) unless --no-fit-check; the check is in the
JSON (`fit_check`).
The work: usv_predictor.replay.evaluate.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from usv_predictor.replay.evaluate import EVALUATION_FILE, SERIES_FILE
from usv_predictor.replay.options import add_model_arguments, evaluation_request, log

NAME = "evaluate"
HELP = "evaluate a model on bags: closed-loop tracks, turning-circle and zig-zag metrics, open-loop errors"
INPUTS = ("bags", "model", "config")
OUTPUTS = {"output": "dir"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="*", type=Path, metavar="BAG",
                        help="bags or directories of bags (default: the shipped bags/sea_trial, calm twins skipped)")
    add_model_arguments(parser)
    parser.add_argument("--adaptive", action="store_true",
                        help="also run the online estimator of the current (docs/online.md) over each bag and score "
                             "the open loop with its live estimate in the grey box's terms (JSON section "
                             "`adaptive`; a learned model without those terms gets the estimate reported, not "
                             "applied)")
    parser.add_argument("--output", type=Path, default=None, metavar="DIR",
                        help=f"write {EVALUATION_FILE} and {SERIES_FILE} (time series for `replay report`) into DIR")


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.analysis.reports import evaluation_table
    from usv_predictor.atomic import jsonable
    from usv_predictor.replay.evaluate import evaluate

    data = evaluate(evaluation_request(args, args.bags), args.output, progress=log)
    print(evaluation_table(jsonable(data)))
    if "adaptive" in data:
        summary = data["adaptive"]["summary"]
        errors = ", ".join(f"{k.removeprefix('mean_position_error_after_').removesuffix('_m')} {v:.2f} m"
                           for k, v in summary.items() if k.startswith("mean_position_error") and v is not None)
        print(f"adaptive ({'applied' if summary['applied'] else 'not applied'}): open-loop error {errors}")
    return data

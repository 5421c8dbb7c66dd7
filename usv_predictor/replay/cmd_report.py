"""`replay report [EVALUATION.json | BAGS...] --output DIR`: Markdown report with figures of an evaluation.

Input: an evaluation file written by `replay evaluate --output DIR` (its time series, evaluation_series.npz,
are read from beside it for the figures), or bags (or nothing: the shipped sea trial) evaluated here with the
same options as `replay evaluate`.
Output in DIR: report.md (model, data, date; tables in the layout of seed 000 Tables 6-8; closed-loop state
errors; open-loop errors; figures), report.json (the same numbers) and PNG figures (seed 000 Fig. 10-15).
Every file is written to a temporary name and renamed; report.md is written last. Bags are only read.
The work: usv_predictor.replay.evaluate.report and usv_predictor.analysis.reports.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from usv_predictor.replay.options import add_model_arguments, evaluation_request, log

NAME = "report"
HELP = "write a Markdown report (report.md, report.json, PNG figures) of an evaluation file or of bags"
INPUTS = ("inputs", "model", "config")
OUTPUTS = {"output": "dir"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("inputs", nargs="*", type=Path, metavar="EVALUATION.json | BAG",
                        help="an evaluation file of `replay evaluate --output`, or bags / directories of bags "
                             "(default: the shipped bags/sea_trial)")
    parser.add_argument("--output", type=Path, required=True, metavar="DIR", help="directory for the report")
    parser.add_argument("--title", default="USV motion prediction: evaluation report", help="report title")
    add_model_arguments(parser)


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.replay.evaluate import report

    return report(evaluation_request(args, args.inputs), args.output, args.title, progress=log)

"""`replay convert`: public measured manoeuvres (HSVA/MARIN KVLCC2, Fuzhou and Dalian USVs) -> one rosbag2 each
(a MARIN turning / pull-out file -> two: the turning circle and the pull-out).

Bags carry the default input topics of config/predictor.yaml (no ground truth: measured data have
none) and custom_data with source, licence note, scale, conventions and conversion version. The readers
and the conversion live in usv_predictor.replay.convert (`convert`); docs/data.md says what each source supports.
"""
from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from usv_predictor.replay.options import log

NAME = "convert"
HELP = ("convert public measured manoeuvres (HSVA/MARIN KVLCC2 zig-zags, MARIN KVLCC2 turning circles and pull-outs, "
        "Fuzhou USV zig-zag, Dalian twin-thruster USV runs) to rosbag2 bags")
INPUTS = ("sources",)
OUTPUTS = {"output": "dir"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from usv_predictor.replay.convert.formats import FORMATS

    parser.add_argument("sources", nargs="+", type=Path, metavar="SOURCE_DIR_OR_FILE",
                        help="data directories (e.g. ../shared/data/raw/kvlcc2_hsva_simman2008) or manoeuvre files")
    parser.add_argument("--output", type=Path, required=True, help="directory for the bags (one per manoeuvre)")
    parser.add_argument("--format", choices=("auto", *FORMATS), default="auto",
                        help="input format (default auto: from the file names)")
    parser.add_argument("--storage", choices=("sqlite3", "mcap"), default="sqlite3",
                        help="rosbag2 storage (default sqlite3)")
    parser.add_argument("--overwrite", action="store_true", help="replace existing bags")


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.replay.convert import convert

    command = shlex.join(["replay", *sys.argv[1:]]) if sys.argv else "replay convert"
    return convert(args.sources, args.output, fmt=args.format, storage=args.storage, overwrite=args.overwrite,
                   command=command, progress=log)

"""Command-line options shared by several replay commands, and the typed values they become.

Only argparse plumbing lives here: the commands call `add_*_arguments(parser)` and turn the parsed options
into the typed request of their library function, so no argparse Namespace travels further. `log` is how a
command shows a library function's progress (stderr: stdout is the command's result).

Numbers: every numeric option is parsed by one of NUMBER_TYPES (never a bare float or int), so "nan", "inf",
a zero step or a negative seed is a one-line usage error naming the option before any work.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Callable, Sequence

from usv_predictor.replay.evaluate import (REFERENCES, ROLLOUT_BUDGET_S, EvaluationRequest, given_vessel,
                                           is_evaluation_file)


def _number(text: str, kind: type, what: str, ok: Callable[[float], bool]) -> float | int:
    try:
        value = kind(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
    if not math.isfinite(value) or not ok(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
    return value


def finite_float(text: str) -> float:
    """A finite number (no nan, no inf)."""
    return float(_number(text, float, "a finite number", lambda v: True))


def positive_float(text: str) -> float:
    """A finite number > 0 (steps, horizons, strides, durations)."""
    return float(_number(text, float, "a finite number > 0", lambda v: v > 0.0))


def non_negative_float(text: str) -> float:
    """A finite number >= 0."""
    return float(_number(text, float, "a finite number >= 0", lambda v: v >= 0.0))


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    return int(_number(text, int, "a whole number >= 1", lambda v: v >= 1))


def non_negative_int(text: str) -> int:
    """A whole number >= 0 (seeds, counts where 0 means none or automatic)."""
    return int(_number(text, int, "a whole number >= 0", lambda v: v >= 0))


SCALE_RANGE = (0.01, 100.0)  # accepted Froude scales L_bags / L_model (-): towing-tank models are 1:10 to 1:100


def froude_scale(text: str) -> float:
    """A Froude scale L_bags / L_model within SCALE_RANGE."""
    low, high = SCALE_RANGE
    return float(_number(text, float, f"a scale between {low:g} and {high:g} (L_bags / L_model)",
                         lambda v: low <= v <= high))


NUMBER_TYPES = (finite_float, positive_float, non_negative_float, positive_int, non_negative_int, froude_scale)

SCALE_HELP = ("Froude-scale the bags to the model's size first: LAMBDA = L_bags / L_model, the bags' vessel is LAMBDA "
              "times as long as the model's (full-scale bags, model-scale model: > 1, KVLCC2 45.714; model-scale "
              "bags, full-scale model: < 1, 1/45.714 = 0.021875). Lengths / LAMBDA, times and speeds / sqrt(LAMBDA), "
              "yaw rates and rpm x sqrt(LAMBDA), angles and normalised commands kept; results are at the model's "
              "scale. A wrong direction or factor is refused by the fit check (default 1: none)")


def add_scale_argument(parser: argparse.ArgumentParser) -> None:
    """--scale LAMBDA: Froude scaling of the bags (usv_predictor.data.recording.froude_scaled)."""
    parser.add_argument("--scale", type=froude_scale, default=1.0, metavar="LAMBDA", help=SCALE_HELP)


def log(message: str) -> None:
    """A progress line on stderr."""
    print(message, file=sys.stderr)


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    """--config: the predictor parameter file whose input topics (and their options) the bags are read with.
    Every command that reads bags takes it (list "config" in the command's INPUTS)."""
    parser.add_argument("--config", type=Path, default=None, metavar="YAML",
                        help="predictor.yaml with the input topics and their options (default: the shipped "
                             "config/predictor.yaml)")


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """The model and how to compare it: options of `replay evaluate` and `replay report` (which can evaluate bags)."""
    parser.add_argument("--model", default=None, metavar="M",
                        help="model artifact (.pt), or 'physics[:VESSEL]' for the calm-water physics baseline "
                             "(default: the shipped models/default.pt)")
    parser.add_argument("--dt", type=positive_float, default=None,
                        help="step (s) to resample the bags at; must equal the model's dt (default: the model's)")
    parser.add_argument("--reference", choices=REFERENCES, default="gnss",
                        help="compare with the measured GNSS track and states (default), the same smoothed (EKF + RTS "
                             "over GNSS, compass, INS, gyro: eq. 27-29 on raw GNSS carry its noise; the model still "
                             "starts from the raw measured state) or the ground truth of simulated bags")
    parser.add_argument("--horizons", type=positive_float, nargs="+", default=[10.0, 30.0, 60.0], metavar="S",
                        help="open-loop horizons (s, default 10 30 60)")
    parser.add_argument("--stride", type=positive_float, default=5.0, metavar="S",
                        help="time between open-loop start points (s, default 5)")
    parser.add_argument("--include-calm", action="store_true", help="also read calm/ twins under bag directories")
    add_config_argument(parser)
    parser.add_argument("--vessel", default=None, metavar="PRESET|YAML",
                        help="vessel preset or YAML file the bags were recorded on: its actuator layout says which "
                             "control topics are read and must be the model's control_layout, the fit check uses its "
                             "length; a model that embeds a different description is refused, naming the fields "
                             "(default: the vessel the model embeds or names, else the config's)")
    add_scale_argument(parser)
    parser.add_argument("--rollout-budget", type=positive_float, default=ROLLOUT_BUDGET_S, metavar="S",
                        help="the longest one rollout of the model over the longest horizon (or recording, if "
                             "shorter; one start, every member) may take (s): a slower model, or one whose code does "
                             "not return, is refused with the measured time (default "
                             f"{ROLLOUT_BUDGET_S:g})")
    parser.add_argument("--no-fit-check", action="store_true",
                        help="evaluate even when the model does not fit the bags at all (its steady speed or yaw rate "
                             "at the recorded commands, or its length scale, is far off: refused otherwise)")


def evaluation_request(args: argparse.Namespace, bags: Sequence[Path]) -> EvaluationRequest:
    """The options of add_model_arguments (and the bags) as an EvaluationRequest."""
    vessel = None if is_evaluation_file(bags) else given_vessel(args.vessel, args.model)  # a file names its own
    return EvaluationRequest(bags=tuple(bags), model=args.model, dt=args.dt, reference=args.reference,
                             horizons_s=tuple(args.horizons), stride_s=args.stride, include_calm=args.include_calm,
                             config=args.config, vessel=vessel,
                             adaptive=bool(getattr(args, "adaptive", False)), fit_check=not args.no_fit_check,
                             scale=args.scale, rollout_budget_s=args.rollout_budget)

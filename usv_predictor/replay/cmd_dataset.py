"""`replay dataset`: bags -> one training set file (usv_predictor.data.dataset format, a compressed .npz).

    replay dataset bags/training bags/sea_trial --output out/ds.npz
    replay dataset bags/training --test 'zigzag_20*' --val 0.25 --features NAF --output out/naf.npz

A directory argument stands for every bag under it, recursively, except sub-directories named `calm`
(the calm-water twins `replay simulate --calm-twin` writes): name a calm directory explicitly, or add
--include-calm, to read them. --val and --test take either a fraction of the manoeuvres not matched by a
pattern, or glob patterns (repeatable) over recording names; --train GLOB pins manoeuvres to training.
Recording names and the rules for gaps, NaNs, duplicates and short pieces: usv_predictor.replay.recordings.
The work: usv_predictor.replay.dataset.
"""
from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from usv_predictor.data.features import FEATURE_SETS
from usv_predictor.replay.options import log, non_negative_float, non_negative_int, positive_float

NAME = "dataset"
HELP = "build a training set (one-step samples, split by manoeuvre) from bags into one .npz file"
INPUTS = ("bags", "config")
OUTPUTS = {"output": "file"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG",
                        help="bags, or directories searched recursively for bags (calm/ twins skipped)")
    parser.add_argument("--output", type=Path, required=True, help="dataset file to write (.npz)")
    parser.add_argument("--dt", type=positive_float, default=None, help="step (s; default: dt of the config, 0.5)")
    parser.add_argument("--features", choices=sorted(FEATURE_SETS), default="NTF",
                        help="input features (seed 000): F0 [u v r delta rpm], NAF + psi, NTF + sin/cos "
                             "psi (default NTF)")
    parser.add_argument("--segment", choices=("bag", "steady"), default="bag",
                        help="one recording per bag, or split bags into manoeuvres at control steps after "
                             "settled holds (default bag)")
    split = parser.add_argument_group("split by manoeuvre")
    split.add_argument("--val", action="append", default=[], metavar="FRACTION|GLOB",
                       help="validation: a fraction of the unpinned manoeuvres (default 0.2) or name "
                            "globs (repeatable)")
    split.add_argument("--test", action="append", default=[], metavar="FRACTION|GLOB",
                       help="test: a fraction (default 0) or name globs (repeatable)")
    split.add_argument("--train", action="append", default=[], metavar="GLOB", help="pin manoeuvres to training")
    split.add_argument("--seed", type=non_negative_int, default=0, help="seed of the random split (default 0)")
    data = parser.add_argument_group("input")
    data.add_argument("--config", type=Path, default=None,
                      help="predictor parameter file (default config/predictor.yaml)")
    data.add_argument("--vessel", default=None, metavar="PRESET",
                      help="vessel preset whose actuator layout the bags record (which control topics are read; "
                           "stored in the dataset); default: the config's vessel")
    data.add_argument("--topic", action="append", default=[], metavar="ROLE=TOPIC",
                      help="read ROLE from TOPIC instead of the config's (repeatable), e.g. velocity=ins/twist")
    data.add_argument("--include-calm", action="store_true", help="also read calm/ twins found under directories")
    data.add_argument("--min-duration", type=non_negative_float, default=10.0,
                      help="skip pieces shorter than this (s, default 10)")
    data.add_argument("--jobs", type=non_negative_int, default=0,
                      help="processes reading bags in parallel (default 0: one per CPU, at most one per bag)")
    data.add_argument("--horizon", type=positive_float, default=None,
                      help="skip recordings with fewer than HORIZON/dt + 1 steps (s; default: no such check)")


def _fraction_or_globs(values: list[str], flag: str, default: float) -> tuple[float, tuple[str, ...]]:
    from usv_predictor.errors import ConfigError

    fractions, globs = [], []
    for value in values:
        try:
            fractions.append(float(value))
        except ValueError:
            globs.append(value)
    if len(fractions) > 1:
        raise ConfigError(f"{flag} given {len(fractions)} fractions {fractions}; give one")
    if fractions and not 0.0 <= fractions[0] < 1.0:
        raise ConfigError(f"{flag} {fractions[0]:g}: a fraction must be in [0, 1)")
    return (fractions[0] if fractions else (0.0 if globs else default)), tuple(globs)


def _topics(pairs: list[str]) -> dict[str, str]:
    from usv_predictor.errors import ConfigError

    out = {}
    for pair in pairs:
        role, sep, topic = pair.partition("=")
        if not sep or not role or not topic:
            raise ConfigError(f"--topic {pair!r}: expected ROLE=TOPIC, e.g. velocity=ins/twist")
        out[role] = topic
    return out


def _command_line(args: argparse.Namespace) -> str:
    """The command that rebuilds this dataset (recorded as provenance)."""
    words = ["replay", NAME, *map(str, args.bags), "--output", str(args.output), "--features", args.features,
             "--segment", args.segment, "--seed", str(args.seed), "--min-duration", f"{args.min_duration:g}"]
    words += ["--dt", f"{args.dt:g}"] if args.dt is not None else []
    words += ["--horizon", f"{args.horizon:g}"] if args.horizon is not None else []
    for flag in ("val", "test", "train", "topic"):
        for value in getattr(args, flag):
            words += [f"--{flag}", value]
    words += ["--config", str(args.config)] if args.config else []
    words += ["--include-calm"] if args.include_calm else []
    words += ["--vessel", args.vessel] if args.vessel else []
    return shlex.join(words)


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.models.loading import resolve_vessel
    from usv_predictor.replay.dataset import DatasetRequest, dataset_from_bags

    request = DatasetRequest(
        bags=tuple(args.bags), output=args.output, features=args.features, dt=args.dt, segment=args.segment,
        val=_fraction_or_globs(args.val, "--val", 0.2), test=_fraction_or_globs(args.test, "--test", 0.0),
        train=tuple(args.train), seed=args.seed, config=args.config, topics=_topics(args.topic),
        include_calm=args.include_calm, min_duration_s=args.min_duration, jobs=args.jobs, horizon_s=args.horizon,
        provenance=_command_line(args))
    result = dataset_from_bags(request, resolve_vessel(args.vessel, config_path=args.config),
                               warn=lambda message: print(f"replay {NAME}: warning: {message}", file=sys.stderr),
                               progress=log)
    _print_table(result)
    return result


def _print_table(result: dict) -> None:
    """One line per recording (split, duration, samples), one per split, and what was written."""
    rows = result["recordings"]
    width = max(len(row["name"]) for row in rows)
    print(f"{'recording':<{width}}  split  duration_s  samples")
    for row in rows:
        print(f"{row['name']:<{width}}  {row['split']:<5}  {row['duration_s']:10.1f}  {row['samples']:7d}")
    for s, c in result["splits"].items():
        print(f"{s}: {c['recordings']} recording(s), {c['duration_s']:.0f} s, {c['samples']} samples")
    print(f"wrote {result['output']} ({result['feature_set']}, dt {result['dt']:g} s, {result['samples']} samples) "
          f"in {result['seconds']:.2f} s")

"""`replay dataset`: bags -> one training set file (usv_predictor.data.dataset format, a compressed .npz).

    replay dataset bags/training bags/sea_trial --output out/ds.npz
    replay dataset bags/training --test 'zigzag_20*' --val 0.25 --features NAF --output out/naf.npz

A directory argument stands for every bag under it, recursively, except sub-directories named `calm`
(the calm-water twins `replay simulate --calm-twin` writes): name a calm directory explicitly, or add
--include-calm, to read them. --val and --test take either a fraction of the manoeuvres not matched by a
pattern, or glob patterns (repeatable) over recording names; --train GLOB pins manoeuvres to training.
Recording names and the rules for gaps, NaNs, duplicates and short pieces: usv_predictor.replay.recordings.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

from usv_predictor.data.features import FEATURE_SETS

NAME = "dataset"
HELP = "build a training set (one-step samples, split by manoeuvre) from bags into one .npz file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bags", nargs="+", type=Path, metavar="BAG",
                        help="bags, or directories searched recursively for bags (calm/ twins skipped)")
    parser.add_argument("--output", type=Path, required=True, help="dataset file to write (.npz)")
    parser.add_argument("--dt", type=float, default=None, help="step (s; default: dt of the config, 0.5)")
    parser.add_argument("--features", choices=sorted(FEATURE_SETS), default="NTF",
                        help="input features (seed 000): F0 [u v r delta rpm], NAF + psi, NTF + sin/cos psi (default NTF)")
    parser.add_argument("--segment", choices=("bag", "steady"), default="bag",
                        help="one recording per bag, or split bags into manoeuvres at control steps after "
                             "settled holds (default bag)")
    split = parser.add_argument_group("split by manoeuvre")
    split.add_argument("--val", action="append", default=[], metavar="FRACTION|GLOB",
                       help="validation: a fraction of the unpinned manoeuvres (default 0.2) or name globs (repeatable)")
    split.add_argument("--test", action="append", default=[], metavar="FRACTION|GLOB",
                       help="test: a fraction (default 0) or name globs (repeatable)")
    split.add_argument("--train", action="append", default=[], metavar="GLOB", help="pin manoeuvres to training")
    split.add_argument("--seed", type=int, default=0, help="seed of the random split (default 0)")
    data = parser.add_argument_group("input")
    data.add_argument("--config", type=Path, default=None, help="predictor parameter file (default config/predictor.yaml)")
    data.add_argument("--topic", action="append", default=[], metavar="ROLE=TOPIC",
                      help="read ROLE from TOPIC instead of the config's (repeatable), e.g. velocity=ins/twist")
    data.add_argument("--include-calm", action="store_true", help="also read calm/ twins found under directories")
    data.add_argument("--min-duration", type=float, default=10.0, help="skip pieces shorter than this (s, default 10)")
    data.add_argument("--jobs", type=int, default=0,
                      help="processes reading bags in parallel (default 0: one per CPU, at most one per bag)")
    data.add_argument("--horizon", type=float, default=None,
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
    return shlex.join(words)


def run(args: argparse.Namespace) -> dict:
    from usv_predictor.config import load_predictor_config
    from usv_predictor.data.dataset import build_dataset, save_dataset, split_by_manoeuvre
    from usv_predictor.errors import DatasetError
    from usv_predictor.replay.recordings import bag_sha256, load_recordings

    started = time.perf_counter()
    warnings: list[str] = []

    def warn(message: str) -> None:
        warnings.append(message)
        print(f"replay {NAME}: warning: {message}", file=sys.stderr)

    def progress(message: str) -> None:
        print(message, file=sys.stderr)

    dt = args.dt if args.dt is not None else load_predictor_config(args.config).dt
    val_fraction, val_globs = _fraction_or_globs(args.val, "--val", 0.2)
    test_fraction, test_globs = _fraction_or_globs(args.test, "--test", 0.0)
    recordings = load_recordings(args.bags, dt, config_path=args.config, topics=_topics(args.topic),
                                 segment=args.segment, min_duration_s=args.min_duration, horizon_s=args.horizon,
                                 include_calm=args.include_calm, jobs=args.jobs, warn=warn, progress=progress)
    if not recordings:
        raise DatasetError(f"no usable recording in {[str(b) for b in args.bags]} (see the warnings above)")
    splits = split_by_manoeuvre([r.name for r in recordings], val_fraction=val_fraction, test_fraction=test_fraction,
                                seed=args.seed, train=args.train, val=val_globs, test=test_globs)
    for split, fraction in (("val", val_fraction), ("test", test_fraction)):
        if fraction > 0.0 and split not in splits.values():
            warn(f"--{split} {fraction:g} left the {split} split empty: too few manoeuvres to spare from training")
    sources = sorted({r.source for r in recordings})
    digests = {source: bag_sha256(Path(source)) for source in sources}
    dataset = build_dataset(recordings, args.features, splits=splits, bag_sha256=digests,
                            provenance=_command_line(args))
    save_dataset(args.output, dataset)
    return _summary(args, dataset, recordings, warnings, time.perf_counter() - started)


def _summary(args: argparse.Namespace, dataset, recordings, warnings: list[str], seconds: float) -> dict:
    import numpy as np

    samples = np.bincount(dataset.arrays["sample_recording"], minlength=len(recordings))
    rows = [{"name": r.name, "source": r.source, "split": e["split"], "steps": len(r),
             "duration_s": r.duration_s, "samples": int(samples[m])}
            for m, (r, e) in enumerate(zip(recordings, dataset.entries))]
    splits = {s: {"recordings": sum(1 for row in rows if row["split"] == s),
                  "duration_s": sum(row["duration_s"] for row in rows if row["split"] == s),
                  "samples": sum(row["samples"] for row in rows if row["split"] == s)}
              for s in ("train", "val", "test")}
    width = max(len(row["name"]) for row in rows)
    print(f"{'recording':<{width}}  split  duration_s  samples")
    for row in rows:
        print(f"{row['name']:<{width}}  {row['split']:<5}  {row['duration_s']:10.1f}  {row['samples']:7d}")
    for s, c in splits.items():
        print(f"{s}: {c['recordings']} recording(s), {c['duration_s']:.0f} s, {c['samples']} samples")
    print(f"wrote {args.output} ({dataset.feature_set}, dt {dataset.dt:g} s, {len(dataset.X)} samples) in {seconds:.2f} s")
    return {"output": str(args.output), "format": dataset.metadata["format"], "digest": dataset.digest(),
            "feature_set": dataset.feature_set, "feature_names": dataset.metadata["feature_names"], "dt": dataset.dt,
            "recordings": rows, "splits": splits, "samples": int(len(dataset.X)), "warnings": warnings,
            "seconds": seconds, "provenance": dataset.metadata["provenance"]}

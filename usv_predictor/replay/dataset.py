"""Bags -> one training-set file (usv_predictor.data.dataset format): what `replay dataset` does.

Recording names and the rules for gaps, NaNs, duplicates and short pieces: usv_predictor.replay.recordings;
the split by manoeuvre: usv_predictor.data.dataset.split_by_manoeuvre.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from usv_predictor.physics.vessel import Vessel


@dataclass(frozen=True)
class DatasetRequest:
    """What `replay dataset` builds: which bags, how they are cut and split, where it is written."""

    bags: tuple[Path, ...]  # bag files or directories of bags
    output: Path  # the dataset file (usv_predictor.data.dataset format)
    features: str = "NTF"  # the feature set (data/features.py)
    dt: float | None = None  # resampling step (s); None: the predictor config's
    segment: str = "bag"  # how a bag is cut (replay/recordings.SEGMENTS)
    val: tuple[float, tuple[str, ...]] = (0.2, ())  # (fraction of the manoeuvres no pattern pins, name globs)
    test: tuple[float, tuple[str, ...]] = (0.0, ())  # ... the same for the test split
    train: tuple[str, ...] = ()  # name globs pinned to training
    seed: int = 0  # the split's random seed
    config: Path | None = None  # predictor.yaml whose topics and step are read; None: the shipped one
    topics: Mapping[str, str] = field(default_factory=dict)  # role -> topic overrides of the config's
    include_calm: bool = False  # also read the calm/ twins under bag directories
    min_duration_s: float = 10.0  # shorter pieces are skipped (s)
    jobs: int = 0  # processes reading bags (0: one per CPU, at most one per bag)
    horizon_s: float | None = None  # pieces too short for this horizon are skipped (s); None: no check
    provenance: str = ""  # the command that rebuilds the dataset


def dataset_from_bags(request: DatasetRequest, vessel: Vessel, *, warn: Callable[[str], None] = lambda _: None,
                      progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Build and save the dataset; the result of `replay dataset` (per-recording rows, splits, digest, warnings).

    vessel: the vessel the bags were recorded on (models/loading.resolve_vessel): its actuator layout says which
    control topics the bags carry, and is stored in the dataset (metadata control_layout).
    """
    import numpy as np

    from usv_predictor.config import load_predictor_config
    from usv_predictor.data.dataset import build_dataset, save_dataset, split_by_manoeuvre
    from usv_predictor.errors import DatasetError
    from usv_predictor.replay.recordings import Pieces, bag_sha256, load_recordings

    started = time.perf_counter()
    warnings: list[str] = []

    def warned(message: str) -> None:
        warnings.append(message)
        warn(message)

    r = request
    step = r.dt if r.dt is not None else load_predictor_config(r.config).dt
    (val_fraction, val_globs), (test_fraction, test_globs) = r.val, r.test
    pieces = Pieces(segment=r.segment, min_duration_s=r.min_duration_s, horizon_s=r.horizon_s,
                    include_calm=r.include_calm)
    recordings = load_recordings(list(r.bags), step, config_path=r.config, topics=r.topics, pieces=pieces,
                                 jobs=r.jobs, warn=warned, progress=progress, layout=vessel.actuator_layout,
                                 vessel_name=vessel.name)
    if not recordings:
        raise DatasetError(f"no usable recording in {[str(b) for b in r.bags]} (see the warnings above)")
    splits = split_by_manoeuvre([rec.name for rec in recordings], val_fraction=val_fraction,
                                test_fraction=test_fraction, seed=r.seed, train=r.train, val=tuple(val_globs),
                                test=tuple(test_globs))
    for split, fraction in (("val", val_fraction), ("test", test_fraction)):
        if fraction > 0.0 and split not in splits.values():
            warned(f"--{split} {fraction:g} left the {split} split empty: too few manoeuvres to spare from training")
    digests = {source: bag_sha256(Path(source)) for source in sorted({rec.source for rec in recordings})}
    dataset = build_dataset(recordings, r.features, splits=splits, bag_sha256=digests, provenance=r.provenance)
    save_dataset(r.output, dataset)
    samples = np.bincount(dataset.arrays["sample_recording"], minlength=len(recordings))
    rows = [{"name": rec.name, "source": rec.source, "split": e["split"], "steps": len(rec),
             "duration_s": rec.duration_s, "samples": int(samples[m])}
            for m, (rec, e) in enumerate(zip(recordings, dataset.entries))]
    per_split = {s: {"recordings": sum(1 for row in rows if row["split"] == s),
                     "duration_s": sum(row["duration_s"] for row in rows if row["split"] == s),
                     "samples": sum(row["samples"] for row in rows if row["split"] == s)}
                 for s in ("train", "val", "test")}
    return {"output": str(r.output), "format": dataset.metadata["format"], "digest": dataset.digest(),
            "feature_set": dataset.feature_set, "feature_names": dataset.metadata["feature_names"], "dt": dataset.dt,
            "control_layout": dataset.control_layout, "control_names": dataset.metadata["control_names"],
            "recordings": rows, "splits": per_split, "samples": int(len(dataset.X)), "warnings": warnings,
            "seconds": time.perf_counter() - started, "provenance": dataset.metadata["provenance"]}

"""Bags -> one training-set file (usv_predictor.data.dataset format): what `replay dataset` does.

Recording names and the rules for gaps, NaNs, duplicates and short pieces: usv_predictor.replay.recordings;
the split by manoeuvre: usv_predictor.data.dataset.split_by_manoeuvre.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any


def dataset_from_bags(bags: Sequence[Path], output: Path, *, features: str = "NTF", dt: float | None = None,
                      segment: str = "bag", val: tuple[float, Sequence[str]] = (0.2, ()),
                      test: tuple[float, Sequence[str]] = (0.0, ()), train: Sequence[str] = (), seed: int = 0,
                      config: Path | None = None, topics: Mapping[str, str] | None = None, include_calm: bool = False,
                      min_duration_s: float = 10.0, jobs: int = 0, horizon_s: float | None = None,
                      provenance: str = "", vessel: str | None = None, warn: Callable[[str], None] = lambda _: None,
                      progress: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Build and save the dataset; the result of `replay dataset` (per-recording rows, splits, digest, warnings).

    val / test: (fraction of the manoeuvres no pattern pins, name globs); train: globs pinned to training;
    dt None: the predictor config's step; topics: role -> topic overrides; provenance: the command that rebuilds it;
    vessel: the preset whose actuator layout says which control topics the bags carry (None: the config's vessel);
    the layout is stored in the dataset (metadata control_layout).
    """
    import numpy as np

    from usv_predictor.config import load_predictor_config
    from usv_predictor.data.dataset import build_dataset, save_dataset, split_by_manoeuvre
    from usv_predictor.errors import DatasetError
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.recordings import bag_sha256, load_recordings

    started = time.perf_counter()
    warnings: list[str] = []

    def warned(message: str) -> None:
        warnings.append(message)
        warn(message)

    predictor = load_predictor_config(config)
    step = dt if dt is not None else predictor.dt
    layout = load_vessel(vessel or predictor.vessel).actuator_layout
    (val_fraction, val_globs), (test_fraction, test_globs) = val, test
    recordings = load_recordings(bags, step, config_path=config, topics=topics, segment=segment,
                                 min_duration_s=min_duration_s, horizon_s=horizon_s, include_calm=include_calm,
                                 jobs=jobs, warn=warned, progress=progress, layout=layout)
    if not recordings:
        raise DatasetError(f"no usable recording in {[str(b) for b in bags]} (see the warnings above)")
    splits = split_by_manoeuvre([r.name for r in recordings], val_fraction=val_fraction, test_fraction=test_fraction,
                                seed=seed, train=train, val=tuple(val_globs), test=tuple(test_globs))
    for split, fraction in (("val", val_fraction), ("test", test_fraction)):
        if fraction > 0.0 and split not in splits.values():
            warned(f"--{split} {fraction:g} left the {split} split empty: too few manoeuvres to spare from training")
    digests = {source: bag_sha256(Path(source)) for source in sorted({r.source for r in recordings})}
    dataset = build_dataset(recordings, features, splits=splits, bag_sha256=digests, provenance=provenance)
    save_dataset(output, dataset)
    samples = np.bincount(dataset.arrays["sample_recording"], minlength=len(recordings))
    rows = [{"name": r.name, "source": r.source, "split": e["split"], "steps": len(r),
             "duration_s": r.duration_s, "samples": int(samples[m])}
            for m, (r, e) in enumerate(zip(recordings, dataset.entries))]
    per_split = {s: {"recordings": sum(1 for row in rows if row["split"] == s),
                     "duration_s": sum(row["duration_s"] for row in rows if row["split"] == s),
                     "samples": sum(row["samples"] for row in rows if row["split"] == s)}
                 for s in ("train", "val", "test")}
    return {"output": str(output), "format": dataset.metadata["format"], "digest": dataset.digest(),
            "feature_set": dataset.feature_set, "feature_names": dataset.metadata["feature_names"], "dt": dataset.dt,
            "control_layout": dataset.control_layout, "control_names": dataset.metadata["control_names"],
            "recordings": rows, "splits": per_split, "samples": int(len(dataset.X)), "warnings": warnings,
            "seconds": time.perf_counter() - started, "provenance": dataset.metadata["provenance"]}

"""Training sets: one-step samples from Recordings, splits by manoeuvre, and one compressed .npz file.

Samples (seed 000 eq. 7): for step k of a recording, the input is
    X_k = features(feature_set, state_k, controls_k)      (F,)  state = [u, v, r, psi], controls = [delta, rpm]
and the target is the motion at the next step
    Y_k = nu_{k+1} = [u, v, r]_{k+1}                      (3,)  m/s, m/s, rad/s
so a recording of T steps gives T - 1 samples and no sample crosses from one recording into another.

Splits are by manoeuvre, never by sample: neighbouring samples of one manoeuvre are nearly equal, so a
sample-wise split would leak the training data into validation. Pieces of one bag cut at a gap (NAME#k,
see replay.recordings) are one manoeuvre and always share a split.

File format "usv_predictor.dataset/1" (np.savez_compressed, no pickles):
    metadata        () str: JSON with format, dt, feature_set, feature_names/units, target_names/units,
                    state_names, control_layout (the actuator layout: physics/actuators.py; a file
                    without it is rudder_propeller), control_names/units (its C columns), recordings [{name, source,
                    t0_ns, length, split, bag_sha256, datum}], software_version, created_utc, provenance
    seq_t_s (T,) seq_nu (T, 3) seq_psi (T,) seq_controls (T, C) seq_position (T, 2) seq_truth (T, 6)
                    the Recordings concatenated (truth NaN where a recording has none);
    seq_offsets (M + 1,) int64: recording m is rows seq_offsets[m]:seq_offsets[m + 1]
    X (N, F) Y (N, 3) sample_recording (N,) int64 sample_step (N,) int64
"""
from __future__ import annotations

import datetime
import fnmatch
import hashlib
import json
import os
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from usv_predictor.atomic import atomic_open
from usv_predictor.bounded import parse_json, regular_file
from usv_predictor.data.features import (
    STATE_NAMES,
    STATE_UNITS,
    TARGET_NAMES,
    TARGET_UNITS,
    feature_names,
    feature_units,
    features,
)  # fmt: skip
from usv_predictor.data.recording import Recording, recording_layout
from usv_predictor.errors import ConfigError, DatasetError
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, actuator_layout

FORMAT = "usv_predictor.dataset/1"
SPLITS = ("train", "val", "test")
SEQUENCE_ARRAYS = ("seq_t_s", "seq_nu", "seq_psi", "seq_controls", "seq_position", "seq_truth")
SAMPLE_ARRAYS = ("X", "Y", "sample_recording", "sample_step")
ARRAYS = SEQUENCE_ARRAYS + ("seq_offsets",) + SAMPLE_ARRAYS
PIECE_MARK = "#"  # NAME#k: a piece of manoeuvre NAME cut at a gap


def manoeuvre_of(name: str) -> str:
    """The manoeuvre a recording belongs to: its name without a gap-piece suffix (#k)."""
    return name.split(PIECE_MARK, 1)[0]


# ------------------------------------------------------------------ samples


def _check_steps(recordings: Sequence[Recording]) -> float:
    if not recordings:
        raise DatasetError("no recordings: give at least one bag with a usable manoeuvre")
    steps = {r.dt for r in recordings}
    if len(steps) != 1:
        raise DatasetError(f"recordings have different steps {sorted(steps)} s; resample them to one dt")
    return recordings[0].dt


def make_samples(recordings: Sequence[Recording], feature_set: str) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                             np.ndarray]:
    """(X (N, F), Y (N, 3), rec_index (N,), step_index (N,)): sample k of recording m pairs step k with k + 1."""
    layout = recording_layout(recordings)
    width = len(feature_names(feature_set, layout))
    xs, ys, recs, steps = [np.zeros((0, width))], [np.zeros((0, 3))], [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for m, rec in enumerate(recordings):
        n = len(rec) - 1
        if n < 1:
            continue
        xs.append(features(feature_set, rec.state()[:-1], rec.controls[:-1], layout))  # (n, F)
        ys.append(rec.nu[1:])  # (n, 3)
        recs.append(np.full(n, m, dtype=np.int64))
        steps.append(np.arange(n, dtype=np.int64))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(recs), np.concatenate(steps)


# ------------------------------------------------------------------ splits


def _matches(name: str, patterns: Sequence[str]) -> bool:
    return any(fnmatch.fnmatchcase(name, p) for p in patterns)


def _fraction_count(fraction: float, available: int) -> int:
    """How many of `available` manoeuvres a fraction asks for: rounded, at least one when > 0."""
    if fraction <= 0.0 or available == 0:
        return 0
    return max(1, int(round(fraction * available)))


def split_by_manoeuvre(names: Sequence[str], *, val_fraction: float = 0.0, test_fraction: float = 0.0, seed: int = 0,
                       train: Sequence[str] = (), val: Sequence[str] = (), test: Sequence[str] = ()) -> dict[str, str]:
    """name -> "train" | "val" | "test", whole manoeuvres at a time (manoeuvre_of groups gap pieces).

    A manoeuvre matching the glob patterns of one split goes there (matching two splits is an error).
    The others are shuffled with `seed` (after sorting, so the input order does not matter) and the
    fractions of *them* go to val and test (rounded, at least one when the fraction is > 0, but never the
    last one left for training); the rest trains. Raises DatasetError when no manoeuvre is left for
    training (the patterns took them all), saying what to change.
    """
    for label, value in (("val_fraction", val_fraction), ("test_fraction", test_fraction)):
        if not 0.0 <= value < 1.0:
            raise DatasetError(f"{label}={value} must be in [0, 1)")
    patterns = {"train": tuple(train), "val": tuple(val), "test": tuple(test)}
    manoeuvres = sorted({manoeuvre_of(n) for n in names})
    chosen: dict[str, str] = {}
    for m in manoeuvres:
        hits = [split for split, globs in patterns.items() if _matches(m, globs)]
        if len(hits) > 1:
            raise DatasetError(f"manoeuvre {m!r} matches the patterns of several splits {hits}: {patterns}")
        if hits:
            chosen[m] = hits[0]
    for split, globs in patterns.items():
        for glob in globs:
            if not any(fnmatch.fnmatchcase(m, glob) for m in manoeuvres):
                raise DatasetError(f"--{split} pattern {glob!r} matches no manoeuvre; names: {manoeuvres}")
    rest = [m for m in manoeuvres if m not in chosen]
    order = [rest[i] for i in np.random.default_rng(seed).permutation(len(rest))]
    # the fractions never take the last manoeuvre left for training (one bag still makes a training set)
    n_val = min(_fraction_count(val_fraction, len(rest)), max(len(rest) - 1, 0))
    n_test = min(_fraction_count(test_fraction, len(rest)), max(len(rest) - 1 - n_val, 0))
    for k, m in enumerate(order):
        chosen[m] = "val" if k < n_val else "test" if k < n_val + n_test else "train"
    if "train" not in chosen.values():
        counts = {s: sum(1 for v in chosen.values() if v == s) for s in SPLITS}
        raise DatasetError(
            f"no manoeuvre left for training ({len(manoeuvres)} manoeuvre(s): {counts}); add bags, "
            "lower the validation/test fractions or name training manoeuvres with --train GLOB")
    return {n: chosen[manoeuvre_of(n)] for n in names}


# ------------------------------------------------------------------ the dataset


@dataclass(frozen=True)
class Dataset:
    """A training set in memory: the sequences it came from, the samples, and where everything came from."""

    metadata: Mapping[str, Any]
    arrays: Mapping[str, np.ndarray] = field(repr=False)
    path: str = ""  # the file it was read from, for messages

    @property
    def dt(self) -> float:
        return float(self.metadata["dt"])

    @property
    def feature_set(self) -> str:
        return str(self.metadata["feature_set"])

    @property
    def entries(self) -> list[dict[str, Any]]:
        return list(self.metadata["recordings"])

    @property
    def X(self) -> np.ndarray:  # noqa: N802 (the usual name of a design matrix)
        return self.arrays["X"]

    @property
    def Y(self) -> np.ndarray:  # noqa: N802
        return self.arrays["Y"]

    @property
    def control_layout(self) -> str:
        """The actuator layout of the controls columns (physics/actuators.py; files without one: the default's)."""
        return str(self.metadata.get("control_layout", DEFAULT_LAYOUT.name))

    def recordings(self) -> list[Recording]:
        """The Recordings, as they were given to build_dataset."""
        a, off = self.arrays, self.arrays["seq_offsets"]
        out = []
        for m, entry in enumerate(self.entries):
            rows = slice(int(off[m]), int(off[m + 1]))
            truth = a["seq_truth"][rows]
            datum = entry.get("datum")
            out.append(Recording(
                name=entry["name"], source=entry["source"], t0_ns=int(entry["t0_ns"]), dt=self.dt,
                t_s=a["seq_t_s"][rows], nu=a["seq_nu"][rows], psi=a["seq_psi"][rows],
                controls=a["seq_controls"][rows], position=a["seq_position"][rows],
                truth=None if entry.get("has_truth") is False else truth,
                datum=None if datum is None else (float(datum[0]), float(datum[1])), layout=self.control_layout,
            ))  # fmt: skip
        return out

    def split(self, name: str) -> Dataset:
        """Only the recordings (and their samples) of split `name`, re-indexed from 0."""
        if name not in SPLITS:
            raise DatasetError(f"{self.path or 'dataset'}: unknown split {name!r}; splits: {list(SPLITS)}")
        keep = [m for m, e in enumerate(self.entries) if e["split"] == name]
        return _subset(self, keep)

    def split_sizes(self) -> dict[str, dict[str, int]]:
        counts = np.bincount(self.arrays["sample_recording"], minlength=len(self.entries))
        return {s: {"recordings": sum(1 for e in self.entries if e["split"] == s),
                    "samples": int(sum(counts[m] for m, e in enumerate(self.entries) if e["split"] == s))}
                for s in SPLITS}

    def digest(self) -> str:
        """SHA-256 over the arrays (name, dtype, shape, bytes in name order): the model's training data id."""
        h = hashlib.sha256()
        for name in sorted(self.arrays):
            array = np.ascontiguousarray(self.arrays[name])
            h.update(f"{name}:{array.dtype.str}:{array.shape};".encode())
            h.update(array.tobytes())
        return h.hexdigest()


def _subset(ds: Dataset, keep: Sequence[int]) -> Dataset:
    a, off = ds.arrays, ds.arrays["seq_offsets"]
    rows = np.concatenate([np.arange(off[m], off[m + 1]) for m in keep] or [np.zeros(0, np.int64)])
    lengths = [int(off[m + 1] - off[m]) for m in keep]
    arrays = {name: a[name][rows] for name in SEQUENCE_ARRAYS}
    arrays["seq_offsets"] = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    picked = np.isin(a["sample_recording"], keep)
    renumber = np.full(len(off) - 1, -1, dtype=np.int64)
    renumber[list(keep)] = np.arange(len(keep))
    for name in SAMPLE_ARRAYS:
        arrays[name] = a[name][picked]
    arrays["sample_recording"] = renumber[arrays["sample_recording"]]
    metadata = dict(ds.metadata, recordings=[ds.entries[m] for m in keep])
    return Dataset(metadata, arrays, ds.path)


def build_dataset(recordings: Sequence[Recording], feature_set: str, *, splits: Mapping[str, str],
                  bag_sha256: Mapping[str, str] | None = None, provenance: str = "",
                  created_utc: str | None = None) -> Dataset:
    """A Dataset of `recordings` (names unique) with their split (name -> train|val|test) and samples.

    bag_sha256: source bag path -> digest (replay.recordings.bag_sha256), recorded per recording.
    """
    from usv_predictor import __version__

    dt = _check_steps(recordings)
    names = [r.name for r in recordings]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise DatasetError(f"recording names must be unique; repeated: {repeated}")
    missing = [n for n in names if splits.get(n) not in SPLITS]
    if missing:
        raise DatasetError(f"no split (one of {list(SPLITS)}) for recording(s) {missing}")
    layout = recording_layout(recordings)  # RecordingError when they mix layouts
    width = len(layout.controls)  # C
    X, Y, rec_index, step_index = make_samples(recordings, feature_set)  # noqa: N806
    lengths = [len(r) for r in recordings]
    arrays = {
        "seq_t_s": np.concatenate([r.t_s for r in recordings]).astype(np.float64),
        "seq_nu": np.concatenate([r.nu for r in recordings]).astype(np.float64).reshape(-1, 3),
        "seq_psi": np.concatenate([r.psi for r in recordings]).astype(np.float64),
        "seq_controls": np.concatenate([r.controls for r in recordings]).astype(np.float64).reshape(-1, width),
        "seq_position": np.concatenate([r.position for r in recordings]).astype(np.float64).reshape(-1, 2),
        "seq_truth": np.concatenate([np.full((len(r), 6), np.nan) if r.truth is None else r.truth
                                     for r in recordings]).astype(np.float64).reshape(-1, 6),
        "seq_offsets": np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        "X": X, "Y": Y, "sample_recording": rec_index, "sample_step": step_index,
    }  # fmt: skip
    entries = [{"name": r.name, "source": r.source, "t0_ns": int(r.t0_ns), "length": len(r), "split": splits[r.name],
                "bag_sha256": (bag_sha256 or {}).get(r.source, ""), "has_truth": r.truth is not None,
                "datum": None if r.datum is None else [float(r.datum[0]), float(r.datum[1])]}
               for r in recordings]
    metadata = {
        "format": FORMAT, "dt": float(dt), "feature_set": feature_set,
        "feature_names": list(feature_names(feature_set, layout)),
        "feature_units": list(feature_units(feature_set, layout)),
        "target_names": list(TARGET_NAMES), "target_units": list(TARGET_UNITS),
        "state_names": list(STATE_NAMES), "state_units": list(STATE_UNITS),
        "control_layout": layout.name, "control_names": list(layout.control_names),
        "control_units": list(layout.control_units),
        "recordings": entries, "software_version": __version__,
        "created_utc": created_utc or datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "provenance": provenance,
    }  # fmt: skip
    return Dataset(metadata, arrays)


# ------------------------------------------------------------------ file


def save_dataset(path: str | os.PathLike[str], dataset: Dataset) -> Path:
    """Write one compressed .npz (temp file beside it, then os.replace: never a half-written file)."""
    path = Path(path)
    with atomic_open(path, "wb", DatasetError, "the dataset") as out:  # a file object: numpy adds no ".npz"
        np.savez_compressed(out, metadata=np.array(json.dumps(dict(dataset.metadata), sort_keys=True)),
                            **{name: np.asarray(dataset.arrays[name]) for name in ARRAYS})
    return path


DATASET_FILE_BYTES = 1 << 44  # bounded by the disk, not by us (bytes)


def load_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Read a dataset file; DatasetError naming the file when it is missing, corrupt or of another format."""
    path = Path(path)
    if os.path.lexists(path):  # a FIFO or a device would block np.load or never end
        regular_file(path, "dataset file", DatasetError, DATASET_FILE_BYTES)
    try:
        with np.load(path, allow_pickle=False) as npz:
            if "metadata" not in npz.files:
                raise DatasetError(f"{path}: not a usv_predictor dataset (no 'metadata' array); expected "
                                   f"format {FORMAT}")
            metadata = parse_json(str(npz["metadata"]), f"{path}: dataset metadata", DatasetError)
            if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
                found = metadata.get("format") if isinstance(metadata, dict) else None
                raise DatasetError(f"{path}: dataset format {found!r}, expected {FORMAT!r}; rebuild it with "
                                   f"`replay dataset`")
            absent = [name for name in ARRAYS if name not in npz.files]
            if absent:
                raise DatasetError(f"{path}: dataset arrays missing: {absent}")
            arrays = {name: npz[name] for name in ARRAYS}
    except FileNotFoundError as err:
        raise DatasetError(f"{path}: no such dataset file") from err
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, TypeError) as err:
        raise DatasetError(f"{path}: corrupt or unreadable dataset ({type(err).__name__}: {err})") from err
    dataset = Dataset(metadata, arrays, str(path))
    _check_consistent(dataset)
    return dataset


def _check_consistent(ds: Dataset) -> None:
    """Shapes that agree with each other and with the metadata, or DatasetError naming the file."""
    a, where = ds.arrays, ds.path
    try:
        entries, width = ds.entries, len(ds.metadata["feature_names"])
        lengths = [int(e["length"]) for e in entries]
    except (KeyError, TypeError, ValueError) as err:
        raise DatasetError(f"{where}: metadata lacks {err} (format {FORMAT})") from err
    off, rows, n = a["seq_offsets"], int(a["seq_t_s"].shape[0]), int(a["X"].shape[0])
    problems = []
    if off.shape != (len(entries) + 1,) or (len(off) and (off[0] != 0 or not np.array_equal(np.diff(off), lengths))):
        problems.append(f"seq_offsets {off.shape} disagree with {len(entries)} recordings of lengths {lengths}")
    try:
        controls = len(actuator_layout(ds.control_layout).controls)  # C
    except ConfigError as err:
        raise DatasetError(f"{where}: {err}") from err
    for name, tail in (("seq_nu", (3,)), ("seq_psi", ()), ("seq_controls", (controls,)), ("seq_position", (2,)),
                       ("seq_truth", (6,))):
        if a[name].shape != (rows, *tail):
            problems.append(f"{name} has shape {a[name].shape}, expected {(rows, *tail)}")
    for name, shape in (("X", (n, width)), ("Y", (n, 3)), ("sample_recording", (n,)), ("sample_step", (n,))):
        if a[name].shape != shape:
            problems.append(f"{name} has shape {a[name].shape}, expected {shape}")
    if n and (a["sample_recording"].min() < 0 or a["sample_recording"].max() >= len(entries)):
        problems.append("sample_recording points outside the recordings")
    if problems:
        raise DatasetError(f"{where}: inconsistent dataset: {'; '.join(problems)}")
    _check_finite(ds)


# arrays whose every value must be a finite number (positions are NaN without GNSS, truth without a simulator)
FINITE_ARRAYS = ("seq_t_s", "seq_nu", "seq_psi", "seq_controls", "X", "Y")


def _check_finite(ds: Dataset) -> None:
    """DatasetError naming the array, the first bad row, its column and recording when a value is NaN or inf."""
    columns = {"X": list(ds.metadata.get("feature_names", [])), "Y": list(TARGET_NAMES),
               "seq_nu": list(STATE_NAMES[:3]),
               "seq_controls": list(actuator_layout(ds.control_layout).control_names)}
    for name in FINITE_ARRAYS:
        values = np.asarray(ds.arrays[name])
        if values.dtype.kind != "f":
            continue
        bad = ~np.isfinite(values)
        if not bad.any():
            continue
        index = np.argwhere(bad)[0]
        row, col = int(index[0]), (int(index[1]) if len(index) > 1 else None)
        names = columns.get(name, [])
        column = "" if col is None else f", column {names[col] if col < len(names) else col}"
        raise DatasetError(f"{ds.path}: {name} holds {int(bad.sum())} non-finite value(s) (first at row {row}{column}: "
                           f"{values[tuple(index)]}); rebuild the dataset with `replay dataset`")

"""dataset: one-step samples (seed 000 eq. 7), splits by manoeuvre, the .npz file format and its errors."""
from __future__ import annotations

import json
import math
import zipfile

import numpy as np
import pytest

from usv_predictor.data.dataset import (
    ARRAYS,
    FORMAT,
    build_dataset,
    load_dataset,
    make_samples,
    manoeuvre_of,
    save_dataset,
    split_by_manoeuvre,
)  # fmt: skip
from usv_predictor.data.features import features
from usv_predictor.data.recording import Recording
from usv_predictor.errors import DatasetError

DT = 0.5


def _recording(name: str, steps: int, seed: int, *, truth: bool = True, dt: float = DT) -> Recording:
    rng = np.random.default_rng(seed)
    t_s = np.arange(steps) * dt
    truth_array = rng.normal(size=(steps, 6)) if truth else None
    position = rng.normal(size=(steps, 2)) * 100.0
    position[:2] = np.nan  # no fix yet: NaN must survive the file
    return Recording(name=name, source=f"/bags/{name}", t0_ns=1_622_527_200_000_000_000 + seed * 10**9, dt=dt,
                     t_s=t_s, nu=rng.normal(size=(steps, 3)), psi=np.cumsum(rng.normal(size=steps)),
                     controls=np.column_stack([rng.uniform(-0.4, 0.4, steps), rng.uniform(600, 700, steps)]),
                     position=position, truth=truth_array, datum=(35.38, 119.56) if truth else None)


@pytest.fixture
def recordings() -> list[Recording]:
    return [_recording("zigzag_a", 12, 1), _recording("turn_b", 7, 2, truth=False), _recording("random_c", 20, 3),
            _recording("turn_d", 2, 4)]


def test_samples_pair_each_step_with_the_next_and_never_cross_recordings(recordings):
    X, Y, rec, step = make_samples(recordings, "NTF")  # noqa: N806
    assert X.shape == (11 + 6 + 19 + 1, 7)
    assert Y.shape == (37, 3)
    for i in range(len(X)):
        r, k = recordings[rec[i]], step[i]
        assert 0 <= k < len(r) - 1  # the target step k + 1 is inside the same recording
        assert np.array_equal(X[i], features("NTF", r.state()[k], r.controls[k]))
        assert np.array_equal(Y[i], r.nu[k + 1])
    assert np.array_equal(np.bincount(rec), [11, 6, 19, 1])
    X0, *_ = make_samples([_recording("one_step", 1, 5)], "F0")  # noqa: N806
    assert X0.shape == (0, 5)


def test_split_is_by_manoeuvre_deterministic_and_disjoint():
    names = [f"bag_{k:02d}" for k in range(20)] + ["gappy#1", "gappy#2", "gappy#3"]
    split = split_by_manoeuvre(names, val_fraction=0.2, test_fraction=0.1, seed=7)
    assert set(split) == set(names)
    assert set(split.values()) == {"train", "val", "test"}
    manoeuvres = {manoeuvre_of(n) for n in names}
    assert len(manoeuvres) == 21
    assert sum(1 for m in manoeuvres if split.get(m, split.get(f"{m}#1")) == "val") == 4  # round(0.2 * 21)
    assert sum(1 for m in manoeuvres if split.get(m, split.get(f"{m}#1")) == "test") == 2
    assert len({split["gappy#1"], split["gappy#2"], split["gappy#3"]}) == 1  # pieces of one manoeuvre stay together
    again = split_by_manoeuvre(list(reversed(names)), val_fraction=0.2, test_fraction=0.1, seed=7)
    assert again == split  # the input order does not matter
    other = split_by_manoeuvre(names, val_fraction=0.2, test_fraction=0.1, seed=8)
    assert other != split  # the seed does


def test_split_patterns_pin_manoeuvres_and_fractions_share_the_rest():
    names = ["turn_15", "turn_20", "turn_25", "zigzag_10", "zigzag_20", "random_1"]
    split = split_by_manoeuvre(names, test=["turn_*"], train=["random_*"], val_fraction=0.5)
    assert [split[n] for n in ("turn_15", "turn_20", "turn_25")] == ["test"] * 3
    assert split["random_1"] == "train"
    assert sorted(split[n] for n in ("zigzag_10", "zigzag_20")) == ["train", "val"]
    one = split_by_manoeuvre(["only"], val_fraction=0.2, test_fraction=0.2)
    assert one == {"only": "train"}  # fractions never take the last training manoeuvre


def test_split_errors_say_what_to_change():
    with pytest.raises(DatasetError, match=r"no manoeuvre left for training .*add bags.*--train GLOB"):
        split_by_manoeuvre(["a", "b"], val=["a"], test=["b"])
    with pytest.raises(DatasetError, match=r"'turn_1' matches the patterns of several splits \['val', 'test'\]"):
        split_by_manoeuvre(["turn_1", "zz"], val=["turn_*"], test=["*_1"])
    with pytest.raises(DatasetError, match=r"--test pattern 'spiral\*' matches no manoeuvre; names: \['a', 'b'\]"):
        split_by_manoeuvre(["a", "b"], test=["spiral*"])
    with pytest.raises(DatasetError, match=r"val_fraction=1.0 must be in \[0, 1\)"):
        split_by_manoeuvre(["a", "b"], val_fraction=1.0)


def _dataset(recordings):
    splits = {"zigzag_a": "train", "turn_b": "val", "random_c": "train", "turn_d": "test"}
    return build_dataset(recordings, "NAF", splits=splits, bag_sha256={"/bags/zigzag_a": "ab" * 32},
                         provenance="replay dataset /bags --output x.npz")


def test_npz_round_trip_keeps_arrays_metadata_and_recordings(recordings, tmp_path):
    dataset = _dataset(recordings)
    path = save_dataset(tmp_path / "sub" / "ds.npz", dataset)
    assert sorted(p.name for p in path.parent.iterdir()) == ["ds.npz"]  # no temporary file left behind
    with np.load(path, allow_pickle=False) as npz:
        assert set(npz.files) == set(ARRAYS) | {"metadata"}
    loaded = load_dataset(path)
    assert loaded.metadata == json.loads(json.dumps(dataset.metadata))
    meta = loaded.metadata
    assert meta["format"] == FORMAT
    assert meta["dt"] == DT
    assert meta["feature_set"] == "NAF"
    assert meta["feature_names"] == ["u", "v", "r", "delta", "rpm", "psi"]
    assert meta["target_names"] == ["u", "v", "r"]
    assert meta["state_names"] == ["u", "v", "r", "psi"]
    assert meta["control_names"] == ["delta", "rpm"]
    assert meta["provenance"].startswith("replay dataset")
    assert [e["bag_sha256"] for e in meta["recordings"]] == ["ab" * 32, "", "", ""]
    for name in ARRAYS:
        assert np.array_equal(loaded.arrays[name], dataset.arrays[name], equal_nan=name.startswith("seq_"))
        assert loaded.arrays[name].dtype == dataset.arrays[name].dtype
    assert loaded.digest() == dataset.digest()
    for got, want in zip(loaded.recordings(), recordings, strict=True):
        assert (got.name, got.source, got.t0_ns, got.dt, got.datum) == (want.name, want.source, want.t0_ns, want.dt,
                                                                        want.datum)
        for field in ("t_s", "nu", "psi", "controls", "position"):
            assert np.array_equal(getattr(got, field), getattr(want, field), equal_nan=True)
        assert (got.truth is None) == (want.truth is None)
        if want.truth is not None:
            assert np.array_equal(got.truth, want.truth)


def test_split_selects_whole_recordings_with_their_samples(recordings):
    dataset = _dataset(recordings)
    train = dataset.split("train")
    assert [r.name for r in train.recordings()] == ["zigzag_a", "random_c"]
    assert np.array_equal(np.bincount(train.arrays["sample_recording"]), [11, 19])
    X, Y, rec, step = make_samples(train.recordings(), "NAF")  # noqa: N806
    assert np.array_equal(train.X, X)
    assert np.array_equal(train.Y, Y)
    assert np.array_equal(train.arrays["sample_recording"], rec)
    assert np.array_equal(train.arrays["sample_step"], step)
    assert dataset.split_sizes() == {"train": {"recordings": 2, "samples": 30}, "val": {"recordings": 1, "samples": 6},
                                     "test": {"recordings": 1, "samples": 1}}
    assert train.digest() != dataset.digest()
    with pytest.raises(DatasetError, match="unknown split 'validation'"):
        dataset.split("validation")


def test_building_refuses_mixed_steps_repeated_names_and_missing_splits(recordings):
    with pytest.raises(DatasetError, match=r"different steps \[0.25, 0.5\]"):
        build_dataset([recordings[0], _recording("fast", 5, 9, dt=0.25)], "F0",
                      splits={"zigzag_a": "train", "fast": "train"})
    with pytest.raises(DatasetError, match=r"repeated: \['zigzag_a'\]"):
        build_dataset([recordings[0], recordings[0]], "F0", splits={"zigzag_a": "train"})
    with pytest.raises(DatasetError, match=r"no split .* for recording\(s\) \['turn_b'\]"):
        build_dataset(recordings[:2], "F0", splits={"zigzag_a": "train"})
    with pytest.raises(DatasetError, match="no recordings"):
        build_dataset([], "F0", splits={})


def test_wrong_old_or_corrupt_files_are_named(recordings, tmp_path):
    good = save_dataset(tmp_path / "good.npz", _dataset(recordings))
    with pytest.raises(DatasetError, match=r"missing\.npz: no such dataset file"):
        load_dataset(tmp_path / "missing.npz")
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"not a zip file at all" * 10)
    with pytest.raises(DatasetError, match=r"garbage\.npz: corrupt or unreadable dataset"):
        load_dataset(garbage)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    with pytest.raises(DatasetError, match=r"truncated\.npz: corrupt"):
        load_dataset(truncated)
    old = tmp_path / "old.npz"
    with np.load(good) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays["metadata"]))
    np.savez_compressed(old,
                        **dict(arrays, metadata=np.array(json.dumps(dict(meta, format="usv_predictor.dataset/0")))))
    with pytest.raises(DatasetError,
                       match=r"old\.npz: dataset format 'usv_predictor.dataset/0', expected 'usv_predictor.dataset/1'"):
        load_dataset(old)
    foreign = tmp_path / "foreign.npz"
    np.savez_compressed(foreign, x=np.zeros(3))
    with pytest.raises(DatasetError, match=r"foreign\.npz: not a usv_predictor dataset"):
        load_dataset(foreign)
    pickled = tmp_path / "pickled.npz"
    np.savez_compressed(pickled, **dict(arrays, metadata=np.array([{"format": FORMAT}], dtype=object)))
    with pytest.raises(DatasetError, match=r"pickled\.npz: corrupt"):
        load_dataset(pickled)  # never unpickles
    shapes = tmp_path / "shapes.npz"
    np.savez_compressed(shapes, **dict(arrays, Y=arrays["Y"][:-1]))
    with pytest.raises(DatasetError,
                       match=r"shapes\.npz: inconsistent dataset: Y has shape \(36, 3\), expected \(37, 3\)"):
        load_dataset(shapes)
    assert zipfile.is_zipfile(good)
    assert math.isfinite(load_dataset(good).dt)


def test_an_unwritable_target_is_a_dataset_error(recordings, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(DatasetError, match=r"cannot write the dataset .*file/ds\.npz"):
        save_dataset(blocker / "ds.npz", _dataset(recordings))

"""replay.recordings and `replay dataset`: bags -> Recordings -> dataset file, and every kind of bad input.

Tiny bags are written into tmp_path, from Signals crafted here (so each defect is exactly known) or by
`replay simulate`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msg_adapters import ROLE_FIELDS
from usv_predictor.data.dataset import load_dataset
from usv_predictor.errors import BagError
from usv_predictor.records import Signal
from usv_predictor.replay.bagio import TopicSpec, write_bag
from usv_predictor.replay.cli import main
from usv_predictor.replay.recordings import (
    Pieces,
    bag_sha256,
    clean_signal,
    find_bags,
    load_recordings,
    steady_cuts,
    topic_specs,
)  # fmt: skip

NS = 1_000_000_000
T0 = 1_622_527_200 * NS
RATES_HZ = {"imu": 100.0, "velocity": 20.0, "heading": 20.0, "rudder_angle": 10.0, "engine_rpm": 10.0,
            "gnss": 5.0, "odometry": 20.0}


def _rudder_deg(t_s: np.ndarray) -> np.ndarray:
    return 10.0 * np.sin(2 * np.pi * t_s / 20.0)


def crafted_signals(seconds: float, rudder_deg=_rudder_deg) -> dict[str, Signal]:
    """Plausible signals of every role at the simulator's rates: a gentle weave at 5 m/s."""
    out = {}
    for role, hz in RATES_HZ.items():
        t_ns = T0 + np.arange(int(seconds * hz) + 1, dtype=np.int64) * int(NS / hz)
        t = (t_ns - T0) / NS
        delta = np.radians(rudder_deg(t))
        psi = np.radians(30.0) + 0.1 * np.sin(2 * np.pi * t / 20.0)
        rpm = np.full_like(t, 650.0)
        columns = {
            "imu": [0.01 * delta, 0 * t, 0 * t, -9.81 + 0 * t, np.full_like(t, np.nan)],
            "velocity": [5.0 + 0 * t, 0.1 * delta, 0.01 * delta],
            "heading": [psi],
            "rudder_angle": [delta],
            "engine_rpm": [rpm],
            "gnss": [35.38 + 1e-5 * t, 119.56 + 1e-5 * t, 0 * t],
            "odometry": [5.0 * t, 0 * t, psi, 5.0 + 0 * t, 0 * t, 0 * t],
        }[role]
        out[role] = Signal(t_ns, np.column_stack(columns), ROLE_FIELDS[role])
    return out


def write(path: Path, signals: dict[str, Signal], specs: dict[str, TopicSpec] | None = None) -> Path:
    specs = specs or {s.role: s for s in topic_specs()}
    return write_bag(path, [(specs[role], sig) for role, sig in signals.items()])


def drop_window(signal: Signal, start_s: float, end_s: float) -> Signal:
    t = (signal.t_ns - T0) / NS
    keep = (t < start_s) | (t > end_s)
    return Signal(signal.t_ns[keep], signal.values[keep], signal.fields)


@pytest.fixture
def warnings() -> list[str]:
    return []


def load(paths, warnings, **kwargs):
    """load_recordings at 0.5 s, its Pieces (segment, min_duration_s, horizon_s, include_calm) given by keyword."""
    rules = {name: kwargs.pop(name) for name in ("segment", "min_duration_s", "horizon_s", "include_calm")
             if name in kwargs}
    return load_recordings([paths] if isinstance(paths, Path) else paths, 0.5, warn=warnings.append,
                           pieces=Pieces(**rules), **kwargs)


# ------------------------------------------------------------------ good input


def test_a_clean_bag_becomes_one_recording_and_is_not_modified(tmp_path, warnings):
    bag = write(tmp_path / "weave", crafted_signals(40.0))
    before = bag_sha256(bag)
    files_before = {p.name: p.read_bytes() for p in bag.iterdir()}
    [rec] = load(bag, warnings)
    assert warnings == []
    assert rec.name == "weave"
    assert rec.source == str(bag)
    assert rec.dt == 0.5
    assert len(rec) == 80 and rec.duration_s == pytest.approx(39.5)  # whole 0.5 s windows within 40 s
    assert np.allclose(rec.nu[:, 0], 5.0)
    assert np.allclose(rec.controls[:, 1], 650.0)
    assert rec.truth is not None
    assert np.all(np.isfinite(rec.position))
    assert bag_sha256(bag) == before
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == files_before


def test_directories_expand_to_bags_without_calm_twins_unless_asked(tmp_path):
    signals = crafted_signals(12.0)
    for rel in ("trial/a", "trial/calm/a", "trial/more/b", "other/a"):
        write(tmp_path / rel, signals)
    names = lambda sources: [(s.path.relative_to(tmp_path).as_posix(), s.name) for s in sources]  # noqa: E731
    assert names(find_bags([tmp_path / "trial"])) == [("trial/a", "a"), ("trial/more/b", "b")]
    assert names(find_bags([tmp_path / "trial"], include_calm=True)) == [
        ("trial/a", "trial/a"), ("trial/calm/a", "calm/a"), ("trial/more/b", "b")]
    assert names(find_bags([tmp_path / "trial/calm"])) == [("trial/calm/a", "a")]  # named: read in full
    assert names(find_bags([tmp_path / "trial/a", tmp_path / "other/a", tmp_path / "trial"])) == [
        ("trial/a", "trial/a"), ("other/a", "other/a"), ("trial/more/b", "b")]  # each bag once, names unique


def test_finding_nothing_is_an_error_naming_the_argument(tmp_path):
    with pytest.raises(BagError, match=r"nowhere: no such bag or directory"):
        find_bags([tmp_path / "nowhere"])
    (tmp_path / "empty" / "calm").mkdir(parents=True)
    with pytest.raises(BagError, match=r"empty: no rosbag2 bag .* found under it \(sub-directories named 'calm'"):
        find_bags([tmp_path / "empty"])


# ------------------------------------------------------------------ bad input


def test_missing_and_corrupt_bags_are_named(tmp_path, warnings):
    with pytest.raises(BagError, match=r"absent: no such bag or directory"):
        load(tmp_path / "absent", warnings)
    bag = write(tmp_path / "broken", crafted_signals(12.0))
    db = next(p for p in bag.iterdir() if p.name != "metadata.yaml")
    db.write_bytes(b"\x28\xb5\x2f\xfd garbage, not zstd" * 50)
    with pytest.raises(BagError, match=r"broken: cannot read bag"):
        load(bag, warnings)
    bag2 = write(tmp_path / "badmeta", crafted_signals(12.0))
    (bag2 / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed")
    with pytest.raises(BagError, match=r"badmeta: cannot read rosbag2 metadata"):
        load(bag2, warnings)


def test_a_missing_required_topic_names_bag_topic_and_what_is_there(tmp_path, warnings):
    signals = crafted_signals(12.0)
    del signals["velocity"]
    bag = write(tmp_path / "novel", signals)
    with pytest.raises(BagError, match=r"novel: no topic 'velocity' \(role velocity\); topics present: \['engine_rpm', "
                                       r"'gps/fix', 'ground_truth/odometry', 'heading', 'imu/data', 'rudder_angle'\]"):
        load(bag, warnings)
    with pytest.raises(BagError, match=r"novel: no topic 'ins/twist'"):
        load(bag, warnings, topics={"velocity": "ins/twist"})


def test_a_missing_optional_topic_is_a_warning(tmp_path, warnings, capsys):
    signals = crafted_signals(12.0)
    del signals["gnss"]
    bag = write(tmp_path / "nofix", signals)
    [rec] = load_recordings([bag], 0.5)  # the default warn prints to stderr
    assert np.all(np.isnan(rec.position))
    assert rec.truth is not None
    assert f"warning: {bag}: optional topic 'gps/fix' (role gnss) is absent" in capsys.readouterr().err
    assert warnings == []


def test_a_topic_of_another_type_is_refused(tmp_path, warnings):
    specs = {s.role: s for s in topic_specs()}
    specs["velocity"] = TopicSpec("velocity", "velocity", "geometry_msgs/msg/TwistWithCovarianceStamped")
    bag = write(tmp_path / "cov", crafted_signals(12.0), specs)
    with pytest.raises(BagError, match=r"cov: topic 'velocity' has type geometry_msgs/msg/TwistWithCovarianceStamped, "
                                       r"expected geometry_msgs/msg/TwistStamped"):
        load(bag, warnings)


def test_duplicate_stamps_are_dropped_with_a_count(tmp_path, warnings):
    signals = crafted_signals(20.0)
    h = signals["heading"]
    rows = np.sort(np.concatenate([np.arange(len(h)), [10, 10, 50, 120]]))  # 4 exact duplicates
    signals["heading"] = Signal(h.t_ns[rows], h.values[rows], h.fields)
    bag = write(tmp_path / "dupes", signals)
    [rec] = load(bag, warnings)
    assert len(rec) == 40
    [message] = warnings
    assert "topic 'heading'" in message
    assert "dropped 4 samples with a repeated stamp (4 exact duplicates)" in message


def test_stamps_out_of_order_are_sorted_but_a_jump_back_is_an_error(warnings):
    sig = crafted_signals(10.0)["heading"]
    order = np.arange(len(sig))
    order[[20, 21]] = order[[21, 20]]  # 50 ms disorder, e.g. two messages swapped in transport
    swapped = clean_signal(Signal(sig.t_ns[order], sig.values[order], sig.fields), where="x: topic 'heading'",
                           role="heading", dt=0.5, t_ref_ns=T0, warn=warnings.append)
    assert np.array_equal(swapped.t_ns, sig.t_ns)
    assert np.array_equal(swapped.values, sig.values)
    assert warnings == ["x: topic 'heading': 1 samples out of order (at most 0.050 s); sorted"]
    warnings.clear()
    rows = np.array([0, 1, 1, 2, 3, 3, 4])
    values = sig.values[rows].copy()
    values[5] += 0.1  # same stamp as row 4, another heading: ambiguous, the first is kept
    deduped = clean_signal(Signal(sig.t_ns[rows], values, sig.fields), where="x: topic 'heading'", role="heading",
                           dt=0.5, t_ref_ns=T0, warn=warnings.append)
    assert np.array_equal(deduped.t_ns, sig.t_ns[:5])
    assert np.array_equal(deduped.values, sig.values[:5])
    assert warnings == ["x: topic 'heading': dropped 2 samples with a repeated stamp "
                        "(1 exact duplicates, 1 with other values (kept the first))"]
    jumped = sig.t_ns.copy()
    jumped[100:] -= 3 * NS  # the clock stepped back 3 s at t = 5 s
    with pytest.raises(BagError,
                       match=r"topic 'heading': time goes back 2.950 s at t=4.950 s .* more than the step 0.5 s"):
        clean_signal(Signal(jumped, sig.values, sig.fields), where="x: topic 'heading'", role="heading", dt=0.5,
                     t_ref_ns=T0, warn=warnings.append)


def test_nan_fields_are_dropped_with_topic_field_and_count(tmp_path, warnings):
    signals = crafted_signals(20.0)
    v = signals["velocity"].values.copy()
    v[[5, 6, 7, 90, 200], 0] = np.nan  # u
    v[[7, 150], 1] = np.nan  # v (row 7 has both)
    signals["velocity"] = Signal(signals["velocity"].t_ns, v, signals["velocity"].fields)
    bag = write(tmp_path / "nans", signals)
    [rec] = load(bag, warnings)
    assert np.all(np.isfinite(rec.nu))
    assert len(rec) == 40
    assert warnings == [f"{bag}: topic 'velocity': dropped 6 of 401 samples with NaN/inf (u: 5, v: 2)"]


def test_gaps_cut_the_recording_into_pieces(tmp_path, warnings):
    signals = crafted_signals(60.0)
    signals["velocity"] = drop_window(signals["velocity"], 25.0, 29.0)
    bag = write(tmp_path / "gappy", signals)
    first, second = load(bag, warnings)
    assert (first.name, second.name) == ("gappy#1", "gappy#2")
    assert [w for w in warnings if "gap" in w] == [
        f"{bag}: topic 'velocity' has a 4.10 s gap at t=24.95 s (longer than the step 0.5 s); cutting the "
        f"recording there"]
    assert first.duration_s == pytest.approx(24.0, abs=0.5)
    assert second.duration_s == pytest.approx(30.5, abs=0.5)
    assert (second.t0_ns - first.t0_ns) / NS > 29.0  # nothing of the gap is interpolated over
    assert first.datum == second.datum  # one plane for both pieces


def test_short_pieces_and_recordings_too_short_for_the_horizon_are_skipped(tmp_path, warnings):
    signals = crafted_signals(40.0)
    signals["rudder_angle"] = drop_window(signals["rudder_angle"], 6.0, 8.0)
    bag = write(tmp_path / "early_gap", signals)
    [rec] = load(bag, warnings, min_duration_s=10.0)
    assert rec.name == "early_gap#2"
    assert any("piece early_gap#1 from t=0.00 s lasts 5.90 s, shorter than 10 s; skipped" in w for w in warnings)
    warnings.clear()
    assert load(bag, warnings, horizon_s=60.0) == []
    assert any("too few for the 60 s horizon (121 steps); skipped" in w for w in warnings)


def test_steady_cuts_start_manoeuvres_after_settled_holds():
    dt = 0.5
    t = np.arange(0, 200, dt)
    delta = np.where(t < 40, 0.0, np.where(t < 100, 20.0, np.where(t < 140, 0.0, np.where(t < 170, 0.0, 0.0))))
    zig = (t >= 140) & (t < 170)
    delta[zig] = np.where(((t[zig] - 140) // 5) % 2 == 0, 10.0, -10.0)  # a zig-zag: holds of 5 s only
    controls = np.column_stack([np.radians(delta), np.full_like(t, 650.0)])
    controls += np.random.default_rng(0).normal(0, [0.0005, 1.0], controls.shape)  # sensor noise after averaging
    assert steady_cuts(controls, dt) == [60, 180, 260]  # 10 s before the steps at 40, 100 and 140 s
    controls[300:, 1] += 100.0  # rpm step at 150 s, inside the zig-zag: no settled hold before it
    assert steady_cuts(controls, dt) == [60, 180, 260]
    assert steady_cuts(controls, dt, settle_s=70.0) == []


def test_steady_segments_split_a_long_bag_into_manoeuvres(tmp_path, warnings):
    def rudder(t):
        return np.where((t >= 40) & (t < 100), 20.0,
                        np.where((t >= 140) & (t < 170), 10.0 * np.sign(np.sin(np.pi * t / 5)), 0.0))

    bag = write(tmp_path / "day", crafted_signals(200.0, rudder))
    whole = load(bag, warnings)
    parts = load(bag, warnings, segment="steady")
    assert [p.name for p in parts] == ["day@1", "day@2", "day@3", "day@4"]
    # cuts 10 s before the steps at 40, 100, 140 s (the 0.5 s window holding the 40.0 s sample moves first)
    assert [p.duration_s for p in parts] == pytest.approx([29.0, 59.5, 39.5, 70.0])
    assert sum(len(p) for p in parts) == len(whole[0])
    assert np.array_equal(np.concatenate([p.nu for p in parts]), whole[0].nu)  # a partition, nothing lost
    assert parts[1].t0_ns == whole[0].t0_ns + 59 * NS // 2
    assert parts[1].t_s[0] == 0.0
    rudder_deg = np.degrees(parts[1].controls[:, 0])
    assert np.abs(rudder_deg[:20]).max() < 1e-9 and rudder_deg[21:].min() > 19.9  # 10 s straight, then the turn


def test_parallel_reading_gives_the_same_recordings_warnings_and_errors(tmp_path):
    write(tmp_path / "bags" / "a_clean", crafted_signals(30.0))
    gappy = crafted_signals(30.0)
    gappy["heading"] = drop_window(gappy["heading"], 12.0, 14.0)
    write(tmp_path / "bags" / "b_gappy", gappy)
    write(tmp_path / "bags" / "c_clean", crafted_signals(20.0))
    serial_warnings, parallel_warnings = [], []
    serial = load_recordings([tmp_path / "bags"], 0.5, jobs=1, warn=serial_warnings.append)
    parallel = load_recordings([tmp_path / "bags"], 0.5, jobs=3, warn=parallel_warnings.append)
    assert [r.name for r in parallel] == ["a_clean", "b_gappy#1", "b_gappy#2", "c_clean"]
    assert parallel_warnings == serial_warnings
    assert len(serial_warnings) == 1
    for a, b in zip(serial, parallel, strict=True):
        assert a.name == b.name
        assert a.t0_ns == b.t0_ns
        assert np.array_equal(a.nu, b.nu)
        assert np.array_equal(a.truth, b.truth)
    broken = crafted_signals(20.0)
    del broken["engine_rpm"]
    write(tmp_path / "bags" / "d_broken", broken)
    with pytest.raises(BagError, match=r"d_broken: no topic 'engine_rpm'"):
        load_recordings([tmp_path / "bags"], 0.5, jobs=2, warn=parallel_warnings.append)


# ------------------------------------------------------------------ the command


def _simulate(out: Path, *extra: str) -> None:
    assert main(["simulate", "--duration", "40", "--output", str(out), "--sea", "rizhao", *extra]) == 0


def test_replay_dataset_end_to_end_on_simulated_bags(tmp_path, capsys):
    _simulate(tmp_path / "bags", "--manoeuvre", "zigzag", "--calm-twin")
    _simulate(tmp_path / "bags", "--manoeuvre", "turning-circle", "--rudder", "25", "--seed", "4")
    capsys.readouterr()
    bags = sorted(p.parent for p in (tmp_path / "bags").rglob("metadata.yaml"))
    hashes = {b: bag_sha256(b) for b in bags}
    out, report = tmp_path / "out" / "ds.npz", tmp_path / "out" / "ds.json"
    code = main(["dataset", str(tmp_path / "bags"), "--val", "0.5", "--output", str(out), "--json", str(report)])
    streams = capsys.readouterr()
    assert code == 0, streams.err
    result = json.loads(report.read_text())
    names = sorted(r["name"] for r in result["recordings"])
    assert names == ["turning_circle_stbd_25deg_650rpm", "zigzag_20_20_stbd_650rpm"]  # calm twin skipped
    assert sorted(r["split"] for r in result["recordings"]) == ["train", "val"]
    assert result["samples"] == 2 * 79
    assert result["feature_set"] == "NTF"
    assert result["dt"] == 0.5
    assert result["splits"]["train"]["recordings"] == 1
    assert result["warnings"] == []
    assert "[1/2]" in streams.err
    assert "wrote " in streams.out
    assert "train: 1 recording(s)" in streams.out
    dataset = load_dataset(out)
    assert dataset.digest() == result["digest"]
    assert len(dataset.X) == 158
    assert dataset.X.shape[1] == 7
    entries = {e["name"]: e for e in dataset.entries}
    zig = entries["zigzag_20_20_stbd_650rpm"]
    assert zig["bag_sha256"] == hashes[Path(zig["source"])]
    assert zig["length"] == 80
    assert dataset.metadata["provenance"].startswith("replay dataset ")
    assert "--val 0.5" in dataset.metadata["provenance"]
    assert {b: bag_sha256(b) for b in bags} == hashes  # inputs untouched
    assert all(r.truth is not None and np.isfinite(r.position).all() for r in dataset.recordings())
    again = tmp_path / "again.npz"
    assert main(["dataset", str(tmp_path / "bags"), "--val", "0.5", "--output", str(again)]) == 0
    assert load_dataset(again).digest() == dataset.digest()  # deterministic
    capsys.readouterr()
    code = main(["dataset", str(tmp_path / "bags"), "--include-calm", "--test", "calm/*", "--features", "NAF",
                 "--output", str(tmp_path / "calm.npz"), "--json", str(report)])
    assert code == 0, capsys.readouterr().err
    result = json.loads(report.read_text())
    splits = {r["name"]: r["split"] for r in result["recordings"]}
    assert splits.pop("calm/zigzag_20_20_stbd_650rpm") == "test"  # pinned by its glob; the twin is named apart
    assert sorted(splits) == ["bags/zigzag_20_20_stbd_650rpm", "turning_circle_stbd_25deg_650rpm"]
    assert sorted(splits.values()) == ["train", "val"]  # the default --val 0.2 of the other two: at least one
    assert result["feature_names"][-1] == "psi"


def test_replay_dataset_errors_are_one_line(tmp_path, capsys):
    assert main(["dataset", str(tmp_path / "none"), "--output", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"replay dataset: error: {tmp_path / 'none'}: no such bag or directory"]
    _simulate(tmp_path / "bags", "--manoeuvre", "zigzag")
    capsys.readouterr()
    assert main(["dataset", str(tmp_path / "bags"), "--test", "spiral*", "--output", str(tmp_path / "x.npz")]) == 2
    assert "--test pattern 'spiral*' matches no manoeuvre" in capsys.readouterr().err
    assert main(["dataset", str(tmp_path / "bags"), "--horizon", "60", "--output", str(tmp_path / "x.npz")]) == 2
    err = capsys.readouterr().err
    assert "warning:" in err
    assert "no usable recording" in err
    assert not (tmp_path / "x.npz").exists()
    assert main(["dataset", str(tmp_path / "bags"), "--topic", "speed", "--output", str(tmp_path / "x.npz")]) == 2
    assert "expected ROLE=TOPIC" in capsys.readouterr().err

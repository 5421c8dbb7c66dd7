"""replay convert: readers on the real public data, conventions, bag round trips, CLI, bad input.

Real-data tests use the `raw_data_dir` fixture (skip when ../shared/data/raw is absent, fail under CI).
Bad-input tests craft small synthetic files in tmp_path, so they run everywhere.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from usv_predictor.analysis import metrics
from usv_predictor.config import input_topics, load_predictor_config
from usv_predictor.errors import DatasetError
from usv_predictor.frames import LocalTangentPlane, wrap_angle
from usv_predictor.replay import cli, convert
from usv_predictor.replay.bagio import TopicSpec, read_bag, read_custom_data

HSVA = "kvlcc2_hsva_simman2008"
MARIN = "kvlcc2_marin_simman2008"
FUZHOU = "usv_alexandersson2022_fuzhou"


def _specs() -> dict[str, TopicSpec]:
    cfg = load_predictor_config()
    return {t.role: TopicSpec(t.topic, t.role, t.ros_type, t.options, t.frame_id or cfg.base_frame_id)
            for t in input_topics(cfg, include_ground_truth=True)}


def _all(raw: Path) -> list[convert.Manoeuvre]:
    return [m for p, f in convert.find_sources([raw / HSVA, raw / MARIN, raw / FUZHOU])
            for m in convert.read_manoeuvres(p, f)]


@pytest.fixture(scope="module")
def manoeuvres(raw_data_dir: Path) -> dict[str, convert.Manoeuvre]:
    return {m.name: m for m in _all(raw_data_dir)}


# ----------------------------------------------------------------------------- real data


def test_every_file_is_read_with_consistent_shapes(manoeuvres):
    assert len([n for n in manoeuvres if n.startswith("hsva_")]) == 13
    assert sorted(n for n in manoeuvres if n.startswith("marin_zz")) == [
        "marin_zz_10_10_p", "marin_zz_10_10_s", "marin_zz_20_20_p", "marin_zz_20_20_s"]
    assert "fuzhou_zigzag_30" in manoeuvres
    for m in manoeuvres.values():
        n = len(m.t_s)
        assert n > 400, m.name
        for name in ("x_n", "y_e", "psi", "u", "v", "r", "delta"):
            values = getattr(m, name)
            assert values.shape == (n,), (m.name, name)
            assert np.all(np.isfinite(values)), (m.name, name)
        assert (m.t_s[0] == 0.0) != (m.kind == "pullout"), m.name
        assert np.all(np.diff(m.t_s) > 0), m.name
        assert np.all(np.diff(convert.time_ns(m)) > 0), m.name
        assert np.all(np.abs(m.psi) <= math.pi), m.name


def test_hsva_model_scale_units(manoeuvres):
    for m in (m for m in manoeuvres.values() if m.source == "hsva"):
        assert m.scale.scale == "model"
        assert m.scale.scale_factor == pytest.approx(45.714)
        assert m.scale.L_pp_m == 7.0
        assert m.rate_hz == pytest.approx(20.0)
        speed = np.hypot(m.u, m.v)
        assert speed[0] == pytest.approx(1.18, abs=0.02)  # approach speed ~1.18 m/s (SOURCE.txt)
        assert 0.6 < speed.min()
        assert speed.max() < 1.25
        assert np.allclose(m.rpm, 10.2295 * 60.0)  # propeller 10.23 rps
        assert np.max(np.abs(m.v)) < 0.25 * speed.max()  # body sway, not the earth-fixed dy/dt (up to 0.35 m/s)


def test_marin_full_scale_units_and_rebuilt_time(manoeuvres):
    for m in (m for m in manoeuvres.values() if m.source == "marin"):
        assert m.scale.scale == "full"
        assert m.scale.L_pp_m == 320.0
        np.testing.assert_allclose(m.t_s, np.arange(len(m.t_s)) * 0.13535)
        speed = np.hypot(m.u, m.v)
        assert np.median(speed[:50]) == pytest.approx(7.97, abs=0.2)
        assert 85.0 < np.median(m.rpm) < 100.0
        assert np.max(np.abs(m.v)) < 2.0  # body sway; the file's earth-fixed v reaches 4 m/s


def test_fuzhou_speed_is_knots_and_no_rpm(manoeuvres):
    m = manoeuvres["fuzhou_zigzag_30"]
    assert m.rpm is None
    assert m.lat_deg is not None
    assert m.rate_hz == pytest.approx(2.0)
    assert m.duration_s == pytest.approx(209.5)
    assert "kn" in m.notes["speed_unit"]
    assert 0.4 < np.median(np.hypot(m.u, m.v)) < 0.8  # 1.0-1.3 knots over ground


def test_rudder_amplitude_equals_the_angle_in_the_name(manoeuvres):
    for m in (m for m in manoeuvres.values() if m.kind == "zigzag"):
        # half the span of the hold angles: MARIN holds +10.7/-9.9 deg about a neutral offset (file row 1: -0.82)
        amplitude = np.degrees(np.percentile(m.delta, 99) - np.percentile(m.delta, 1)) / 2.0
        tolerance = 0.15 * m.rudder_amplitude_deg if m.source == "fuzhou" else 0.1 + 0.03 * m.rudder_amplitude_deg
        assert amplitude == pytest.approx(m.rudder_amplitude_deg, abs=tolerance), m.name
        assert np.degrees(m.delta.max()) > 0.9 * m.rudder_amplitude_deg, m.name  # both sides are used
        assert np.degrees(m.delta.min()) < -0.9 * m.rudder_amplitude_deg, m.name


@pytest.mark.parametrize("source, after_s", [("hsva", 6.0), ("marin", 40.0), ("fuzhou", 3.0)])
def test_positive_rudder_turns_to_starboard(manoeuvres, source, after_s):
    """After the first rudder execute the heading moves towards the rudder's side within a few seconds."""
    for m in (m for m in manoeuvres.values() if m.source == source and m.kind != "pullout"):
        half = math.radians(0.5 * m.rudder_amplitude_deg)
        k = int(np.flatnonzero(np.abs(m.delta) > half)[0])
        side = np.sign(m.delta[k])
        later = int(np.searchsorted(m.t_s, m.t_s[k] + after_s))
        psi = np.unwrap(m.psi)
        assert side * (psi[later] - psi[k]) > math.radians(0.5), m.name
        assert side * m.r[later] > 0, m.name
        assert m.first_side == ("starboard" if side > 0 else "port"), m.name


def test_first_side_follows_the_file_name(manoeuvres):
    assert manoeuvres["hsva_z_10_10_p"].first_side == "port"
    assert manoeuvres["hsva_z_20_10_s"].first_side == "starboard"
    assert manoeuvres["marin_zz_10_10_p"].path.name == "MARIN_FREE_KVLCC2_zz_10_m.dat"  # file delta > 0 = port


def test_yaw_rate_is_the_derivative_of_heading(manoeuvres):
    """Proves the choice of the HSVA yaw-rate column (labelled p in SOURCE.txt) and the units of r."""
    for m in manoeuvres.values():
        half = max(1, int(round(1.0 * m.rate_hz)))
        dpsi = convert.centred_derivative(m.t_s, np.unwrap(m.psi), half)
        r = convert.centred_derivative(m.t_s, np.cumsum(np.r_[0.0, 0.5 * (m.r[1:] + m.r[:-1]) * np.diff(m.t_s)]), half)
        assert np.sqrt(np.mean((r - dpsi) ** 2)) < 0.25 * np.sqrt(np.mean(dpsi ** 2)), m.name


def test_track_agrees_with_velocity(manoeuvres):
    """Body u, v rotated back to NED integrate to the track (the velocity frame conversion is right)."""
    for name in ("hsva_z_20_05", "marin_zz_20_20_s"):
        m = manoeuvres[name]
        c, s = np.cos(m.psi), np.sin(m.psi)
        vn, ve = m.u * c - m.v * s, m.u * s + m.v * c
        dt = np.diff(m.t_s)
        x = m.x_n[0] + np.r_[0.0, np.cumsum(0.5 * (vn[1:] + vn[:-1]) * dt)]
        y = m.y_e[0] + np.r_[0.0, np.cumsum(0.5 * (ve[1:] + ve[:-1]) * dt)]
        run = np.sum(np.hypot(np.diff(m.x_n), np.diff(m.y_e)))
        assert np.max(np.hypot(x - m.x_n, y - m.y_e)) < 0.005 * run, name


# ----------------------------------------------------------------------------- round trip


@pytest.mark.parametrize("name", ["hsva_z_10_10_s", "marin_zz_10_10_p", "fuzhou_zigzag_30"])
def test_bag_round_trip(manoeuvres, tmp_path, name):
    m = manoeuvres[name]
    specs = _specs()
    bag = tmp_path / name
    count = convert.write_manoeuvre_bag(bag, m, {r: s for r, s in specs.items() if r != "odometry"})
    signals = convert.to_signals(m)
    assert count == sum(len(s) for s in signals.values())
    back = read_bag(bag, [specs[role] for role in signals])
    assert specs["odometry"].topic not in back
    t_ns = convert.time_ns(m)
    for role, written in signals.items():
        got = back[specs[role].topic]
        np.testing.assert_array_equal(got.t_ns, t_ns)
        assert got.fields == written.fields
        if role == "heading":
            np.testing.assert_allclose(wrap_angle(got.values[:, 0] - m.psi), 0.0, atol=1e-9)
        else:
            np.testing.assert_allclose(got.values, written.values, rtol=1e-9, atol=1e-9, equal_nan=True)
    np.testing.assert_allclose(back[specs["velocity"].topic].values, np.column_stack([m.u, m.v, m.r]), atol=1e-9)
    np.testing.assert_allclose(back[specs["rudder_angle"].topic].values[:, 0], m.delta, atol=1e-12)
    lat, lon = back[specs["gnss"].topic].values[:, 0], back[specs["gnss"].topic].values[:, 1]
    if m.lat_deg is None:
        x, y = LocalTangentPlane(*convert.DATUM_DEG[m.source]).to_ned(lat, lon)
    else:
        x, y = LocalTangentPlane(m.lat_deg[0], m.lon_deg[0]).to_ned(lat, lon)
    np.testing.assert_allclose(x, m.x_n, atol=1e-3)
    np.testing.assert_allclose(y, m.y_e, atol=1e-3)
    assert ("engine_rpm" in signals) == (m.rpm is not None)
    meta = read_custom_data(bag)
    assert meta["source"] == m.source
    assert meta["scale"] == m.scale.scale
    assert meta["conversion_version"] == convert.CONVERSION_VERSION
    assert meta["source_file"] == m.path.name
    assert float(meta["scale_factor"]) == m.scale.scale_factor
    assert "licence" in meta


def test_cli_converts_and_refuses_overwrite(raw_data_dir, tmp_path, capsys):
    out, result = tmp_path / "bags", tmp_path / "r.json"
    args = ["convert", str(raw_data_dir / FUZHOU), str(raw_data_dir / HSVA / "HSVA_CPMC_KVLCC2_Z_10_10_P.dat"),
            "--output", str(out), "--json", str(result)]
    assert cli.main(args) == 0
    summary = json.loads(result.read_text())
    assert [b["manoeuvre"] for b in summary["bags"]] == ["fuzhou_zigzag_30", "hsva_z_10_10_p"]
    hsva = summary["bags"][1]
    assert hsva["rate_hz"] == pytest.approx(20.0)
    assert hsva["rpm"] == [pytest.approx(613.77)] * 2
    assert summary["bags"][0]["rpm"] is None
    assert (out / "hsva_z_10_10_p" / "metadata.yaml").is_file()
    assert "[2/2]" in capsys.readouterr().err
    assert cli.main(args) == 2
    assert "exists already; use --overwrite" in capsys.readouterr().err
    assert cli.main([*args, "--overwrite"]) == 0


# ----------------------------------------------------------------------------- bad input (synthetic files)


def _turn(n: int, dt: float, speed: float, rate_deg_s: float):
    """A steady turn to starboard: t, x, y, psi_deg, dx/dt, dy/dt (exact)."""
    t = np.arange(n) * dt
    w = math.radians(rate_deg_s)
    psi = w * t
    return (t, speed / w * np.sin(psi), speed / w * (1.0 - np.cos(psi)), np.degrees(psi), speed * np.cos(psi),
            speed * np.sin(psi))


def _hsva_text(n: int = 200) -> str:
    t, x, y, psi, ue, ve = _turn(n, 0.05, 1.18, 2.0)
    delta = np.where(t < 1.0, 0.0, -10.0)  # file convention: negative = starboard
    rows = [" ".join(f"{v:18.9f}" for v in (t[i], x[i], y[i], psi[i], ue[i], ve[i], 2.0, 0.05, delta[i], 10.2295,
                                            41.0, 1.02)) for i in range(n)]
    head = [" HSVA, experimental data CPMC", " KVLCC2", " Z10°/5°", " Time series of motions"]
    return "\n".join([*head, *rows]) + "\n"


def _write(path: Path, text: str, encoding: str = "cp1252") -> Path:
    path.write_text(text, encoding=encoding)
    return path


def test_synthetic_hsva_reads(tmp_path):
    m = convert.read_hsva(_write(tmp_path / "HSVA_CPMC_KVLCC2_Z_10_05.dat", _hsva_text()))
    assert m.name == "hsva_z_10_05"
    assert m.first_side == "starboard"
    np.testing.assert_allclose(m.r, math.radians(2.0))
    np.testing.assert_allclose(m.u, 1.18, atol=1e-6)
    np.testing.assert_allclose(m.v, 0.0, atol=1e-6)
    assert "'p'" in m.notes["yaw_rate_column"]


@pytest.mark.parametrize("corrupt, message", [
    (lambda lines: lines[:14], "only 10 data rows"),
    (lambda lines: lines[:10] + [lines[10].replace("10.229500000", "10.2x9500000")] + lines[11:], ":11: column 'rev'"),
    (lambda lines: lines[:10] + [lines[10].rsplit(" ", 1)[0]] + lines[11:], ":11: expected 12 columns"),
    (lambda lines: lines[:10] + [lines[9]] + lines[11:], ":11: column 'time': time 0.25 s repeats"),
    (lambda lines: lines[:4] + [" ".join(["nan"] * 12)] + lines[5:], ":5: column 'time': 'nan' is not finite"),
    (lambda lines: lines[:2] + [" Turning circle"] + lines[3:], ":3: expected the zig-zag title"),
    (lambda lines: lines[:4], "only 0 data rows"),
    (lambda lines: [" Some other tank"] + lines[1:], ":1: expected the HSVA header"),
])
def test_hsva_bad_input(tmp_path, corrupt, message):
    path = _write(tmp_path / "HSVA_CPMC_KVLCC2_Z_10_05.dat", "\n".join(corrupt(_hsva_text().splitlines())) + "\n")
    with pytest.raises(DatasetError, match=message.replace("(", r"\(")) as err:
        convert.read_hsva(path)
    assert str(path) in str(err.value)


def test_hsva_wrong_units_and_wrong_columns(tmp_path):
    lines = _hsva_text().splitlines()
    cm = [lines[i] if i < 4 else " ".join(f"{float(c) * (100.0 if j in (4, 5) else 1.0):18.9f}"
                                           for j, c in enumerate(lines[i].split())) for i in range(len(lines))]
    with pytest.raises(DatasetError, match=r"column 'u': median 118 .* model-scale speed in m/s"):
        convert.read_hsva(_write(tmp_path / "HSVA_CPMC_KVLCC2_Z_10_05.dat", "\n".join(cm)))
    no_yaw = [lines[i] if i < 4 else " ".join(c if j != 6 else "0.5" for j, c in enumerate(lines[i].split()))
              for i in range(len(lines))]
    with pytest.raises(DatasetError, match="no column is the yaw rate"):
        convert.read_hsva(_write(tmp_path / "HSVA_CPMC_KVLCC2_Z_10_05.dat", "\n".join(no_yaw)))
    mirrored = [lines[i] if i < 4 else " ".join(f"{-float(c):18.9f}" if j in (2, 5) else c
                                                 for j, c in enumerate(lines[i].split())) for i in range(len(lines))]
    with pytest.raises(DatasetError, match="turns against the heading|off the heading"):
        convert.read_hsva(_write(tmp_path / "HSVA_CPMC_KVLCC2_Z_10_05.dat", "\n".join(mirrored)))


def _marin_text(n: int = 600, first: float = 10.0, file_delta: float | None = None) -> str:
    t, x, y, psi, ue, ve = _turn(n, 0.13535, 7.97, 0.3)
    delta = np.where(t < 5.0, 0.0, first if file_delta is None else file_delta)
    cols = [t, x, y, 0.1 + 0 * t, psi, ue, ve, 0 * t, 0.3 + 0 * t, delta, 91.5 + 0 * t]
    rows = ["\t".join(f"{c[i]:.2E}" for c in cols) for i in range(n)]
    head = ["MARIN(Maritime Research Institute Netherlands)",
            f"Zig-zag manoeuvring for KVLCC2 : {first:g} / {-first:g}", ""]
    return "\n".join([*head, *rows, "\t" * 10, "\t" * 10]) + "\n"


def test_synthetic_marin_reads_and_checks_the_time_column(tmp_path):
    [m] = convert.read_marin(_write(tmp_path / "MARIN_FREE_KVLCC2_zz_10_m.dat", _marin_text()))
    assert m.name == "marin_zz_10_10_p"
    assert m.first_side == "port"
    assert m.kind == "zigzag"
    np.testing.assert_allclose(m.u, 7.97, atol=0.02)
    lines = _marin_text().splitlines()
    cells = lines[103].split("\t")
    cells[0] = "2.00E+01"  # row 100 is at 13.5 s
    lines[103] = "\t".join(cells)
    with pytest.raises(DatasetError, match=r":104: column 'time': 20 s disagrees with the rebuilt time base"):
        convert.read_marin(_write(tmp_path / "MARIN_FREE_KVLCC2_zz_10_m.dat", "\n".join(lines)))
    lines = _marin_text().splitlines()
    with pytest.raises(DatasetError, match=r":204: empty row inside the data"):
        convert.read_marin(_write(tmp_path / "MARIN_FREE_KVLCC2_zz_10_m.dat",
                                  "\n".join(lines[:203] + [""] + lines[203:])))
    with pytest.raises(DatasetError, match="title says first rudder 10 .* goes starboard first"):
        convert.read_marin(_write(tmp_path / "MARIN_FREE_KVLCC2_zz_10_m.dat",
                                  _marin_text(file_delta=-10.0)))


def _marin_turn_text(first: float = 35.0, pullout: bool = True, title: str | None = None, n: int = 2900) -> str:
    """A MARIN-format turning circle (+ pull-out): 20 s approach, rudder `first` (file sign: + = port) at 2.34 deg/s,
    held to 330 s, then back to midships; yaw rate 1.2 deg/s (first order, 15 s), speed 7.97 -> 4 m/s, no drift."""
    dt = convert.MARIN_DT_S
    t = np.arange(n) * dt
    ramp = 2.34 * dt
    file_delta = np.zeros(n)
    for k in range(1, n):  # rate-limited rudder toward its order
        order = first if 20.0 <= t[k] < 330.0 or (not pullout and t[k] >= 20.0) else 0.0
        file_delta[k] = file_delta[k - 1] + np.clip(order - file_delta[k - 1], -ramp, ramp)
    side = -np.sign(first)  # file + = port = negative yaw rate
    on = np.clip(t - 20.0, 0.0, None)
    r = side * 1.2 * (1.0 - np.exp(-on / 15.0))
    if pullout:
        r = np.where(t < 330.0, r, r * np.exp(-np.clip(t - 330.0, 0.0, None) / 25.0))
    speed = 7.97 - 4.0 * (1.0 - np.exp(-on / 40.0))
    psi = 0.2 + np.r_[0.0, np.cumsum(0.5 * (r[1:] + r[:-1]) * dt)]
    ue, ve = speed * np.cos(np.radians(psi)), speed * np.sin(np.radians(psi))
    x = np.r_[0.0, np.cumsum(0.5 * (ue[1:] + ue[:-1]) * dt)]
    y = np.r_[0.0, np.cumsum(0.5 * (ve[1:] + ve[:-1]) * dt)]
    cols = [t, x, y, 0.1 + 0 * t, psi, ue, ve, 0 * t, r, file_delta - 0.5, 91.5 + 0 * t]
    rows = ["\t".join(f"{c[i]:.2E}" for c in cols) for i in range(n)]
    what = "Turning / Pull-out" if pullout else "Turning"
    head = ["MARIN(Maritime Research Institute Netherlands)",
            title or f"{what} manoeuvring for KVLCC2 : {first:g} (deg)", ""]
    return "\n".join([*head, *rows, "\t" * 10, "\t" * 2]) + "\n"


def test_marin_turning_pullout_is_split_into_a_turning_circle_and_a_pullout(tmp_path):
    path = _write(tmp_path / "MARIN_FREE_KVLCC2_tc_35_m.dat", _marin_turn_text())
    turn, pullout = convert.read_marin(path)
    assert (turn.name, turn.kind, pullout.name, pullout.kind) == (
        "marin_tc_35_p", "turning_circle", "marin_tc_35_p_pullout", "pullout")
    assert turn.first_side == "port"
    assert turn.rudder_amplitude_deg == 35.0
    # the split is the last row of the hold: the turn ends on it, the pull-out starts on it (one shared row)
    assert len(turn.t_s) + len(pullout.t_s) - 1 == 2900
    assert pullout.t_s[0] == turn.t_s[-1]
    assert turn.t_s[0] == 0.0
    assert 329.0 < pullout.t_s[0] < 331.0
    hold = np.degrees(turn.delta[-1])
    assert hold == pytest.approx(-34.5, abs=0.35)  # file +35 to port about its -0.5 deg neutral; 1 ramp step: 0.32 deg
    assert np.degrees(pullout.delta[0]) == pytest.approx(hold, abs=1.0)
    assert abs(np.degrees(np.median(pullout.delta[-100:]))) < 1.0  # back to midships
    # the turn's track: execute at 20 s, port turn (heading decreases), nearly a full circle (354 deg)
    psi = np.degrees(np.unwrap(turn.psi))
    assert -360.0 < psi[-1] - psi[0] < -340.0
    meta = convert.custom_data(turn)
    assert meta["manoeuvre_type"] == "turning_circle"
    assert "zigzag" not in meta
    info = json.loads(meta["turning_circle"])
    assert info["side"] == "port"
    assert info["execute_s"] == pytest.approx(20.0, abs=0.3)
    assert json.loads(convert.custom_data(pullout)["pullout"])["execute_s"] == pytest.approx(pullout.t_s[0])
    assert convert.custom_data(pullout)["manoeuvre_type"] == "pullout"


def test_converted_turn_is_classified_as_a_turning_circle(tmp_path):
    from usv_predictor.analysis.evaluation import classify
    from usv_predictor.replay.recordings import load_recordings

    (tmp_path / "raw").mkdir()
    _write(tmp_path / "raw" / "MARIN_FREE_KVLCC2_tc_-35_m.dat", _marin_turn_text(first=-35.0))
    summary = convert.convert([tmp_path / "raw"], tmp_path / "bags")
    assert [b["manoeuvre"] for b in summary["bags"]] == ["marin_tc_35_s", "marin_tc_35_s_pullout"]
    assert [b["manoeuvre_type"] for b in summary["bags"]] == ["turning_circle", "pullout"]
    [rec] = load_recordings([tmp_path / "bags" / "marin_tc_35_s"], 0.5, warn=lambda *_: None)
    kind = classify(rec)
    assert (kind.kind, kind.side) == ("turning_circle", "starboard")
    assert kind.rudder_deg == pytest.approx(35.5, abs=0.2)  # +35 to starboard about the file's -0.5 deg neutral
    assert read_custom_data(tmp_path / "bags" / "marin_tc_35_s_pullout")["manoeuvre_type"] == "pullout"


@pytest.mark.parametrize("title, pullout, name, message", [
    ("Spiral manoeuvring for KVLCC2 : 35 (deg)", True, "tc_35", r":2: expected a manoeuvre title \('Zig-zag"),
    (None, False, "tc_35", "title says 'Turning / Pull-out' but the rudder never returns"),
    ("Zig-zag manoeuvring for KVLCC2 : 35 / -35", True, "tc_35", "title says 'Zig-zag' but the file name says 'tc'"),
    (None, True, "tc_-35", "title says first rudder 35 but the file name says -35"),
    ("Turning / Pull-out manoeuvring for KVLCC2 : hard over", True, "tc_35", "expected the turn's rudder angle"),
])
def test_marin_turn_bad_input(tmp_path, title, pullout, name, message):
    text = _marin_turn_text(pullout=pullout)
    if title is None and not pullout:  # a turn file whose title announces the pull-out that never comes
        text = text.replace("Turning manoeuvring", "Turning / Pull-out manoeuvring")
    elif title is not None:
        text = text.replace(text.splitlines()[1], title)
    path = _write(tmp_path / f"MARIN_FREE_KVLCC2_{name}_m.dat", text)
    with pytest.raises(DatasetError, match=message) as err:
        convert.read_marin(path)
    assert str(path) in str(err.value)


def test_marin_turning_without_pullout_is_one_turning_circle(tmp_path):
    [turn] = convert.read_marin(_write(tmp_path / "MARIN_FREE_KVLCC2_tc_35_m.dat", _marin_turn_text(pullout=False)))
    assert turn.kind == "turning_circle"
    assert len(turn.t_s) == 2900


FUZHOU_HEADER = "time,lon,lat,speed,heading,rudder,delta,psi,x0,y0"


def _fuzhou_text(speed_factor: float = 1.0 / convert.KNOT, n: int = 120, drop: str | None = None) -> str:
    t, x, y, psi, _, _ = _turn(n, 0.5, 0.6, 3.0)
    lat, lon = LocalTangentPlane(26.0666, 119.162).to_geodetic(x, y)
    rudder = np.full(n, 30.0)
    cols = {"time": t, "lon": lon, "lat": lat, "speed": 0.6 * speed_factor + 0 * t, "heading": psi, "rudder": rudder,
            "delta": -np.radians(rudder), "psi": np.radians(psi), "x0": x, "y0": y}
    names = [c for c in FUZHOU_HEADER.split(",") if c != drop]
    return "\n".join([",".join(names), *(",".join(repr(float(cols[c][i])) for c in names) for i in range(n))]) + "\n"


def test_fuzhou_speed_unit_detection_and_bad_input(tmp_path):
    path = tmp_path / "zigzag_30_inter_xy.csv"
    m = convert.read_fuzhou(_write(path, _fuzhou_text(), "utf-8"))
    assert m.name == "fuzhou_zigzag_30"
    assert "kn" in m.notes["speed_unit"]
    np.testing.assert_allclose(np.median(m.u), 0.6, atol=0.01)
    np.testing.assert_allclose(m.r[2:-2], math.radians(3.0), rtol=1e-3)
    assert "m/s" in convert.read_fuzhou(_write(path, _fuzhou_text(speed_factor=1.0), "utf-8")).notes["speed_unit"]
    with pytest.raises(DatasetError, match=r"column 'speed'.*expected 1 \(m/s\) or 0.5144 \(knots\)"):
        convert.read_fuzhou(_write(path, _fuzhou_text(speed_factor=3.6), "utf-8"))  # km/h
    with pytest.raises(DatasetError, match=r":1: missing column\(s\) rudder"):
        convert.read_fuzhou(_write(path, _fuzhou_text(drop="rudder"), "utf-8"))
    with pytest.raises(DatasetError, match="only 5 data rows"):
        convert.read_fuzhou(_write(path, _fuzhou_text(n=5), "utf-8"))
    lines = _fuzhou_text().splitlines()
    lines[7] = lines[7].replace(",30.0,", ",thirty,")
    with pytest.raises(DatasetError, match=r":8: column 'rudder': 'thirty' is not a number"):
        convert.read_fuzhou(_write(path, "\n".join(lines), "utf-8"))
    degrees_as_psi = _fuzhou_text().splitlines()
    header = degrees_as_psi[0].split(",")
    k = header.index("psi")
    degrees_as_psi[1:] = [",".join(c if j != k else row.split(",")[header.index("heading")] for j, c in
                                   enumerate(row.split(","))) for row in degrees_as_psi[1:]]
    with pytest.raises(DatasetError, match=r"columns 'psi' \(rad\) and 'heading' \(deg\) disagree"):
        convert.read_fuzhou(_write(path, "\n".join(degrees_as_psi), "utf-8"))


def test_discovery_errors(tmp_path):
    with pytest.raises(DatasetError, match="no such file or directory"):
        convert.find_sources([tmp_path / "absent"])
    with pytest.raises(DatasetError, match="unknown data format"):
        convert.find_sources([_write(tmp_path / "notes.txt", "x")])
    assert convert.find_sources([_write(tmp_path / "boat1_2_sin.xlsx", "x")]) == [(tmp_path / "boat1_2_sin.xlsx",
                                                                                    "dalian")]
    with pytest.raises(DatasetError, match="not a readable .xlsx workbook"):
        convert.read_dalian(tmp_path / "boat1_2_sin.xlsx")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="no .dat, .csv or .xlsx"):
        convert.find_sources([tmp_path / "empty"])
    with pytest.raises(DatasetError, match="not cp1252 text|expected the HSVA header"):
        convert.read_hsva(_write(tmp_path / "HSVA_x.dat", "garbage\n"))


# ----------------------------------------------------------------------------- Dalian twin-thruster USV

DALIAN = "usv_2345vor_dalian"


@pytest.fixture(scope="module")
def dalian(raw_data_dir: Path) -> dict[str, convert.Manoeuvre]:
    return {m.name: m for m in (convert.read_dalian(raw_data_dir / DALIAN / f)
                                for f in ("boat1_2_circle.xlsx", "boat1_2_sin.xlsx"))}


def test_dalian_positions_time_and_the_circle(dalian):
    """x/y are not metres and t is not time (twin_thruster_research.md sec. 3.6): from lon/lat and DateTime the
    circle's radius is the 22.5 m the path implies (25 logged units / 1.1117), at the Speed column's speed."""
    circle, sine = dalian["dalian_circle"], dalian["dalian_sine"]
    assert circle.duration_s == pytest.approx(257.764, abs=0.05)
    assert sine.duration_s == pytest.approx(167.974, abs=0.05)
    for m in (circle, sine):
        assert "1.1117" in m.notes["positions"]
        assert "not time" in m.notes["time"]
        assert 0.2 < m.fix.mean() < 0.27  # a fix every ~0.22 s on the 0.05 s grid
        assert 0.5 < int(m.notes["fixes"].split(" of ")[0]) / int(m.notes["fixes"].split(" of ")[1].split()[0]) < 0.6
        assert np.all(np.isfinite(m.x_n[m.fix]))
        assert np.all(np.isnan(m.x_n[~m.fix]))
        assert np.all(np.isfinite(np.column_stack([m.u, m.v, m.r])))
        for c in m.thrusters:
            assert -1.0 <= c.min()
            assert c.max() <= 1.0
    steady = circle.fix & (circle.t_s > 40.0)
    fit = metrics.steady_turning_radius(circle.t_s[steady], circle.x_n[steady], circle.y_e[steady],
                                        np.unwrap(circle.psi[steady]), start_change_deg=0.0,
                                        drift_velocity_mps=(0.0, 0.0), refine_drift=False)
    assert fit.radius_m == pytest.approx(22.5, abs=0.5)
    assert fit.rms_residual_m < 0.2
    u, r = np.median(circle.u[circle.t_s > 40.0]), np.median(circle.r[circle.t_s > 40.0])
    assert u == pytest.approx(0.678, abs=0.02)  # m/s, the Speed column's steady value
    # the smoothed u and r describe the same circle within 10 %: the heading turns ~5 % faster than the track
    # (course - heading varies by +-3.5 deg with the heading: twin_thruster_research.md sec. 3.5)
    assert u / r == pytest.approx(fit.radius_m, rel=0.10)
    assert abs(np.median(circle.v[circle.t_s > 40.0])) < 0.05
    assert np.median(np.hypot(sine.u, sine.v)[sine.t_s > 30.0]) == pytest.approx(0.90, abs=0.03)


def test_dalian_port_is_pwm_l_and_turns_to_starboard(dalian):
    """The circle turns to starboard (heading increases) with more port command; the yaw rate follows the
    command difference port - starboard on both runs."""
    circle = dalian["dalian_circle"]
    psi = np.unwrap(circle.psi)
    assert psi[-1] - psi[0] > math.radians(500.0)  # +556 deg in 258 s: a turn to starboard
    late = circle.t_s > 40.0
    port, starboard = circle.thrusters
    assert np.median(port[late] - starboard[late]) > 0.0
    assert np.median(circle.r[late]) > 0.0
    for m in dalian.values():
        difference = m.thrusters[0] - m.thrusters[1]
        assert np.corrcoef(m.r, difference)[0, 1] > 0.5, m.name
        assert "PWM_L = port" in m.notes["thrusters"]


def test_dalian_bag_round_trip(dalian, tmp_path):
    from usv_predictor.physics.actuators import actuator_layout
    from usv_predictor.replay.recordings import load_recordings

    m = dalian["dalian_sine"]
    specs = _specs()
    bag = tmp_path / m.name
    convert.write_manoeuvre_bag(bag, m, {r: s for r, s in specs.items() if r != "odometry"})
    signals = convert.to_signals(m)
    assert set(signals) == {"imu", "velocity", "heading", "gnss", "thruster_port", "thruster_starboard"}
    back = read_bag(bag, [specs[role] for role in signals])
    assert len(back[specs["gnss"].topic]) == int(m.fix.sum())
    assert len(back[specs["heading"].topic]) == len(m.t_s)
    np.testing.assert_allclose(back[specs["thruster_port"].topic].values[:, 0], m.thrusters[0], atol=1e-12)
    np.testing.assert_allclose(back[specs["velocity"].topic].values, np.column_stack([m.u, m.v, m.r]), atol=1e-9)
    meta = read_custom_data(bag)
    assert meta["source"] == "dalian"
    assert "MIT" in meta["licence"]
    assert "zigzag" not in meta
    assert json.loads(meta["path_following"])["x(w)"] == "25*sin(0.05*w)"
    assert int(meta["epoch_ns"]) == convert.time_ns(m)[0]
    warnings = []
    recs = load_recordings([bag], 0.2, layout=actuator_layout("twin_thrusters"), warn=warnings.append)
    assert not [w for w in warnings if "gap" in w], warnings
    assert len(recs) == 1
    assert recs[0].controls.shape[1] == 2
    assert recs[0].layout == "twin_thrusters"
    assert recs[0].duration_s == pytest.approx(m.duration_s, abs=0.5)


def _dalian_xlsx(path: Path, *, swap: bool = False, pwm_l: dict[int, float] | None = None, drop: str | None = None,
                 stamp: dict[int, str] | None = None) -> Path:
    """A synthetic Dalian log: 60 s at 0.11 s per row, a fix every second row, the yaw rate following PWM_L - PWM_R
    (swap: the columns exchanged, so more PWM_L turns to port)."""
    import datetime as dt

    import openpyxl

    n, step = 550, 0.11
    t = np.arange(n) * step
    rate = np.radians(2.0 + 1.5 * np.sin(2 * np.pi * t / 20.0))  # rad/s, always to starboard
    psi = np.cumsum(rate) * step
    speed = 0.7
    x = np.cumsum(speed * np.cos(psi)) * step
    y = np.cumsum(speed * np.sin(psi)) * step
    lat, lon = LocalTangentPlane(38.8658, 121.5343).to_geodetic(x, y)
    left = 1650 + np.round(40.0 * (rate - rate.mean()) / rate.std())
    right = 1650 - np.round(40.0 * (rate - rate.mean()) / rate.std())
    if swap:
        left, right = right, left
    columns = ["DateTime", "t", "Longitude", "Latitude", "x", "y", "Heading", "course", "Speed", "PWM_L", "PWM_R"]
    book = openpyxl.Workbook()
    sheet = book.active
    sheet.title = "Sheet1"
    sheet.append([c for c in columns if c != drop])
    start = dt.datetime(2025, 7, 24, 15, 45, 54)
    for k in range(n):
        j = k - (k % 2)  # the fix of the previous row repeats on odd rows
        heading = (math.degrees(psi[j]) + 180.0) % 360.0 - 180.0
        row = {"DateTime": (start + dt.timedelta(seconds=float(t[k]))).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3],
               "t": 0.1 * k, "Longitude": float(lon[j]), "Latitude": float(lat[j]), "x": 1.1117 * float(x[j]),
               "y": 1.1117 * float(y[j]), "Heading": heading, "course": heading, "Speed": speed,
               "PWM_L": int(left[k]), "PWM_R": int(right[k])}
        row.update({"PWM_L": v for i, v in (pwm_l or {}).items() if i == k})  # noqa: B035
        row.update({"DateTime": v for i, v in (stamp or {}).items() if i == k})  # noqa: B035
        sheet.append([row[c] for c in columns if c != drop])
    book.create_sheet("Sheet2").append(["LongitudeStart", "LatitudeStart"])
    book["Sheet2"].append(["121.5343", "38.8658"])
    book.save(path)
    return path


def test_synthetic_dalian_reads_and_refuses_bad_input(tmp_path):
    path = tmp_path / "boat1_2_circle.xlsx"
    m = convert.read_dalian(_dalian_xlsx(path))
    assert m.name == "dalian_circle"
    assert m.fix.sum() == 275
    assert "275 of 550 rows" in m.notes["fixes"]
    late = m.t_s > 5.0
    np.testing.assert_allclose(np.hypot(m.u, m.v)[late], 0.7, atol=0.03)
    assert np.sqrt(np.mean((m.r - np.radians(2.0 + 1.5 * np.sin(2 * np.pi * m.t_s / 20.0)))[late] ** 2)) < 0.005
    assert "1.1117" in m.notes["positions"]
    with pytest.raises(DatasetError, match=r"'PWM_L', 'PWM_R': the yaw rate correlates -[01]\.\d+ with PWM_L - PWM_R"):
        convert.read_dalian(_dalian_xlsx(path, swap=True))
    with pytest.raises(DatasetError, match=r"Sheet1 row 12: column 'PWM_L': 2500 is outside 1000-2000"):
        convert.read_dalian(_dalian_xlsx(path, pwm_l={10: 2500}))
    with pytest.raises(DatasetError, match=r"Sheet1 row 1: missing column\(s\) Heading"):
        convert.read_dalian(_dalian_xlsx(path, drop="Heading"))
    with pytest.raises(DatasetError, match=r"Sheet1 row 5: column 'DateTime': '15:45' is not a time"):
        convert.read_dalian(_dalian_xlsx(path, stamp={3: "15:45"}))

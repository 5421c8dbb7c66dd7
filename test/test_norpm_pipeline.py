"""Rudder boats without an rpm sensor through replay: simulate -> dataset -> train -> evaluate, and identify ->
evaluate, for `rudder_throttle` (rudder + throttle command) and `rudder_only` (propulsion not logged).

The vessels are the jari_usv preset with its actuator_layout changed, written here as vessel files (every replay
command takes a YAML path for --vessel; the node takes preset names only: its test is in test_node_dds.py). Two
short turning circles (20 deg each way, 40 s, calm water) per layout; the library-level identification of both
layouts on richer programmes is test_identify_layouts.py's, this file checks the commands on bags.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from replay_helpers import assert_one_line, replay, write_layout_variant

from usv_predictor.data.dataset import load_dataset
from usv_predictor.models.artifact import load_artifact
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay.simulate import SimulationRequest, simulate

# forward_N (N) static thrust at full command, reverse_N (N) astern, exponent (-), dead_band (-), time constant (s)
THROTTLE_MAP = {"forward_N": 9000.0, "reverse_N": 3500.0, "exponent": 2.0, "dead_band": 0.05, "time_constant_s": 1.2}
RUDDER_DEG = 20.0  # (deg) held rudder of the turning circles
THROTTLE = 0.6  # (-) rudder_throttle's propulsion command
RPM = 650.0  # (rpm) rudder_only's engine speed (simulated, not recorded)
LAYOUTS = {  # layout -> (extra vessel sections, replay simulate's propulsion option, control columns)
    "rudder_throttle": ({"throttle": THROTTLE_MAP}, {"throttle": THROTTLE}, ["delta", "throttle"]),
    "rudder_only": ({}, {"rpm": RPM}, ["delta"]),
}


def write_vessel(directory: Path, layout: str) -> Path:
    """jari_usv with `layout` (and the sections it needs) as a vessel file named jari_<layout>."""
    return write_layout_variant(directory, layout, **LAYOUTS[layout][0])


@pytest.fixture(scope="module", params=list(LAYOUTS))
def norpm(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path, Path]:
    """(layout, vessel file, bag directory): a 20 deg turning circle each way, 40 s at dt 0.1 s."""
    layout = request.param
    out = tmp_path_factory.mktemp(layout)
    vessel = write_vessel(out, layout)
    boat = load_vessel(vessel)
    for side in ("starboard", "port"):
        simulate(SimulationRequest(output=out / "bags" / side, vessel=boat, vessel_label=str(vessel),
                                   manoeuvre="turning-circle", rudder_deg=RUDDER_DEG, side=side, duration_s=40.0,
                                   dt=0.1, **LAYOUTS[layout][1]))
    return layout, vessel, out / "bags"


def _manoeuvres(evaluation: Path) -> dict:
    result = json.loads((evaluation / "evaluation.json").read_text())
    return result, {r["name"]: r["manoeuvre"] for r in result["recordings"]}


def _check_turns(layout: str, manoeuvres: dict) -> None:
    """evaluate's classification: two turning circles, one each way, at the held rudder in degrees."""
    assert len(manoeuvres) == 2
    for found in manoeuvres.values():
        assert found["kind"] == "turning_circle"
        assert found["turn_unit"] == "deg"
        assert found["turn_command"] == pytest.approx(RUDDER_DEG, abs=0.5) == found["rudder_deg"]
        assert found["rpm"] is None  # neither layout logs an engine speed
        if layout == "rudder_throttle":
            assert found["propulsion_unit"] == "-"
            assert found["propulsion"] == pytest.approx(THROTTLE, abs=0.01)
        else:
            assert found["propulsion"] is None  # propulsion not logged
    assert {found["side"] for found in manoeuvres.values()} == {"starboard", "port"}


def test_dataset_train_evaluate(norpm: tuple[str, Path, Path], tmp_path: Path, capsys) -> None:
    layout, vessel, bags = norpm
    controls_names = LAYOUTS[layout][2]
    dataset = tmp_path / "d.npz"
    code, err = replay(capsys, "dataset", bags, "--output", dataset, "--vessel", vessel, "--val", "0",
                       "--min-duration", "5")
    assert code == 0, err
    loaded = load_dataset(dataset)
    assert loaded.control_layout == layout
    assert loaded.metadata["control_names"] == controls_names
    assert loaded.arrays["seq_controls"].shape[1] == len(controls_names)
    recordings = loaded.recordings()
    assert {round(math.degrees(float(np.median(r.controls[-20:, 0])))) for r in recordings} == {20, -20}
    if layout == "rudder_throttle":
        throttle = np.concatenate([r.controls[:, 1] for r in recordings])
        assert np.median(throttle) == pytest.approx(THROTTLE, abs=0.01)
        assert np.abs(throttle).max() <= 1.0

    model = tmp_path / "m.pt"
    code, err = replay(capsys, "train", dataset, "--output", model, "--vessel", vessel, "--epochs", "2",
                       "--width", "8", "--depth", "1", "--patience", "0")
    assert code == 0, err
    assert load_artifact(model).metadata["control_layout"] == controls_names
    # a 2-epoch network does not fit the bags: refused (for rudder_only by its straight-running speed), then
    # evaluated with --no-fit-check
    code, err = replay(capsys, "evaluate", bags, "--model", model, "--vessel", vessel, "--reference", "truth",
                       "--horizons", "10", "--output", tmp_path / "refused")
    assert_one_line(code, err, "evaluate", (2,))
    assert "does not fit these bags" in err
    assert not (tmp_path / "refused").exists()
    code, err = replay(capsys, "evaluate", bags, "--model", model, "--vessel", vessel, "--reference", "truth",
                       "--horizons", "10", "--no-fit-check", "--output", tmp_path / "eval")
    assert code == 0, err
    result, manoeuvres = _manoeuvres(tmp_path / "eval")
    assert result["fit_check"]["verdict"] == "mismatch"
    _check_turns(layout, manoeuvres)


def test_identify_then_evaluate(norpm: tuple[str, Path, Path], tmp_path: Path, capsys) -> None:
    """`replay identify` on the bags: rudder_only estimates the engine speed of each manoeuvre, rudder_throttle the
    throttle's gain; the exported grey box passes evaluate's fit check and predicts the tactical diameter."""
    layout, vessel, bags = norpm
    model = tmp_path / "identified.pt"
    code, err = replay(capsys, "identify", bags, "--vessel", vessel, "--structure", "mmg", "--prior", "fix",
                       "--output", model, "--json", tmp_path / "identify.json")
    assert code == 0, err
    found = json.loads((tmp_path / "identify.json").read_text())["identification"]
    assert found["actuator_layout"] == layout
    coefficients = {c["name"]: c for c in found["coefficients"]}
    if layout == "rudder_only":
        engines = found["actuators"]
        assert len(engines) == 2
        for manoeuvre in engines.values():
            assert manoeuvre["engine_speed_rpm"] == pytest.approx(RPM, rel=0.01)
        assert "throttle.forward_N" not in coefficients
        assert coefficients["R0"]["status"] == "fixed to prior"
    else:
        gain = coefficients["throttle.forward_N"]
        assert gain["status"] == "identified"
        assert gain["ci95"][0] < THROTTLE_MAP["forward_N"] < gain["ci95"][1]
        assert found["actuators"] == {}
    meta = load_artifact(model).metadata
    assert meta["control_layout"] == LAYOUTS[layout][2]
    assert meta["actuator_layout"] == layout

    code, err = replay(capsys, "evaluate", bags, "--model", model, "--vessel", vessel, "--reference", "truth",
                       "--horizons", "10", "--output", tmp_path / "eval")
    assert code == 0, err
    result, manoeuvres = _manoeuvres(tmp_path / "eval")
    assert result["fit_check"]["verdict"] == "fits"
    _check_turns(layout, manoeuvres)
    # the tactical diameter from the closed-loop run (the slow 0.6-throttle circle never settles to a radius)
    assert result["summary"]["max_abs_tactical_diameter_rel_error_pct"] < 2.0

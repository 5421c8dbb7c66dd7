"""replay on a twin-thruster boat (the otter preset): dataset, train and evaluate read the bags with the vessel's
actuator layout, store it (dataset metadata, model control_layout) and refuse a layout that differs, in one line."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from replay_helpers import assert_one_line, replay
from usv_predictor.data.dataset import load_dataset
from usv_predictor.replay.simulate import SimulationRequest, simulate


@pytest.fixture(scope="module")
def otter_bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short otter bags (a turning circle each way, 40 s) at the default topics."""
    out = tmp_path_factory.mktemp("otter")
    for side in ("starboard", "port"):
        simulate(SimulationRequest(output=out / side, vessel="otter", manoeuvre="turning-circle", differential=0.4,
                                   side=side, duration_s=40.0, dt=0.1))
    return out


def test_dataset_train_evaluate_on_otter_bags(otter_bags: Path, tmp_path: Path, capsys) -> None:
    dataset = tmp_path / "otter.npz"
    code, err = replay(capsys, "dataset", otter_bags, "--output", dataset, "--vessel", "otter", "--val", "0",
                       "--min-duration", "5", "--json", tmp_path / "dataset.json")
    assert code == 0, err
    loaded = load_dataset(dataset)
    assert loaded.control_layout == "twin_thrusters"
    assert loaded.metadata["control_names"] == ["port", "starboard"]
    assert loaded.arrays["seq_controls"].shape[1] == 2
    controls = np.concatenate([r.controls for r in loaded.recordings()])  # (T, 2) port, starboard
    assert {round(float(np.median(d)), 1) for d in (r.controls[-20:, 0] - r.controls[-20:, 1]
                                                    for r in loaded.recordings())} == {0.4, -0.4}
    assert np.abs(controls).max() <= 1.0 + 1e-9

    model = tmp_path / "otter.pt"
    code, err = replay(capsys, "train", dataset, "--output", model, "--vessel", "otter", "--epochs", "2",
                       "--width", "8", "--depth", "1", "--patience", "0")
    assert code == 0, err
    code, err = replay(capsys, "evaluate", otter_bags, "--model", model, "--reference", "truth",
                       "--horizons", "10", "--output", tmp_path / "eval")
    assert code == 0, err
    result = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    manoeuvres = {r["name"]: r["manoeuvre"] for r in result["recordings"]}
    assert len(manoeuvres) == 2
    for found in manoeuvres.values():
        assert found["turn_unit"] == "-" and found["rudder_deg"] is None  # a differential, not degrees
        assert found["turn_command"] == pytest.approx(0.4, abs=0.02)
    assert {found["side"] for found in manoeuvres.values()} == {"starboard", "port"}


def test_layout_mismatches_are_one_line_errors(otter_bags: Path, tmp_path: Path, capsys) -> None:
    # otter bags read as the config's rudder boat (jari_usv): the bag names its vessel
    code, err = replay(capsys, "dataset", otter_bags, "--output", tmp_path / "d.npz")
    assert_one_line(code, err, "dataset", (2,))
    assert "recorded on vessel otter (twin_thrusters ['port', 'starboard']) but read as rudder_propeller" in err
    # a rudder model on otter bags: the model's control layout against the bags'
    code, err = replay(capsys, "evaluate", otter_bags, "--model", "physics:jari_usv", "--vessel", "otter")
    assert_one_line(code, err, "evaluate", (2,))
    assert "has control_layout ['delta', 'rpm'] but the bags of vessel otter have twin_thrusters" in err
    code, err = replay(capsys, "evaluate", otter_bags, "--model", "physics:otter", "--vessel", "jari_usv")
    assert_one_line(code, err, "evaluate", (2,))
    assert "has control_layout ['port', 'starboard'] but the bags of vessel jari_usv have rudder_propeller" in err

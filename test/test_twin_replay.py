"""replay on a twin-thruster boat (the otter preset): dataset, train and evaluate read the bags with the vessel's
actuator layout, store it (dataset metadata, model control_layout) and refuse a layout that differs, in one line."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from replay_helpers import assert_one_line, replay

from usv_predictor.data.dataset import load_dataset
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay.simulate import SimulationRequest, simulate


@pytest.fixture(scope="module")
def otter_bags(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short otter bags (a turning circle each way, 40 s) at the default topics."""
    out = tmp_path_factory.mktemp("otter")
    otter = load_vessel("otter")
    for side in ("starboard", "port"):
        simulate(SimulationRequest(output=out / side, vessel=otter, manoeuvre="turning-circle", differential=0.4,
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
    # a 2-epoch network does not fit the bags: the fit check refuses it, --no-fit-check evaluates it anyway
    code, err = replay(capsys, "evaluate", otter_bags, "--model", model, "--reference", "truth",
                       "--horizons", "10", "--output", tmp_path / "refused")
    assert_one_line(code, err, "evaluate", (2,))
    assert "does not fit these bags" in err
    assert not (tmp_path / "refused").exists()
    code, err = replay(capsys, "evaluate", otter_bags, "--model", model, "--reference", "truth",
                       "--horizons", "10", "--no-fit-check", "--output", tmp_path / "eval")
    assert code == 0, err
    result = json.loads((tmp_path / "eval" / "evaluation.json").read_text())
    assert result["fit_check"]["verdict"] == "mismatch"
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


def test_a_twin_vessel_without_thruster_inputs_is_a_config_error(tmp_path: Path) -> None:
    import yaml

    from usv_predictor.config import default_config_path
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics.actuators import actuator_layout, check_layout_inputs
    from usv_predictor.replay.recordings import topic_specs

    twin = actuator_layout("twin_thrusters")
    notes = check_layout_inputs(twin, {"thruster_port": "t/p", "thruster_starboard": "t/s", "rudder_angle": "rudder"},
                                "cfg.yaml")
    assert notes == ("input rudder_angle (topic 'rudder') is ignored: not a control of actuator layout twin_thrusters",)
    with pytest.raises(ConfigError, match=r"^cfg\.yaml: actuator layout twin_thrusters needs input\(s\) "
                                          r"\['thruster_starboard'\] \(controls \['port', 'starboard'\]\)"):
        check_layout_inputs(twin, {"thruster_port": "t/p", "rudder_angle": "rudder"}, "cfg.yaml")
    params = yaml.safe_load(default_config_path().read_text())
    inputs = params["predictor"]["ros__parameters"]["inputs"]
    del inputs["thruster_port"], inputs["thruster_starboard"]
    params["predictor"]["ros__parameters"]["vessel"] = "otter"
    (config := tmp_path / "predictor.yaml").write_text(yaml.safe_dump(params))
    with pytest.raises(ConfigError, match=r"needs input\(s\) \['thruster_port', 'thruster_starboard'\]"):
        topic_specs(config)
    assert {s.role for s in topic_specs()} >= {"rudder_angle", "engine_rpm"}  # the default vessel: a rudder boat


def test_the_config_examples_build_working_adapters() -> None:
    """Every commented twin-thruster example of config/predictor.yaml is valid YAML whose inputs build adapters
    that can share their topic and round-trip a command pair."""
    import yaml
    from rosbags.typesys import Stores, get_typestore

    import msg_adapters
    from usv_predictor.config import INPUT_KEYS, default_config_path

    lines = default_config_path().read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if "# ---- Examples for twin thrusters" in line)
    stop = next(i for i, line in enumerate(lines) if "# Two roles may share one topic" in line)
    blocks: list[str] = []
    for line in lines[start + 1:stop]:
        text = line.strip().removeprefix("#")
        if text.startswith("   thruster_port:"):
            blocks.append("")
        if text.startswith("   "):
            blocks[-1] += text[3:] + "\n"
    assert len(blocks) == 4  # VRX, Float64MultiArray, JointState, WrenchStamped
    make = msg_adapters.rosbags_factory(get_typestore(Stores.ROS2_JAZZY))
    for block in blocks:
        entries = yaml.safe_load(block)
        adapters = [msg_adapters.get_adapter(role, e["type"], **{k: v for k, v in e.items() if k not in INPUT_KEYS})
                    for role, e in entries.items()]
        assert [a.role for a in adapters] == ["thruster_port", "thruster_starboard"]
        if entries["thruster_port"]["topic"] == entries["thruster_starboard"]["topic"]:
            msg_adapters.check_shared(entries["thruster_port"]["topic"], adapters)
            messages = [msg_adapters.encode_shared(adapters, 0, [(0.6,), (-0.3,)], make)] * 2
        else:
            messages = [a.encode(0, (c,), make) for a, c in zip(adapters, (0.6, -0.3))]
        assert [a.decode(m)[1][0] for a, m in zip(adapters, messages)] == pytest.approx([0.6, -0.3])

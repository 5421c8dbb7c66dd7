"""`replay simulate` end to end: bags that rosbags opens, what they contain, and bad input."""
from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from usv_predictor.config import input_topics, load_predictor_config
from usv_predictor.replay.bagio import TopicSpec, read_bag, read_custom_data
from usv_predictor.replay.cli import main

EXPECTED_TYPES = {
    "imu/data": "sensor_msgs/msg/Imu",
    "velocity": "geometry_msgs/msg/TwistStamped",
    "heading": "std_msgs/msg/Float64",
    "rudder_angle": "std_msgs/msg/Float64",
    "engine_rpm": "std_msgs/msg/Float64",
    "gps/fix": "sensor_msgs/msg/NavSatFix",
    "ground_truth/odometry": "nav_msgs/msg/Odometry",
}


def specs() -> list[TopicSpec]:
    cfg = load_predictor_config()
    return [TopicSpec(t.topic, t.role, t.ros_type, t.options, t.frame_id) for t in input_topics(cfg, include_ground_truth=True)]


def simulate(tmp_path: Path, *extra: str) -> tuple[int, dict]:
    out = tmp_path / "result.json"
    code = main(["simulate", "--output", str(tmp_path / "bags"), "--json", str(out), *extra])
    return code, (json.loads(out.read_text()) if out.exists() else {})


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_simulated_bag_opens_with_anyreader_and_round_trips(tmp_path, storage):
    code, result = simulate(tmp_path, "--manoeuvre", "turning-circle", "--rudder", "25", "--duration", "40",
                            "--storage", storage, "--effect", "current", "--current-speed", "0.4", "--current-to", "135")
    assert code == 0
    bag = Path(result["bags"][0]["bag"])
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert types == EXPECTED_TYPES
    assert counts["imu/data"] == 4001 and counts["gps/fix"] == 201 and counts["rudder_angle"] == 401
    signals = read_bag(bag, specs())
    truth = signals["ground_truth/odometry"]
    # the recorded heading is the true heading plus noise, in the marine convention after the adapters
    psi = np.interp(signals["heading"].t_ns, truth.t_ns, np.unwrap(truth.column("psi")))
    err = np.angle(np.exp(1j * (signals["heading"].column("psi") - psi)))
    assert np.std(err) < math.radians(1.5)
    assert signals["rudder_angle"].column("delta")[-1] == pytest.approx(math.radians(25.0), abs=0.01)
    meta = read_custom_data(bag)
    assert json.loads(meta["scenario"])["effects"]["current"]["current_speed"] == 0.4
    assert meta["generator"] == "usv_predictor replay simulate"


def test_same_seed_same_bag_content(tmp_path):
    args = ("--manoeuvre", "zigzag", "--duration", "30", "--sea", "rizhao", "--seed", "3")
    simulate(tmp_path / "a", *args)
    simulate(tmp_path / "b", *args)
    simulate(tmp_path / "c", *args[:-1], "4")
    read = lambda d: read_bag(next((d / "bags").iterdir()), specs())
    a, b, c = read(tmp_path / "a"), read(tmp_path / "b"), read(tmp_path / "c")
    assert all(np.array_equal(a[t].values, b[t].values, equal_nan=True) for t in a)
    assert not np.array_equal(a["imu/data"].values, c["imu/data"].values, equal_nan=True)


def test_programme_with_calm_twins_and_blind_metadata(tmp_path):
    code, result = simulate(tmp_path, "--programme", "diagnosis", "--sea", "rizhao", "--calm-twin", "--blind",
                            "--dt", "0.1")
    assert code == 0
    bags = [Path(b["bag"]) for b in result["bags"]]
    assert len(bags) == 8 and sum(p.parent.name == "calm" for p in bags) == 4
    meta = read_custom_data(bags[0])
    assert "scenario" not in meta and len(meta["scenario_sha256"]) == 64
    assert result["scenario"] is None
    sea, calm = read_bag(bags[0], specs()), read_bag(bags[4], specs())
    # the twin shares time, place, seed and manoeuvre, so only the sea makes the tracks differ
    assert sea["gps/fix"].t_ns[0] == calm["gps/fix"].t_ns[0]
    drift = np.hypot(*(sea["ground_truth/odometry"].values[-1, :2] - calm["ground_truth/odometry"].values[-1, :2]))
    assert drift > 10.0  # 0.35 m/s current over 150 s


@pytest.mark.parametrize(
    "args, message",
    [
        (["--effect", "current", "--current-speed", "-0.4"], "current_speed=-0.4 m/s is outside the allowed range [0.0, 3.0]"),
        (["--rudder", "60"], "--rudder 60 deg is outside the preset's range [0, 35] deg"),
        (["--vessel", "titanic"], "unknown vessel preset 'titanic'"),
        (["--current-speed", "0.3"], "--current-speed belongs to effect 'current': add --effect current"),
        (["--rpm", "-5"], "--rpm -5 is outside"),
        (["--effect", "gremlins"], "invalid choice: 'gremlins'"),
        (["--wind-speed", "abc", "--effect", "wind"], "argument --wind-speed: 'abc' is not a finite number"),
        (["--wind-speed", "nan", "--effect", "wind"], "argument --wind-speed: 'nan' is not a finite number"),
        (["--seed", "-1"], "argument --seed: '-1' is not a whole number >= 0"),
        (["--duration", "inf"], "argument --duration: 'inf' is not a finite number > 0"),
    ],
)
def test_bad_input_is_one_line_exit_2_and_no_bag(tmp_path, capsys, args, message):
    code = main(["simulate", "--output", str(tmp_path / "bags"), "--duration", "5", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1].startswith("replay simulate: error:") and message in err[-1]
    assert not (tmp_path / "bags").exists() or not any((tmp_path / "bags").iterdir())


def test_existing_output_needs_overwrite_and_unwritable_output_fails(tmp_path, capsys):
    args = ["--manoeuvre", "pullout", "--duration", "10"]
    assert simulate(tmp_path, *args)[0] == 0
    assert simulate(tmp_path, *args)[0] == 2
    assert "use --overwrite" in capsys.readouterr().err
    assert simulate(tmp_path, *args, "--overwrite")[0] == 0
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    code = main(["simulate", "--output", str(blocker / "bags"), "--duration", "5"])
    assert code == 2
    assert "replay simulate: error:" in capsys.readouterr().err


def test_module_entry_point_help():
    done = subprocess.run([sys.executable, "-m", "usv_predictor.replay", "simulate", "--help"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "--current-to" in done.stdout and "--calm-twin" in done.stdout


def test_shipped_bags_open_and_say_how_they_were_made():
    from usv_predictor.config import package_share_path

    bags = sorted(p.parent for p in package_share_path("bags").rglob("metadata.yaml"))
    assert len(bags) == 20  # 6 turns + 4 training runs, each with its calm twin
    for bag in bags:
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            assert {c.topic: c.msgtype for c in reader.connections} == EXPECTED_TYPES
        meta = read_custom_data(bag)
        effects = json.loads(meta["scenario"])["effects"]
        assert (set(effects) == {"current", "wind", "wave_drift"}) == (bag.parent.name != "calm")


# ------------------------------------------------------------------ the typed request behind the command


def test_the_simulation_request_refuses_bad_values_with_the_commands_messages(tmp_path):
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.simulate import SimulationRequest, manoeuvres

    out = tmp_path / "bags"
    for fields, message in (({"programme": "diagnosis", "manoeuvre": "zigzag"}, "give either --programme or --manoeuvre"),
                            ({"duration_s": 0.5}, "--duration 0.5 s is outside [1, 3600] s"),
                            ({"manoeuvre": "zigzag", "check_deg": 95.0}, "--check 95 deg is outside (0, 90] deg"),
                            ({"manoeuvre": "barrel-roll"}, "--manoeuvre 'barrel-roll': expected one of"),
                            ({"sea": "stormy"}, "--sea 'stormy': expected one of calm, rizhao")):
        with pytest.raises(ConfigError, match=re.escape(message)):
            SimulationRequest(output=out, **fields)
    assert SimulationRequest(output=out, manoeuvre="turning-circle", check_deg=95.0).check_angle_deg == 95.0  # unused
    vessel = load_vessel("jari_usv")
    with pytest.raises(ConfigError, match=r"--rudder 60 deg is outside the preset's range \[0, 35\] deg"):
        manoeuvres(SimulationRequest(output=out, rudder_deg=60.0), vessel)
    with pytest.raises(ConfigError, match="--rpm -5 is outside"):
        manoeuvres(SimulationRequest(output=out, rpm=-5.0), vessel)
    [zigzag] = manoeuvres(SimulationRequest(output=out, manoeuvre="zigzag", rudder_deg=15.0, side="port"), vessel)
    assert (zigzag.rudder_deg, zigzag.check_deg, zigzag.side) == (15.0, 15.0, -1)
    assert not out.exists()  # nothing is written before the bags are simulated


def test_given_effects_go_on_top_of_the_sea():
    from usv_predictor.physics.scenario import RIZHAO_SEA
    from usv_predictor.replay.simulate import scenario_effects

    assert scenario_effects("calm", {"rudder_offset": {}}) == {"rudder_offset": {}}
    sea = scenario_effects("rizhao", {"current": {"current_speed": 0.9}, "rudder_offset": {}})
    assert set(sea) == set(RIZHAO_SEA) | {"rudder_offset"}
    assert sea["current"] == {**RIZHAO_SEA["current"], "current_speed": 0.9}
    assert RIZHAO_SEA["current"].get("current_speed") != 0.9  # the sea itself is not modified

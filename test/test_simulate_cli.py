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
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from usv_predictor.config import input_topics, load_predictor_config
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout, actuator_layout, unused_roles
from usv_predictor.physics.vessel import vessel_dir
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


def specs(layout: ActuatorLayout = DEFAULT_LAYOUT) -> list[TopicSpec]:
    """The config's topics that a boat of this layout uses (the config lists every layout's controls)."""
    cfg = load_predictor_config()
    return [TopicSpec(t.topic, t.role, t.ros_type, t.options, t.frame_id)
            for t in input_topics(cfg, include_ground_truth=True)
            if t.role not in unused_roles(layout)]


def simulate(tmp_path: Path, *extra: str) -> tuple[int, dict]:
    out = tmp_path / "result.json"
    code = main(["simulate", "--output", str(tmp_path / "bags"), "--json", str(out), *extra])
    return code, (json.loads(out.read_text()) if out.exists() else {})


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_simulated_bag_opens_with_anyreader_and_round_trips(tmp_path, storage):
    code, result = simulate(tmp_path, "--manoeuvre", "turning-circle", "--rudder", "25", "--duration", "40",
                            "--storage", storage, "--effect", "current", "--current-speed", "0.4", "--current-to",
                            "135")
    assert code == 0
    bag = Path(result["bags"][0]["bag"])
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert types == EXPECTED_TYPES
    assert counts["imu/data"] == 4001
    assert counts["gps/fix"] == 201
    assert counts["rudder_angle"] == 401
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
    def read(d):
        return read_bag(next((d / "bags").iterdir()), specs())
    a, b, c = read(tmp_path / "a"), read(tmp_path / "b"), read(tmp_path / "c")
    assert all(np.array_equal(a[t].values, b[t].values, equal_nan=True) for t in a)
    assert not np.array_equal(a["imu/data"].values, c["imu/data"].values, equal_nan=True)


def test_programme_with_calm_twins_and_blind_metadata(tmp_path):
    code, result = simulate(tmp_path, "--programme", "diagnosis", "--sea", "rizhao", "--calm-twin", "--blind",
                            "--dt", "0.1")
    assert code == 0
    bags = [Path(b["bag"]) for b in result["bags"]]
    assert len(bags) == 8
    assert sum(p.parent.name == "calm" for p in bags) == 4
    meta = read_custom_data(bags[0])
    assert "scenario" not in meta
    assert len(meta["scenario_sha256"]) == 64
    assert result["scenario"] is None
    sea, calm = read_bag(bags[0], specs()), read_bag(bags[4], specs())
    # the twin shares time, place, seed and manoeuvre, so only the sea makes the tracks differ
    assert sea["gps/fix"].t_ns[0] == calm["gps/fix"].t_ns[0]
    drift = np.hypot(*(sea["ground_truth/odometry"].values[-1, :2] - calm["ground_truth/odometry"].values[-1, :2]))
    assert drift > 10.0  # 0.35 m/s current over 150 s


@pytest.mark.parametrize(
    "args, message",
    [
        (["--effect", "current", "--current-speed", "-0.4"],
         "current_speed=-0.4 m/s is outside the allowed range [0.0, 3.0]"),
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
    assert err[-1].startswith("replay simulate: error:")
    assert message in err[-1]
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
    assert done.returncode == 0
    assert "--current-to" in done.stdout
    assert "--calm-twin" in done.stdout


def test_shipped_bags_open_and_say_how_they_were_made():
    from usv_predictor.config import package_share_path
    from usv_predictor.physics.actuators import actuator_layout
    from usv_predictor.physics.manoeuvres import twin_calm_day

    bags = sorted(p.parent for p in package_share_path("bags").rglob("metadata.yaml"))
    otter = [bag for bag in bags if "otter" in bag.parts]
    assert len(bags) - len(otter) == 20  # jari_usv: 6 turns + 4 training runs, each with its calm twin
    assert len(otter) == 26  # otter: 4 turns + 4 training runs, each with its calm twin, and the 10 of the calm day
    assert sorted(b.name for b in otter if b.parent.name == "calm_day") == sorted(
        m.name for m in twin_calm_day(actuator_layout("twin_thrusters")))  # the calm_day programme
    twin_types = {**{k: v for k, v in EXPECTED_TYPES.items() if k not in ("rudder_angle", "engine_rpm")},
                  "thrusters/port": "std_msgs/msg/Float64", "thrusters/starboard": "std_msgs/msg/Float64"}
    for bag in bags:
        with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            expected = twin_types if bag in otter else EXPECTED_TYPES
            assert {c.topic: c.msgtype for c in reader.connections} == expected
        meta = read_custom_data(bag)
        effects = json.loads(meta["scenario"])["effects"]
        assert (set(effects) == {"current", "wind", "wave_drift"}) == (bag.parent.name not in ("calm", "calm_day"))


# ------------------------------------------------------------------ the typed request behind the command


def test_the_simulation_request_refuses_bad_values_with_the_commands_messages(tmp_path):
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.simulate import SimulationRequest, manoeuvres

    out = tmp_path / "bags"
    vessel = load_vessel("jari_usv")
    for fields, message in (({"programme": "diagnosis", "manoeuvre": "zigzag"},
                             "give either --programme or --manoeuvre"),
                            ({"duration_s": 0.5}, "--duration 0.5 s is outside [1, 3600] s"),
                            ({"manoeuvre": "zigzag", "check_deg": 95.0}, "--check 95 deg is outside (0, 90] deg"),
                            ({"manoeuvre": "barrel-roll"}, "--manoeuvre 'barrel-roll': expected one of"),
                            ({"sea": "stormy"}, "--sea 'stormy': expected one of calm, rizhao")):
        with pytest.raises(ConfigError, match=re.escape(message)):
            SimulationRequest(output=out, vessel=vessel, **fields)
    assert SimulationRequest(output=out, vessel=vessel, manoeuvre="turning-circle",
                             check_deg=95.0).check_angle_deg == 95.0  # unused
    with pytest.raises(ConfigError, match=r"--rudder 60 deg is outside the preset's range \[0, 35\] deg"):
        manoeuvres(SimulationRequest(output=out, vessel=vessel, rudder_deg=60.0))
    with pytest.raises(ConfigError, match="--rpm -5 is outside"):
        manoeuvres(SimulationRequest(output=out, vessel=vessel, rpm=-5.0))
    [zigzag] = manoeuvres(SimulationRequest(output=out, vessel=vessel, manoeuvre="zigzag", rudder_deg=15.0,
                                            side="port"))
    assert (zigzag.rudder_deg, zigzag.check_deg, zigzag.side) == (15.0, 15.0, -1)
    assert not out.exists()  # nothing is written before the bags are simulated


TWIN_TYPES = {**{k: v for k, v in EXPECTED_TYPES.items() if k not in ("rudder_angle", "engine_rpm")},
              "thrusters/port": "std_msgs/msg/Float64", "thrusters/starboard": "std_msgs/msg/Float64"}


def test_a_twin_thruster_boat_writes_its_thruster_commands(tmp_path):
    code, result = simulate(tmp_path, "--vessel", "otter", "--manoeuvre", "turning-circle", "--differential", "0.5",
                            "--throttle", "0.7", "--duration", "30", "--effect", "thruster_imbalance",
                            "--thruster-imbalance-pct", "6")
    assert code == 0
    bag = Path(result["bags"][0]["bag"])
    assert bag.name == "turning_circle_stbd_d0.5_p0.7"
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TWIN_TYPES
    signals = read_bag(bag, specs(actuator_layout("twin_thrusters")))
    assert signals["thrusters/port"].column("command")[-1] == pytest.approx(0.95, abs=2**-9)  # 0.7 + 0.5 / 2
    assert signals["thrusters/starboard"].column("command")[-1] == pytest.approx(0.45, abs=2**-9)
    meta = read_custom_data(bag)
    assert json.loads(meta["manoeuvre"]) == {"layout": "twin_thrusters", "turn": 0.5, "propulsion": 0.7,
                                             "duration_s": 30.0, "approach_s": 10.0, "side": 1}
    sensors = json.loads(meta["scenario"])["sensors"]
    assert "command_lsb" in sensors and "rudder_lsb" not in sensors  # what shaped this boat's recording
    assert result["bags"][0]["heading_change_deg"] > 90.0  # a starboard turn


def test_a_twin_thruster_programme_is_stated_in_commands(tmp_path):
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.simulate import SimulationRequest, manoeuvres

    otter = load_vessel("otter")
    names = [m.name for m in manoeuvres(SimulationRequest(output=tmp_path, vessel=otter, programme="diagnosis"))]
    assert names == ["turning_circle_stbd_d0.4_p0.6", "turning_circle_port_d0.4_p0.6", "zigzag_d0.4_20_stbd_p0.6",
                     "zigzag_d0.4_20_port_p0.6"]
    [zigzag] = manoeuvres(SimulationRequest(output=tmp_path, vessel=otter, manoeuvre="zigzag", differential=0.3,
                                            side="port"))
    assert (zigzag.turn, zigzag.check_deg, zigzag.propulsion, zigzag.side) == (0.3, 20.0, 0.6, -1)


@pytest.mark.parametrize("layout, extra, topics", [
    ("rudder_throttle", ["--rudder", "15", "--throttle", "0.7"], {"rudder_angle", "throttle"}),
    ("rudder_only", ["--rudder", "15", "--rpm", "600"], {"rudder_angle"}),
])
def test_rudder_layouts_write_their_own_controls(tmp_path, layout, extra, topics):
    """A rudder boat that logs a throttle writes rudder_angle and throttle; one that logs no propulsion only the
    rudder (its simulated engine runs at --rpm all the same)."""
    raw = yaml.safe_load((vessel_dir() / "jari_usv.yaml").read_text())
    raw["actuator_layout"] = layout
    if layout == "rudder_throttle":
        raw["throttle"] = {"forward_N": 9000.0, "reverse_N": 3500.0, "exponent": 2.0, "dead_band": 0.05,
                           "time_constant_s": 1.2}
    boat = tmp_path / "boat.yaml"
    boat.write_text(yaml.safe_dump(raw))
    code, result = simulate(tmp_path, "--vessel", str(boat), "--duration", "20", *extra)
    assert code == 0
    bag = Path(result["bags"][0]["bag"])
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        written = {c.topic for c in reader.connections}
    controls = {"rudder_angle", "engine_rpm", "throttle", "thrusters/port", "thrusters/starboard"}
    assert written & controls == topics
    expected = {"rudder_throttle": "turning_circle_stbd_15deg_p0.7", "rudder_only": "turning_circle_stbd_15deg_600rpm"}
    assert bag.name == expected[layout]
    assert result["bags"][0]["final_speed_mps"] > 2.0


@pytest.mark.parametrize("args, message", [
    (["--vessel", "otter", "--rudder", "10"], "--rudder does not apply to vessel otter (actuator layout "
                                              "twin_thrusters); it takes --differential and --throttle"),
    (["--vessel", "otter", "--rpm", "600"], "--rpm does not apply to vessel otter"),
    (["--differential", "0.3"], "--differential does not apply to vessel jari_usv (actuator layout rudder_propeller); "
                                "it takes --rudder and --rpm"),
    (["--vessel", "otter", "--differential", "2.5"], "--differential 2.5 is outside the range (0, 2]"),
    (["--vessel", "otter", "--throttle", "0"], "--throttle 0 is outside the range (0, 1]"),
    (["--vessel", "otter", "--effect", "rudder_offset"], "effect 'rudder_offset' does not apply to vessel otter "
                                                         "(actuator layout twin_thrusters)"),
    (["--effect", "thruster_imbalance"], "effect 'thruster_imbalance' does not apply to vessel jari_usv"),
])
def test_options_and_effects_of_another_layout_are_refused(tmp_path, capsys, args, message):
    code = main(["simulate", "--output", str(tmp_path / "bags"), "--duration", "5", *args])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1
    assert err[-1].startswith("replay simulate: error:")
    assert message in err[-1]
    assert not (tmp_path / "bags").exists() or not any((tmp_path / "bags").iterdir())


def test_given_effects_go_on_top_of_the_sea():
    from usv_predictor.physics.scenario import RIZHAO_SEA
    from usv_predictor.replay.simulate import scenario_effects

    assert scenario_effects("calm", {"rudder_offset": {}}) == {"rudder_offset": {}}
    sea = scenario_effects("rizhao", {"current": {"current_speed": 0.9}, "rudder_offset": {}})
    assert set(sea) == set(RIZHAO_SEA) | {"rudder_offset"}
    assert sea["current"] == {**RIZHAO_SEA["current"], "current_speed": 0.9}
    assert RIZHAO_SEA["current"].get("current_speed") != 0.9  # the sea itself is not modified


def test_the_calm_day_programme_is_the_twin_layouts_and_refused_for_another(tmp_path):
    from usv_predictor.errors import ConfigError
    from usv_predictor.physics.vessel import load_vessel
    from usv_predictor.replay.simulate import SimulationRequest, manoeuvres

    names = [m.name for m in manoeuvres(SimulationRequest(output=tmp_path, vessel=load_vessel("otter"),
                                                          programme="calm_day"))]
    assert names[:4] == ["turning_circle_stbd_d0.4_p0.6", "turning_circle_port_d0.4_p0.6",
                         "turning_circle_stbd_d0.8_p0.6", "turning_circle_port_d0.8_p0.6"]
    assert names[4:] == ["zigzag_d0.4_20_stbd_p0.6", "zigzag_d0.4_20_port_p0.6", "straight_p0.6", "straight_p0.9",
                         "spin_stbd_d2", "spin_port_d2"]
    with pytest.raises(ConfigError, match="--programme calm_day: vessel jari_usv: programme 'calm_day' is for "
                                          "actuator layout\\(s\\) twin_thrusters, not rudder_propeller"):
        manoeuvres(SimulationRequest(output=tmp_path, vessel=load_vessel("jari_usv"), programme="calm_day"))

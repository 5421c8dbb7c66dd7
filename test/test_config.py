"""config/predictor.yaml and its typed loader (usv_predictor.config)."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import yaml

import msg_adapters
from usv_predictor.config import (
    FLOAT_RANGES,
    ONLINE_RANGES,
    PredictorConfig,
    Range,
    default_config_path,
    flatten_ros_parameters,
    input_topics,
    load_predictor_config,
    package_share_path,
    parse_predictor_config,
    read_ros_parameters,
    unflatten_ros_parameters,
    vessel_preset_path,
)
from usv_predictor.errors import ConfigError

REPO_ROOT = Path(__file__).resolve().parents[1]
SHIPPED = REPO_ROOT / "config" / "predictor.yaml"


def shipped_params() -> dict[str, Any]:
    """The shipped parameters read with plain YAML, independently of the loader."""
    return yaml.safe_load(SHIPPED.read_text(encoding="utf-8"))["predictor"]["ros__parameters"]


def write_params(tmp_path: Path, params: dict[str, Any]) -> Path:
    path = tmp_path / "predictor.yaml"
    path.write_text(yaml.safe_dump({"predictor": {"ros__parameters": params}}), encoding="utf-8")
    return path


def test_default_path_is_the_shipped_file() -> None:
    cfg = load_predictor_config()
    assert Path(cfg.source).resolve() == SHIPPED.resolve()
    assert package_share_path("config", "predictor.yaml").resolve() == SHIPPED.resolve()


def test_loaded_values_match_the_file() -> None:
    raw = shipped_params()
    cfg = load_predictor_config(SHIPPED)
    for key in ("model_path", "vessel", "rate_hz", "horizon_s", "dt", "ensemble_size", "frame_id", "base_frame_id"):
        assert getattr(cfg, key) == raw[key], key
    assert cfg.horizon_steps * cfg.dt == pytest.approx(cfg.horizon_s)
    assert [i.role for i in cfg.inputs] == list(raw["inputs"])
    for entry in cfg.inputs:
        source = raw["inputs"][entry.role]
        assert (entry.topic, entry.ros_type, entry.max_age_s) == (source["topic"], source["type"], source["max_age_s"])
        assert dict(entry.options) == {k: v for k, v in source.items() if k not in ("topic", "type", "max_age_s")}
        assert entry.frame_id == raw["base_frame_id"]  # body-frame default when the entry has none
    assert cfg.ground_truth.role == raw["ground_truth"]["role"]
    assert cfg.ground_truth.topic == raw["ground_truth"]["topic"]
    assert {role: out.topic for role, out in cfg.outputs.items()} == {
        role: out["topic"] for role, out in raw["outputs"].items()
    }


def test_shipped_inputs_have_the_design_defaults() -> None:
    """The default topics of DESIGN.md, and adapter options for heading and rudder sign."""
    cfg = load_predictor_config()
    topics = {i.role: (i.topic, i.ros_type) for i in cfg.inputs}
    assert topics["imu"] == ("imu/data", "sensor_msgs/msg/Imu")
    assert topics["gnss"] == ("gps/fix", "sensor_msgs/msg/NavSatFix")
    assert cfg.input("heading").options["units"] == "deg"
    assert cfg.input("rudder_angle").options["sign"] == 1
    assert cfg.ground_truth.ros_type == "nav_msgs/msg/Odometry"
    assert cfg.ground_truth.topic not in {i.topic for i in cfg.inputs}  # never an input


def test_every_configured_input_has_an_adapter() -> None:
    """Config and msg_adapters agree: each (role, type, options) builds an adapter."""
    cfg = load_predictor_config()
    for entry in (*cfg.inputs, cfg.ground_truth):
        adapter = msg_adapters.get_adapter(entry.role, entry.ros_type, **entry.options)
        assert adapter.fields == msg_adapters.ROLE_FIELDS[entry.role]


def test_input_topics_is_topicspec_shaped() -> None:
    cfg = load_predictor_config()
    topics = input_topics(cfg, include_ground_truth=True)
    assert [t.role for t in topics] == [i.role for i in cfg.inputs] + [cfg.ground_truth.role]
    assert topics[-1].frame_id == cfg.frame_id  # ground truth lives in the earth frame
    assert input_topics(cfg)[0]._fields == ("topic", "role", "ros_type", "options", "frame_id")


def test_input_topics_field_order_matches_replay_topicspec() -> None:
    """replay builds its TopicSpec records straight from the config: TopicSpec(*input_topic)."""
    bagio = pytest.importorskip("usv_predictor.replay.bagio")
    for topic in input_topics(load_predictor_config(), include_ground_truth=True):
        spec = bagio.TopicSpec(*topic)
        assert (spec.topic, spec.role, spec.ros_type, spec.frame_id) == (topic.topic, topic.role, topic.ros_type,
                                                                         topic.frame_id)
        assert dict(spec.options) == dict(topic.options)
        assert spec.adapter().fields == msg_adapters.ROLE_FIELDS[topic.role]


def test_flatten_gives_rclpy_names_and_round_trips() -> None:
    raw = shipped_params()
    flat = flatten_ros_parameters(raw)
    assert flat["inputs.imu.topic"] == raw["inputs"]["imu"]["topic"]
    assert flat["outputs.predicted_path.type"] == raw["outputs"]["predicted_path"]["type"]
    assert all(not isinstance(v, dict) for v in flat.values())
    assert unflatten_ros_parameters(flat) == raw


def test_parse_of_unflattened_parameters_equals_file_load() -> None:
    """The node's path (flat rclpy parameters) and replay's path (file) give the same config."""
    from_file = load_predictor_config(SHIPPED)
    from_params = parse_predictor_config(unflatten_ros_parameters(flatten_ros_parameters(shipped_params())), "x")
    assert from_params == PredictorConfig(**{**from_file.__dict__, "source": "x"})


def test_custom_file_with_frame_and_extra_input(tmp_path: Path) -> None:
    params = shipped_params()
    params["inputs"]["odometry"] = {"topic": "odom", "type": "nav_msgs/msg/Odometry", "max_age_s": 1.0,
                                    "frame_id": "gps_antenna"}
    params["rate_hz"] = 20
    cfg = load_predictor_config(write_params(tmp_path, params))
    assert cfg.input("odometry").frame_id == "gps_antenna"
    assert cfg.rate_hz == 20.0
    assert isinstance(cfg.rate_hz, float)
    with pytest.raises(ConfigError, match="no input with role 'wind'"):
        cfg.input("wind")


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda p: p.update(rate_hz=0.0), r"rate_hz = 0.0 is out of range; allowed 0.1 <= rate_hz <= 100 \(Hz\)"),
        (lambda p: p.update(horizon_s=1e6), r"horizon_s = 1000000.0 is out of range; allowed 1 <= horizon_s"),
        (lambda p: p.update(dt=-0.5), r"dt = -0.5 is out of range"),
        (lambda p: p.update(dt=0.7), r"horizon_s = 60 s is not a whole number of steps of dt = 0.7 s"),
        (lambda p: p.update(dt="fast"), r"dt = 'fast' must be a number"),
        (lambda p: p.update(ensemble_size=2.5), r"ensemble_size = 2.5 must be an integer"),
        (lambda p: p.update(ensemble_size=True), r"ensemble_size = True must be an integer"),
        (lambda p: p.update(ensemble_size=0), r"ensemble_size = 0 is out of range"),
        (lambda p: p.pop("vessel"), r"predictor.ros__parameters.vessel is missing"),
        (lambda p: p.update(vessel="../etc"), r"vessel = '../etc' is not valid"),
        (lambda p: p.update(rate_hzz=10.0), r"unknown key\(s\) \['rate_hzz'\]"),
        (lambda p: p["inputs"]["imu"].update(type="sensor_msgs/Imu"), r"imu.type = 'sensor_msgs/Imu' is not valid"),
        (lambda p: p["inputs"]["imu"].update(max_age_s=0.0), r"inputs.imu.max_age_s = 0.0 is out of range"),
        (lambda p: p["inputs"]["imu"].pop("topic"), r"inputs.imu.topic is missing"),
        (lambda p: p["inputs"]["imu"].update(units={"a": 1}), r"inputs.imu.units: adapter options must be plain"),
        (lambda p: p.update(inputs={}), r"has no inputs"),
        (lambda p: p["outputs"].pop("predicted_path"), r"outputs.predicted_path is missing"),
        (lambda p: p["ground_truth"].pop("role"), r"ground_truth.role is missing"),
    ],
)
def test_invalid_values_name_file_key_and_allowed_range(tmp_path: Path, edit, message: str) -> None:
    params = shipped_params()
    edit(params)
    path = write_params(tmp_path, params)
    with pytest.raises(ConfigError, match=message) as caught:
        load_predictor_config(path)
    assert str(path) in str(caught.value)


def test_every_float_range_admits_the_shipped_value() -> None:
    cfg = load_predictor_config()
    for name, allowed in FLOAT_RANGES.items():
        assert allowed.low <= getattr(cfg, name) <= allowed.high


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("predictor: [1, 2", "not valid YAML"),
        ("other_node:\n  ros__parameters: {}\n", "expected a top-level 'predictor:' mapping"),
        ("predictor:\n  rate_hz: 1.0\n", "expected 'predictor: ros__parameters:' to be a mapping"),
    ],
)
def test_malformed_files(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError, match=message):
        read_ros_parameters(path)


def test_missing_file_names_the_path(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"cannot read predictor config .*nowhere\.yaml"):
        load_predictor_config(tmp_path / "nowhere.yaml")


def test_missing_share_file_lists_where_it_looked() -> None:
    expected = r"cannot find 'config/vessels/no_such_boat.yaml' of package usv_predictor; looked in: /"
    with pytest.raises(ConfigError, match=expected):
        vessel_preset_path("no_such_boat")
    with pytest.raises(ConfigError, match="not a preset name"):
        vessel_preset_path("../predictor")


def test_source_tree_wins_over_a_sourced_install(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Code running from this checkout reads this checkout's data even in a sourced workspace."""
    prefix = tmp_path / "install"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / "usv_predictor").touch()
    (prefix / "share" / "usv_predictor" / "config").mkdir(parents=True)
    (prefix / "share" / "usv_predictor" / "config" / "predictor.yaml").write_text("stale", encoding="utf-8")
    (prefix / "share" / "usv_predictor" / "only_installed.txt").write_text("x", encoding="utf-8")
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    assert package_share_path("config", "predictor.yaml").resolve() == SHIPPED.resolve()
    # a file only the install has is still found there, through the ament index
    found = package_share_path("only_installed.txt")
    assert found == prefix / "share" / "usv_predictor" / "only_installed.txt"
    assert math.isinf(load_predictor_config().ground_truth.max_age_s)  # ground truth has no staleness


def test_a_range_check_names_source_name_value_and_unit() -> None:
    speed = Range(0.0, 5.0, "m/s")
    assert speed.check("current_speed", 5.0, "environment") == 5.0  # closed interval
    for value in (-0.1, 5.5, math.nan, math.inf):
        with pytest.raises(ConfigError, match=rf"^environment: current_speed={value} m/s is outside the allowed "
                                              rf"range \[0.0, 5.0\]$"):
            speed.check("current_speed", value, "environment")
    with pytest.raises(ConfigError, match=r"^zigzag: rudder_deg=99.0 is outside the allowed range \[0.0, 90.0\]$"):
        Range(0.0, 90.0, "").check("rudder_deg", 99.0, "zigzag")  # no unit: nothing after the value


def test_the_online_section_is_onlineconfigs_defaults_and_is_checked() -> None:
    """The shipped `online` section changes none of OnlineConfig's defaults (replay evaluate --adaptive and the node
    read it); a file without it gets them, enabled; a wrong value or key is refused naming it."""
    from usv_predictor.fitting.online import OnlineConfig

    shipped = load_predictor_config()
    assert shipped.online_enabled
    assert set(shipped.online) == set(ONLINE_RANGES)
    assert OnlineConfig(**shipped.online) == OnlineConfig()
    assert shipped.outputs["estimated_current"].ros_type == "geometry_msgs/msg/TwistWithCovarianceStamped"
    params = read_ros_parameters(default_config_path())
    without = {k: v for k, v in params.items() if k != "online"}
    without["outputs"] = {k: v for k, v in params["outputs"].items() if k != "estimated_current"}
    older = parse_predictor_config(without, "older.yaml")
    assert older.online_enabled
    assert dict(older.online) == {}
    assert older.outputs["estimated_current"].topic == "estimated_current"
    for online, message in (({"enabled": "yes"}, r"online.enabled = 'yes' must be true or false"),
                            ({"current_noise": -1.0}, r"online.current_noise = -1.0 is out of range"),
                            ({"gate": 0.9}, r"unknown key\(s\) \['gate'\]")):
        with pytest.raises(ConfigError, match=message):
            parse_predictor_config({**params, "online": online}, "bad.yaml")

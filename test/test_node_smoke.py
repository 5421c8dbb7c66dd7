"""The `predictor` node in a real rclpy context over DDS loopback: inputs in, /diagnostics out.

Each test process uses its own ROS_DOMAIN_ID (derived from the pid) and localhost-only discovery,
so parallel runs on one machine do not hear each other.
"""
from __future__ import annotations

import math
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from rclpy.context import Context
from rclpy.parameter import Parameter

from usv_predictor.config import load_predictor_config
from usv_predictor.errors import ConfigError
from usv_predictor.node import node as predictor_node

from ros_helpers import Harness, localhost_env, ros_context, values_of  # noqa: F401 (ros_context is a fixture)


@pytest.fixture()
def harness(ros_context: Context) -> Iterator[Harness]:
    fixture = Harness(ros_context, [Parameter("rate_hz", value=20.0)], peer_name="smoke_peer")
    try:
        yield fixture
    finally:
        fixture.close()


def test_inputs_are_decoded_and_reported(harness: Harness) -> None:
    heading_psi = math.radians(90.0)  # east, NED heading (rad)
    rudder = math.radians(-10.0)  # port rudder (rad)

    def feed() -> None:
        harness.publish("heading", (heading_psi,))
        harness.publish("rudder_angle", (rudder,))
        harness.publish("engine_rpm", (1200.0,))

    statuses = harness.spin_until(
        lambda s: all(s[r].level[0] == predictor_node.OK for r in ("heading", "rudder_angle", "engine_rpm")), feed
    )
    # values went ROS message -> adapter -> plain numbers, and come back in the report
    assert float(values_of(statuses["heading"])["psi"]) == pytest.approx(heading_psi, abs=1e-5)
    assert float(values_of(statuses["rudder_angle"])["delta"]) == pytest.approx(rudder, abs=1e-5)
    assert float(values_of(statuses["engine_rpm"])["rpm"]) == pytest.approx(1200.0)
    assert int(values_of(statuses["heading"])["messages"]) >= 1
    # inputs nobody published are errors; the shipped model is loaded, but without inputs nothing is predicted
    assert statuses["velocity"].level[0] == predictor_node.ERROR
    assert statuses["velocity"].message == "no message received"
    assert statuses["model"].level[0] == predictor_node.OK
    assert statuses["prediction"].level[0] == predictor_node.WARN
    assert "no message yet" in statuses["prediction"].message
    configured = [i.role for i in harness.node.config.inputs]
    assert sorted(statuses) == sorted([*configured, "model", "prediction"])


def test_stale_input_turns_to_warn_and_limit_is_live(harness: Harness) -> None:
    harness.spin_until(lambda s: s["engine_rpm"].level[0] == predictor_node.OK,
                       lambda: harness.publish("engine_rpm", (900.0,)))
    # shrink the staleness limit at run time; with no more messages the input must go stale
    result = harness.node.set_parameters([Parameter("inputs.engine_rpm.max_age_s", value=0.05)])
    assert result[0].successful
    statuses = harness.spin_until(lambda s: s["engine_rpm"].level[0] == predictor_node.WARN)
    assert statuses["engine_rpm"].message.startswith("stale: last message")
    assert values_of(statuses["engine_rpm"])["max_age_s"] == "0.05"


def test_read_only_and_ranged_parameters(harness: Harness) -> None:
    assert not harness.node.set_parameters([Parameter("inputs.imu.topic", value="other")])[0].successful
    assert not harness.node.set_parameters([Parameter("inputs.imu.max_age_s", value=1e6)])[0].successful
    descriptor = harness.node.describe_parameter("horizon_s")
    assert descriptor.read_only
    assert descriptor.floating_point_range[0].from_value <= load_predictor_config().horizon_s
    assert harness.node.get_parameter("rate_hz").value == 20.0  # the override won over the file


@pytest.mark.parametrize(
    ("override", "message"),
    [
        (Parameter("dt", value=0.0), "out of range"),  # rejected by rclpy through the descriptor range
        (Parameter("dt", value=0.7), "not a whole number of steps"),  # rejected by the shared loader
    ],
)
def test_invalid_overrides_are_config_errors(ros_context: Context, override: Parameter, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        predictor_node.PredictorNode(context=ros_context, parameter_overrides=[override])


def test_config_option_file_becomes_the_defaults(ros_context: Context, tmp_path: Path) -> None:
    """A custom file (integer rate, one input) is declared as typed, ranged parameters."""
    params = yaml.safe_load(Path(load_predictor_config().source).read_text(encoding="utf-8"))
    inner = params["predictor"]["ros__parameters"]
    inner["rate_hz"] = 4  # an int in YAML: still the double parameter rate_hz
    inner["inputs"] = {"engine_rpm": inner["inputs"]["engine_rpm"]}
    path = tmp_path / "custom.yaml"
    path.write_text(yaml.safe_dump(params), encoding="utf-8")
    node = predictor_node.PredictorNode(config_path=path, context=ros_context)
    try:
        assert node.get_parameter("rate_hz").value == 4.0
        assert node.describe_parameter("rate_hz").floating_point_range[0].to_value == 100.0
        assert [i.role for i in node.config.inputs] == ["engine_rpm"]
        assert not node.has_parameter("inputs.imu.topic")
    finally:
        node.destroy_node()


def test_help_exits_before_ros_starts(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def forbidden(**_: Any) -> None:
        raise AssertionError("rclpy.init must not run for --help")

    monkeypatch.setattr(predictor_node.rclpy, "init", forbidden)
    with pytest.raises(SystemExit) as exited:
        predictor_node.main(["predictor", "--help", "--ros-args", "-p", "rate_hz:=5.0"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.startswith("usage: predictor")


def test_missing_config_file_exits_2_with_its_name(tmp_path: Path) -> None:
    missing = tmp_path / "absent.yaml"
    env = localhost_env(0)
    done = subprocess.run(
        [sys.executable, "-m", "usv_predictor.node", "--config", str(missing)],
        capture_output=True, text=True, timeout=60, env=env,
    )
    assert done.returncode == predictor_node.EXIT_ERROR == 2  # a start-up error, like the replay tool's bad input
    assert str(missing) in done.stderr and "Traceback" not in done.stderr

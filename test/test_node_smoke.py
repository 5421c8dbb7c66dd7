"""The `predictor` node in a real rclpy context over DDS loopback: inputs in, /diagnostics out.

Each test process uses its own ROS_DOMAIN_ID (derived from the pid) and localhost-only discovery,
so parallel runs on one machine do not hear each other.
"""
from __future__ import annotations

import math
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml
from rclpy.context import Context
from rclpy.parameter import Parameter

import msg_adapters
from usv_predictor.config import load_predictor_config, package_share_path
from usv_predictor.errors import ConfigError
from usv_predictor.node import node as predictor_node
from usv_predictor.physics.actuators import unused_roles

from replay_helpers import never_returning_model, slow_model, stop_and_time
from ros_helpers import GOOD, Harness, domain_id, localhost_env, values_of


SHIPPED = Path(package_share_path("models", "default.pt"))


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
    # every configured input the vessel's actuator layout uses is reported; the controls of other layouts are not
    # subscribed, and one status says so (check_layout_inputs)
    used = [i.role for i in harness.node.config.inputs if i.role not in unused_roles(harness.node.layout)]
    assert "throttle" not in used
    assert "thruster_port" not in used
    assert "rudder_angle" in used
    assert sorted(statuses) == sorted([*used, "model", "prediction", "plan", "candidate plans", "sea estimate",
                                       "fit check",
                                       "ignored inputs"])
    ignored = statuses["ignored inputs"]
    assert ignored.level[0] == predictor_node.OK
    assert ignored.message == ("not subscribed: throttle, thruster_port, thruster_starboard (controls of other "
                               "actuator layouts than rudder_propeller)")
    assert values_of(ignored) == {"actuator_layout": "rudder_propeller", "vessel": "jari_usv", "throttle": "/throttle",
                                  "thruster_port": "/thrusters/port", "thruster_starboard": "/thrusters/starboard"}


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
    """A custom file (integer rate, only the two control inputs of the vessel) is declared as typed, ranged
    parameters."""
    params = yaml.safe_load(Path(load_predictor_config().source).read_text(encoding="utf-8"))
    inner = params["predictor"]["ros__parameters"]
    inner["rate_hz"] = 4  # an int in YAML: still the double parameter rate_hz
    inner["inputs"] = {role: inner["inputs"][role] for role in ("engine_rpm", "rudder_angle")}
    path = tmp_path / "custom.yaml"
    path.write_text(yaml.safe_dump(params), encoding="utf-8")
    node = predictor_node.PredictorNode(config_path=path, context=ros_context)
    try:
        assert node.get_parameter("rate_hz").value == 4.0
        assert node.describe_parameter("rate_hz").floating_point_range[0].to_value == 100.0
        assert [i.role for i in node.config.inputs] == ["engine_rpm", "rudder_angle"]
        assert not node.has_parameter("inputs.imu.topic")
        assert node.ignored == {}
    finally:
        node.destroy_node()


@pytest.mark.parametrize(("vessel", "drop", "message"), [
    ("otter", ("thruster_starboard",), "vessel otter: actuator layout twin_thrusters needs input(s) "
                                       "['thruster_starboard'] (controls ['port', 'starboard'])"),
    ("jari_usv", ("rudder_angle", "engine_rpm"), "vessel jari_usv: actuator layout rudder_propeller needs input(s) "
                                                 "['rudder_angle', 'engine_rpm'] (controls ['delta', 'rpm'])"),
])
def test_a_missing_control_input_is_one_line_and_exit_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str], vessel: str,
                                                          drop: tuple[str, ...], message: str) -> None:
    """A configuration without an input of a control of the vessel's actuator layout is refused at start-up
    (physics.actuators.check_layout_inputs), before the model is loaded: one line naming the roles and the layout."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id(44)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    params = yaml.safe_load(Path(load_predictor_config().source).read_text(encoding="utf-8"))
    inner = params["predictor"]["ros__parameters"]
    inner["vessel"] = vessel
    for role in drop:
        del inner["inputs"][role]
    path = tmp_path / "missing_control.yaml"
    path.write_text(yaml.safe_dump(params), encoding="utf-8")
    code = predictor_node.main(["predictor", "--config", str(path)])
    err = capsys.readouterr().err
    assert code == predictor_node.EXIT_ERROR == 2, err
    lines = [line for line in err.strip().splitlines() if not line.startswith("[")]  # rcl's own log lines
    assert len(lines) == 1
    assert lines[0].startswith(f"predictor: error: {path} (with the node's parameter overrides), ")
    assert message in lines[0]
    assert "Traceback" not in err


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
    assert str(missing) in done.stderr
    assert "Traceback" not in done.stderr


# ----------------------------------------------------------------------------- start-up and stop


def _failing_model(path: Path) -> Path:
    import torch

    from usv_predictor.models.artifact import export_like, load_artifact

    class Raises(torch.nn.Module):
        def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
            if bool(state.sum() > -1e30):
                raise RuntimeError("boom at start-up")
            return torch.zeros(1, state.shape[0], controls.shape[1], 6)

    export_like(path, Raises(), load_artifact(package_share_path("models", "default.pt")))  # its metadata, vessel
    return path


ALIAS_BOMB = "".join(f"    lol{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9) if i else ', '.join(['lol'] * 9)}]\n"
                     for i in range(9))  # the "billion laughs": 9**9 nodes for whoever expands the aliases

STARTUP_CASES = {
    "datum out of range": (["-p", "datum_lat_deg:=999.0", "-p", "datum_lon_deg:=119.5"],
                           "datum_lat_deg=999.0 deg is outside the allowed range [-89.9, 89.9]"),
    "datum without longitude": (["-p", "datum_lat_deg:=35.0"], "datum_lat_deg is set but datum_lon_deg is not"),
    "datum not finite": (["-p", "datum_lat_deg:=35.0", "-p", "datum_lon_deg:=inf"], "datum_lon_deg=inf deg"),
    "datum not a number": (["-p", "datum_lat_deg:=north"], "expecting type 'DOUBLE'"),
    "broken params file": (["--params-file", "{broken}"], "invalid ROS arguments: Failed to parse ROS arguments: "
                                                          "Couldn't parse params file"),
    "missing params file": (["--params-file", "{missing}"], "Couldn't parse params file"),
    "broken remap": (["-r", "__node:="], "invalid ROS arguments"),
    "rate out of range": (["-p", "rate_hz:=1000.0"], "Parameter rate_hz out of range"),
    "unknown vessel": (["-p", "vessel:=nope"], "unknown vessel preset 'nope'"),
    "vessel of another layout/model": (["-p", "vessel:=kvlcc2_model"],
                                       "was made for vessel 'jari_usv' (the description it embeds), vessel "
                                       "kvlcc2_model differs: "),
    "adapter option": (["-p", "inputs.heading.units:=furlongs"], "option units='furlongs' is invalid"),
    "adapter sign": (["-p", "inputs.rudder_angle.sign:=3"], "rudder_angle"),
    "message type": (["-p", "inputs.heading.type:=std_msgs/msg/String"], "no adapter for role 'heading'"),
    "ensemble": (["-p", "ensemble_size:=8"], "ensemble_size 8 requested"),
    "failing model": (["-p", "model_path:={failing}"], "fails when run: RuntimeError: boom at start-up"),
    "model slower than the cycle": (["-p", "model_path:={slow}"], "is too slow for the node's cycle (1 / rate_hz "
                                    "10 Hz): a rollout of 120 steps takes "),
    # a parameter of the wrong type, endpoints remapped onto each other, params files past the bounds
    "use_sim_time not a bool": (["-p", "use_sim_time:=maybe"],
                                "invalid parameter: Trying to set parameter 'use_sim_time' to 'maybe'"),
    "input remapped onto /diagnostics": (["-r", "imu/data:=/diagnostics"], "output /diagnostics resolves to "
                                         "/diagnostics, the topic of its input imu too"),
    "output remapped onto /diagnostics": (["-r", "predicted_path:=/diagnostics"],
                                          "output /diagnostics resolves to /diagnostics, the topic of its output "
                                          "predicted_path too"),
    "two outputs on one topic": (["-r", "predicted_velocities:=predicted_path"], "output predicted_velocities "
                                 "resolves to /predicted_path, the topic of its output predicted_path too"),
    "params file alias bomb": (["--params-file", "{bomb}"], "invalid ROS arguments"),
    "params file python tag": (["--params-file", "{tagged}"], "parameter rejected"),  # rcl reads no tags: a list
}


@pytest.mark.parametrize("case", sorted(STARTUP_CASES))
def test_a_wrong_start_up_parameter_is_one_line_and_exit_2(case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    """Every parameter that can be wrong at start-up: `predictor: error: ...` on one line, exit 2, no traceback."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id(43)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    broken = tmp_path / "broken.yaml"
    broken.write_text("predictor:\n  ros__parameters:\n    rate_hz: [1,\n", encoding="utf-8")
    bomb, tagged = tmp_path / "bomb.yaml", tmp_path / "tagged.yaml"
    bomb.write_text(f"predictor:\n  ros__parameters:\n{ALIAS_BOMB}", encoding="utf-8")
    tagged.write_text("predictor:\n  ros__parameters:\n    rate_hz: !!python/object/apply:os.system ['true']\n",
                      encoding="utf-8")
    paths = {"broken": broken, "missing": tmp_path / "missing.yaml", "bomb": bomb, "tagged": tagged,
             "failing": _failing_model(tmp_path / "raises.pt") if case == "failing model" else "",
             "slow": slow_model(tmp_path / "slow.pt", SHIPPED) if case == "model slower than the cycle" else ""}
    args, message = STARTUP_CASES[case]
    code = predictor_node.main(["predictor", "--ros-args", *[a.format(**paths) for a in args]])
    err = capsys.readouterr().err
    assert code == predictor_node.EXIT_ERROR == 2, err
    assert "Traceback" not in err
    lines = [line for line in err.strip().splitlines() if not line.startswith("[")]  # rcl's own log lines
    assert len(lines) == 1, err
    assert lines[0].startswith("predictor: error: "), err
    assert message in lines[0], err


CONFIG_CASES = {  # --config files beyond bounds (usv_predictor.bounded), read before ROS starts
    "dev_zero": (None, "cannot read predictor config /dev/zero: it is a character device, expected a regular file"),
    "alias_bomb": ("predictor:\n  ros__parameters:\n" + ALIAS_BOMB, "expands to more than"),
    "python_tag": ("predictor:\n  ros__parameters: !!python/object/new:dict {}\n", "constructor for the tag"),
    "deep": ("predictor:\n  ros__parameters:\n    inputs: " + "[" * 100_000 + "]" * 100_000 + "\n",
             "nested deeper than"),
}


@pytest.mark.parametrize("case", sorted(CONFIG_CASES))
def test_a_config_beyond_bounds_is_one_line_and_exit_2(case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Was: a MemoryError (/dev/zero), a RecursionError, a parser's caret lines. Now one line, exit 2."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id(43)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    text, message = CONFIG_CASES[case]
    config = Path("/dev/zero") if text is None else tmp_path / "predictor.yaml"
    if text is not None:
        config.write_text(text, encoding="utf-8")
    code = predictor_node.main(["predictor", "--config", str(config)])
    err = capsys.readouterr().err
    lines = [line for line in err.strip().splitlines() if not line.startswith("[")]
    assert code == 2 and "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("predictor: error: ") and message in lines[0], err


def test_a_broken_params_file_in_a_process(tmp_path: Path) -> None:
    """The issue's case as a user meets it: RCLInvalidROSArgsError came out of the argument parsing."""
    broken = tmp_path / "broken.yaml"
    broken.write_text("predictor:\n  ros__parameters:\n    rate_hz: [1,\n", encoding="utf-8")
    done = subprocess.run([sys.executable, "-m", "usv_predictor.node", "--ros-args", "--params-file", str(broken)],
                          capture_output=True, text=True, timeout=60, env=localhost_env(44))
    assert done.returncode == 2
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1].startswith("predictor: error: invalid ROS arguments: ")


class _Feeder:
    """A peer in its own context that publishes plausible inputs and counts the Paths it receives."""

    def __init__(self, offset: int) -> None:
        from rclpy.context import Context as RclContext
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.context = RclContext()
        rclpy.init(context=self.context, domain_id=domain_id(offset))
        self.node = Node("sigterm_feeder", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.make = msg_adapters.rclpy_factory()
        self.paths = 0
        self.node.create_subscription(self.make("nav_msgs/msg/Path"), "predicted_path", self._count, 10)
        cfg = load_predictor_config()
        self.publishers = {e.role: (self.node.create_publisher(self.make(e.ros_type), e.topic, 100),
                                    msg_adapters.get_adapter(e.role, e.ros_type, **e.options), e)
                           for e in cfg.inputs if e.role in GOOD}  # the default vessel's inputs

    def _count(self, _: Any) -> None:
        self.paths += 1

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            stamp = self.node.get_clock().now().nanoseconds
            for role, (publisher, adapter, entry) in self.publishers.items():
                publisher.publish(adapter.encode(stamp, GOOD[role], self.make, entry.frame_id))
            self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


STOPS = 8  # before the fix the first fed stop already ended in the traceback; unfed, 3 stops of 12 did


@pytest.mark.slow
def test_stop_signals_while_publishing_end_it_cleanly_every_time() -> None:
    """SIGTERM (systemd, docker, launch) while the node publishes once gave `RCLError: Failed to publish:
    publisher's context is invalid` and exit 1 in 4 of 9 stops. Now 143 (SIGTERM) or 130 (SIGINT) and no
    traceback, every time (SIGTERM and SIGINT alternate, fed and unfed runs alternate; the moment of the stop is
    random but seeded)."""
    offset = 45
    feeder = _Feeder(offset)
    rng = random.Random(12)
    try:
        for stop in range(STOPS):
            process = subprocess.Popen(
                [sys.executable, "-m", "usv_predictor.node", "--ros-args", "-p", "rate_hz:=100.0"],
                env=localhost_env(offset if stop % 4 < 2 else offset + 1),  # unfed: alone on its domain
                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            lines: list[str] = []
            reader = threading.Thread(target=lambda: lines.extend(process.stderr),  # type: ignore[arg-type]
                                      daemon=True)
            reader.start()
            try:
                deadline = time.monotonic() + 60.0
                while not any("usv_predictor" in line and "model" in line for line in lines):  # its start-up log
                    assert time.monotonic() < deadline, "the node did not start"
                    assert process.poll() is None, "the node did not start"
                    feeder.spin(0.1)
                if stop % 4 < 2:  # fed: it publishes Paths (60 s horizon) and /diagnostics at up to 100 Hz
                    feeder.paths = 0
                    while feeder.paths < 3:  # Paths of this node (the start-up line came before its first)
                        assert time.monotonic() < deadline, "the node never published"
                        assert process.poll() is None, "the node never published"
                        feeder.spin(0.05)
                    feeder.spin(rng.uniform(0.0, 0.3))
                else:  # not fed: /diagnostics at 100 Hz only (how the race showed in 3 of 12 stops before the fix)
                    time.sleep(rng.uniform(0.2, 1.0))
                process.send_signal(signal.SIGTERM if stop % 2 == 0 else signal.SIGINT)
                process.wait(timeout=30)
                reader.join(timeout=10)
                err = "".join(lines)
            finally:
                if process.poll() is None:
                    process.kill()
            expected = 143 if stop % 2 == 0 else 130  # SIGTERM, SIGINT
            assert process.returncode == expected, f"stop {stop}: exit {process.returncode}\n{err[-3000:]}"
            assert "Traceback" not in err, err[-3000:]
            assert "RCLError" not in err, err[-3000:]
    finally:
        feeder.close()


def test_a_stop_signal_inside_a_publishing_callback_is_clean(monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """The race of the issue made certain: SIGTERM arrives inside the timer callback, before its publish (with
    rclpy's own handler the context was shut down meanwhile: RCLError, exit 1). The signal only sets the stop
    flag: the context stays valid, the publish succeeds, the loop ends, exit 143, the handlers are restored."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id(46)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    original = predictor_node.PredictorNode._publish_diagnostics
    seen: list[bool] = []

    def publish_after_a_signal(node: predictor_node.PredictorNode, now_ns: int) -> None:
        if not seen:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(0.2)  # room for any asynchronous shutdown to happen first
        seen.append(node.context.ok())
        original(node, now_ns)  # RCLError "publisher's context is invalid" if the context went away

    monkeypatch.setattr(predictor_node.PredictorNode, "_publish_diagnostics", publish_after_a_signal)
    started = time.monotonic()
    assert predictor_node.main(["predictor", "--ros-args", "-p", "rate_hz:=20.0"]) == 143
    assert seen
    assert all(seen)
    assert time.monotonic() - started < 30.0
    assert "Traceback" not in capsys.readouterr().err
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # the node's handlers are gone with it


@pytest.mark.slow
def test_a_model_that_never_returns_at_start_up_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """A model whose code never returns: its first rollout is given up on after loading.FIRST_CALL_S, one line, exit
    2, and the process ends (os._exit: with the thread inside torch a normal exit aborts, exit 134)."""
    model = never_returning_model(tmp_path / "never.pt", SHIPPED)
    done = subprocess.run([sys.executable, "-m", "usv_predictor.node", "--ros-args", "-p", f"model_path:={model}"],
                          capture_output=True, text=True, timeout=120, env=localhost_env(42))
    assert done.returncode == 2, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and "terminate called" not in done.stderr, done.stderr[-3000:]
    lines = [line for line in done.stderr.strip().splitlines() if not line.startswith("[")]
    assert lines == [f"predictor: error: model {model}: its first two-step rollout did not return within 5 s"], lines
    assert "model: running" in done.stdout


def _set_model_path(feeder: _Feeder, path: Path) -> Any:
    """A peer's set_parameters call of model_path on the node (the future of its answer)."""
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(feeder.node, predictor_node.NODE_NAME)
    assert client.wait_for_services(timeout_sec=30.0), "the node's parameter services did not come up"
    return client.set_parameters([Parameter("model_path", value=str(path))])


@pytest.mark.slow
def test_a_swap_to_a_model_that_never_returns_is_refused_and_a_stop_during_one_is_clean(tmp_path: Path) -> None:
    """Any peer can set model_path. A model slower than the cycle is refused with the measured time, one that never
    returns after loading.FIRST_CALL_S; the old model keeps predicting. A SIGTERM while a swap waits on a model
    that never returns ends the node within 2 s, exit 143 (the wait gives up on the stop)."""
    never = never_returning_model(tmp_path / "never.pt", SHIPPED)
    slow = slow_model(tmp_path / "slow.pt", SHIPPED)
    offset = 48
    feeder = _Feeder(offset)
    process = subprocess.Popen([sys.executable, "-m", "usv_predictor.node"], env=localhost_env(offset),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(process.stderr), daemon=True)  # type: ignore[arg-type]
    reader.start()
    try:
        deadline = time.monotonic() + 90.0
        while feeder.paths < 3:  # up and predicting
            assert process.poll() is None and time.monotonic() < deadline, "".join(lines)[-3000:]
            feeder.spin(0.1)
        for path, reason in ((slow, f"model {slow} is too slow for the node's cycle (1 / rate_hz 10 Hz): a rollout "
                                    "of 120 steps takes "),
                             (never, f"model {never}: its first two-step rollout did not return within 5 s")):
            answer = _set_model_path(feeder, path)
            while not answer.done():
                assert time.monotonic() < deadline, "no answer to the swap"
                feeder.spin(0.05)
            result = answer.result().results[0]
            assert not result.successful
            assert result.reason.startswith(reason), result.reason
            feeder.paths = 0
            feeder.spin(1.0)
            assert feeder.paths >= 3, "the old model stopped predicting"  # 10 Hz
        answer = _set_model_path(feeder, never)
        feeder.spin(1.0)  # the node now waits on the model's first rollout
        assert not answer.done()
        sent = time.monotonic()
        process.send_signal(signal.SIGTERM)
        process.wait(timeout=30)
        took = time.monotonic() - sent
        reader.join(timeout=10)
    finally:
        if process.poll() is None:
            process.kill()
        feeder.close()
    err = "".join(lines)
    assert process.returncode == 143, err[-3000:]
    assert took < STOP_WITHIN_S, f"ended {took:.2f} s after SIGTERM"
    assert "Traceback" not in err and "terminate called" not in err, err[-3000:]


STOP_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143, signal.SIGHUP: 0}  # usv_predictor.node.EXIT_CODES
PROCESS_STOPS = 6  # in a process of its own: 3 signals x (while importing, later in the start-up)
IN_PROCESS_STOPS = 24  # predictor_node.main in this process: 3 signals x 8 moments spread over start-up and running
STOP_WITHIN_S = 2.0  # a stop signal ends the node within this (s)


def _catches_stop_signals(pid: int) -> bool:
    """Whether process `pid` has handlers for SIGINT, SIGTERM and SIGHUP (SigCgt in /proc: the node's own, the
    moment from which it can honour a stop)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except FileNotFoundError:
        return False
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return all(caught >> (sig - 1) & 1 for sig in STOP_CODES)


@pytest.mark.slow
def test_every_stop_signal_at_any_moment_ends_the_node_within_2_s(monkeypatch: pytest.MonkeyPatch) -> None:
    """Was: SIGINT at some moments of start-up hung the node, SIGTERM during the imports killed it as signal 15,
    SIGHUP ended it with 129; later 0 for all three, in up to 10 s. Now, 30 times at moments drawn with a seed:
    SIGINT ends it with 130, SIGTERM 143, SIGHUP 0, no traceback, within 2 s of the signal. Six stops hit a
    process of its own while it imports and starts (the imports end it at once: nothing exists yet to end); 24 hit
    predictor_node.main in this process (imports done, numba's cache warm) at moments spread over its start-up
    (parameters, model, kernel, fit check's model: about 1 s here) and its running."""
    rng = random.Random(28)
    env = localhost_env(46)
    for k in range(PROCESS_STOPS):
        sig = tuple(STOP_CODES)[k % 3]
        delay = rng.uniform(0.0, 0.5) if k < 3 else rng.uniform(1.0, 4.0)  # after its handlers are installed
        process = subprocess.Popen([sys.executable, "-m", "usv_predictor.node"], env=env, stdout=subprocess.PIPE,
                                   stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 30.0
            while not _catches_stop_signals(process.pid):
                assert process.poll() is None and time.monotonic() < deadline, "no handlers installed"
                time.sleep(0.01)
            time.sleep(delay)
        except BaseException:
            process.kill()
            raise
        err, took = stop_and_time(process, sig)
        what = f"{signal.Signals(sig).name} {delay:.2f} s after the handlers (a process of its own)"
        assert process.returncode == STOP_CODES[sig], f"{what}: exit {process.returncode}\n{err[-3000:]}"
        assert "Traceback" not in err, f"{what}:\n{err[-3000:]}"
        assert took < STOP_WITHIN_S, f"{what}: ended {took:.2f} s after the signal"

    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain_id(47)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    stray: list[int] = []  # a signal that arrives after main returned lands here, not in pytest's handlers
    previous = {sig: signal.signal(sig, lambda signum, frame: stray.append(signum)) for sig in STOP_CODES}
    try:
        moments = [(k + rng.random()) * 2.5 / IN_PROCESS_STOPS for k in range(IN_PROCESS_STOPS)]  # 0 .. 2.5 s
        rng.shuffle(moments)
        for k, moment in enumerate(moments):
            sig = tuple(STOP_CODES)[k % 3]
            sent: list[float] = []

            def send(sig: int = sig, moment: float = moment, sent: list[float] = sent) -> None:
                time.sleep(moment)
                sent.append(time.monotonic())
                os.kill(os.getpid(), sig)

            sender = threading.Thread(target=send, daemon=True)
            sender.start()
            code = predictor_node.main(["predictor", "--ros-args", "-p", "rate_hz:=20.0"])
            ended = time.monotonic()
            sender.join(timeout=10)
            what = f"{signal.Signals(sig).name} {moment:.2f} s after main started"
            assert sent and not stray, f"{what}: main ended (exit {code}) before the signal"
            assert code == STOP_CODES[sig], f"{what}: exit {code}"
            assert ended - sent[0] < STOP_WITHIN_S, f"{what}: ended {ended - sent[0]:.2f} s after the signal"
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

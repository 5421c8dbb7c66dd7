"""The `predictor` node over real DDS, fed from a shipped bag with /clock (use_sim_time).

1. In process, lock-step: the bag's messages go out over DDS one stamp at a time; every Path the node
   publishes equals the artifact's prediction on the state of the Recording that `replay evaluate`
   builds from the same bag (load_recordings), at the same time, with the controls held.
2. Across processes: `python -m usv_predictor.node` with use_sim_time, the bag played free-running;
   Paths arrive at rate_hz (sim time) with H poses in frame odom, stamped in the future.
3. The ament-index executable of a colcon build starts with the shipped model and publishes a Path.
Unique ROS_DOMAIN_IDs (from the pid) and localhost-only discovery (ros_helpers), as test_node_smoke.py.
"""
from __future__ import annotations

import itertools
import math
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

import msg_adapters
from msg_adapters import outputs
from msg_adapters.outputs import decode_predicted_velocities
from usv_predictor.analysis import adaptive
from usv_predictor.config import load_predictor_config
from usv_predictor.data.recording import NS, Recording
from usv_predictor.fitting.online import OnlineConfig
from usv_predictor.models import loading
from usv_predictor.models.artifact import export_module
from usv_predictor.models.greybox import greybox_predictor
from usv_predictor.node import node as predictor_node
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay.recordings import load_recordings

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tools"))
import play_bag  # noqa: E402  (tools/ is not a package)
from ros_helpers import domain_id, localhost_env  # noqa: E402 (ros_context: a fixture of conftest.py)

BAG = REPO / "bags" / "sea_trial" / "turning_circle_stbd_20deg_700rpm"
DT = 0.5
WAIT_S = 20.0


def spin_until(executor: SingleThreadedExecutor, condition: Callable[[], bool], what: str,
               also: SingleThreadedExecutor | None = None) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out waiting for {what}")
        executor.spin_once(timeout_sec=0.005)
        if also is not None:
            also.spin_once(timeout_sec=0.0)


HEADERLESS_TYPES = ("std_msgs/msg/Float64", "std_msgs/msg/Float32", "std_msgs/msg/Float64MultiArray")


class Lockstep(NamedTuple):
    """What a lock-step run published (rclpy messages), the messages sent, and the node."""

    node: predictor_node.PredictorNode
    paths: list  # play_bag.PathListener.paths: (stamp, t_ns, eta, frame)
    velocities: list  # MultiDOFJointTrajectory
    currents: list  # TwistWithCovarianceStamped of estimated_current
    sent: int  # messages the player published


def lockstep(context: Context, bag: Path, recording: Recording, *, seconds: float, config_path: Path | None = None,
             overrides: tuple[Parameter, ...] = ()) -> Lockstep:
    """Play `seconds` of `bag` to a node over DDS one stamp at a time (use_sim_time, rate 2 Hz, state_delay dt:
    each state window on the Recording's grid, so the node's cycle k assembles the Recording's state k)."""
    node = predictor_node.PredictorNode(config_path=config_path, context=context, parameter_overrides=[
        Parameter("use_sim_time", value=True), Parameter("rate_hz", value=2.0),
        # windows end on whole half-seconds of the bag, like the Recording's (t0 = first stamp + dt/2)
        Parameter("state_delay_s", value=DT),
        Parameter("datum_lat_deg", value=recording.datum[0]), Parameter("datum_lon_deg", value=recording.datum[1]),
        *overrides,
    ])
    peer = Node("lockstep_player", context=context)
    node_executor, peer_executor = SingleThreadedExecutor(context=context), SingleThreadedExecutor(context=context)
    node_executor.add_node(node)
    peer_executor.add_node(peer)
    make = msg_adapters.rclpy_factory()
    try:
        player = play_bag.BagPlayer(peer, play_bag.read_messages(bag, 0.0, seconds, config_path))
        listener = play_bag.PathListener(peer)
        velocities: list = []
        currents: list = []
        peer.create_subscription(make("trajectory_msgs/msg/MultiDOFJointTrajectory"), "predicted_velocities",
                                 velocities.append, 10)
        peer.create_subscription(make(outputs.CURRENT_TYPE), "estimated_current", currents.append, 10)
        spin_until(node_executor, lambda: peer.count_subscribers("imu/data") > 0
                   and peer.count_publishers("predicted_path") > 0
                   and peer.count_publishers("estimated_current") > 0, "discovery", also=peer_executor)

        def received() -> int:  # arrived at the node (kept as bytes; decoded in bulk at its next timer)
            return sum(node.arrived.values())

        # Header-less inputs (Float64, Float64MultiArray) are stamped by the node on arrival, as the recorder
        # stamped them: the clock must read their log time when they arrive. So the clock steps to each of their
        # stamps, then every message up to that stamp goes out (stamped ones carry their own time). A topic that
        # carries two roles (both thrusters) arrives once per role.
        fanout = {topic: sum(node._entries[role].topic == topic for role in node._entries)
                  for topic in {m.topic for m in player.messages}}
        ticks = sorted({m.log_time_ns for m in player.messages if m.ros_type in HEADERLESS_TYPES})
        for stamp in ticks:
            player.publish_clock(stamp)
            spin_until(node_executor, lambda: node.get_clock().now().nanoseconds == stamp, "the clock")
            before = received()
            due = sum(fanout[m.topic] for m in itertools.takewhile(lambda m: m.log_time_ns <= stamp,
                                                                    player.messages[player.cursor:]))
            player.publish_until(stamp)
            spin_until(node_executor, lambda: received() == before + due, "the messages", also=peer_executor)
        spin_until(peer_executor, lambda: len(velocities) >= node.published and len(currents) >= node.sea.fed,
                   "the last outputs")
        node._catch_up(node.get_clock().now().nanoseconds)  # decode what arrived after the last timer
    finally:
        node_executor.shutdown()
        peer_executor.shutdown()
        node.destroy_node()
        peer.destroy_node()
    return Lockstep(node, listener.paths, velocities, currents, player.published)


def recording_step(recording: Recording, stamp: int) -> int:
    """The Recording's step whose state the Path stamped `stamp` starts from (state_delay dt, t_c = end - dt/2)."""
    dt_ns = int(DT * NS)
    n = (stamp - dt_ns - dt_ns // 2 - recording.t0_ns) // dt_ns
    assert recording.t0_ns + n * dt_ns == stamp - dt_ns - dt_ns // 2
    return n


def check_every_message_taken(node: predictor_node.PredictorNode, paths: list, *, received: int,
                              min_paths: int) -> None:
    """A Path per prediction (at least min_paths), every message sent received by an input, none refused."""
    assert node.published >= min_paths
    assert len(paths) == node.published
    assert sum(track.received for track in node.inputs.tracks.values()) == received
    assert all(not track.rejected for track in node.inputs.tracks.values())


def check_equal_to_replay(node: predictor_node.PredictorNode, recording, paths: list, velocities: list,
                          horizon_steps: int, yaw_atol: float = 1e-6, nu_atol: float = 1e-6) -> None:
    """Every Path (and its velocities) equals the artifact's prediction on the Recording's state at the same time,
    controls held, anchored at the Recording's position: what `replay evaluate` predicts for the bag."""
    artifact = node.rollout.artifact
    dt_ns = int(DT * NS)
    first_n = []
    for (stamp, t_ns, eta, frame), trajectory in zip(paths, velocities, strict=True):
        n = recording_step(recording, stamp)
        first_n.append(n)
        controls = np.repeat(recording.controls[n:n + 1, None], horizon_steps, axis=1)  # (1, H, C)
        reference = artifact.predict(recording.state()[n:n + 1], controls).mean(axis=0)[0]  # (H, 6)
        np.testing.assert_allclose(eta[:, :2], reference[:, 3:5] + recording.position[n], rtol=0, atol=1e-4)
        yaw_error = np.remainder(eta[:, 2] - reference[:, 5] + math.pi, 2 * math.pi) - math.pi
        np.testing.assert_allclose(yaw_error, 0.0, atol=yaw_atol)
        t_v, nu = decode_predicted_velocities(trajectory)
        np.testing.assert_allclose(nu, reference[:, :3], rtol=0, atol=nu_atol)
        expected_t = recording.t0_ns + (n + 1 + np.arange(horizon_steps)) * dt_ns
        assert np.array_equal(t_ns, expected_t)
        assert np.array_equal(t_v, expected_t)
        assert frame == "odom"
    assert first_n[0] == 0  # the first whole window, as the Recording's first step


def test_node_predictions_equal_replay_evaluate_on_the_recording(ros_context: Context) -> None:
    """The shipped DNN: the online estimator runs (on by default) but is not applied, so every Path is the plain
    prediction of `replay evaluate`; the estimate is still published."""
    recording = load_recordings([BAG], DT, jobs=1, warn=lambda _: None)[0]  # what `replay evaluate` reads
    run = lockstep(ros_context, BAG, recording, seconds=10.0)
    node = run.node
    check_every_message_taken(node, run.paths, received=run.sent, min_paths=16)
    assert not node.sea.applied
    assert node.sea.enabled
    assert len(run.currents) == node.sea.fed >= 16
    check_equal_to_replay(node, recording, run.paths, run.velocities, horizon_steps=120)


@pytest.fixture(scope="module")
def greybox_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The preset's calm-water grey box exported as a TorchScript artifact (what `replay identify` writes)."""
    predictor = greybox_predictor(load_vessel("jari_usv"), DT)
    path = tmp_path_factory.mktemp("greybox") / "greybox.pt"
    export_module(path, predictor.rollout, predictor.metadata)
    return path


def test_with_the_online_estimator_the_node_predicts_as_replay_evaluate_adaptive(ros_context: Context,
                                                                                greybox_model: Path) -> None:
    """A grey box with the estimator on: every Path equals `replay evaluate --adaptive`'s prediction from the same
    step (the estimate after that sample in the model's terms, analysis/adaptive.py), and every published current
    equals that estimate (ENU, its covariance)."""
    recording = load_recordings([BAG], DT, jobs=1, warn=lambda _: None)[0]
    run = lockstep(ros_context, BAG, recording, seconds=10.0, overrides=(
        Parameter("model_path", value=str(greybox_model)), Parameter("ensemble_size", value=1)))
    assert run.node.published >= 16
    assert len(run.paths) == run.node.published
    assert run.node.sea.applied
    assert run.node.sea.fed == len(run.currents) >= 16
    model = loading.load_model(str(greybox_model), dt=DT)  # as evaluate_bags loads it
    config = OnlineConfig(**load_predictor_config().online)  # as adaptive_section configures it
    evaluated = adaptive.adaptive_open_loop(model, recording, "gnss", (30.0,), 5.0, config)
    assert evaluated.applied
    estimates, original = evaluated.estimates, adaptive.model_terms(model)
    moved = 0.0
    for stamp, _, eta, _ in run.paths:
        n = recording_step(recording, stamp)
        state, controls = recording.state()[n:n + 1], np.repeat(recording.controls[n:n + 1, None], 120, axis=1)
        plain = model.predict(state, controls)[0, 0]  # (H, 6)
        with adaptive.per_start_terms(model, [adaptive.live_terms(estimates[n], original)]):
            reference = model.predict(state, controls)[0, 0]  # (H, 6)
        np.testing.assert_allclose(eta[:, :2], reference[:, 3:5] + recording.position[n], rtol=0, atol=1e-4)
        moved = max(moved, float(np.abs(reference[-1, 3:5] - plain[-1, 3:5]).max()))
    assert moved > 1.0, f"the estimate moves the 60 s prediction by {moved:.3f} m at most: the test would not see it"
    dt_ns = int(DT * NS)
    for msg in run.currents:
        stamp, current_ne, covariance = outputs.decode_current(msg)
        assert msg.header.frame_id == "odom"
        n, rest = divmod(stamp - recording.t0_ns, dt_ns)  # stamped with the sample's time, on the grid
        assert rest == 0
        expected = estimates[n]
        np.testing.assert_allclose(current_ne, expected.current_ne, rtol=0, atol=1e-9)
        p_nn, p_ne, p_ee = expected.current_cov
        np.testing.assert_allclose(covariance, [[p_nn, p_ne], [p_ne, p_ee]], rtol=1e-6, atol=1e-12)
    assert outputs.decode_current(run.currents[0])[0] == recording.t0_ns  # the first sample is the Recording's first


# ----------------------------------------------------------------------------- a twin-thruster boat

OTTER_BAG = REPO / "bags" / "otter" / "sea_trial" / "turning_circle_port_d0.4_p0.6"
OTTER_HORIZON_S = 10.0  # a short horizon: the grey box's RK4 in TorchScript is ~3 ms per step on CI
OTTER_SECONDS = 13.0  # s of the bag played: 10 s approach, then the turn


@pytest.fixture(scope="module")
def otter_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The otter preset's calm-water grey box as a model artifact (models/greybox + models/artifact)."""
    from usv_predictor.models.greybox import GreyBoxRollout, greybox_metadata

    vessel = load_vessel("otter")
    rollout = GreyBoxRollout(vessel, dt=DT)
    path = tmp_path_factory.mktemp("otter_model") / "otter_greybox.pt"
    export_module(path, rollout, greybox_metadata(vessel, rollout, horizon_steps=int(OTTER_HORIZON_S / DT)))
    return path


def otter_overrides(model: Path) -> tuple[Parameter, ...]:
    """The otter's model; the online estimator off (the plain prediction of `replay evaluate`; the adaptive one is
    test_with_the_online_estimator_the_node_predicts_as_replay_evaluate_adaptive's)."""
    return (Parameter("vessel", value="otter"), Parameter("model_path", value=str(model)),
            Parameter("horizon_s", value=OTTER_HORIZON_S), Parameter("ensemble_size", value=1),
            Parameter("online.enabled", value=False))


def test_twin_thruster_node_predictions_equal_replay_evaluate(ros_context: Context, otter_model: Path) -> None:
    """The otter (twin_thrusters) bag with its thrusters on two Float64 topics (normalised commands): the node
    subscribes to the layout's roles only (the config's rudder, engine and throttle topics are ignored and said
    so), and its Paths equal the grey box's prediction on the Recording `replay evaluate` builds from the bag."""
    layout = load_vessel("otter").actuator_layout
    recording = load_recordings([OTTER_BAG], DT, jobs=1, warn=lambda _: None, layout=layout)[0]
    node, paths, velocities, _, sent = lockstep(ros_context, OTTER_BAG, recording, seconds=OTTER_SECONDS,
                                                overrides=otter_overrides(otter_model))
    assert sorted(node.inputs.tracks) == ["gnss", "heading", "imu", "thruster_port", "thruster_starboard", "velocity"]
    assert sorted(node.ignored) == ["engine_rpm", "rudder_angle", "throttle"]
    check_every_message_taken(node, paths, received=sent, min_paths=20)
    steps = int(OTTER_SECONDS / DT) - 2
    assert np.ptp(recording.controls[:steps, 0] - recording.controls[:steps, 1]) > 0.3  # straight, then the turn
    check_equal_to_replay(node, recording, paths, velocities, horizon_steps=int(OTTER_HORIZON_S / DT))


PWM_THRUSTERS = {  # both thrusters in one std_msgs/Float64MultiArray, PWM in us (1500 neutral, 500 us to full)
    "thruster_port": {"topic": "thrusters/pwm", "type": "std_msgs/msg/Float64MultiArray", "index": 0,
                      "units": "pwm", "neutral": 1500.0, "full_scale": 500.0, "max_age_s": 1.0},
    "thruster_starboard": {"topic": "thrusters/pwm", "type": "std_msgs/msg/Float64MultiArray", "index": 1,
                           "units": "pwm", "neutral": 1500.0, "full_scale": 500.0, "max_age_s": 1.0},
}


def test_twin_thrusters_on_one_pwm_topic_equal_replay_evaluate(ros_context: Context, otter_model: Path,
                                                               tmp_path: Path) -> None:
    """The same otter run rewritten with both thrusters as PWM in one Float64MultiArray (bagio.write_bag through
    the adapters), read by `replay evaluate` and played to the node with one configuration: equal predictions."""
    import yaml

    from usv_predictor.records import Signal
    from usv_predictor.replay.bagio import config_topic_specs, read_signals, write_bag

    params = yaml.safe_load(Path(load_predictor_config().source).read_text(encoding="utf-8"))
    inner = params["predictor"]["ros__parameters"]
    inner.update(vessel="otter", model_path=str(otter_model), horizon_s=OTTER_HORIZON_S, ensemble_size=1)
    inner["inputs"].update(PWM_THRUSTERS)
    inner["online"]["enabled"] = False  # the plain prediction, as otter_overrides
    for role in ("rudder_angle", "engine_rpm", "throttle"):
        del inner["inputs"][role]
    config = tmp_path / "otter_pwm.yaml"
    config.write_text(yaml.safe_dump(params), encoding="utf-8")

    layout = load_vessel("otter").actuator_layout
    source = config_topic_specs(load_predictor_config())
    target = config_topic_specs(load_predictor_config(config))
    roles = ["imu", "velocity", "heading", "gnss", "thruster_port", "thruster_starboard"]
    signals = read_signals(OTTER_BAG, [source[role] for role in roles])
    end_ns = int(signals[0].t_ns[0]) + int((OTTER_SECONDS + 2.0) * NS)
    cut = [Signal(s.t_ns[s.t_ns <= end_ns], s.values[s.t_ns <= end_ns], s.fields) for s in signals]
    bag = write_bag(tmp_path / "otter_pwm", [(target[role], signal) for role, signal in zip(roles, cut)])

    recording = load_recordings([bag], DT, config_path=config, jobs=1, warn=lambda _: None, layout=layout)[0]
    reference = load_recordings([OTTER_BAG], DT, jobs=1, warn=lambda _: None, layout=layout)[0]
    n = len(recording.controls)
    np.testing.assert_allclose(recording.controls, reference.controls[:n], rtol=0, atol=1e-9)  # PWM decodes back
    node, paths, velocities, _, sent = lockstep(ros_context, bag, recording, seconds=OTTER_SECONDS,
                                                config_path=config)
    assert node._entries["thruster_port"].topic == node._entries["thruster_starboard"].topic == "thrusters/pwm"
    assert node.ignored == {}
    assert node.arrived["thruster_port"] == node.arrived["thruster_starboard"] > 0  # one message, both roles
    check_every_message_taken(node, paths, received=sent + node.arrived["thruster_port"], min_paths=20)
    check_equal_to_replay(node, recording, paths, velocities, horizon_steps=int(OTTER_HORIZON_S / DT))


def node_environment(offset: int) -> dict[str, str]:
    return localhost_env(offset)


def play_to(command: list[str], env: dict[str, str], seconds: float, rate: float,
            start_up_s: float = 60.0) -> play_bag.PathListener:
    """Start the node process, play `seconds` of the bag to it at `rate` x real time, return what it published;
    the node must come up (publish and subscribe) within start_up_s."""
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    context = Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    peer = Node("bag_player", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(peer)
    try:
        player = play_bag.BagPlayer(peer, play_bag.read_messages(BAG, 30.0, seconds))
        listener = play_bag.PathListener(peer)
        deadline = time.monotonic() + start_up_s  # the node's start-up (torch import, model load) and discovery
        while peer.count_publishers("predicted_path") == 0 or peer.count_subscribers("imu/data") == 0:
            assert process.poll() is None, f"the node exited: {process.communicate()[1][-2000:]}"
            assert time.monotonic() < deadline, f"the node did not come up within {start_up_s:.0f} s"
            executor.spin_once(timeout_sec=0.05)
        play_bag.play(player, executor, rate)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        return listener
    finally:
        executor.shutdown()
        peer.destroy_node()
        rclpy.try_shutdown(context=context)
        process.terminate()
        try:
            process.wait(timeout=15)
        except subprocess.TimeoutExpired:
            process.kill()


def check_paths(listener: play_bag.PathListener, rate_hz: float, seconds: float) -> None:
    paths = listener.paths
    assert len(paths) >= 0.6 * rate_hz * seconds, listener.summary()
    stamps = np.array([p[0] for p in paths])
    spacing = np.diff(stamps) / NS
    assert np.median(spacing) == pytest.approx(1.0 / rate_hz, abs=0.011)  # at rate_hz in sim time (10 ms clock)
    for stamp, t_ns, eta, frame in paths:
        assert frame == "odom"
        assert len(t_ns) == 120
        assert eta.shape == (120, 3)
        assert np.all(np.diff(t_ns) == int(DT * NS)) and t_ns[0] > stamp - int(DT * NS)  # future poses
        assert t_ns[-1] - stamp >= 59 * NS
        assert np.all(np.isfinite(eta))


def test_across_processes_paths_arrive_at_rate_hz(tmp_path: Path) -> None:
    command = [sys.executable, "-m", "usv_predictor.node", "--ros-args", "-p", "use_sim_time:=true",
               "-p", "rate_hz:=5.0"]
    listener = play_to(command, node_environment(1), seconds=6.0, rate=2.0)
    check_paths(listener, rate_hz=5.0, seconds=6.0)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from test_package_layout import installed as build  # the colcon build of the layout test

    return build.__wrapped__(tmp_path_factory)


def test_installed_executable_publishes_a_path_with_the_default_model(installed: Path) -> None:
    from test_package_layout import installed_env

    executable = installed / "lib" / "usv_predictor" / "predictor"
    env = {**installed_env(installed), "ROS_DOMAIN_ID": str(domain_id(2))}  # (ros_helpers.domain_id)
    # the installed copy's kernel is another source file to numba, whose cache is keyed by the file: this first run
    # compiles it (the warm-up, docs/kernel.md: ~36 s alone on 2 cores, longer beside the other tests), then comes up
    listener = play_to([str(executable), "--ros-args", "-p", "use_sim_time:=true"], env, seconds=4.0, rate=1.0,
                       start_up_s=180.0)
    check_paths(listener, rate_hz=10.0, seconds=4.0)


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_the_node_process_stops_on_a_signal(signal_name: str) -> None:
    """main() spins the EventsExecutor in a spin_once loop that reads the stop flag of its own SIGINT/SIGTERM
    handlers (docs/node.md): it stops within SPIN_PERIOD_S of the signal, exit 130 after SIGINT and 143 after
    SIGTERM (usv_predictor.node.EXIT_CODES), no traceback. (The
    executor's own spin() never returns on a shutdown in rclpy 7.1.5; the slow test of test_node_smoke.py
    stops a node that publishes at 100 Hz 8 times.)"""
    import signal

    env = node_environment(4)
    process = subprocess.Popen([sys.executable, "-m", "usv_predictor.node"], env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    context = Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    peer = Node("signal_peer", context=context)
    try:
        deadline = time.monotonic() + 60.0
        while peer.count_publishers("predicted_path") == 0:  # up and spinning
            assert process.poll() is None, process.communicate()[1][-2000:]
            assert time.monotonic() < deadline, "the node did not come up within 60 s"
            time.sleep(0.1)
        time.sleep(0.5)
        process.send_signal(getattr(signal, signal_name))
        try:
            process.wait(timeout=10.0)
        except subprocess.TimeoutExpired:
            process.kill()
            pytest.fail(f"the node ignored {signal_name} for 10 s")
        err = process.communicate()[1]
        assert process.returncode == {"SIGINT": 130, "SIGTERM": 143}[signal_name], err[-2000:]
        assert "Traceback" not in err, err[-2000:]
        assert "RCLError" not in err, err[-2000:]
    finally:
        peer.destroy_node()
        rclpy.try_shutdown(context=context)
        if process.poll() is None:
            process.kill()


# ----------------------------------------------------------------------------- a rudder boat without rpm

RUDDER_THROTTLE = "jari_rudder_throttle"  # jari_usv as rudder_throttle (test_norpm_pipeline.write_vessel)


@pytest.fixture(scope="module")
def rudder_throttle_presets(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    """(preset directory, bag, grey box): the node's `vessel` is a preset name, so the jari_usv variant sits in a
    copy of config/vessels (the tests point physics.vessel.vessel_dir at it); a turning circle of it (10 s approach,
    throttle 0.6, 20 deg) simulated from its file; its calm-water grey box exported."""
    import shutil

    from test_norpm_pipeline import write_vessel

    from usv_predictor.models.greybox import GreyBoxRollout, greybox_metadata
    from usv_predictor.physics.vessel import vessel_dir
    from usv_predictor.replay.simulate import SimulationRequest, simulate

    root = tmp_path_factory.mktemp("rudder_throttle")
    presets = root / "vessels"
    shutil.copytree(vessel_dir(), presets)
    vessel_file = write_vessel(presets, "rudder_throttle")
    assert vessel_file.stem == RUDDER_THROTTLE
    vessel = load_vessel(vessel_file)
    summary = simulate(SimulationRequest(output=root / "bags", vessel=vessel, vessel_label=str(vessel_file),
                                         manoeuvre="turning-circle", rudder_deg=20.0, throttle=0.6, duration_s=20.0,
                                         dt=0.1))
    rollout = GreyBoxRollout(vessel, dt=DT)
    model = root / "rudder_throttle_greybox.pt"
    export_module(model, rollout, greybox_metadata(vessel, rollout, horizon_steps=int(OTTER_HORIZON_S / DT)))
    return presets, Path(summary["bags"][0]["bag"]), model


def test_rudder_throttle_node_predictions_equal_replay_evaluate(ros_context: Context, rudder_throttle_presets,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A rudder boat that logs its throttle command, not its rpm: the node subscribes to rudder and throttle only
    (engine_rpm and the thrusters are ignored and said so), and its Paths equal the grey box's prediction (the
    throttle through the motor lag and the thrust map) on the Recording `replay evaluate` builds from the bag."""
    from usv_predictor.physics import vessel as vessel_module

    presets, bag, model = rudder_throttle_presets
    monkeypatch.setattr(vessel_module, "vessel_dir", lambda: presets)
    layout = load_vessel(RUDDER_THROTTLE).actuator_layout
    assert layout.name == "rudder_throttle"
    recording = load_recordings([bag], DT, jobs=1, warn=lambda _: None, layout=layout)[0]
    overrides = (Parameter("vessel", value=RUDDER_THROTTLE), Parameter("model_path", value=str(model)),
                 Parameter("horizon_s", value=OTTER_HORIZON_S), Parameter("ensemble_size", value=1),
                 Parameter("online.enabled", value=False))
    node, paths, velocities, _, sent = lockstep(ros_context, bag, recording, seconds=OTTER_SECONDS,
                                                overrides=overrides)
    assert sorted(node.inputs.tracks) == ["gnss", "heading", "imu", "rudder_angle", "throttle", "velocity"]
    assert sorted(node.ignored) == ["engine_rpm", "thruster_port", "thruster_starboard"]
    check_every_message_taken(node, paths, received=sent, min_paths=20)
    steps = int(OTTER_SECONDS / DT) - 2
    assert np.ptp(recording.controls[:steps, 0]) > math.radians(15.0)  # straight, then the rudder over
    assert np.median(recording.controls[:steps, 1]) == pytest.approx(0.6, abs=0.01)  # the throttle column
    check_equal_to_replay(node, recording, paths, velocities, horizon_steps=int(OTTER_HORIZON_S / DT))

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


class Lockstep(NamedTuple):
    """What a lock-step run published: Paths, velocities, estimated currents (rclpy messages), and the node."""

    node: predictor_node.PredictorNode
    player: play_bag.BagPlayer
    listener: play_bag.PathListener
    velocities: list
    currents: list


def lockstep(ros_context: Context, recording: Recording, *parameters: Parameter) -> Lockstep:
    """The first 10 s of BAG through DDS in lock-step: each state window on the Recording's grid (rate 2 Hz,
    state_delay dt), so the node's cycle k assembles the Recording's state k."""
    node = predictor_node.PredictorNode(context=ros_context, parameter_overrides=[
        Parameter("use_sim_time", value=True), Parameter("rate_hz", value=2.0),
        # windows end on whole half-seconds of the bag, like the Recording's (t0 = first stamp + dt/2)
        Parameter("state_delay_s", value=DT),
        Parameter("datum_lat_deg", value=recording.datum[0]), Parameter("datum_lon_deg", value=recording.datum[1]),
        *parameters,
    ])
    peer = Node("lockstep_player", context=ros_context)
    node_executor, peer_executor = SingleThreadedExecutor(context=ros_context), SingleThreadedExecutor(context=ros_context)
    node_executor.add_node(node)
    peer_executor.add_node(peer)
    make = msg_adapters.rclpy_factory()
    try:
        player = play_bag.BagPlayer(peer, play_bag.read_messages(BAG, 0.0, 10.0))
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

        # Header-less inputs (Float64) are stamped by the node on arrival, as the recorder stamped them: the
        # clock must read their log time when they arrive. So the clock steps to each of their stamps, then
        # every message up to that stamp goes out (stamped ones carry their own time).
        headerless = {"heading", "rudder_angle", "engine_rpm"}
        ticks = sorted({m.log_time_ns for m in player.messages if m.topic in headerless})
        for stamp in ticks:
            player.publish_clock(stamp)
            spin_until(node_executor, lambda: node.get_clock().now().nanoseconds == stamp, "the clock")
            before = received()
            sent = player.publish_until(stamp)
            spin_until(node_executor, lambda: received() == before + sent, "the messages", also=peer_executor)
        spin_until(peer_executor, lambda: len(velocities) >= node.published and len(currents) >= node.sea.fed,
                   "the last outputs")
        node._catch_up(node.get_clock().now().nanoseconds)  # decode what arrived after the last timer
    finally:
        node_executor.shutdown()
        peer_executor.shutdown()
        node.destroy_node()
        peer.destroy_node()
    assert node.published >= 16 and len(listener.paths) == node.published
    assert sum(track.received for track in node.inputs.tracks.values()) == player.published
    assert all(not track.rejected for track in node.inputs.tracks.values())
    return Lockstep(node, player, listener, velocities, currents)


def recording_step(recording: Recording, stamp: int) -> int:
    """The Recording's step whose state the Path stamped `stamp` starts from (state_delay dt, t_c = end - dt/2)."""
    dt_ns = int(DT * NS)
    n = (stamp - dt_ns - dt_ns // 2 - recording.t0_ns) // dt_ns
    assert recording.t0_ns + n * dt_ns == stamp - dt_ns - dt_ns // 2
    return n


def test_node_predictions_equal_replay_evaluate_on_the_recording(ros_context: Context) -> None:
    """The shipped DNN: the online estimator runs (on by default) but is not applied, so every Path is the plain
    prediction of `replay evaluate`; the estimate is still published."""
    recording = load_recordings([BAG], DT, jobs=1, warn=lambda _: None)[0]  # what `replay evaluate` reads
    run = lockstep(ros_context, recording)
    artifact = run.node.rollout.artifact
    assert not run.node.sea.applied and run.node.sea.enabled and len(run.currents) == run.node.sea.fed >= 16
    dt_ns = int(DT * NS)
    first_n = []
    for (stamp, t_ns, eta, frame), trajectory in zip(run.listener.paths, run.velocities, strict=True):
        n = recording_step(recording, stamp)
        first_n.append(n)
        controls = np.repeat(recording.controls[n:n + 1, None], 120, axis=1)
        reference = artifact.predict(recording.state()[n:n + 1], controls).mean(axis=0)[0]  # (H, 6)
        np.testing.assert_allclose(eta[:, :2], reference[:, 3:5] + recording.position[n], rtol=0, atol=1e-4)
        yaw_error = np.remainder(eta[:, 2] - reference[:, 5] + math.pi, 2 * math.pi) - math.pi
        np.testing.assert_allclose(yaw_error, 0.0, atol=1e-6)
        t_v, nu = decode_predicted_velocities(trajectory)
        np.testing.assert_allclose(nu, reference[:, :3], rtol=0, atol=1e-6)
        expected_t = recording.t0_ns + (n + 1 + np.arange(120)) * dt_ns
        assert np.array_equal(t_ns, expected_t) and np.array_equal(t_v, expected_t)
        assert frame == "odom"
    assert first_n[0] == 0  # the first whole window, as the Recording's first step


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
    run = lockstep(ros_context, recording, Parameter("model_path", value=str(greybox_model)),
                   Parameter("ensemble_size", value=1))
    assert run.node.sea.applied and run.node.sea.fed == len(run.currents) >= 16
    model = loading.load_model(str(greybox_model), dt=DT)  # as evaluate_bags loads it
    config = OnlineConfig(**load_predictor_config().online)  # as adaptive_section configures it
    evaluated = adaptive.adaptive_open_loop(model, recording, "gnss", (30.0,), 5.0, config)
    assert evaluated.applied
    estimates, original = evaluated.estimates, adaptive.model_terms(model)
    moved = 0.0
    for stamp, _, eta, _ in run.listener.paths:
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


def node_environment(offset: int) -> dict[str, str]:
    return localhost_env(offset)


def play_to(command: list[str], env: dict[str, str], seconds: float, rate: float) -> play_bag.PathListener:
    """Start the node process, play `seconds` of the bag to it at `rate` x real time, return what it published."""
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    context = Context()
    rclpy.init(context=context, domain_id=int(env["ROS_DOMAIN_ID"]))
    peer = Node("bag_player", context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(peer)
    try:
        player = play_bag.BagPlayer(peer, play_bag.read_messages(BAG, 30.0, seconds))
        listener = play_bag.PathListener(peer)
        deadline = time.monotonic() + 60.0  # the node's start-up (torch import, model load) and discovery
        while peer.count_publishers("predicted_path") == 0 or peer.count_subscribers("imu/data") == 0:
            assert process.poll() is None, f"the node exited: {process.communicate()[1][-2000:]}"
            assert time.monotonic() < deadline, "the node did not come up within 60 s"
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
        assert frame == "odom" and len(t_ns) == 120 and eta.shape == (120, 3)
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
    listener = play_to([str(executable), "--ros-args", "-p", "use_sim_time:=true"], env, seconds=4.0, rate=1.0)
    check_paths(listener, rate_hz=10.0, seconds=4.0)


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_the_node_process_stops_on_a_signal(signal_name: str) -> None:
    """main() spins the EventsExecutor in a spin_once loop that reads the stop flag of its own SIGINT/SIGTERM
    handlers (docs/node.md): it stops within SPIN_PERIOD_S of the signal, exit 0 (EXIT_OK), no traceback. (The
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
        assert process.returncode == predictor_node.EXIT_OK == 0, err[-2000:]
        assert "Traceback" not in err and "RCLError" not in err, err[-2000:]
    finally:
        peer.destroy_node()
        rclpy.try_shutdown(context=context)
        if process.poll() is None:
            process.kill()

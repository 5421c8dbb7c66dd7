"""The node over DDS: plans and candidate plans, diagnostics at their own rate, inputs decoded in bulk.

Each test feeds the node from a peer (ros_helpers.Harness: pid-derived ROS_DOMAIN_ID, localhost discovery) and
checks what comes back on predicted_path, candidate_predictions and /diagnostics.
"""
from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from msg_adapters.outputs import decode_path
from usv_predictor.config import load_predictor_config
from usv_predictor.frames import enu_yaw_to_heading, quaternion_to_yaw
from usv_predictor.errors import ConfigError
from usv_predictor.node import node as predictor_node
from usv_predictor.node import plans

from ros_helpers import GOOD, WAIT_S, Harness, level, statuses, values_of

NS = 1_000_000_000
HORIZON_STEPS = 20  # 10 s at dt 0.5 s


@pytest.fixture()
def harness(ros_context: Context, request: pytest.FixtureRequest) -> Iterator[Harness]:
    extra = list(getattr(request, "param", ()))  # more parameters (indirect parametrisation)
    fixture = Harness(ros_context, [Parameter("rate_hz", value=20.0), Parameter("horizon_s", value=10.0),
                                    Parameter("plan_max_age_s", value=2.0), *extra], peer_name="plan_peer")
    try:
        yield fixture
    finally:
        fixture.close()


def stamp_of(msg: Any) -> int:
    return msg.header.stamp.sec * NS + msg.header.stamp.nanosec


def joint_trajectory(harness: Harness, names: list[str], positions: np.ndarray, times_s: list[float],
                     stamp_ns: int) -> Any:
    msg = harness.make("trajectory_msgs/msg/JointTrajectory")()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_ns), NS)
    msg.joint_names = names
    point = harness.make("trajectory_msgs/msg/JointTrajectoryPoint")
    duration = harness.make("builtin_interfaces/msg/Duration")
    msg.points = [point(positions=[float(x) for x in row],
                        time_from_start=duration(sec=int(t), nanosec=int(t % 1 * NS)))
                  for row, t in zip(np.atleast_2d(positions), times_s)]
    return msg


def publisher(harness: Harness, topic: str) -> Any:
    """The peer's publisher on `topic`, returned once the node's subscription has matched it: a message published
    before discovery has matched the two is dropped (reliable, volatile QoS), and the test would wait for nothing."""
    if topic not in harness.publishers:
        created = harness.peer.create_publisher(harness.make("trajectory_msgs/msg/JointTrajectory"), topic, 10)
        wait_for(harness, lambda: created.get_subscription_count() > 0, f"the node to subscribe to {topic!r}")
        harness.publishers[topic] = created
    return harness.publishers[topic]


def now_ns(harness: Harness) -> int:
    return harness.peer.get_clock().now().nanoseconds


def wait_for(harness: Harness, condition: Any, what: str) -> None:
    deadline = time.monotonic() + WAIT_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        harness.feed()
        harness.executor.spin_once(timeout_sec=0.01)


def turn(path: Any) -> float:
    """Heading change over the predicted path (rad, clockwise +)."""
    heading = np.unwrap(decode_path(path)[1][:, 2])
    return float(heading[-1] - heading[0])


def test_a_plan_is_predicted_under_and_its_stamp_tags_the_outputs(harness: Harness) -> None:
    velocities: list[Any] = []
    harness.peer.create_subscription(harness.make("trajectory_msgs/msg/MultiDOFJointTrajectory"),
                                     "predicted_velocities", velocities.append, 10)
    harness.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, harness.feed)
    held = harness.paths[-1]
    stamp = now_ns(harness)
    plan = joint_trajectory(harness, ["rpm", "delta"], np.array([[650.0, 0.45], [650.0, 0.45]]), [0.0, 30.0], stamp)
    publisher(harness, "plan").publish(plan)
    wait_for(harness, lambda: any(stamp_of(p) == stamp for p in harness.paths), "a Path tagged with the plan's stamp")
    wait_for(harness, lambda: any(stamp_of(v) == stamp for v in velocities), "a trajectory tagged with the stamp")
    tagged = [p for p in harness.paths if stamp_of(p) == stamp][-1]
    # GOOD holds 0.1 rad of starboard rudder; the plan 0.45 rad from its stamp on: a tighter turn to starboard
    assert turn(tagged) - turn(held) > 0.3
    t_ns, _ = decode_path(tagged)
    assert len(t_ns) == HORIZON_STEPS
    assert np.all(np.diff(t_ns) == NS // 2)
    found = harness.spin_until(lambda s: level(s["plan"]) == predictor_node.OK
                               and "under the plan" in s["plan"].message)
    assert plans.describe_stamp(stamp) in found["plan"].message
    assert values_of(found["prediction"])["controls"] == f"plan stamped {plans.describe_stamp(stamp)}"
    assert values_of(found["plan"])["received"] == "1"
    assert values_of(found["plan"])["refused"] == "0"


def test_malformed_and_stale_plans_are_refused_and_the_commands_held(harness: Harness) -> None:
    harness.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, harness.feed)
    good = now_ns(harness)
    publisher(harness,
              "plan").publish(joint_trajectory(harness, ["delta", "rpm"], np.array([[0.3, 650.0]]), [0.0], good))
    wait_for(harness, lambda: any(stamp_of(p) == good for p in harness.paths), "the good plan followed")
    # a malformed plan replaces it: refused, and the node goes back to the held commands
    bad = now_ns(harness)
    publisher(harness,
              "plan").publish(joint_trajectory(harness, ["rudder", "rpm"], np.array([[0.3, 650.0]]), [0.0], bad))
    found = harness.spin_until(lambda s: "refused" in s["plan"].message, harness.feed)
    assert level(found["plan"]) == predictor_node.WARN
    assert "joint_names ['rudder', 'rpm']: expected the controls of the actuator layout" in found["plan"].message
    assert "current commands held" in found["plan"].message
    assert values_of(found["plan"])["refused_joints"] == "1"
    assert harness.node.following is None
    count = len(harness.paths)
    harness.spin(0.3, harness.feed)
    assert len(harness.paths) > count
    assert all(stamp_of(p) not in (good, bad) for p in harness.paths[count:])
    # a plan stamped longer ago than plan_max_age_s (2 s) is refused as stale
    old = now_ns(harness) - 3 * NS
    publisher(harness,
              "plan").publish(joint_trajectory(harness, ["delta", "rpm"], np.array([[0.3, 650.0]]), [0.0], old))
    found = harness.spin_until(lambda s: values_of(s["plan"]).get("refused_stale") == "1", harness.feed)
    assert "s old (limit plan_max_age_s 2 s)" in values_of(found["plan"])["last_refused"]
    # a followed plan that ages past the limit is dropped for the held commands
    fresh = now_ns(harness)
    publisher(harness,
              "plan").publish(joint_trajectory(harness, ["delta", "rpm"], np.array([[0.3, 650.0]]), [0.0], fresh))
    wait_for(harness, lambda: any(stamp_of(p) == fresh for p in harness.paths), "the fresh plan followed")
    found = harness.spin_until(lambda s: "is stale" in s["plan"].message, harness.feed)
    assert level(found["plan"]) == predictor_node.WARN
    assert plans.describe_stamp(fresh) in found["plan"].message
    assert values_of(found["prediction"])["controls"] == "held"
    harness.spin(0.2, harness.feed)  # what was in flight arrives
    count = len(harness.paths)
    harness.spin(0.3, harness.feed)
    assert len(harness.paths) > count
    assert all(stamp_of(p) != fresh for p in harness.paths[count:])


def candidates_message(harness: Harness, rudders: dict[str, float], stamp_ns: int) -> Any:
    names = [f"{name}/{control}" for name in rudders for control in ("delta", "rpm")]
    positions = np.array([[value for rudder in rudders.values() for value in (rudder, 650.0)]])
    return joint_trajectory(harness, names, positions, [0.0], stamp_ns)


@pytest.mark.parametrize("harness", [(), (Parameter("candidates_threads", value=2),
                                      Parameter("candidates_members", value=3))], indirect=True, ids=["default", "2x3"])
def test_candidate_plans_are_answered_in_one_batch_tagged_with_their_stamp(harness: Harness) -> None:
    """Also with the batch split across two threads (its first half on a helper: the turns stay in the candidates'
    order) and the mean of the first 3 members."""
    answers: list[Any] = []
    harness.peer.create_subscription(harness.make("trajectory_msgs/msg/MultiDOFJointTrajectory"),
                                     "candidate_predictions", answers.append, 10)
    harness.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, harness.feed)
    stamp = now_ns(harness)
    publisher(harness, "candidate_plans").publish(
        candidates_message(harness, {"hold": 0.1, "stbd": 0.5, "port": -0.5}, stamp))
    wait_for(harness, lambda: answers, "candidate_predictions")
    answer = answers[0]
    assert stamp_of(answer) == stamp
    assert answer.header.frame_id == "odom"
    assert list(answer.joint_names) == ["hold", "stbd", "port"]
    assert len(answer.points) == HORIZON_STEPS
    assert all(len(p.transforms) == 3 == len(p.velocities) for p in answer.points)
    t_ns = np.array([stamp + p.time_from_start.sec * NS + p.time_from_start.nanosec for p in answer.points])
    assert np.all(np.diff(t_ns) == NS // 2)
    assert t_ns[0] > stamp - NS // 2
    headings = np.array([[enu_yaw_to_heading(quaternion_to_yaw(q.x, q.y, q.z, q.w)) for q in
                          (tf.rotation for tf in p.transforms)] for p in answer.points])  # (H, 3)
    turn = np.unwrap(headings, axis=0)[-1] - np.unwrap(headings, axis=0)[0]
    assert turn[1] > turn[0] > turn[2]  # more starboard rudder turns the vessel further clockwise
    found = harness.spin_until(lambda s: values_of(s["candidate plans"]).get("answered") == "1")
    values = values_of(found["candidate plans"])
    assert level(found["candidate plans"]) == predictor_node.OK
    assert values["last_batch"] == "3"
    assert float(values["answer_ms_p50"]) > 0
    assert float(values["compute_ms_p50"]) > 0
    split = harness.node.get_parameter("candidates_threads").value == 2
    assert values["threads"] == ("2" if split else "1")
    assert values["members"] == ("3/5" if split else "5/5")


def test_more_candidate_members_than_the_node_uses_are_refused(ros_context: Context) -> None:
    with pytest.raises(ConfigError, match="candidates_members = 6: expected at most the 5 member"):
        predictor_node.PredictorNode(context=ros_context,
                                     parameter_overrides=[Parameter("candidates_members", value=6)])


def test_the_cycle_publishes_while_a_candidate_batch_is_computed(harness: Harness, monkeypatch) -> None:
    """The batched rollout of candidate plans runs on the node's candidates worker: while it runs (here held until
    the test releases it, 10 s at most) the 20 Hz cycle keeps publishing Paths; then the answer arrives, tagged.
    Run on the executor's thread, as before, the held rollout would have stopped every Path until it ended."""
    import threading

    answers: list[Any] = []
    harness.peer.create_subscription(harness.make("trajectory_msgs/msg/MultiDOFJointTrajectory"),
                                     "candidate_predictions", answers.append, 10)
    harness.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, harness.feed)
    entered, release = threading.Event(), threading.Event()
    during: list[int] = []
    original = predictor_node.live.predict_prepared

    def held(*args: Any) -> Any:
        count = len(harness.paths)
        entered.set()
        release.wait(10.0)
        during.append(len(harness.paths) - count)  # Paths received while the rollout was held
        return original(*args)

    monkeypatch.setattr(predictor_node.live, "predict_prepared", held)
    stamp = now_ns(harness)
    publisher(harness, "candidate_plans").publish(candidates_message(harness, {"a": 0.1, "b": -0.3}, stamp))
    wait_for(harness, entered.is_set, "the candidates' rollout to start")
    count = len(harness.paths)
    wait_for(harness, lambda: len(harness.paths) >= count + 3 or during, "Paths while the rollout is held")
    release.set()
    wait_for(harness, lambda: answers, "candidate_predictions")
    assert during, during
    assert during[0] >= 3, during
    assert stamp_of(answers[0]) == stamp
    assert list(answers[0].joint_names) == ["a", "b"]


def test_too_many_candidates_are_refused_and_nothing_is_answered(harness: Harness) -> None:
    answers: list[Any] = []
    harness.peer.create_subscription(harness.make("trajectory_msgs/msg/MultiDOFJointTrajectory"),
                                     "candidate_predictions", answers.append, 10)
    harness.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, harness.feed)
    many = {f"c{i}": 0.0 for i in range(plans.MAX_CANDIDATES + 1)}
    publisher(harness, "candidate_plans").publish(candidates_message(harness, many, now_ns(harness)))
    found = harness.spin_until(lambda s: "refused" in s["candidate plans"].message, harness.feed)
    assert level(found["candidate plans"]) == predictor_node.WARN
    assert "65 candidates, at most 64" in found["candidate plans"].message
    assert values_of(found["candidate plans"])["refused_too_many"] == "1"
    assert answers == []


def test_diagnostics_run_at_their_own_rate_of_1_hz_by_default(ros_context: Context) -> None:
    node = predictor_node.PredictorNode(context=ros_context, parameter_overrides=[Parameter("rate_hz", value=20.0)])
    peer = Node("rate_peer", context=ros_context)
    executor = SingleThreadedExecutor(context=ros_context)
    executor.add_node(node)
    executor.add_node(peer)
    reports: list[DiagnosticArray] = []
    peer.create_subscription(DiagnosticArray, "/diagnostics", reports.append, 10)
    try:
        deadline = time.monotonic() + WAIT_S
        while not reports:  # discovery, then the first report
            assert time.monotonic() < deadline, "no /diagnostics"
            executor.spin_once(timeout_sec=0.02)
        cycles, first = node.skipped, len(reports)
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.02)
        assert node.get_parameter("diagnostics_rate_hz").value == 1.0
        assert 2 <= len(reports) - first <= 4  # ~3 in 3 s
        assert node.skipped - cycles >= 30  # while the prediction timer ran at 20 Hz (no inputs: skipped)
    finally:
        executor.shutdown()
        node.destroy_node()
        peer.destroy_node()


def test_an_undecodable_message_is_counted_and_the_good_ones_kept(harness: Harness) -> None:
    harness.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, harness.feed)
    entry = harness.node.config.input("imu")
    garbage = harness.peer.create_publisher(harness.make(entry.ros_type), entry.topic, 10)
    sent = [0]

    def feed() -> None:  # the inputs, a truncated Imu every third time, and time to take them all (depth 5)
        harness.feed()
        if sent[0] % 3 == 0:
            garbage.publish(b"\x00\x01\x00\x00\x07\x00")
        sent[0] += 1
        for _ in range(8):
            harness.executor.spin_once(timeout_sec=0.0)

    found = harness.spin_until(lambda s: int(values_of(s["imu"])["decode_errors"]) >= 3, feed)
    values = values_of(found["imu"])
    assert "truncated" in values["last_decode_error"]
    assert "sensor_msgs/msg/Imu" in values["last_decode_error"]
    received, errors = harness.node.inputs.tracks["imu"].received, harness.node._failures["imu"].count
    deadline = time.monotonic() + WAIT_S  # the good ones between the bad ones: a count, not a rate (busy machine)
    while harness.node.inputs.tracks["imu"].received <= received + 10 or harness.node._failures["imu"].count <= errors:
        assert time.monotonic() < deadline, "the good IMU messages between the bad ones were not all decoded"
        harness.spin(0.1, feed)
    harness.spin(0.2, feed)  # a /diagnostics report after them
    assert harness.node._failures["imu"].count > int(values["decode_errors"])
    assert not harness.node.inputs.tracks["imu"].rejected
    assert level(statuses(harness.latest)["prediction"]) == predictor_node.OK


def test_a_joint_state_input_is_decoded_message_by_message(ros_context: Context, tmp_path: Path) -> None:
    """sensor_msgs/JointState has no fixed layout: the node decodes it with rclpy, one message at a time."""
    params = yaml.safe_load(Path(load_predictor_config().source).read_text(encoding="utf-8"))
    inner = params["predictor"]["ros__parameters"]
    inner["inputs"]["rudder_angle"] = {"topic": "joint_states", "type": "sensor_msgs/msg/JointState",
                                       "joint": "rudder_joint", "max_age_s": 0.5}
    path = tmp_path / "joint_state.yaml"
    path.write_text(yaml.safe_dump(params), encoding="utf-8")
    fixture = Harness(ros_context, [Parameter("rate_hz", value=20.0)], peer_name="joint_peer")
    fixture.node.destroy_node()  # rebuilt from the custom file
    fixture.executor.remove_node(fixture.node)
    fixture.node = predictor_node.PredictorNode(config_path=path, context=ros_context, parameter_overrides=[
        Parameter("rate_hz", value=20.0), Parameter("diagnostics_rate_hz", value=20.0)])
    fixture.executor.add_node(fixture.node)
    try:
        found = fixture.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK,
                                   lambda: fixture.feed(rudder_angle=(-0.2,)))
        assert float(values_of(found["rudder_angle"])["delta"]) == pytest.approx(-0.2)
        assert values_of(found["rudder_angle"])["decode_errors"] == "0"
        assert math.isfinite(GOOD["velocity"][0])
    finally:
        fixture.close()

"""Planned controls without ROS: JointTrajectory bytes -> Plan, its refusals, its schedule, predictions under it."""
from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

import msg_adapters
from msg_adapters.cdr import decode_joint_trajectory, decode_joint_trajectory_walk
from usv_predictor.config import package_share_path
from usv_predictor.errors import AdapterError, InputRejected
from usv_predictor.models.artifact import load_artifact
from usv_predictor.node import live, plans
from usv_predictor.physics.actuators import DEFAULT_LAYOUT

NS = 1_000_000_000
NOW = 1_700_000_000 * NS
LIMITS = plans.PlanLimits(max_age_s=1.0, max_future_s=0.5)
MAKE = msg_adapters.rclpy_factory()


def trajectory(names: list[str], positions: np.ndarray, times_s: list[float], stamp_ns: int = NOW,
               frame_id: str = "", velocities: bool = False) -> bytes:
    """CDR of a trajectory_msgs/JointTrajectory as rclpy serialises it (positions (P, J))."""
    msg = MAKE("trajectory_msgs/msg/JointTrajectory")()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS)
    msg.header.frame_id = frame_id
    msg.joint_names = names
    point_type, duration = MAKE("trajectory_msgs/msg/JointTrajectoryPoint"), MAKE("builtin_interfaces/msg/Duration")
    points = []
    for row, t in zip(positions, times_s):
        sec, nanosec = divmod(int(round(t * NS)), NS)
        points.append(point_type(positions=[float(x) for x in row], time_from_start=duration(sec=sec, nanosec=nanosec),
                                 velocities=[0.5] * len(row) if velocities else []))
    msg.points = points
    return serialize_message(msg)


def parse(raw: bytes, candidates: bool = False, now_ns: int = NOW) -> plans.Plan:
    return plans.parse_plan(decode_joint_trajectory(raw), DEFAULT_LAYOUT, now_ns, LIMITS, candidates=candidates)


# --- decoding -----------------------------------------------------------------------------------


@pytest.mark.parametrize("velocities", [False, True])
@pytest.mark.parametrize("frame", ["", "m", "map", "odom", "base_link_1"])
def test_joint_trajectory_decodes_like_rclpy_serialised_it(frame: str, velocities: bool) -> None:
    rng = np.random.default_rng(len(frame))
    names = ["delta", "rpm", "x" * (len(frame) % 3)]  # odd and even name lengths move the alignment
    positions = rng.normal(size=(7, 3))
    times = [0.0, 0.25, 0.5, 1.0, 2.0, 3.5, 61.0]
    data = decode_joint_trajectory(trajectory(names, positions, times, NOW + 17, frame, velocities))
    assert data.stamp_ns == NOW + 17
    assert data.frame_id == frame
    assert data.joint_names == tuple(names)
    np.testing.assert_array_equal(data.positions, positions)
    np.testing.assert_array_equal(data.time_from_start_ns, np.round(np.array(times) * NS).astype(np.int64))


def wire_bytes(raw: bytes) -> bytes:
    """The content of rclpy's serialisation, as DDS sends it (rclpy may append unused bytes: test_output_cdr.py)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    msg = deserialize_message(raw, MAKE("trajectory_msgs/msg/JointTrajectory"))
    points = [store.types["trajectory_msgs/msg/JointTrajectoryPoint"](
        positions=np.array(p.positions), velocities=np.array(p.velocities), accelerations=np.array(p.accelerations),
        effort=np.array(p.effort), time_from_start=store.types["builtin_interfaces/msg/Duration"](
            sec=p.time_from_start.sec, nanosec=p.time_from_start.nanosec)) for p in msg.points]
    header = store.types["std_msgs/msg/Header"](stamp=store.types["builtin_interfaces/msg/Time"](
        sec=msg.header.stamp.sec, nanosec=msg.header.stamp.nanosec), frame_id=msg.header.frame_id)
    out = store.types["trajectory_msgs/msg/JointTrajectory"](header=header, joint_names=list(msg.joint_names),
                                                             points=points)
    return bytes(store.serialize_cdr(out, "trajectory_msgs/msg/JointTrajectory"))


def test_malformed_trajectory_bytes_are_adapter_errors_naming_the_field() -> None:
    raw = wire_bytes(trajectory(["delta", "rpm"], np.zeros((3, 2)), [0.0, 1.0, 2.0]))
    decode_joint_trajectory(raw)  # whole: fine
    with pytest.raises(AdapterError, match=r"truncated in points\[2\]"):
        decode_joint_trajectory(raw[:-1])
    with pytest.raises(AdapterError, match="not a little-endian CDR message"):
        decode_joint_trajectory(b"\x00\x00\x00\x00" + raw[4:])
    uneven = trajectory(["delta", "rpm"], np.zeros((1, 3)), [0.0])  # 3 positions for 2 joints
    with pytest.raises(AdapterError, match=r"points\[0\] has 3 positions for 2 joint names"):
        decode_joint_trajectory(uneven)
    huge = bytearray(raw)
    struct.pack_into("<I", huge, 4 + 8 + 4 + 4, 10**9)  # the joint_names count (after stamp, frame_id "\0" + pad)
    with pytest.raises(AdapterError, match="joint names, more than"):
        decode_joint_trajectory(bytes(huge))


def random_trajectory(rng: np.random.Generator, joints: int, points: int, irregular: bool) -> Any:
    """A JointTrajectory message (rclpy) of `points` points with one position per joint; the other sequences of
    one length for all points (0-3), or (irregular) a random length for some points; frame and names of random
    lengths (they move the alignment of everything after them)."""
    msg = MAKE("trajectory_msgs/msg/JointTrajectory")()
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(rng.integers(-2**31, 2**31)), int(rng.integers(0, NS))
    msg.header.frame_id = "f" * int(rng.integers(0, 9))
    msg.joint_names = [f"j{j}" + "x" * int(rng.integers(0, 4)) for j in range(joints)]
    point_type, duration = MAKE("trajectory_msgs/msg/JointTrajectoryPoint"), MAKE("builtin_interfaces/msg/Duration")
    lengths = rng.integers(0, 4, 3)
    out = []
    for _k in range(points):
        own = rng.integers(0, 4, 3) if irregular and rng.random() < 0.3 else lengths
        out.append(point_type(positions=rng.normal(size=joints).tolist(),
                              velocities=rng.normal(size=int(own[0])).tolist(),
                              accelerations=rng.normal(size=int(own[1])).tolist(),
                              effort=rng.normal(size=int(own[2])).tolist(),
                              time_from_start=duration(sec=int(rng.integers(-2**31, 2**31)),
                                                       nanosec=int(rng.integers(0, NS)))))
    msg.points = out
    return msg


def decoded_or_error(decode: Any, raw: bytes) -> Any:
    try:
        data = decode(raw)
    except AdapterError as err:
        return str(err)
    return (data.stamp_ns, data.frame_id, data.joint_names, data.time_from_start_ns.tobytes(), data.positions.shape,
            data.positions.tobytes())


@pytest.mark.parametrize("irregular", [False, True])
@pytest.mark.parametrize("joints", [0, 1, 2, 3, 128])
def test_the_numpy_reading_of_the_points_equals_rclpy_and_the_walk(joints: int, irregular: bool) -> None:
    """decode_joint_trajectory reads points 2.. with numpy at point 1's offsets when the layout repeats; on random
    plans (0-120 points, 0-3 velocities, accelerations and effort per point, all alike or some not, names and
    frame of every alignment) it equals rclpy's deserialisation, and the point-by-point walk exactly."""
    rng = np.random.default_rng(joints * 2 + irregular)
    for case in range(12):
        msg = random_trajectory(rng, joints, [0, 1, 2, 3, 5, 120][case % 6], irregular)
        raw = wire_bytes(serialize_message(msg))
        data = decode_joint_trajectory(raw)
        assert decoded_or_error(decode_joint_trajectory, raw) == decoded_or_error(decode_joint_trajectory_walk, raw)
        assert data.stamp_ns == msg.header.stamp.sec * NS + msg.header.stamp.nanosec
        assert data.frame_id == msg.header.frame_id
        assert data.joint_names == tuple(msg.joint_names)
        expected = np.array([p.positions for p in msg.points], dtype=np.float64).reshape(len(msg.points), joints)
        np.testing.assert_array_equal(data.positions, expected)
        assert data.time_from_start_ns.tolist() == [p.time_from_start.sec * NS + p.time_from_start.nanosec
                                                    for p in msg.points]


@pytest.mark.parametrize("first", [(0, 0, 0), (1, 0, 0), (0, 1, 1), (2, 0, 1)])
@pytest.mark.parametrize("later", [(0, 0, 0), (1, 0, 0), (0, 0, 1)])
def test_a_first_point_unlike_the_others_moves_their_alignment_and_still_decodes(first: tuple[int, ...],
                                                                                later: tuple[int, ...]) -> None:
    """Point 0's sequence lengths set where point 1 starts within 8 bytes; unlike the later points' they can make
    point 1's size 4 bytes off a multiple of 8, so that point 2's padding differs from point 1's: then the points
    are walked. Every pairing of first-point and later-point lengths equals rclpy's values and the walk."""
    rng = np.random.default_rng(sum(first) * 7 + sum(later))
    for joints in (1, 2, 3):
        msg = random_trajectory(rng, joints, 6, irregular=False)
        for k, point in enumerate(msg.points):
            point.velocities, point.accelerations, point.effort = ([0.25] * n for n in (first if k == 0 else later))
        raw = wire_bytes(serialize_message(msg))
        found = decoded_or_error(decode_joint_trajectory, raw)
        assert found == decoded_or_error(decode_joint_trajectory_walk, raw)
        np.testing.assert_array_equal(decode_joint_trajectory(raw).positions, [p.positions for p in msg.points])


def test_malformed_plans_are_refused_by_the_numpy_reading_as_by_the_walk() -> None:
    """Truncated at every length, a sequence length or a byte overwritten anywhere, a later point with a position
    more or fewer: decode_joint_trajectory refuses with the walk's message (or both decode the same)."""
    rng = np.random.default_rng(13)
    outcomes = set()
    for joints, points in ((2, 6), (3, 5), (128, 4)):
        raw = wire_bytes(serialize_message(random_trajectory(rng, joints, points, irregular=False)))
        variants = [raw[:cut] for cut in range(len(raw) - 1, 0, -max(1, len(raw) // 300))]
        for _ in range(200):
            spoiled = bytearray(raw)
            at = int(rng.integers(4, len(raw) - 3)) & -4
            struct.pack_into("<I", spoiled, at, int(rng.choice([0, 1, joints - 1, joints + 1, 2**31, 255])))
            variants.append(bytes(spoiled))
        uneven = random_trajectory(rng, joints, points, irregular=False)
        uneven.points[-1].positions = uneven.points[-1].positions[:-1]  # the last point one position short
        variants.append(wire_bytes(serialize_message(uneven)))
        for variant in variants:
            found = decoded_or_error(decode_joint_trajectory, variant)
            assert found == decoded_or_error(decode_joint_trajectory_walk, variant)
            outcomes.add("refused" if isinstance(found, str) else "decoded")
    assert outcomes == {"refused", "decoded"}


# --- one plan ----------------------------------------------------------------------------------


def test_joint_names_in_any_order_map_to_the_layout_columns() -> None:
    plan = parse(trajectory(["rpm", "delta"], np.array([[700.0, 0.1], [800.0, 0.2]]), [0.0, 1.0]))
    assert plan.names == ("",)
    assert plan.stamp_ns == NOW
    np.testing.assert_array_equal(plan.controls[0], [[0.1, 700.0], [0.2, 800.0]])  # (P, C) in [delta, rpm]
    np.testing.assert_array_equal(plan.t_ns, [NOW, NOW + NS])


def test_schedule_holds_before_interpolates_between_and_holds_the_last_point() -> None:
    plan = parse(trajectory(["delta", "rpm"], np.array([[0.0, 600.0], [0.2, 800.0], [0.1, 800.0]]), [1.0, 2.0, 4.0]))
    grid = NOW + np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 9.0]) * NS
    held = np.array([-0.3, 500.0])
    out = plan.schedule(grid.astype(np.int64), held)
    expected = [[-0.3, 500.0], [-0.3, 500.0], [0.0, 600.0], [0.1, 700.0], [0.2, 800.0], [0.15, 800.0], [0.1, 800.0],
                [0.1, 800.0]]
    np.testing.assert_allclose(out[0], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize(("names", "positions", "times", "stamp", "kind", "message"), [
    (["delta", "rpm"], [[0.1, 700.0]], [0.0], 0, "stamp", "header.stamp is 0"),
    (["delta", "rpm"], [[0.1, 700.0]], [0.0], NOW - 2 * NS, "stale", "s old"),
    (["delta", "rpm"], [[0.1, 700.0]], [0.0], NOW + NS, "future", "ahead of the clock"),
    (["delta"], [[0.1]], [0.0], NOW, "joints", "expected the controls of the actuator layout"),
    (["delta", "rpm", "flaps"], [[0.1, 700.0, 0.0]], [0.0], NOW, "joints", "'delta', 'rpm'"),
    (["delta", "delta"], [[0.1, 0.1]], [0.0], NOW, "joints", "each once"),
    (["delta", "rpm"], np.zeros((0, 2)), [], NOW, "empty", "no points"),
    (["delta", "rpm"], [[0.1, 700.0], [0.1, 700.0]], [1.0, 1.0], NOW, "time", "strictly increasing"),
    (["delta", "rpm"], [[0.1, 700.0]], [-1.0], NOW, "time", ">= 0"),
    (["delta", "rpm"], [[math.nan, 700.0]], [0.0], NOW, "non_finite", "delta is nan at point 0"),
    (["delta", "rpm"], [[0.1, 700.0], [20.0, 700.0]], [0.0, 1.0], NOW, "range", "delta = 20 rad at point 1"),
])
def test_bad_plans_are_refused_with_the_kind_and_reason(names, positions, times, stamp, kind, message) -> None:
    raw = trajectory(names, np.asarray(positions, dtype=float).reshape(len(times), len(names)), times, stamp)
    with pytest.raises(InputRejected, match=message) as refused:
        parse(raw)
    assert refused.value.kind == kind


# --- candidates ----------------------------------------------------------------------------------


def candidate_names(candidates: list[str]) -> list[str]:
    return [f"{c}/{control}" for c in candidates for control in DEFAULT_LAYOUT.control_names]


def test_candidates_keep_their_order_and_names() -> None:
    names = ["b/rpm", "a/delta", "b/delta", "a/rpm", "x/y/delta", "x/y/rpm"]  # the candidate is before the last "/"
    positions = np.array([[800.0, 0.1, 0.2, 700.0, -0.1, 600.0]])
    plan = parse(trajectory(names, positions, [0.0]), candidates=True)
    assert plan.names == ("b", "a", "x/y")
    np.testing.assert_array_equal(plan.controls[:, 0], [[0.2, 800.0], [0.1, 700.0], [-0.1, 600.0]])


@pytest.mark.parametrize(("names", "kind", "message"), [
    (["a/delta"], "joints", r"joints \['a/rpm'\] missing"),
    (["delta", "rpm"], "joints", "joint name 'delta': expected '<candidate>/<control>'"),
    (["a/delta", "a/rpm", "a/delta"], "joints", "joint name 'a/delta'"),
    (["a/delta", "a/thrust"], "joints", "joint name 'a/thrust'"),
    (candidate_names([f"c{i}" for i in range(plans.MAX_CANDIDATES + 1)]), "too_many", "65 candidates, at most 64"),
])
def test_bad_candidate_names_are_refused(names: list[str], kind: str, message: str) -> None:
    raw = trajectory(names, np.full((1, len(names)), 0.1), [0.0])
    with pytest.raises(InputRejected, match=message) as refused:
        parse(raw, candidates=True)
    assert refused.value.kind == kind


# --- predictions under plans -------------------------------------------------------------------


@pytest.fixture(scope="module")
def rollout() -> live.Rollout:
    return live.Rollout(load_artifact(package_share_path("models", "default.pt")), horizon_steps=120)


def fed_inputs() -> live.InputSet:
    from test_live import feed_all, make_inputs  # the plausible 20 Hz inputs of the live tests

    inputs = make_inputs()
    feed_all(inputs, NOW - 5 * NS, 5.0)
    return inputs


def test_a_plan_of_the_held_commands_predicts_what_holding_them_predicts(rollout: live.Rollout) -> None:
    inputs = fed_inputs()
    held = live.predict(inputs, rollout, NOW)
    same = parse(trajectory(["delta", "rpm"], np.array([[0.1, 650.0]]), [0.0], NOW - NS // 2))
    planned = live.predict(inputs, rollout, NOW, same.schedule)
    np.testing.assert_array_equal(planned.eta, held.eta)
    np.testing.assert_array_equal(planned.nu, held.nu)


def test_a_plan_is_the_model_under_those_controls(rollout: live.Rollout) -> None:
    inputs = fed_inputs()
    raw = trajectory(["delta", "rpm"], np.array([[0.0, 600.0], [0.35, 900.0]]), [0.0, 10.0], NOW)
    plan = parse(raw)
    prediction = live.predict(inputs, rollout, NOW, plan.schedule)
    state = inputs.assemble(NOW)
    grid = state.t_c_ns + inputs.settings.dt_ns * np.arange(120)
    controls = plan.schedule(grid, state.controls)  # (1, H, C)
    assert np.array_equal(controls[0, 0], state.controls)  # t_c is before the plan's stamp: the held command
    reference = rollout.artifact.predict(state.state[None], controls).mean(axis=0)[0]  # (H, 6)
    np.testing.assert_allclose(prediction.nu, reference[:, :3], atol=1e-6)
    assert state.position is None  # no GNSS fed: the path starts at (0, 0)
    np.testing.assert_allclose(prediction.eta[:, :2], reference[:, 3:5], atol=1e-4)
    assert prediction.eta[-1, 2] - prediction.eta[0, 2] > 1.0  # 0.35 rad of starboard rudder: heading grows


def test_one_batched_call_equals_the_candidates_one_by_one(rollout: live.Rollout) -> None:
    inputs = fed_inputs()
    rudders = [0.1, 0.4, -0.4, 0.0]
    names = candidate_names(["hold", "stbd", "port", "zero"])
    positions = np.array([[value for rudder in rudders for value in (rudder, 650.0)]])
    batch = parse(trajectory(names, positions, [0.0], NOW - NS), candidates=True)
    result = live.predict_batch(inputs, rollout, NOW, batch.schedule)
    assert result.eta.shape == (4, 120, 3)
    assert result.nu.shape == (4, 120, 3)
    # float32 model: a batch of 4 sums in another order than a batch of 1 (~1e-4 m after 60 s of ~300 m)
    held = live.predict(inputs, rollout, NOW)
    np.testing.assert_allclose(result.eta[0], held.eta, atol=1e-3)  # "hold" is the held commands
    for i, rudder in enumerate(rudders):
        single = parse(trajectory(["delta", "rpm"], np.array([[rudder, 650.0]]), [0.0], NOW - NS))
        alone = live.predict(inputs, rollout, NOW, single.schedule)
        np.testing.assert_allclose(result.eta[i], alone.eta, atol=1e-3)
        np.testing.assert_allclose(result.nu[i], alone.nu, atol=1e-5)
    turn = result.eta[:, -1, 2] - result.eta[:, 0, 2]  # heading change over the horizon (rad, clockwise +)
    assert turn[1] > turn[0] > turn[3] > turn[2]  # more starboard rudder, more clockwise

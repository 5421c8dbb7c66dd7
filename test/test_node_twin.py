"""The `predictor` node on a twin-thruster boat (the otter preset, actuator layout twin_thrusters) over DDS.

Both thrusters as PWM in one std_msgs/Float64MultiArray (the Dalian USV's convention): one subscription, each
role's adapter reading its element; a bad message on the shared topic is counted for the roles it breaks and the
good ones are kept; a plan's joints are the layout's controls (port, starboard). The model is the preset's
calm-water grey box exported as an artifact. The equality with `replay evaluate` is in test_node_dds.py.
"""
from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rclpy.context import Context
from rclpy.parameter import Parameter
from test_node_plans import joint_trajectory, now_ns, publisher, stamp_of, wait_for

import msg_adapters
from msg_adapters.outputs import decode_path
from usv_predictor.config import load_predictor_config
from usv_predictor.node import node as predictor_node
from usv_predictor.node import plans

from ros_helpers import GOOD, Harness, level, statuses, values_of

HORIZON_S = 10.0  # s: 20 steps of the grey box
PWM = {"port": 1800.0, "starboard": 1700.0}  # us: c = (pwm - 1500) / 500 = 0.6 and 0.4 (a turn to starboard)
TOPIC = "thrusters/pwm"


@pytest.fixture(scope="module")
def otter_config(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """config/predictor.yaml for the otter: both thrusters as PWM on one topic, the grey box, the rudder and engine
    inputs removed (the throttle left: a control of another layout, ignored)."""
    from usv_predictor.models.artifact import export_module
    from usv_predictor.models.greybox import GreyBoxRollout, greybox_metadata
    from usv_predictor.physics.vessel import load_vessel

    folder = tmp_path_factory.mktemp("otter_node")
    vessel = load_vessel("otter")
    rollout = GreyBoxRollout(vessel, dt=0.5)
    model = export_module(folder / "otter.pt", rollout, greybox_metadata(vessel, rollout, horizon_steps=20)).path
    params = yaml.safe_load(Path(load_predictor_config().source).read_text(encoding="utf-8"))
    inner = params["predictor"]["ros__parameters"]
    inner.update(vessel="otter", model_path=str(model), horizon_s=HORIZON_S, ensemble_size=1)
    for role in ("rudder_angle", "engine_rpm"):
        del inner["inputs"][role]
    for index, role in enumerate(("thruster_port", "thruster_starboard")):
        inner["inputs"][role] = {"topic": TOPIC, "type": "std_msgs/msg/Float64MultiArray", "index": index,
                                 "units": "pwm", "neutral": 1500.0, "full_scale": 500.0, "max_age_s": 1.0}
    path = folder / "otter_pwm.yaml"
    path.write_text(yaml.safe_dump(params), encoding="utf-8")
    return path


class TwinHarness(Harness):
    """The Harness feeding GOOD motion inputs and both thrusters in one Float64MultiArray of PWM."""

    def __init__(self, context: Context, config: Path) -> None:
        super().__init__(context, [Parameter("rate_hz", value=20.0), Parameter("plan_max_age_s", value=2.0)],
                         peer_name="twin_peer", config_path=config)
        entries = [self.node.config.input(role) for role in ("thruster_port", "thruster_starboard")]
        self.adapters = [msg_adapters.get_adapter(e.role, e.ros_type, **e.options) for e in entries]
        self.thrusters = self.peer.create_publisher(self.make("std_msgs/msg/Float64MultiArray"), TOPIC, 100)
        self.pwm: list[float] = [PWM["port"], PWM["starboard"]]  # what the next shared message carries

    def feed(self, skip: tuple[str, ...] = (), **override: tuple[float, ...]) -> None:
        super().feed(skip=(*skip, "rudder_angle", "engine_rpm"), **override)
        msg = self.make("std_msgs/msg/Float64MultiArray")()
        msg.data = [float(v) for v in self.pwm]
        self.thrusters.publish(msg)


@pytest.fixture()
def twin(ros_context: Context, otter_config: Path) -> Iterator[TwinHarness]:
    fixture = TwinHarness(ros_context, otter_config)
    try:
        yield fixture
    finally:
        fixture.close()


def test_both_thrusters_on_one_topic_give_predictions_and_the_other_controls_are_ignored(twin: TwinHarness) -> None:
    found = twin.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, twin.feed)
    assert sorted(twin.node.inputs.tracks) == ["gnss", "heading", "imu", "thruster_port", "thruster_starboard",
                                               "velocity"]
    assert twin.node.count_subscribers(TOPIC) == 1  # one subscription for both roles
    assert float(values_of(found["thruster_port"])["command"]) == pytest.approx(0.6)
    assert float(values_of(found["thruster_starboard"])["command"]) == pytest.approx(0.4)
    assert values_of(found["thruster_port"])["topic"] == values_of(found["thruster_starboard"])["topic"] == "/" + TOPIC
    assert found["ignored inputs"].message.startswith("not subscribed: throttle (controls of other actuator layouts "
                                                      "than twin_thrusters)")
    assert values_of(found["ignored inputs"])["throttle"] == "/throttle"
    heading = np.unwrap(decode_path(twin.paths[-1])[1][:, 2])
    assert heading[-1] - heading[0] > 0.2  # more port thrust: the boat turns to starboard (rad)


@pytest.mark.parametrize(("pwm", "raw", "broken", "reason"), [
    (None, b"\x00\x01\x00\x00\x07\x00", ("thruster_port", "thruster_starboard"),
     "cannot decode std_msgs/msg/Float64MultiArray message"),
    # one element: the starboard part is missing
    ([1800.0], None, ("thruster_starboard",), "data has 1 entries, expected entry 1"),
    ([1800.0, 2400.0], None, ("thruster_starboard",), "1.8 x full scale"),  # 900 us above neutral: refused
])
def test_a_bad_shared_message_is_counted_for_the_roles_it_breaks(twin: TwinHarness, pwm: Any, raw: bytes | None,
                                                                 broken: tuple[str, ...], reason: str) -> None:
    twin.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, twin.feed)
    before = {role: twin.node.inputs.tracks[role].received for role in ("thruster_port", "thruster_starboard")}
    bad: Any = raw
    if raw is None:
        bad = twin.make("std_msgs/msg/Float64MultiArray")()
        bad.data = pwm
    sent = [0]

    def feed() -> None:  # the inputs, the bad message every third time (a best-effort queue may drop one)
        twin.feed()
        if sent[0] % 3 == 0:
            twin.thrusters.publish(bad)
        sent[0] += 1

    found = twin.spin_until(lambda s: all(int(values_of(s[role])["decode_errors"]) >= 2 for role in broken), feed)
    for role in ("thruster_port", "thruster_starboard"):
        if role in broken:
            assert reason in values_of(found[role])["last_decode_error"], values_of(found[role])
        else:
            assert values_of(found[role])["decode_errors"] == "0"
            assert twin.node.inputs.tracks[role].received > before[role]
    # the good messages are decoded: once the bad ones stop, the broken roles turn OK and the predictions go on
    twin.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK
                    and all(level(s[role]) == predictor_node.OK for role in broken), twin.feed)
    assert all(not twin.node.inputs.tracks[role].rejected for role in ("thruster_port", "thruster_starboard"))


def test_a_plan_names_the_thrusters(twin: TwinHarness) -> None:
    twin.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, twin.feed)
    held = twin.paths[-1]
    stamp = now_ns(twin)  # the opposite turn: more starboard thrust, any joint order
    plan = joint_trajectory(twin, ["starboard", "port"], np.array([[0.8, 0.2], [0.8, 0.2]]), [0.0, 30.0], stamp)
    publisher(twin, "plan").publish(plan)
    wait_for(twin, lambda: any(stamp_of(p) == stamp for p in twin.paths), "a Path tagged with the plan's stamp")
    tagged = [p for p in twin.paths if stamp_of(p) == stamp][-1]
    turned = [float(np.unwrap(decode_path(p)[1][:, 2])[-1] - decode_path(p)[1][0, 2]) for p in (held, tagged)]
    assert turned[0] > 0.2 and turned[1] < -0.2  # held: to starboard; the plan: to port (rad)
    found = twin.spin_until(lambda s: "under the plan" in s["plan"].message)
    assert values_of(found["prediction"])["controls"] == f"plan stamped {plans.describe_stamp(stamp)}"
    # a rudder boat's plan is refused naming the layout; a PWM value in a plan is out of the command's range
    for names, positions, why in ((["delta", "rpm"], [[0.3, 650.0]], "expected the controls of the actuator "
                                   "layout twin_thrusters, ['port', 'starboard']"),
                                  (["port", "starboard"], [[1800.0, 1700.0]], "port")):
        publisher(twin, "plan").publish(joint_trajectory(twin, names, np.array(positions), [0.0], now_ns(twin)))
        found = twin.spin_until(lambda s: why in values_of(s["plan"]).get("last_refused", ""), twin.feed)
        assert level(found["plan"]) == predictor_node.WARN
        assert twin.node.following is None
    assert math.isfinite(GOOD["heading"][0])
    assert statuses(twin.latest)["prediction"].level[0] == predictor_node.OK


def test_a_grey_box_s_candidates_take_turns_with_the_sea_estimate_and_are_answered(twin: TwinHarness) -> None:
    """The grey box with the sea estimate applied (it writes the live current into the model): a candidate batch's
    rollout on the node's candidates worker takes the terms lock, as the estimate's writes on the executor's thread
    do, and the answer comes: more starboard thrust turns to port."""
    import threading

    answers: list[Any] = []
    twin.peer.create_subscription(twin.make("trajectory_msgs/msg/MultiDOFJointTrajectory"), "candidate_predictions",
                                  answers.append, 10)
    twin.spin_until(lambda s: level(s["prediction"]) == predictor_node.OK, twin.feed)
    assert twin.node.sea.applied
    holders: list[str] = []
    lock = twin.node._terms_lock

    class Counted:
        def __enter__(self) -> None:
            lock.acquire()
            holders.append(threading.current_thread().name)

        def __exit__(self, *exc: object) -> None:
            lock.release()

    twin.node._terms_lock = Counted()
    stamp = now_ns(twin)
    names = ["port_turn/port", "port_turn/starboard", "stbd_turn/port", "stbd_turn/starboard"]
    publisher(twin, "candidate_plans").publish(joint_trajectory(twin, names, np.array([[0.2, 0.8, 0.8, 0.2]]), [0.0],
                                                                stamp))
    wait_for(twin, lambda: answers, "candidate_predictions")
    answer = answers[0]
    assert stamp_of(answer) == stamp
    assert list(answer.joint_names) == ["port_turn", "stbd_turn"]
    yaw = np.array([[2.0 * math.atan2(tf.rotation.z, tf.rotation.w) for tf in p.transforms] for p in answer.points])
    turned = np.unwrap(yaw, axis=0)[-1] - np.unwrap(yaw, axis=0)[0]  # ENU yaw: + counter-clockwise (to port)
    assert turned[0] > 0.2
    assert turned[1] < -0.2
    assert any(name.startswith("candidates") for name in holders)  # the worker's rollout under the lock
    # the estimate's writes (the executor's thread) with the next inputs: the grey box's answer may come before them
    twin.spin_until(lambda s: any(name == threading.main_thread().name for name in holders), twin.feed)
    assert any(name == threading.main_thread().name for name in holders)

"""Sensor models: every error source does what its name says (noise-free specs isolate each one)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from usv_predictor.errors import ConfigError
from usv_predictor.frames import LocalTangentPlane, wrap_angle
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import CommandZigZag, TurningCircle, ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import ActuatorFaults, simulate
from usv_predictor.physics.vessel import GRAVITY, load_vessel

CLEAN = SensorSpec().noiseless()


@pytest.fixture(scope="module")
def turn():
    model = ManoeuvringModel(load_vessel("jari_usv"))
    return simulate(model, TurningCircle(20.0, 650.0, duration_s=60.0), heading_deg=45.0)


def truth_at(traj, t_ns, values):
    return np.interp((t_ns - traj.t_ns[0]).astype(float), (traj.t_ns - traj.t_ns[0]).astype(float), values)


def test_rates_match_the_spec(turn):
    signals = measure(turn, Environment())
    rates = {role: 1e9 / np.median(np.diff(s.t_ns)) for role, s in signals.items()}
    assert rates["imu"] == pytest.approx(100.0)
    assert rates["velocity"] == pytest.approx(20.0)
    assert rates["heading"] == pytest.approx(20.0)
    assert rates["rudder_angle"] == pytest.approx(10.0)
    assert rates["engine_rpm"] == pytest.approx(10.0)
    assert rates["gnss"] == pytest.approx(5.0)
    assert all(s.t_ns[0] == turn.t_ns[0] for s in signals.values())


def test_noise_free_sensors_report_the_truth(turn):
    s = measure(turn, Environment(), CLEAN)
    imu = s["imu"]
    assert np.allclose(imu.column("yaw_rate"), truth_at(turn, imu.t_ns, turn.nu[:, 2]), atol=1e-12)
    # specific force of a turning hull: centripetal a_y = v_dot + r u, gravity on z (FRD: -g)
    a_y = turn.nu_dot[:, 1] + turn.nu[:, 2] * turn.nu[:, 0]
    assert np.allclose(imu.column("accel_y"), truth_at(turn, imu.t_ns, a_y), atol=1e-9)
    assert np.allclose(imu.column("accel_z"), -GRAVITY)
    assert np.all(np.isnan(imu.column("heading")))  # no orientation estimate (REP-145)
    hdg = s["heading"]
    assert np.allclose(wrap_angle(hdg.column("psi") - truth_at(turn, hdg.t_ns, turn.psi_unwrapped)), 0.0, atol=1e-12)
    gnss = s["gnss"]
    x_n, y_e = LocalTangentPlane(CLEAN.datum_lat_deg,
                                 CLEAN.datum_lon_deg).to_ned(gnss.column("lat"), gnss.column("lon"))
    assert np.allclose(x_n, truth_at(turn, gnss.t_ns, turn.eta[:, 0]), atol=1e-6)
    assert np.allclose(y_e, truth_at(turn, gnss.t_ns, turn.eta[:, 1]), atol=1e-6)


def test_biases_and_offsets_are_what_they_say(turn):
    bias, offset = math.radians(0.5), math.radians(3.0)
    spec = dataclasses.replace(CLEAN, gyro_bias=bias, heading_offset=offset)
    clean, biased = measure(turn, Environment(), CLEAN), measure(turn, Environment(), spec)
    assert np.allclose(biased["imu"].column("yaw_rate") - clean["imu"].column("yaw_rate"), bias)
    assert np.allclose(biased["velocity"].column("r") - clean["velocity"].column("r"), bias)  # same gyro
    assert np.allclose(wrap_angle(biased["heading"].column("psi") - clean["heading"].column("psi")), offset)
    assert np.array_equal(biased["gnss"].values, clean["gnss"].values)


def test_rudder_offset_is_hidden_from_the_feedback():
    model = ManoeuvringModel(load_vessel("jari_usv"))
    faults = ActuatorFaults(rudder_offset_rad=math.radians(2.0))
    traj = simulate(model, TurningCircle(15.0, 650.0, duration_s=30.0), faults=faults)
    s = measure(traj, Environment(), CLEAN, faults)
    # the feedback reads the command the crew gave, the hull feels 2 deg more
    assert s["rudder_angle"].column("delta")[-1] == pytest.approx(math.radians(15.0), abs=1e-6)
    assert traj.rudder[-1] == pytest.approx(math.radians(17.0), abs=1e-6)


def test_actuator_delay_makes_the_record_lead_the_motion():
    model = ManoeuvringModel(load_vessel("jari_usv"))
    traj = simulate(model, ZigZag(20.0, 20.0, 650.0, duration_s=60.0))
    delay = 0.8
    led = measure(traj, Environment(), dataclasses.replace(CLEAN, actuator_delay_s=delay))["rudder_angle"]
    on_time = measure(traj, Environment(), CLEAN)["rudder_angle"]
    shift = int(round(delay * 10.0))  # 10 Hz feedback
    assert np.allclose(led.values[:-shift - 1], on_time.values[shift:-1], atol=1e-12)


def test_noise_levels_match_the_spec(turn):
    spec = dataclasses.replace(SensorSpec(), wave_motion_gain=0.0)
    s = measure(turn, Environment(), spec, seed=4)
    residual = s["imu"].column("yaw_rate") - truth_at(turn, s["imu"].t_ns, turn.nu[:, 2])
    assert np.std(residual) == pytest.approx(spec.gyro_noise_std, rel=0.05)
    vel = s["velocity"]
    assert np.std(vel.column("u")
                  - truth_at(turn, vel.t_ns, turn.nu[:, 0])) == pytest.approx(spec.velocity_noise_std, rel=0.1)
    # quantised to the LSB: values are exact multiples of it
    assert np.allclose(s["imu"].column("yaw_rate") / spec.gyro_lsb,
                       np.round(s["imu"].column("yaw_rate") / spec.gyro_lsb))


def test_waves_shake_the_measured_motion_but_not_the_mean(turn):
    env = Environment(wave_height=0.5, wave_period_s=3.0, wave_from_deg=120.0)
    spec = dataclasses.replace(CLEAN)
    s = measure(turn, env, spec, seed=2)
    vel = s["velocity"]
    residual = vel.column("u") - truth_at(turn, vel.t_ns, turn.nu[:, 0])
    assert 0.02 < np.std(residual) < 0.5  # a wave-frequency oscillation of a few cm/s to dm/s
    assert abs(np.mean(residual)) < 0.3 * np.std(residual)


def test_spec_validation():
    with pytest.raises(ConfigError, match="imu_rate_hz"):
        SensorSpec(imu_rate_hz=0.0)
    with pytest.raises(ConfigError, match="unknown sensor parameters"):
        SensorSpec.from_mapping({"gyro_bais": 0.1})
    with pytest.raises(ConfigError, match="actuator_delay_s"):
        SensorSpec(actuator_delay_s=-1.0)


def test_a_twin_thruster_boat_reports_its_commands():
    """Normalised commands at the actuator rate, quantised to command_lsb, no rudder or engine speed; a thruster
    imbalance is invisible in the log (it reports what was sent), an actuator delay makes the log lead."""
    model = ManoeuvringModel(load_vessel("otter"))
    faults = ActuatorFaults(thruster_imbalance=0.1)
    traj = simulate(model, CommandZigZag("twin_thrusters", 0.5, 15.0, 0.6, duration_s=40.0), faults=faults)
    signals = measure(traj, Environment(), SensorSpec(), faults)
    assert set(signals) == {"imu", "velocity", "heading", "thruster_port", "thruster_starboard", "gnss", "odometry"}
    port = signals["thruster_port"]
    assert port.fields == ("command",)
    assert 1e9 / np.median(np.diff(port.t_ns)) == pytest.approx(10.0)
    lsb = SensorSpec().command_lsb
    assert np.allclose(port.values / lsb, np.round(port.values / lsb))
    truth = traj.command("port")[np.searchsorted(traj.t_ns, port.t_ns)]
    assert np.max(np.abs(port.column("command") - truth)) <= 0.5 * lsb
    assert np.allclose(signals["thruster_starboard"].column("command") + port.column("command"), 1.2, atol=lsb)
    led = measure(traj, Environment(), dataclasses.replace(CLEAN, actuator_delay_s=0.5), faults)["thruster_port"]
    on_time = measure(traj, Environment(), CLEAN, faults)["thruster_port"]
    assert np.array_equal(led.values[:-6], on_time.values[5:-1])

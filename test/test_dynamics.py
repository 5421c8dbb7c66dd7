"""Physics of the simulator against closed-form cases (DESIGN tier 1)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from usv_predictor.analysis.metrics import steady_turning_radius
from usv_predictor.errors import ConfigError
from usv_predictor.physics.dynamics import CALM, ManoeuvringModel, SeaLoads
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import PullOut, RandomManoeuvre, Spiral, TurningCircle, ZigZag, sea_trial_turns
from usv_predictor.physics.simulator import ActuatorFaults, simulate
from usv_predictor.physics.vessel import GRAVITY, RHO_WATER, load_vessel, vessel_from_dict


@pytest.fixture(scope="module")
def model() -> ManoeuvringModel:
    return ManoeuvringModel(load_vessel("jari_usv"))


@dataclasses.dataclass(frozen=True)
class RpmStep:
    """Straight running at `rpm`, then a step to `rpm_after` at t=5 s."""

    rpm: float
    rpm_after: float
    duration_s: float = 150.0
    name: str = "rpm_step"

    @property
    def propulsion(self) -> float:  # the approach's propulsion command (simulator.Manoeuvre)
        return self.rpm

    def controller(self):
        return lambda t, psi, r: (0.0, self.rpm if t < 5.0 else self.rpm_after)


def test_zero_rudder_calm_water_keeps_heading(model):
    traj = simulate(model, TurningCircle(0.0, 650.0, duration_s=60.0), heading_deg=33.0)
    assert np.allclose(traj.eta[:, 2], math.radians(33.0), atol=1e-12)
    assert np.allclose(traj.nu[:, 1:], 0.0, atol=1e-12)
    # and it runs straight along 33 deg
    bearing = math.degrees(math.atan2(traj.eta[-1, 1], traj.eta[-1, 0]))
    assert bearing == pytest.approx(33.0, abs=1e-9)


def test_straight_run_reaches_thrust_resistance_speed(model):
    u_700 = model.straight_speed(700.0)
    # at that speed the surge force balances exactly
    assert model.accelerations(0.0, u_700, 0.0, 0.0, 0.0, 700.0)[0] == pytest.approx(0.0, abs=1e-5)
    traj = simulate(model, RpmStep(650.0, 700.0))
    assert traj.nu[0, 0] == pytest.approx(model.straight_speed(650.0), rel=1e-9)
    assert traj.nu[-1, 0] == pytest.approx(u_700, rel=1e-4)
    assert u_700 > traj.nu[0, 0]  # more rpm, more speed


def test_positive_rudder_turns_to_starboard(model):
    traj = simulate(model, TurningCircle(20.0, 650.0, duration_s=40.0))
    assert traj.nu[-1, 2] > 0.05  # r > 0: heading increases clockwise
    assert traj.nu[-1, 1] < 0.0  # outward (port) sway in a starboard turn: drift angle beta > 0


def test_port_and_starboard_turns_mirror(model):
    stbd = simulate(model, TurningCircle(25.0, 650.0, duration_s=60.0, side=1))
    port = simulate(model, TurningCircle(25.0, 650.0, duration_s=60.0, side=-1))
    assert np.allclose(stbd.eta[:, 0], port.eta[:, 0], atol=1e-9)
    assert np.allclose(stbd.eta[:, 1], -port.eta[:, 1], atol=1e-9)
    assert np.allclose(stbd.nu[:, 2], -port.nu[:, 2], atol=1e-12)


def test_current_drifts_the_track_at_exactly_the_current_velocity(model):
    """Forces act on the velocity relative to the water, so a uniform current only adds V_c * t."""
    speed, to_deg = 0.4, 135.0
    env = Environment(current_speed=speed, current_to_deg=to_deg)
    calm = simulate(model, TurningCircle(20.0, 650.0, duration_s=120.0), heading_deg=10.0)
    sea = simulate(model, TurningCircle(20.0, 650.0, duration_s=120.0), env, heading_deg=10.0)
    t = calm.t_s
    v_n, v_e = speed * math.cos(math.radians(to_deg)), speed * math.sin(math.radians(to_deg))
    assert np.allclose(sea.eta[:, 0] - calm.eta[:, 0], v_n * t, atol=1e-6)
    assert np.allclose(sea.eta[:, 1] - calm.eta[:, 1], v_e * t, atol=1e-6)
    assert np.allclose(sea.nu_r, calm.nu_r, atol=1e-9)
    assert np.allclose(sea.eta[:, 2], calm.eta[:, 2], atol=1e-9)


def test_turning_current_matches_a_steady_one_when_it_does_not_turn(model):
    env = Environment(current_speed=0.3, current_to_deg=200.0, current_turn_rate_deg_s=0.0)
    a = simulate(model, ZigZag(20.0, 20.0, 650.0, duration_s=60.0), env)
    turning = dataclasses.replace(env, current_turn_rate_deg_s=0.05)
    b = simulate(model, ZigZag(20.0, 20.0, 650.0, duration_s=60.0), turning)
    # after 60 s at 0.05 deg/s the current has turned 3 deg: a small but non-zero difference
    gap = np.hypot(*(a.eta[-1, :2] - b.eta[-1, :2]))
    assert 0.01 < gap < 0.3 * 60 * 0.3 * math.radians(3.0) * 10


def test_headwind_slows_and_beam_wind_pushes_downwind(model):
    u_calm = simulate(model, TurningCircle(0.0, 650.0, duration_s=120.0)).nu[-1, 0]
    head = simulate(model, TurningCircle(0.0, 650.0, duration_s=120.0), Environment(wind_speed=15.0, wind_from_deg=0.0))
    assert head.nu[-1, 0] < u_calm - 0.01
    beam = simulate(model, TurningCircle(0.0, 650.0, duration_s=5.0), Environment(wind_speed=15.0, wind_from_deg=90.0))
    # wind from the east (starboard beam, heading north) pushes the boat to port, i.e. west
    assert beam.nu[-1, 1] < -0.01
    assert beam.eta[-1, 1] < 0.0


def test_wave_drift_pushes_away_from_the_waves(model):
    traj = simulate(model, TurningCircle(0.0, 650.0, duration_s=5.0), Environment(wave_height=1.5, wave_from_deg=90.0))
    assert traj.nu[-1, 1] < -0.005  # waves from the east push the boat (heading north) west
    head = model.loads(5.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 650.0, SeaLoads(wave_amplitude=0.5, wave_from=0.0))
    assert head.waves[0] < 0.0 and head.waves[1] == pytest.approx(0.0, abs=1e-9)  # head seas: added resistance


@pytest.mark.parametrize("chi_deg, share", [(0.0, 1.0), (60.0, 0.25), (-60.0, 0.25), (90.0, 0.0), (150.0, 0.0)])
def test_the_head_sea_resistance_is_a_surge_force_over_the_bow_quarter(model, chi_deg, share):
    """C_AW adds -0.5 rho g zeta_a^2 L C_AW max(cos chi, 0)^2 to the wave surge force and nothing to sway or yaw:
    all of it in head seas, a quarter 60 deg off the bow on either side, none from abeam or astern."""
    psi, amplitude, c_aw = 0.7, 0.5, 0.4  # heading (rad), zeta_a (m), C_AW (-)
    sea = SeaLoads(wave_amplitude=amplitude, wave_from=psi + math.radians(chi_deg))
    plain = model.loads(5.0, 0.3, 0.02, psi, 5.0, 0.3, 0.0, 650.0, sea).waves
    added = model.loads(5.0, 0.3, 0.02, psi, 5.0, 0.3, 0.0, 650.0,
                        dataclasses.replace(sea, wave_resistance=c_aw)).waves
    q = 0.5 * RHO_WATER * GRAVITY * model.vessel.geometry.L_pp  # (N/m^2)
    assert added[0] - plain[0] == pytest.approx(-q * amplitude**2 * c_aw * share, rel=1e-12, abs=1e-9)
    assert added[1:] == plain[1:]


def test_rudder_offset_makes_zero_reported_rudder_turn(model):
    traj = simulate(model, TurningCircle(0.0, 650.0, duration_s=60.0), faults=ActuatorFaults(math.radians(3.0)))
    assert traj.nu[-1, 2] > 0.0
    assert traj.rudder[-1] == pytest.approx(math.radians(3.0), abs=1e-9)
    assert np.all(traj.rudder_cmd == 0.0)


def test_rk4_converges_with_the_step(model):
    # open-loop commands switching on a common step boundary, so only the integration differs
    env = Environment(current_speed=0.3, current_to_deg=60.0, wind_speed=8.0, wind_from_deg=200.0, wave_height=0.5)
    coarse = simulate(model, TurningCircle(25.0, 700.0, duration_s=80.0), env, dt=0.1)
    fine = simulate(model, TurningCircle(25.0, 700.0, duration_s=80.0), env, dt=0.01)
    assert np.max(np.hypot(*(coarse.eta[:, :2] - fine.eta[:, :2]).T)) < 0.05


def test_dense_output_velocity_is_the_derivative_of_position(model):
    traj = simulate(model, TurningCircle(25.0, 700.0, duration_s=40.0))
    t = traj.t_s
    v_n = np.gradient(traj.eta[:, 0], t)
    psi = traj.psi_unwrapped
    expected = traj.nu[:, 0] * np.cos(psi) - traj.nu[:, 1] * np.sin(psi)
    assert np.max(np.abs(v_n[2:-2] - expected[2:-2])) < 2e-3
    r_dot = np.gradient(traj.nu[:, 2], t)
    assert np.max(np.abs(r_dot[20:-2] - traj.nu_dot[20:-2, 2])) < 5e-3


def test_jari_preset_turning_radii_are_of_the_order_of_seed_000(model):
    """Seed 000 Table 7 measured 6-18 m at the Table 3 settings; the preset is tuned to that order."""
    radii = {}
    for turn in sea_trial_turns():
        traj = simulate(model, turn)
        fit = steady_turning_radius(traj.t_s, traj.eta[:, 0], traj.eta[:, 1], traj.eta[:, 2])
        radii[(turn.rudder_deg, turn.rpm)] = fit.radius_m
    assert all(6.0 <= r <= 20.0 for r in radii.values()), radii
    # more rudder, tighter turn
    assert radii[(15.0, 650.0)] > radii[(20.0, 650.0)] > radii[(25.0, 650.0)]


def test_zigzag_reverses_at_the_check_angle(model):
    traj = simulate(model, ZigZag(20.0, 20.0, 650.0, duration_s=100.0))
    change = np.degrees(traj.psi_unwrapped - traj.psi_unwrapped[0])
    reversals = np.flatnonzero(np.diff(np.sign(traj.rudder_cmd)) != 0)
    assert len(reversals) >= 3
    # the autopilot samples once per 0.05 s step: it reverses within one step of yaw past the check
    late = math.degrees(np.max(np.abs(traj.nu[:, 2]))) * 0.05
    for k in reversals[1:]:  # the first sign change is the execute from 0
        assert 20.0 <= abs(change[k + 1]) <= 20.0 + late


def test_other_manoeuvres_run_and_respect_rudder_limits(model):
    for manoeuvre in (PullOut(25.0, 650.0), Spiral(rpm=650.0, hold_s=10.0), RandomManoeuvre(seed=3, duration_s=60.0)):
        traj = simulate(model, manoeuvre)
        assert np.all(np.abs(traj.rudder) <= math.radians(35.0) + 1e-9)
        assert np.all(np.isfinite(traj.eta))
    pull = simulate(model, PullOut(25.0, 650.0, turn_s=30.0, duration_s=120.0))
    assert abs(pull.nu[-1, 2]) < 0.1 * np.max(np.abs(pull.nu[:, 2]))  # stable: yaw rate decays


def test_simulation_is_deterministic_for_a_seed(model):
    env = Environment(wind_speed=6.0, gust_std=1.5, wave_height=0.5)
    a = simulate(model, RandomManoeuvre(seed=1, duration_s=30.0), env, seed=5)
    b = simulate(model, RandomManoeuvre(seed=1, duration_s=30.0), env, seed=5)
    c = simulate(model, RandomManoeuvre(seed=1, duration_s=30.0), env, seed=6)
    assert np.array_equal(a.eta, b.eta)
    assert not np.array_equal(a.eta, c.eta)  # different gusts


def test_bad_inputs_are_refused(model):
    with pytest.raises(ConfigError, match="current_speed"):
        Environment(current_speed=-0.1)
    with pytest.raises(ConfigError, match="dt"):
        simulate(model, TurningCircle(20.0, 650.0, duration_s=10.0), dt=0.5)
    raw = {"geometry": {"L_pp": 10.0}}
    with pytest.raises(ConfigError, match="missing"):
        vessel_from_dict(raw, source="bad.yaml")
    with pytest.raises(ConfigError, match="unknown vessel preset 'nope'"):
        load_vessel("nope")


def test_loads_decomposition_sums_to_the_total(model):
    sea = SeaLoads(0.2, -0.1, 0.0, 0.0, 8.0, 1.0, 0.3, 2.0)
    forces = model.loads(4.0, -0.5, 0.1, 0.7, 4.1, -0.4, 0.2, 650.0, sea)
    total = forces.total()
    parts = np.array([forces.hull, forces.steering, forces.propulsion, forces.wind, forces.waves])
    assert np.allclose(parts.sum(axis=0), total)
    assert forces.steering[1] < 0.0  # positive rudder: side force to port ...
    assert forces.steering[2] > 0.0  # ... and a starboard yaw moment
    assert model.loads(4.0, 0.0, 0.0, 0.0, 4.0, 0.0, 0.0, 650.0, CALM).wind == (0.0, 0.0, 0.0)


def test_a_force_model_missing_an_equation_cannot_be_combined(model, monkeypatch):
    """ManoeuvringModel's hull/actuator methods are abstract: a layout whose force model lacks one (here
    initial_actuators) is refused when the model is built, naming the method, not at the first call."""
    from usv_predictor.physics import dynamics

    class NoInitialActuators:
        constants = ()

        def actuator_loads(self, u_r, v_r, r, a, b):
            return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)

        def actuator_rates(self, a, b, cmd_a, cmd_b):
            return 0.0, 0.0

    vessel = model.vessel
    monkeypatch.setitem(dynamics.ACTUATOR_FORCES, vessel.layout, NoInitialActuators)
    monkeypatch.setattr(dynamics, "_CLASSES", {})
    with pytest.raises(TypeError, match="initial_actuators"):
        ManoeuvringModel(vessel)

"""The small-craft hull, twin thrusters, thrust maps and the new rudder layouts against closed forms, and the
presets against their published figures (DESIGN tier 1)."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from usv_predictor.errors import ConfigError
from usv_predictor.physics.dynamics import CALM, ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import CommandTurningCircle, CommandZigZag
from usv_predictor.physics.simulator import ActuatorFaults, simulate
from usv_predictor.physics.vessel import RHO_WATER, ThrustMap, load_vessel, vessel_dir, vessel_from_dict

KNOT = 1852.0 / 3600.0  # (m/s)


def preset(name: str) -> dict:
    return yaml.safe_load((vessel_dir() / f"{name}.yaml").read_text())


@pytest.fixture(scope="module")
def otter() -> ManoeuvringModel:
    return ManoeuvringModel(load_vessel("otter"))


@pytest.fixture(scope="module")
def wamv() -> ManoeuvringModel:
    return ManoeuvringModel(load_vessel("wamv"))


def balance_speed(thrust: float, x_u: float, x_uu: float) -> float:
    """u > 0 with thrust = -X_u u - X_uu u^2 (N, N s/m, N s^2/m^2), the straight-running balance in closed form."""
    if x_uu == 0.0:
        return thrust / -x_u
    return (x_u + math.sqrt(x_u * x_u - 4.0 * x_uu * thrust)) / (-2.0 * x_uu)


# ---- the presets against their published figures ----------------------------------------------------------

def test_otter_reaches_fossens_top_speed_at_full_command(otter):
    """otter.py defines X_u from Umax = 6 kn with both propellers at full (2 x 119.7 N bollard): 3.086 m/s."""
    u = otter.straight_speed(1.0)
    assert u == pytest.approx(6.0 * 0.5144, abs=1e-4)  # Fossen's Umax (his knot: 0.5144 m/s)
    assert u == pytest.approx(6.0 * KNOT, rel=2e-3)
    assert otter.accelerations(0.0, u, 0.0, 0.0, 1.0, 1.0)[0] == pytest.approx(0.0, abs=1e-4)


def test_wamv_reaches_the_vrx_speed_at_full_command(wamv):
    """VRX classic: 51.3 u + 72.4 u^2 = 2 x 242.7 N (the logistic map at 1) gives about 2.26 m/s."""
    u = wamv.straight_speed(1.0)
    assert u == pytest.approx(2.259, abs=2e-3)
    assert u == pytest.approx(balance_speed(2.0 * 242.67, -51.3, -72.4), abs=1e-5)


@pytest.mark.parametrize("name", ["otter", "wamv"])
@pytest.mark.parametrize("command", [0.25, 0.6, 1.0])
def test_straight_speed_is_the_thrust_resistance_balance(name, command):
    vessel = load_vessel(name)
    model = ManoeuvringModel(vessel)
    h, thrusters = vessel.small_craft, vessel.thrusters
    thrust = thrusters.port.thrust(command) + thrusters.starboard.thrust(command)
    assert model.straight_speed(command) == pytest.approx(balance_speed(thrust, h.X_u, h.X_uu), abs=1e-5)


def test_preset_mass_matrices_are_fossens(otter):
    """otter.py with SIMotter's payload: M11 = 80 + 5.5, M22 = 80 + 82.5, M26 = m x_G = 12.25, M66 = 42.65."""
    ((m11, _, _), (_, m22, m23), (_, m32, m33)) = otter.vessel.mass_matrix()
    assert (m11, m22) == pytest.approx((85.5, 162.5))
    assert m23 == m32 == pytest.approx(12.25)
    assert m33 == pytest.approx(42.65, abs=0.01)
    h = otter.vessel.small_craft
    assert h.Y_v == pytest.approx(-m22 / 1.0) and h.N_r == pytest.approx(-m33 / 1.0, abs=1e-3)  # T_sway = T_yaw = 1 s
    assert h.N_rr == pytest.approx(10.0 * h.N_r)


# ---- loads: the thrusters ------------------------------------------------------------------------------------

@pytest.mark.parametrize("k", [0.0, 0.12, -0.07])
def test_yaw_moment_is_the_thrust_difference_times_half_spacing(k):
    vessel = load_vessel("otter")
    model = ManoeuvringModel(vessel, thrust_imbalance=k)
    port, starboard = 0.8, 0.2
    t_p = (1.0 + k) * 119.682 * port**2  # (N): the port thruster, k_pos n^2 with n / n_max = 0.8
    t_s = (1.0 - k) * 119.682 * starboard**2
    forces = model.loads(1.5, 0.0, 0.0, 0.3, 1.5, 0.0, port, starboard, CALM)
    assert forces.steering == pytest.approx((0.0, 0.0, 0.395 * (t_p - t_s)), rel=1e-12)  # (N m) = (m) x (N)
    assert forces.propulsion == pytest.approx((t_p + t_s, 0.0, 0.0), rel=1e-12)
    assert forces.steering[2] > 0.0  # more port thrust: bow to starboard


def test_more_port_thrust_turns_to_starboard_and_the_turns_mirror(otter):
    stbd = simulate(otter, CommandTurningCircle("twin_thrusters", 0.4, 0.6, duration_s=60.0))
    port = simulate(otter, CommandTurningCircle("twin_thrusters", 0.4, 0.6, duration_s=60.0, side=-1))
    assert stbd.command("port")[-1] == pytest.approx(0.8)
    assert stbd.command("starboard")[-1] == pytest.approx(0.4)
    assert stbd.nu[-1, 2] > 0.1  # (rad/s), heading increases
    assert np.allclose(stbd.eta[:, 0], port.eta[:, 0], atol=1e-9)
    assert np.allclose(stbd.eta[:, 1], -port.eta[:, 1], atol=1e-9)
    assert np.allclose(stbd.nu[:, 2], -port.nu[:, 2], atol=1e-12)


def test_a_twin_boat_turns_on_the_spot(otter, wamv):
    """Opposite full commands from rest: a steady spin to starboard on a circle of radius below the boat's length
    (the reverse thrust is weaker, so the boat creeps ahead round it), and the mirror to port."""
    for model in (otter, wamv):
        spin = simulate(model, CommandTurningCircle("twin_thrusters", 2.0, 0.0, duration_s=60.0, approach_s=0.0))
        assert spin.nu[0, 0] == 0.0
        assert spin.command("port")[-1] == 1.0
        assert spin.command("starboard")[-1] == -1.0
        assert spin.nu[-1, 2] > 0.3  # (rad/s), > 17 deg/s
        assert np.max(np.hypot(spin.eta[:, 0], spin.eta[:, 1])) < 2.0 * model.vessel.geometry.L_pp  # diameter
        mirror = simulate(model, CommandTurningCircle("twin_thrusters", 2.0, 0.0, duration_s=60.0, approach_s=0.0,
                                                      side=-1))
        assert np.allclose(mirror.nu[:, 2], -spin.nu[:, 2], atol=1e-12)
        assert np.all(np.isfinite(spin.nu))


@pytest.mark.parametrize("turn, throttle", [(0.4, 0.6), (0.8, 0.3)])
def test_a_twin_boat_follows_its_turn_without_skidding(otter, wamv, turn, throttle):
    """A held differential turn settles with the hull's lateral resistance balancing the centrifugal force m u r
    (Fossen 2021 eq. 6.5, C_RB), at a drift angle atan(-v / u) of a catamaran's 5-17 deg (otter 4.8, 4.5; wamv 15.3,
    16.5 deg). The WAM-V preset once had VRX's 40 N s/m of linear sway damping alone (yVV = 0: VRX also
    leaves out C_RB, so its own boat cannot skid): with the Coriolis force the boat slid at 60 and 62 deg (v -1.74 m/s
    for u 0.99 m/s), and 1.5 m beam seas pushed it at ~41 m/s. The floats' cross-flow drag holds it now."""
    for model in (otter, wamv):
        held = simulate(model, CommandTurningCircle("twin_thrusters", turn, throttle, duration_s=120.0))
        u, v, r = held.nu[-1]
        assert r > math.radians(5.0) and u > 0.5, (model.vessel.name, held.nu[-1])  # a turn ahead, settled below
        assert np.ptp(held.nu[-100:, 2]) < 1e-3 * r, (model.vessel.name, held.nu[-100:, 2])
        assert 2.0 < math.degrees(math.atan2(-v, u)) < 20.0, (model.vessel.name, held.nu[-1])


def test_a_thruster_imbalance_pulls_to_the_weaker_side_s_opposite(otter):
    """k > 0: the starboard side is weaker, so at equal commands the boat turns to starboard; the surge force is
    unchanged (the imbalance moves thrust from one side to the other)."""
    straight = CommandTurningCircle("twin_thrusters", 0.0, 0.6, duration_s=60.0)
    weak_stbd = simulate(otter, straight, faults=ActuatorFaults(thruster_imbalance=0.1))
    weak_port = simulate(otter, straight, faults=ActuatorFaults(thruster_imbalance=-0.1))
    assert weak_stbd.nu[-1, 2] > 0.02
    assert weak_port.nu[-1, 2] == pytest.approx(-weak_stbd.nu[-1, 2], abs=1e-12)
    assert np.all(weak_stbd.command("port") == weak_stbd.command("starboard"))  # the log shows equal commands
    model = ManoeuvringModel(otter.vessel, thrust_imbalance=0.1)
    assert model.loads(2.0, 0, 0, 0, 2.0, 0, 0.6, 0.6).propulsion[0] == pytest.approx(
        otter.loads(2.0, 0, 0, 0, 2.0, 0, 0.6, 0.6).propulsion[0], rel=1e-12)


def test_a_twin_zigzag_reverses_the_differential_at_the_check_heading(otter):
    traj = simulate(otter, CommandZigZag("twin_thrusters", 0.5, 20.0, 0.6, duration_s=90.0))
    d = traj.command("port") - traj.command("starboard")
    change = np.degrees(traj.psi_unwrapped - traj.psi_unwrapped[0])
    reversals = np.flatnonzero(np.diff(np.sign(d)) != 0)
    assert len(reversals) >= 3
    assert set(np.round(np.abs(d[traj.t_s > 5.0]), 12)) == {0.5}
    late = math.degrees(np.max(np.abs(traj.nu[:, 2]))) * 0.05  # one 0.05 s step of yaw
    for k in reversals[1:]:  # the first sign change is the execute from 0
        assert 20.0 <= abs(change[k + 1]) <= 20.0 + late


# ---- the small-craft hull ------------------------------------------------------------------------------------

def test_current_drifts_a_small_craft_at_exactly_the_current_velocity(otter):
    speed, to_deg = 0.4, 250.0
    turn = CommandTurningCircle("twin_thrusters", 0.5, 0.7, duration_s=90.0)
    calm = simulate(otter, turn, heading_deg=30.0)
    sea = simulate(otter, turn, Environment(current_speed=speed, current_to_deg=to_deg), heading_deg=30.0)
    t = calm.t_s
    assert np.allclose(sea.eta[:, 0] - calm.eta[:, 0], speed * math.cos(math.radians(to_deg)) * t, atol=1e-6)
    assert np.allclose(sea.eta[:, 1] - calm.eta[:, 1], speed * math.sin(math.radians(to_deg)) * t, atol=1e-6)
    assert np.allclose(sea.nu_r, calm.nu_r, atol=1e-9)


def test_cross_flow_drag_in_closed_form(otter):
    """Pure sway: Y = Y_v v - 0.5 rho d C_d L |v| v and no moment (the strips are symmetric); pure yaw: no sway
    force and N = N_r r + N_rr |r| r - 0.5 rho d C_d r|r| int |x|^3 dx, int = L^4 / 32 (midpoint rule: 0.4 %)."""
    v = otter.vessel
    g, h = v.geometry, v.small_craft
    q = 0.5 * RHO_WATER * g.d * h.cross_flow_cd  # (kg/m^2)
    x, y, n = otter.hull_loads(0.0, 0.3, 0.0)
    assert x == 0.0
    assert y == pytest.approx(h.Y_v * 0.3 - q * g.L_pp * 0.09, rel=1e-12)
    assert n == pytest.approx(0.0, abs=1e-12)
    x, y, n = otter.hull_loads(0.0, 0.0, -0.5)
    assert y == pytest.approx(0.0, abs=1e-12)
    expected = h.N_r * -0.5 + h.N_rr * 0.25 * -1.0 + q * 0.25 * g.L_pp**4 / 32.0
    assert n == pytest.approx(expected, rel=2e-3) and n > 0.0  # damping opposes the (port) turn
    assert otter.hull_loads(1.2, 0.0, 0.0)[0] == pytest.approx(h.X_u * 1.2)


def test_munk_moment_turns_the_hull_broadside(otter):
    """Fossen's C_A(nu_r) nu_r in yaw is (X_udot - Y_vdot) u v: with u, v > 0 (drifting to starboard) the bow turns
    to port, away from the flow (destabilising), and r_dot is the closed form of M^-1."""
    v = otter.vessel
    h = v.small_craft
    u, sway = 1.0, 0.2  # (m/s)
    ((m11, _, _), (_, m22, m23), (_, m32, m33)) = v.mass_matrix()
    _, y_h, n_h = otter.hull_loads(u, sway, 0.0)
    rhs_y, rhs_n = y_h, n_h + (h.Y_vdot - h.X_udot) * u * sway
    _, v_dot, r_dot = otter.accelerations(0.0, u, sway, 0.0, 0.0, 0.0)
    assert r_dot == pytest.approx((m22 * rhs_n - m32 * rhs_y) / (m22 * m33 - m23 * m32), rel=1e-12)
    assert v_dot == pytest.approx((m33 * rhs_y - m23 * rhs_n) / (m22 * m33 - m23 * m32), rel=1e-12)
    assert (h.Y_vdot - h.X_udot) * u * sway < 0.0
    assert r_dot < 0.0


def test_the_small_craft_model_is_regular_at_rest(otter):
    assert otter.accelerations(0.0, 0.0, 0.0, 0.0, 0.0, 0.0) == (0.0, 0.0, 0.0)
    u_dot, v_dot, r_dot = otter.accelerations(0.0, 0.0, 0.0, 0.0, 1.0, -1.0)
    assert r_dot == pytest.approx(0.395 * (119.682 + 66.708) * 162.5 / (162.5 * otter.m33 - 12.25**2), rel=1e-9)
    assert u_dot == pytest.approx((119.682 - 66.708) / 85.5, rel=1e-9) and v_dot < 0.0  # M26 couples yaw into sway


def test_instantaneous_and_lagged_motors(otter, wamv):
    """The Otter's motors follow a command step as 1 - exp(-t / 0.1 s) (RK4 at 0.05 s: within 1e-3); the WAM-V's
    (time constant 0, as VRX) are at the command at once."""
    step = CommandTurningCircle("twin_thrusters", 0.4, 0.6, duration_s=3.0, approach_s=1.0)
    traj = simulate(otter, step)
    after = traj.t_s >= 1.0
    t = traj.t_s[after] - 1.0
    expected = 0.8 - 0.2 * np.exp(-t / 0.1)  # port from 0.6 to 0.8
    assert np.max(np.abs(traj.actuator("port")[after][1:] - expected[1:])) < 1e-3
    fast = simulate(wamv, step)
    assert np.array_equal(fast.actuators, fast.commands)


# ---- thrust maps ---------------------------------------------------------------------------------------------

def test_thrust_maps():
    otter_map = load_vessel("otter").thrusters.port
    assert otter_map.thrust(1.0) == 119.682 and otter_map.thrust(-1.0) == -66.708  # (N): reverse is weaker
    assert otter_map.thrust(0.5) == pytest.approx(119.682 / 4.0) and otter_map.thrust(1.7) == 119.682  # clipped
    banded = ThrustMap(forward_N=100.0, reverse_N=40.0, exponent=1.0, dead_band=0.1, time_constant_s=0.2)
    assert banded.thrust(0.09) == 0.0 and banded.thrust(-0.1) == 0.0  # the dead band gives no thrust
    assert banded.thrust(0.55) == pytest.approx(50.0) and banded.thrust(-1.0) == -40.0  # rescaled past it
    vrx = load_vessel("wamv").thrusters.starboard
    assert vrx.thrust(1.0) == pytest.approx(242.67)
    assert vrx.thrust(-1.0) == -100.0
    assert vrx.thrust(0.0) == pytest.approx(0.0, abs=1e-12)
    assert vrx.thrust(0.45) == pytest.approx(0.5 * (45.59 + 80.6))  # linear between the table's points
    assert all(vrx.thrust(c) <= vrx.thrust(c + 0.01) for c in np.linspace(-1.0, 0.99, 200))


@pytest.mark.parametrize("change, message", [
    ({"table_command": [-1.0, 0.0, 1.0], "table_thrust_N": [-50.0, 10.0, 5.0]}, "thrust table .* is not monotonic"),
    ({"table_command": [-1.0, 0.5, 0.2, 1.0], "table_thrust_N": [-50.0, 0.0, 1.0, 100.0]}, "must increase strictly"),
    ({"table_command": [-1.0, 1.0], "table_thrust_N": [-50.0, 90.0]}, "must be the table's ends"),
    ({"dead_band": 0.5}, r"dead_band 0.5 is outside \[0, 0.5\)"),
    ({"dead_band": -0.1}, r"dead_band -0.1 is outside \[0, 0.5\)"),
    ({"time_constant_s": -1.0}, "must be >= 0"),
    ({"reverse_N": -5.0}, "reverse_N >= 0"),
])
def test_bad_thrust_maps_are_refused_naming_the_field(change, message):
    raw = preset("otter")
    raw["thrusters"]["port"] = {**raw["thrusters"]["port"], "forward_N": 100.0, "reverse_N": 50.0, **change}
    with pytest.raises(ConfigError, match=r"boat.yaml: section 'thrusters'.port: .*" + message):
        vessel_from_dict(raw, source="boat.yaml")


# ---- vessel sections by hull model and layout ------------------------------------------------------------------

def test_sections_follow_the_hull_model_and_the_layout():
    jari = load_vessel("jari_usv")
    assert (jari.layout, jari.hull_model_name, jari.small_craft,
            jari.thrusters) == ("rudder_propeller", "mmg", None, None)
    otter = preset("otter")
    with pytest.raises(ConfigError,
                       match=r"boat.yaml: section\(s\) \['rudder'\] are not used by hull model small_craft "
                                          r"and actuator layout twin_thrusters"):
        vessel_from_dict({**otter, "rudder": preset("jari_usv")["rudder"]}, source="boat.yaml")
    with pytest.raises(ConfigError, match="missing section 'thrusters' .*actuator layout twin_thrusters need"):
        vessel_from_dict({k: v for k, v in otter.items() if k != "thrusters"}, source="boat.yaml")
    with pytest.raises(ConfigError, match="missing section 'throttle'"):
        vessel_from_dict({**preset("jari_usv"), "actuator_layout": "rudder_throttle"}, source="boat.yaml")
    with pytest.raises(ConfigError, match=r"small_craft.X_u = 77.5 must be <= 0 \(a hydrodynamic derivative"):
        vessel_from_dict({**otter, "small_craft": {**otter["small_craft"], "X_u": 77.5}}, source="boat.yaml")
    with pytest.raises(ConfigError, match="hull_model: unknown hull model 'barge'; known: mmg, small_craft"):
        vessel_from_dict({**otter, "hull_model": "barge"}, source="boat.yaml")
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['thruster'\]"):
        vessel_from_dict({**otter, "thruster": {}}, source="boat.yaml")
    lean = {k: v for k, v in otter["small_craft"].items() if k not in ("Y_r", "N_v")}  # optional couplings
    assert vessel_from_dict({**otter, "small_craft": lean}).small_craft == load_vessel("otter").small_craft


# ---- rudder_throttle and rudder_only -------------------------------------------------------------------------

def throttle_boat() -> ManoeuvringModel:
    raw = preset("jari_usv")
    throttle = {"forward_N": 9000.0, "reverse_N": 3500.0, "exponent": 2.0, "dead_band": 0.05, "time_constant_s": 1.2}
    return ManoeuvringModel(vessel_from_dict({**raw, "actuator_layout": "rudder_throttle", "throttle": throttle}))


def test_a_throttle_is_the_engine_speed_of_its_static_thrust():
    model = throttle_boat()
    p = model.vessel.propeller
    for c in (0.3, 0.7, 1.0):
        n = model.engine_speed(c) / 60.0 / p.gear_ratio  # (rev/s)
        assert RHO_WATER * n * n * p.D_P**4 * p.k0 == pytest.approx(model.throttle.thrust(c), rel=1e-12)
    assert model.engine_speed(-0.6) == 0.0 and model.engine_speed(0.04) == 0.0  # astern, dead band: no thrust
    speeds = [model.straight_speed(c) for c in (0.04, 0.3, 0.6, 1.0)]
    assert speeds[0] == 0.0
    assert speeds[1] < speeds[2] < speeds[3]
    rpm_model = ManoeuvringModel(load_vessel("jari_usv"))
    assert model.straight_speed(0.6) == pytest.approx(rpm_model.straight_speed(model.engine_speed(0.6)), abs=1e-5)


def test_rudder_only_engine_speed_inverts_straight_speed():
    raw = preset("jari_usv")
    model = ManoeuvringModel(vessel_from_dict({**raw, "actuator_layout": "rudder_only"}))
    for rpm in (400.0, 650.0, 900.0):
        assert model.engine_speed_for(model.straight_speed(rpm)) == pytest.approx(rpm, rel=1e-6)
    assert model.engine_speed_for(0.0) == 0.0


def test_a_model_pickles_and_is_built_once_per_hull_model_and_layout(otter):
    import pickle

    copy = pickle.loads(pickle.dumps(ManoeuvringModel(otter.vessel, thrust_imbalance=0.05)))
    assert type(copy) is type(otter)
    assert copy.thrust_imbalance == 0.05
    assert copy.derivative([0, 0, 0, 1.0, 0.1, 0.2, 0.5, 0.4], 0.6, 0.3, CALM) == \
        ManoeuvringModel(otter.vessel, thrust_imbalance=0.05).derivative([0, 0, 0, 1.0, 0.1, 0.2, 0.5, 0.4], 0.6, 0.3,
                                                                         CALM)
    assert type(ManoeuvringModel(load_vessel("wamv"))) is type(otter)  # the same hull model and layout
    assert isinstance(otter, ManoeuvringModel)
    assert type(otter).__name__ == "ManoeuvringModel[small_craft, twin_thrusters]"

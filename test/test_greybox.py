"""The torch rollout equals the float simulator model, term by term, for every hull model and actuator layout, and
scripts to TorchScript."""
from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch
import yaml

from usv_predictor.models.greybox import ACTUATOR_MODULES, HULL_MODULES, GreyBoxRollout, greybox_metadata
from usv_predictor.physics.actuators import ACTUATOR_LAYOUTS
from usv_predictor.physics.dynamics import ACTUATOR_FORCES, HULL_FORCES, ManoeuvringModel, SeaLoads
from usv_predictor.physics.hulls import HULL_MODELS
from usv_predictor.physics.vessel import load_vessel, vessel_dir, vessel_from_dict

VESSEL = load_vessel("jari_usv")
T64 = dict(dtype=torch.float64)
THROTTLE = {"forward_N": 9000.0, "reverse_N": 3500.0, "exponent": 2.0, "dead_band": 0.05,  # (N), (N), (-), (-)
            "time_constant_s": 1.2}  # (s)


def variant(layout: str, **sections) -> object:
    """The jari preset as another rudder layout (with a throttle map for rudder_throttle)."""
    raw = yaml.safe_load((vessel_dir() / "jari_usv.yaml").read_text())
    return vessel_from_dict({**raw, "actuator_layout": layout, **sections}, source=f"jari_usv as {layout}")


def small_rudder_boat() -> object:
    """The Otter's small-craft hull with a rudder and propeller: the small_craft hull under a rudder layout."""
    otter = yaml.safe_load((vessel_dir() / "otter.yaml").read_text())
    jari = yaml.safe_load((vessel_dir() / "jari_usv.yaml").read_text())
    propeller = {**jari["propeller"], "D_P": 0.12}  # (m)
    rudder = {**jari["rudder"], "A_R": 0.02}  # (m^2)
    raw = {k: v for k, v in otter.items() if k != "thrusters"}
    # every coefficient non-zero, so that the twins are compared on each (the Otter has no Y_r, N_v, X_uu)
    hull = {**otter["small_craft"], "Y_r": -20.0, "N_v": -15.0, "X_uu": -10.0}  # (N s), (N s), (N s^2/m^2)
    return vessel_from_dict({**raw, "small_craft": hull, "actuator_layout": "rudder_propeller", "propeller": propeller,
                             "rudder": rudder, "actuators": jari["actuators"]}, source="otter hull with a rudder")


VESSELS = {  # every hull model and every layout at least once
    "jari_usv (mmg, rudder_propeller)": VESSEL,
    "jari_usv (mmg, rudder_throttle)": variant("rudder_throttle", throttle=THROTTLE),
    "jari_usv (mmg, rudder_only)": variant("rudder_only"),
    "otter (small_craft, twin_thrusters)": load_vessel("otter"),
    "wamv (small_craft, twin_thrusters, table map, no lag)": load_vessel("wamv"),
    "otter hull (small_craft, rudder_propeller)": small_rudder_boat(),
}


def test_every_hull_model_and_layout_has_both_twins_and_is_compared_here():
    assert set(HULL_FORCES) == set(HULL_MODULES) == set(HULL_MODELS)
    assert set(ACTUATOR_FORCES) == set(ACTUATOR_MODULES) == set(ACTUATOR_LAYOUTS)
    assert {v.hull_model_name for v in VESSELS.values()} == set(HULL_MODELS)
    assert {v.layout for v in VESSELS.values()} == set(ACTUATOR_LAYOUTS)


def set_terms(g: GreyBoxRollout, **terms) -> None:
    with torch.no_grad():
        for name, value in terms.items():
            getattr(g, name)[:] = torch.tensor(value, **T64)


def sea_of(current=(0.0, 0.0), wind=(0.0, 0.0), wave=(0.0, 0.0)) -> SeaLoads:
    """The float model's SeaLoads for the torch model's vector parameters."""
    wind_speed = math.hypot(*wind)
    return SeaLoads(current[0], current[1], 0.0, 0.0, wind_speed, math.atan2(-wind[1], -wind[0]) if wind_speed else 0.0,
                    math.sqrt(math.hypot(*wave)), math.atan2(wave[1], wave[0]))


def float_rollout(model: ManoeuvringModel, sea: SeaLoads, state, controls, dt: float, substeps: int):
    """Reference: the same RK4 on the float model, state relative to the water."""
    u, v, r, psi = state
    c, s = math.cos(psi), math.sin(psi)
    x = [0.0, 0.0, psi, u - (sea.current_n * c + sea.current_e * s), v - (-sea.current_n * s + sea.current_e * c), r]

    def f(x, delta, rpm):
        d = model.derivative(x + [delta, rpm], delta, rpm, sea)
        return d[:6]

    h = dt / substeps
    out = []
    for k, (delta, rpm) in enumerate(controls):
        nxt = controls[min(k + 1, len(controls) - 1)]

        def at(a):  # first-order hold between the samples
            return delta + a * (nxt[0] - delta), rpm + a * (nxt[1] - rpm)

        for j in range(substeps):
            c0, c1, c2 = at(j / substeps), at((j + 0.5) / substeps), at((j + 1) / substeps)
            k1 = f(x, *c0)
            k2 = f([a + 0.5 * h * b for a, b in zip(x, k1)], *c1)
            k3 = f([a + 0.5 * h * b for a, b in zip(x, k2)], *c1)
            k4 = f([a + h * b for a, b in zip(x, k3)], *c2)
            x = [a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        c, s = math.cos(x[2]), math.sin(x[2])
        out.append([x[3] + sea.current_n * c + sea.current_e * s, x[4] - sea.current_n * s + sea.current_e * c,
                    x[5], x[0], x[1], x[2]])
    return np.array(out)


def test_accelerations_match_the_float_model_everywhere():
    model, g = ManoeuvringModel(VESSEL), GreyBoxRollout(VESSEL, dt=0.5)
    rng = np.random.default_rng(0)
    for _ in range(50):
        current, wind, wave = rng.normal(0, 0.3, 2), rng.normal(0, 6.0, 2), np.abs(rng.normal(0, 0.05, 2))
        side = rng.normal(0, 0.03)
        set_terms(g, current_ne=current, wind_ne=wind, wave_ne=wave, propeller_side_force=[side])
        model = ManoeuvringModel(VESSEL, propeller_side_force=side)
        psi, u, v, r = rng.uniform(-3, 3), rng.uniform(0.5, 8), rng.uniform(-1.5, 1.5), rng.uniform(-0.4, 0.4)
        delta, rpm = rng.uniform(-0.6, 0.6), rng.uniform(300, 900)
        expected = model.accelerations(psi, u, v, r, delta, rpm, sea_of(current, wind, wave))
        got = g._accelerations(*(torch.tensor([x], **T64) for x in (psi, u, v, r, delta, rpm)))
        assert np.allclose([float(a) for a in got], expected, rtol=1e-7, atol=1e-9)


@pytest.mark.parametrize("sea", [{}, {"current_ne": (0.3, -0.2), "wind_ne": (-6.0, 2.0), "wave_ne": (0.04, 0.03)}])
def test_rollout_matches_the_float_model(sea):
    model, g = ManoeuvringModel(VESSEL), GreyBoxRollout(VESSEL, dt=0.5, substeps=2)
    set_terms(g, **{k: v for k, v in sea.items()})
    controls = [(0.35 if k > 3 else 0.0, 650.0 + 3.0 * k) for k in range(40)]
    state = (5.4, 0.05, 0.0, 0.4)
    expected = float_rollout(model, sea_of(sea.get("current_ne", (0, 0)), sea.get("wind_ne", (0, 0)),
                                           sea.get("wave_ne", (0, 0))), state, controls, 0.5, 2)
    got = g(torch.tensor([state], **T64), torch.tensor([controls], **T64))[0, 0].numpy()
    assert np.allclose(got, expected, rtol=1e-6, atol=1e-6)


def test_sensor_terms_shift_what_is_measured():
    g = GreyBoxRollout(VESSEL, dt=0.5)
    state = torch.tensor([[5.5, 0.0, 0.02, 1.0]], **T64)
    controls = torch.tensor([[[0.1, 650.0]] * 20], **T64)
    base = g(state, controls)
    set_terms(g, yaw_rate_bias=[0.02], heading_offset=[0.05])
    # the same measured initial state now means a true r of 0 and a true heading of 0.95 rad
    shifted = g(state + torch.tensor([[0.0, 0.0, 0.02, 0.05]], **T64), controls)
    assert torch.allclose(shifted[..., 2], base[..., 2] + 0.02)
    assert torch.allclose(shifted[..., 5], base[..., 5] + 0.05)
    assert torch.allclose(shifted[..., 3:5], base[..., 3:5])


def test_actuator_delay_shifts_the_controls():
    g = GreyBoxRollout(VESSEL, dt=0.5)
    state = torch.tensor([[5.5, 0.0, 0.0, 0.0]], **T64)
    controls = torch.tensor([[[0.0 if k < 6 else 0.3, 650.0] for k in range(30)]], **T64)
    later = torch.tensor([[[0.0 if k < 8 else 0.3, 650.0] for k in range(30)]], **T64)
    set_terms(g, actuator_delay=[1.0])  # two steps
    delayed = g(state, controls)
    set_terms(g, actuator_delay=[0.0])
    assert torch.allclose(delayed, g(state, later))


def test_current_moves_the_track_and_is_differentiable():
    g = GreyBoxRollout(VESSEL, dt=0.5)
    state = torch.tensor([[5.5, 0.0, 0.0, 0.0]], **T64)
    controls = torch.tensor([[[0.3, 650.0]] * 40], **T64)
    calm = g(state, controls)
    set_terms(g, current_ne=(0.4, 0.0))
    g.current_ne.requires_grad_(True)
    # the same water-relative start: the measured over-ground speed includes the current
    sea = g(state + torch.tensor([[0.4, 0.0, 0.0, 0.0]], **T64), controls)
    t = 0.5 * torch.arange(1, 41, **T64)
    assert torch.allclose(sea[0, 0, :, 3] - calm[0, 0, :, 3], 0.4 * t, atol=1e-9)
    sea[0, 0, -1, 3].backward()
    # autograd agrees with a central difference (at a fixed MEASURED start, the current also changes the
    # water-relative start, so the derivative is not simply t)
    eps, moved = 1e-6, []
    for sign in (1.0, -1.0):
        set_terms(g, current_ne=(0.4 + sign * eps, 0.0))
        with torch.no_grad():
            moved.append(float(g(state + torch.tensor([[0.4, 0.0, 0.0, 0.0]], **T64), controls)[0, 0, -1, 3]))
    assert float(g.current_ne.grad[0]) == pytest.approx((moved[0] - moved[1]) / (2 * eps), rel=1e-5)


def test_scripts_saves_and_loads():
    g = GreyBoxRollout(VESSEL, dt=0.5)
    set_terms(g, current_ne=(0.1, 0.2), rudder_offset=[0.02])
    scripted = torch.jit.script(g)
    buffer = io.BytesIO()
    torch.jit.save(scripted, buffer)
    buffer.seek(0)
    loaded = torch.jit.load(buffer)
    state = torch.tensor([[5.0, 0.1, 0.05, 2.0]], **T64)
    controls = torch.tensor([[[0.2, 700.0]] * 10], **T64)
    assert torch.allclose(loaded(state, controls), g(state, controls))


# ---- every hull model and layout ---------------------------------------------------------------------------

def random_levels(vessel, rng) -> tuple[float, float]:
    """Actuator levels (a, b) of the layout's force model: delta rad and rpm; delta and a throttle level; the two
    thruster levels."""
    if vessel.layout == "twin_thrusters":
        return rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)
    if vessel.layout == "rudder_throttle":
        return rng.uniform(-0.6, 0.6), rng.uniform(-0.3, 1.0)
    return rng.uniform(-0.6, 0.6), rng.uniform(0.3, 1.0) * vessel.actuators.rpm_max


@pytest.mark.parametrize("name", list(VESSELS))
def test_accelerations_match_for_every_hull_model_and_layout(name):
    vessel = VESSELS[name]
    g = GreyBoxRollout(vessel, dt=0.5)
    rng = np.random.default_rng(1)
    speed = 2.0 if vessel.hull_model_name == "small_craft" else 8.0  # (m/s) typical of the craft
    for _ in range(40):
        current, wind, wave = rng.normal(0, 0.2, 2), rng.normal(0, 5.0, 2), np.abs(rng.normal(0, 0.02, 2))
        side, k = rng.normal(0, 0.03), rng.normal(0, 0.1)
        set_terms(g, current_ne=current, wind_ne=wind, wave_ne=wave, propeller_side_force=[side],
                  thrust_imbalance=[k])
        model = ManoeuvringModel(vessel, propeller_side_force=side, thrust_imbalance=k)
        psi, u, v, r = rng.uniform(-3, 3), rng.uniform(-0.2,
                                                       1.0) * speed, rng.normal(0, 0.2) * speed, rng.normal(0, 0.3)
        a, b = random_levels(vessel, rng)
        expected = model.accelerations(psi, u, v, r, a, b, sea_of(current, wind, wave))
        got = g._accelerations(*(torch.tensor([x], **T64) for x in (psi, u, v, r, a, b)))
        assert np.allclose([float(x) for x in got], expected, rtol=1e-9, atol=1e-9), name
    # the resistance term scales the hull's straight-running resistance in both hull models
    set_terms(g, current_ne=(0, 0), wind_ne=(0, 0), wave_ne=(0, 0), propeller_side_force=[0.0], thrust_imbalance=[0.0])
    zero = torch.zeros(1, **T64)
    u = torch.tensor([0.5 * speed], **T64)
    a, b = (torch.tensor([x], **T64) for x in ManoeuvringModel(vessel).initial_actuators(0.0))
    base = float(g._accelerations(zero, u, zero, zero, a, b)[0])
    set_terms(g, resistance_change=[0.5])
    assert float(g._accelerations(zero, u, zero, zero, a, b)[0]) < base < 0.0  # 50 % more resistance, coasting


def lagged(y0: float, u0: float, u1: float, u2: float, t: float, h: float) -> tuple[float, float, float]:
    """A first-order lag T y' = u - y driven by the linear command u0 -> u2 over h: its exact level at 0, h/2, h."""
    if t == 0.0:
        return u0, u1, u2
    drift = t * (u2 - u0) / h
    return y0, u1 - drift + (y0 - u0 + drift) * math.exp(-0.5
                                                         * h / t), u2 - drift + (y0 - u0 + drift) * math.exp(-h / t)


def float_rollout_of(vessel, model: ManoeuvringModel, sea: SeaLoads, state, controls, dt: float, substeps: int,
                     rudder_offset: float = 0.0):
    """Reference for any layout: RK4 on the float model, the reported controls held first-order; a reported
    command drives its motor lag exactly (`lagged`), rudder_only runs at the engine speed of its initial speed."""
    u, v, r, psi = state
    c, s = math.cos(psi), math.sin(psi)
    x = [0.0, 0.0, psi, u - (sea.current_n * c + sea.current_e * s), v - (-sea.current_n * s + sea.current_e * c), r]
    layout = vessel.actuator_layout
    lags = {"throttle": getattr(vessel.throttle, "time_constant_s", 0.0)}
    if vessel.thrusters is not None:
        lags.update(port=vessel.thrusters.port.time_constant_s, starboard=vessel.thrusters.starboard.time_constant_s)
    commanded = [k for k, control in enumerate(layout.controls) if control.source == "command"]
    level = {k: controls[0][k] for k in commanded}  # the motors at the first reported command
    rpm = model.engine_speed_for(x[3]) if layout.name == "rudder_only" else None
    h = dt / substeps

    def f(x, levels):
        a, b = levels
        return model.derivative(x + [a, b], a, b, sea)[:6]

    out = []
    for k, now in enumerate(controls):
        nxt = controls[min(k + 1, len(controls) - 1)]
        for j in range(substeps):
            stage = [[now[i] + w * (nxt[i] - now[i]) for i in range(len(now))]
                     for w in (j / substeps, (j + 0.5) / substeps, (j + 1) / substeps)]
            for i in commanded:
                name = layout.controls[i].name
                ys = lagged(level[i], stage[0][i], stage[1][i], stage[2][i], lags[name], h)
                for q in range(3):
                    stage[q][i] = ys[q]
                level[i] = ys[2]
            if layout.name == "twin_thrusters":
                levels = [(st[0], st[1]) for st in stage]
            elif rpm is not None:
                levels = [(st[0] + rudder_offset, rpm) for st in stage]
            else:
                levels = [(st[0] + rudder_offset, st[1]) for st in stage]
            k1 = f(x, levels[0])
            k2 = f([a + 0.5 * h * b for a, b in zip(x, k1)], levels[1])
            k3 = f([a + 0.5 * h * b for a, b in zip(x, k2)], levels[1])
            k4 = f([a + h * b for a, b in zip(x, k3)], levels[2])
            x = [a + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        c, s = math.cos(x[2]), math.sin(x[2])
        out.append([x[3] + sea.current_n * c + sea.current_e * s, x[4] - sea.current_n * s + sea.current_e * c,
                    x[5], x[0], x[1], x[2]])
    return np.array(out)


def zigzag_rudder(k: int) -> float:
    """A zig-zag of the reported rudder angle (rad): +-20 deg, reversed every 12 steps after 3."""
    return 0.0 if k < 3 else math.radians(20.0) * (1.0 if ((k - 3) // 12) % 2 == 0 else -1.0)


CASES = {  # the spec's runs: a twin turning circle with a current and an imbalance, a throttle zig-zag, rudder only
    "otter turning circle, current, imbalance": (
        "otter (small_craft, twin_thrusters)", (1.8, 0.0, 0.0, 0.3),
        [(0.6, 0.6) if k < 4 else (0.8, 0.4) for k in range(60)],
        {"current_ne": (0.3, -0.2), "thrust_imbalance": [0.08]}),
    "otter spin on the spot from rest": (
        "otter (small_craft, twin_thrusters)", (0.0, 0.0, 0.0, 0.0), [(1.0, -1.0)] * 40, {"thrust_imbalance": [-0.05]}),
    "wamv turning circle with wind": (
        "wamv (small_craft, twin_thrusters, table map, no lag)", (2.0, 0.0, 0.0, 1.0),
        [(0.7, 0.7) if k < 4 else (0.9, 0.3) for k in range(60)], {"wind_ne": (-5.0, 2.0), "thrust_imbalance": [0.05]}),
    "rudder_throttle zig-zag with waves": (
        "jari_usv (mmg, rudder_throttle)", (5.0, 0.0, 0.0, 0.5),
        [(zigzag_rudder(k), 0.6 + 0.005 * k) for k in range(60)], {"wave_ne": (0.02, 0.01), "rudder_offset": [0.01]}),
    "rudder_only turn with a current": (
        "jari_usv (mmg, rudder_only)", (5.0, 0.1, 0.0, -0.4), [(0.0 if k < 4 else 0.3,) for k in range(50)],
        {"current_ne": (-0.2, 0.3)}),
    "small-craft hull under a rudder": (
        "otter hull (small_craft, rudder_propeller)", (1.5, 0.0, 0.0, 0.0),
        [(0.0 if k < 4 else 0.3, 1500.0) for k in range(40)], {}),
}


@pytest.mark.parametrize("case", list(CASES))
def test_rollouts_match_for_every_layout(case):
    name, state, controls, terms = CASES[case]
    vessel = VESSELS[name]
    g = GreyBoxRollout(vessel, dt=0.5, substeps=2)
    set_terms(g, **terms)
    model = ManoeuvringModel(vessel, thrust_imbalance=terms.get("thrust_imbalance", [0.0])[0])
    sea = sea_of(terms.get("current_ne", (0, 0)), terms.get("wind_ne", (0, 0)), terms.get("wave_ne", (0, 0)))
    expected = float_rollout_of(vessel, model, sea, state, controls, 0.5, 2, terms.get("rudder_offset", [0.0])[0])
    got = g(torch.tensor([state], **T64), torch.tensor([controls], **T64))[0, 0].numpy()
    assert np.allclose(got, expected, rtol=1e-7, atol=1e-7), case
    scripted = torch.jit.script(g)
    assert torch.allclose(scripted(torch.tensor([state], **T64), torch.tensor([controls], **T64))[0, 0],
                          torch.from_numpy(got), rtol=1e-12, atol=1e-12)


def test_a_command_lag_is_exact_and_a_level_control_is_not_lagged():
    """The Otter's 0.1 s motor lag: a step of the port command shows up in the thrust over a few tenths of a
    second, while an instantaneous map (WAM-V) and a rudder angle act at once."""
    otter = load_vessel("otter")
    g = GreyBoxRollout(otter, dt=0.05, substeps=1)
    step = [(0.5, 0.5)] * 2 + [(1.0, 0.5)] * 20
    out = g(torch.tensor([[1.5, 0.0, 0.0, 0.0]], **T64), torch.tensor([step], **T64))[0, 0].numpy()
    r = out[:, 2]
    # the yaw rate builds up as exp(-t / 0.1 s) of the motor times the boat's own yaw lag: later than instant
    wamv_like = GreyBoxRollout(otter, dt=0.05, substeps=1)
    wamv_like.actuator_forces.lag.e_half.zero_()
    wamv_like.actuator_forces.lag.e_full.zero_()
    wamv_like.actuator_forces.lag.t.zero_()
    instant = wamv_like(torch.tensor([[1.5, 0.0, 0.0, 0.0]], **T64), torch.tensor([step], **T64))[0, 0].numpy()
    assert 0.0 < r[3] < instant[3, 2]  # lagged thrust: less yaw rate early on
    assert r[-1] == pytest.approx(instant[-1, 2], rel=0.05)  # the lag is 0.1 s: after 1 s both have caught up


def test_metadata_names_the_layout_and_the_hull_model():
    for vessel in (VESSEL, load_vessel("otter"), VESSELS["jari_usv (mmg, rudder_only)"]):
        g = GreyBoxRollout(vessel, dt=0.5)
        meta = greybox_metadata(vessel, g)
        assert meta["control_layout"] == list(vessel.actuator_layout.control_names)
        assert meta["actuator_layout"] == vessel.layout
        assert meta["hull_model"] == vessel.hull_model_name
        assert list(meta["architecture"]["hull"]) == list(g.hull_names)
    assert greybox_metadata(VESSEL, GreyBoxRollout(VESSEL, dt=0.5))["control_layout"] == ["delta", "rpm"]
    with pytest.raises(ValueError, match=r"controls must be \(B, H, 2\)"):
        GreyBoxRollout(load_vessel("otter"), dt=0.5)(torch.zeros(1, 4, **T64), torch.zeros(1, 3, 1, **T64))


def test_rudder_only_holds_the_engine_speed_of_its_initial_speed():
    vessel = VESSELS["jari_usv (mmg, rudder_only)"]
    model, g = ManoeuvringModel(vessel), GreyBoxRollout(vessel, dt=0.5)
    u0 = model.straight_speed(650.0)
    assert model.engine_speed_for(u0) == pytest.approx(650.0, rel=1e-6)  # the closed form inverts straight_speed
    straight = g(torch.tensor([[u0, 0.0, 0.0, 0.0]], **T64), torch.zeros(1, 40, 1, **T64))[0, 0].numpy()
    assert np.allclose(straight[:, 0], u0, atol=1e-6)  # it holds its speed, rudder amidships
    with torch.no_grad():
        g.engine_speed_rpm[:] = 700.0  # a known engine speed replaces the inferred one
    faster = g(torch.tensor([[u0, 0.0, 0.0, 0.0]], **T64), torch.zeros(1, 40, 1, **T64))[0, 0].numpy()
    assert faster[-1, 0] > u0 + 0.1


def test_rudder_only_holds_the_engine_speed_of_its_reference_state():
    """A prediction started inside a turn (slowed down at the same engine setting) holds the engine speed of the
    manoeuvre's straight running when given it as the reference state; the reference's water speed is its surge less
    the current term along its heading; without a reference the start state is the reference."""
    vessel = VESSELS["jari_usv (mmg, rudder_only)"]
    model, g = ManoeuvringModel(vessel), GreyBoxRollout(vessel, dt=0.5)
    approach = model.straight_speed(650.0)  # (m/s)
    in_turn = torch.tensor([[0.6 * approach, 0.4, 0.05, 1.0]], **T64)  # (1, 4) slower, drifting, turning
    held = torch.full((1, 60, 1), math.radians(20.0), **T64)  # (1, H, 1) the turn's rudder
    reference = torch.tensor([[approach, 0.0, 0.0, 0.2]], **T64)  # (1, 4) the approach
    start_only = g(in_turn, held)[0, 0].numpy()
    assert np.array_equal(start_only, g(in_turn, held, in_turn)[0, 0].numpy())  # None = the start state
    with torch.no_grad():
        g.engine_speed_rpm[:] = 650.0
    known = g(in_turn, held)[0, 0].numpy()  # the engine speed the boat really runs at
    with torch.no_grad():
        g.engine_speed_rpm[:] = 0.0
    approached = g(in_turn, held, reference)[0, 0].numpy()
    assert np.allclose(approached, known, atol=1e-6)  # the approach's engine speed is the boat's (650 rpm)
    assert start_only[-1, 0] < known[-1, 0] - 0.1  # the start state's engine speed runs slow in the turn
    # a current along the approach heading: the engine holds the water speed, approach minus the current's share
    with torch.no_grad():
        g.current_ne[:] = torch.tensor([0.5 * math.cos(0.2), 0.5 * math.sin(0.2)], **T64)  # 0.5 m/s toward 0.2 rad
    over_ground = torch.tensor([[approach + 0.5, 0.0, 0.0, 0.2]], **T64)
    straight = g(over_ground, torch.zeros(1, 40, 1, **T64), over_ground)[0, 0].numpy()
    assert np.allclose(straight[:, 0], approach + 0.5, atol=1e-6)  # it holds its ground speed: 650 rpm + the current

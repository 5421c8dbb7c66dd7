"""The torch MMG rollout equals the float simulator model, term by term, and scripts to TorchScript."""
from __future__ import annotations

import io
import math

import numpy as np
import pytest
import torch

from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.physics.dynamics import ManoeuvringModel, SeaLoads
from usv_predictor.physics.vessel import load_vessel

VESSEL = load_vessel("jari_usv")
T64 = dict(dtype=torch.float64)


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

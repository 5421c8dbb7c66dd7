"""The low-order model family (models/nomoto.py, fitting/nomoto_fit.py, replay/low_order.py): identification of a
simulated Nomoto boat, the artifact's round trip, evaluate and the node's rollout, and `--family auto`'s choice."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
import torch

from usv_predictor.data.recording import Recording
from usv_predictor.errors import ModelError
from usv_predictor.fitting.nomoto_fit import NomotoFitOptions, fit_nomoto
from usv_predictor.models.artifact import quiet_jit
from usv_predictor.models.loading import load_model
from usv_predictor.models.nomoto import (NUMPY_FORM, NomotoCoefficients, NomotoRollout, export_nomoto, layout_weights,
                                         numpy_rollout, probe_inputs)
from usv_predictor.physics.actuators import actuator_layout
from usv_predictor.physics.vessel import load_vessel

REPO = Path(__file__).resolve().parents[1]
FUZHOU_VESSEL = REPO / "docs" / "vessels" / "fuzhou_usv.yaml"  # a rudder_only vessel file (assumed values)
TRUE = {"K": 0.25, "T": 6.0, "s_0": math.radians(1.0), "T_u": 8.0, "k_r": 0.6, "k_v": -0.5}  # the simulated boat
DT = 0.5  # (s)


def nomoto_boat(noise: float = 0.0, seed: int = 0, duration_s: float = 240.0, rudder_deg: float = 25.0,
                check_deg: float = 20.0, name: str = "zigzag") -> Recording:
    """A rudder_only zig-zag of the first-order Nomoto boat TRUE (approach 1.5 m/s), integrated by RK4 at 0.01 s
    (not the model's exact-step scheme) with a rudder rate of 10 deg/s, sampled at DT, with measurement noise
    `noise` x (0.03 m/s, 0.03 m/s, 0.005 rad/s, 0.01 rad, 0.3 m) on u, v, r, psi, position."""
    k, t, s_0, t_u, k_r, k_v = (TRUE[n] for n in ("K", "T", "s_0", "T_u", "k_r", "k_v"))
    speed, fine = 1.5, 0.01
    every = int(round(DT / fine))

    def derivative(st: np.ndarray, delta: float) -> np.ndarray:  # [u, r, psi, x, y]
        u, r, psi = st[0], st[1], st[2]
        v = k_v * r
        return np.array([(speed - u) / t_u - k_r * r * r, (k * (delta - s_0) - r) / t, r,
                         u * math.cos(psi) - v * math.sin(psi), u * math.sin(psi) + v * math.cos(psi)])

    st, delta, side, rows = np.array([speed, 0.0, 0.0, 0.0, 0.0]), 0.0, 1, []
    for i in range(int(round(duration_s / fine)) + 1):
        if i % every == 0:
            rows.append([st[0], k_v * st[1], st[1], st[2], st[3], st[4], delta])
        if i * fine > 10.0:
            heading = math.degrees(st[2])
            side = -1 if side > 0 and heading >= check_deg else 1 if side < 0 and heading <= -check_deg else side
            goal = side * math.radians(rudder_deg)
        else:
            goal = 0.0
        delta += max(-math.radians(10.0) * fine, min(math.radians(10.0) * fine, goal - delta))
        k1 = derivative(st, delta)
        k2 = derivative(st + 0.5 * fine * k1, delta)
        k3 = derivative(st + 0.5 * fine * k2, delta)
        k4 = derivative(st + fine * k3, delta)
        st = st + fine / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    a = np.array(rows)
    rng = np.random.default_rng(seed)
    n = len(a)
    return Recording(name=name, source=name, t0_ns=0, dt=DT, t_s=DT * np.arange(n),
                     nu=a[:, 0:3] + noise * rng.normal(size=(n, 3)) * np.array([0.03, 0.03, 0.005]),
                     psi=a[:, 3] + noise * rng.normal(size=n) * 0.01, controls=a[:, 6:7],
                     position=a[:, 4:6] + noise * rng.normal(size=(n, 2)) * 0.3, layout="rudder_only")


def test_the_fit_recovers_the_constants_of_a_noise_free_nomoto_boat():
    fit = fit_nomoto([nomoto_boat()], NomotoFitOptions(intervals=False))
    c = fit.coefficients
    assert c.speed_mode == "reference"  # rudder_only: no propulsion level
    for have, want in ((c.K, TRUE["K"]), (c.T1, TRUE["T"]), (c.T_u, TRUE["T_u"]), (c.k_r, TRUE["k_r"]),
                       (c.k_v, TRUE["k_v"]), (c.s_0, TRUE["s_0"])):
        assert have == pytest.approx(want, rel=0.01)  # within 1 %: the integrators differ (RK4 0.01 s vs exact)


def test_the_fit_recovers_k_and_t_of_a_noisy_record_within_3_percent_and_inside_their_intervals():
    fit = fit_nomoto([nomoto_boat(noise=1.0, seed=1)])
    c, ci = fit.coefficients, fit.intervals()
    assert c.K == pytest.approx(TRUE["K"], rel=0.03)
    assert c.T1 == pytest.approx(TRUE["T"], rel=0.03)
    assert ci["K"][0] < TRUE["K"] < ci["K"][1]
    assert ci["T1"][0] < TRUE["T"] < ci["T1"][1]
    assert c.T_u == pytest.approx(TRUE["T_u"], rel=0.5)  # the speed response of a zig-zag is weakly determined
    assert ci["T_u"][0] < c.T_u < ci["T_u"][1]
    turn = fit.turning_circle(math.radians(20.0), 1.5)
    lo, hi = turn["radius_ci95_m"]
    assert lo < turn["radius_m"] < hi and math.isfinite(hi)


def test_the_second_order_with_t3_equal_to_t2_is_the_first_order():
    first = NomotoCoefficients(1, 0.3, 7.0, 0.0, 0.0, 0.01, 9.0, 0.4, -0.6, "reference")
    second = replace(first, order=2, T2=1.5, T3=1.5)
    w_s, w_p = layout_weights(actuator_layout("rudder_only"))
    state, controls, reference = probe_inputs(1)
    one = numpy_rollout(first, w_s, w_p, DT, state, controls, reference)
    two = numpy_rollout(second, w_s, w_p, DT, state, controls, reference)
    np.testing.assert_allclose(two, one, atol=1e-12)


def test_the_second_order_lags_the_first_for_a_step():
    first = NomotoCoefficients(1, 0.3, 7.0, 0.0, 0.0, 0.0, 9.0, 0.0, 0.0, "reference")
    second = replace(first, order=2, T2=2.0, T3=0.0)
    w_s, w_p = layout_weights(actuator_layout("rudder_only"))
    state, controls = np.array([[1.0, 0.0, 0.0, 0.0]]), np.full((1, 200, 1), 0.2)
    r1 = numpy_rollout(first, w_s, w_p, DT, state, controls)[0, 0, :, 2]
    r2 = numpy_rollout(second, w_s, w_p, DT, state, controls)[0, 0, :, 2]
    assert np.all(r2[:20] < r1[:20])  # the extra pole delays the response
    assert r2[-1] == pytest.approx(0.3 * 0.2, rel=1e-6) and r1[-1] == pytest.approx(0.3 * 0.2, rel=1e-6)


def test_coefficients_that_would_diverge_are_refused():
    with pytest.raises(ModelError, match="time constants"):
        NomotoCoefficients(1, 0.3, -1.0, 0.0, 0.0, 0.0, 9.0, 0.0, 0.0, "reference")
    with pytest.raises(ModelError, match="T2"):
        NomotoCoefficients(2, 0.3, 5.0, 6.0, 0.0, 0.0, 9.0, 0.0, 0.0, "reference")


@pytest.mark.parametrize("layout", ["rudder_only", "rudder_propeller", "twin_thrusters"])
def test_the_torchscript_rollout_equals_the_numpy_one(layout):
    c = NomotoCoefficients(2, 0.3, 7.0, 1.2, 0.5, 0.02, 9.0, 0.4, -0.6,
                           "reference" if layout == "rudder_only" else "command", 0.2, 0.8)
    lay = actuator_layout(layout)
    w_s, w_p = layout_weights(lay)
    state, controls, reference = probe_inputs(len(lay.control_names))
    with quiet_jit():
        module = torch.jit.script(NomotoRollout(c, lay, DT))
    want = module(torch.from_numpy(state), torch.from_numpy(controls), torch.from_numpy(reference)).numpy()
    np.testing.assert_allclose(numpy_rollout(c, w_s, w_p, DT, state, controls, reference), want, atol=1e-12)


def test_the_artifact_round_trips_and_predicts_as_the_fitted_model(tmp_path):
    rec = nomoto_boat(noise=1.0, seed=2)
    fit = fit_nomoto([rec], NomotoFitOptions(intervals=False))
    vessel = load_vessel(FUZHOU_VESSEL)
    path = tmp_path / "nomoto.pt"
    export_nomoto(str(path), fit.coefficients, vessel, DT, training_data_sha256="0" * 64,
                  identification=fit.to_json())
    model = load_model(str(path), dt=DT)
    assert model.metadata["model_type"] == "nomoto" and model.inference_note == NUMPY_FORM
    state, controls = rec.state()[10:14], np.stack([rec.controls[10 + k:70 + k] for k in range(4)])
    reference = np.repeat(rec.state()[:1], 4, axis=0)
    want = fit.predict(state, controls, reference)
    np.testing.assert_allclose(model.predict(state, controls, reference), want, atol=1e-9)
    with torch.inference_mode():  # the file's own TorchScript rollout too
        scripted = model.module(torch.from_numpy(state), torch.from_numpy(controls), torch.from_numpy(reference))
    np.testing.assert_allclose(scripted.numpy(), want, atol=1e-9)
    assert model.embedded_vessel.name == vessel.name


def test_evaluate_and_the_node_rollout_run_the_low_order_model(tmp_path):
    from usv_predictor.analysis.evaluation import evaluate
    from usv_predictor.node.live import Rollout

    rec = nomoto_boat(noise=1.0, seed=3)
    fit = fit_nomoto([rec], NomotoFitOptions(intervals=False))
    path = tmp_path / "nomoto.pt"
    export_nomoto(str(path), fit.coefficients, load_vessel(FUZHOU_VESSEL), DT, training_data_sha256="0" * 64,
                  identification=fit.to_json())
    model = load_model(str(path), dt=DT)
    result = evaluate(model, [rec], "gnss", (10.0, 30.0), 5.0)
    assert result.summary["mean_position_error_after_30s_m"] < 2.0  # m: the fitted boat, noise 0.3 m
    assert result.summary["open_loop_diverged_windows"] == 0
    rollout = Rollout(model, 40)
    state, control, reference = rec.state()[20], rec.controls[20], rec.state()[0]
    live = rollout(state, control, reference)  # (E, H, 6) the node's call
    want = model.predict(state[None], np.tile(control, (1, 40, 1)), reference[None])[:, 0]
    np.testing.assert_allclose(live, want, atol=1e-12)
    assert rollout.accepts_reference  # the approach's speed reaches it, as in replay


# ---- --family auto ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class GentleThenHard:
    """A manoeuvre of the simulator: a 10/10 zig-zag for half the run, then hard-over turns held 40 s each."""

    duration_s: float = 240.0
    rpm: float = 0.0

    name = "gentle_then_hard"

    @property
    def propulsion(self) -> float:
        return self.rpm

    def controller(self):
        state = {"side": 1, "psi0": None}

        def command(t: float, psi: float, r: float) -> tuple[float, float]:
            if t < 5.0:
                return 0.0, self.rpm
            if t >= 0.5 * self.duration_s:
                return math.radians(35.0) * (1 if int((t - 0.5 * self.duration_s) // 40.0) % 2 == 0 else -1), self.rpm
            if state["psi0"] is None:
                state["psi0"] = psi
            change = psi - state["psi0"]
            if (state["side"] > 0 and change >= math.radians(10.0)) or (state["side"] < 0
                                                                        and change <= -math.radians(10.0)):
                state["side"] = -state["side"]
            return state["side"] * math.radians(10.0), self.rpm

        return command


def mmg_recording(vessel) -> Recording:
    """GentleThenHard by the vessel file's own MMG model, at DT, as a rudder_only recording."""
    from usv_predictor.physics.dynamics import ManoeuvringModel
    from usv_predictor.physics.simulator import simulate

    traj = simulate(ManoeuvringModel(vessel), GentleThenHard(rpm=300.0), output_rate_hz=1.0 / DT)  # ~0.6 m/s
    return Recording(name="mmg", source="mmg", t0_ns=0, dt=DT, t_s=traj.t_s, nu=traj.nu, psi=traj.psi_unwrapped,
                     controls=traj.actuator("delta")[:, None], position=traj.eta[:, :2], layout="rudder_only")


def test_auto_keeps_the_family_that_predicts_the_held_out_half_better():
    from usv_predictor.replay.low_order import LowOrderRequest, compare_families

    vessel = load_vessel(FUZHOU_VESSEL)
    request = LowOrderRequest((), Path("unused.pt"), str(FUZHOU_VESSEL), family="auto", dt=DT, prior="fix")
    # a Nomoto boat: the grey box of the assumed vessel file cannot become it, the low-order model is it
    chosen, why, candidates = compare_families(request, vessel, [nomoto_boat(noise=1.0, seed=4)])
    assert chosen == "nomoto", why
    assert candidates["nomoto"]["open_loop_m"]["30s"] < candidates["greybox"]["open_loop_m"]["30s"]
    assert "nomoto predicts the held-out halves better" in why and "greybox" in why
    # the vessel file's own MMG boat, gentle zig-zags then hard-over turns: the linear yaw of the first half
    # overshoots the saturating hull of the second, the grey box (its hull the file's) does not
    chosen, why, candidates = compare_families(request, vessel, [mmg_recording(vessel)])
    assert chosen == "greybox", why
    assert candidates["greybox"]["open_loop_m"]["30s"] < candidates["nomoto"]["open_loop_m"]["30s"]


def test_the_node_loads_the_low_order_model_for_its_vessel(tmp_path):
    """node.load_model: the family's compiled rollout, the vessel it embeds, the approach reference taken."""
    import dataclasses

    from usv_predictor.config import load_predictor_config
    from usv_predictor.node.node import load_model as node_load_model

    vessel = load_vessel(FUZHOU_VESSEL)
    fit = fit_nomoto([nomoto_boat(seed=5)], NomotoFitOptions(intervals=False))
    path = tmp_path / "nomoto.pt"
    export_nomoto(str(path), fit.coefficients, vessel, DT, training_data_sha256="0" * 64,
                  identification=fit.to_json())
    config = dataclasses.replace(load_predictor_config(), model_path=str(path), vessel=vessel.name, dt=DT,
                                 horizon_s=30.0, ensemble_size=1)
    rollout, chosen = node_load_model(str(path), config)
    assert chosen.name == vessel.name and rollout.accepts_reference
    assert rollout.artifact.inference_note == NUMPY_FORM
    out = rollout(np.array([1.5, 0.0, 0.05, 0.3]), np.array([0.2]), np.array([1.5, 0.0, 0.0, 0.3]))
    assert out.shape == (1, 60, 6) and np.all(np.isfinite(out))


def test_auto_s_choice_refuses_what_cannot_be_identified_or_diverges():
    from usv_predictor.errors import NotIdentifiableError
    from usv_predictor.replay.low_order import choose

    good = {"open_loop_m": {"10s": 2.0, "30s": 9.0}, "diverged": 0}
    better_short = {"open_loop_m": {"10s": 1.0, "30s": 9.5}, "diverged": 0}
    assert choose({"greybox": good, "nomoto": better_short})[0] == "greybox"  # 30 s decides, then 10 s
    assert choose({"greybox": {"refused": "needs 2 manoeuvres"}, "nomoto": good})[0] == "nomoto"
    chosen, why = choose({"greybox": {**better_short, "open_loop_m": {"10s": 0.1, "30s": 0.2}, "diverged": 3},
                          "nomoto": good})
    assert chosen == "nomoto" and "3 rollouts diverged" in why
    with pytest.raises(NotIdentifiableError, match="no family predicts"):
        choose({"greybox": {"refused": "a"}, "nomoto": {"refused": "b"}})

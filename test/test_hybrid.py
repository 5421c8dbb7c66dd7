"""The generalising hybrid: the identified grey box + a bounded, data-supported learned residual ensemble.

What is proven here: the ensemble runs as one batched rollout and equals its members run one by one; an untrained
residual is exactly the grey box; the learned term never exceeds its bound and vanishes away from the data it was
fitted on (so the physics alone predicts there); and, trained on recordings in a steady wind the calm-water grey
box does not carry (a heading-dependent force: what the residual's sin / cos psi features are for), the hybrid
predicts held-out manoeuvres better than the grey box, exported as one TorchScript ensemble whose members spread.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from usv_predictor.data.recording import recording_from_signals
from usv_predictor.fitting import hybrid_fit
from usv_predictor.fitting import identification as idf
from usv_predictor.models.artifact import load_artifact
from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.models.hybrid import (GENERALISING_FEATURES, GeneralisingResidual, ResidualGreyBox, SumResidual,
                                         ZeroResidual)
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import RandomManoeuvre, TurningCircle, ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

DT = 0.2  # (s) identification step
F = len(GENERALISING_FEATURES)


@pytest.fixture(scope="module")
def vessel():
    return load_vessel("jari_usv")


def _randomised(residual: GeneralisingResidual, scale: float, seed: int = 0) -> GeneralisingResidual:
    """Non-zero output weights (a trained-looking residual) and a wide training range."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        residual.head_weight.copy_(torch.randn(residual.head_weight.shape, generator=g, dtype=torch.float64) * scale)
        residual.head_bias.copy_(torch.randn(residual.head_bias.shape, generator=g, dtype=torch.float64) * scale)
        residual.z_low.fill_(-50.0)
        residual.z_high.fill_(50.0)
        residual.in_mean.copy_(torch.tensor([0.0, 0.0, 1.0, 0.0, 650.0, 0.0, 0.0], dtype=torch.float64))
        residual.in_std.copy_(torch.tensor([0.1, 0.3, 0.2, 0.2, 50.0, 0.7, 0.7], dtype=torch.float64))
        residual.bound.copy_(torch.tensor([0.02, 0.05, 0.05], dtype=torch.float64))
    return residual


def _member(residual: GeneralisingResidual, e: int) -> GeneralisingResidual:
    """Member e of an ensemble residual as a one-member residual with the same weights and statistics."""
    one = GeneralisingResidual(residual.L, residual.u_ref, 1, residual.head_weight.shape[1], len(residual.weights))
    with torch.no_grad():
        for mine, theirs in zip(one.parameters(), residual.parameters()):
            mine.copy_(theirs[e:e + 1] if theirs.dim() == 3 else theirs)
    return one


def _inputs(batch: int = 4, steps: int = 30) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(3)
    state = torch.tensor([[5.5, 0.1, 0.02, 0.3]], dtype=torch.float64).repeat(batch, 1)
    state[:, 3] = torch.rand(batch, generator=g, dtype=torch.float64) * 6.0  # headings all round
    delta = 0.35 * torch.sin(torch.linspace(0.0, 3.0, steps, dtype=torch.float64))[None, :].repeat(batch, 1)
    controls = torch.stack([delta, torch.full_like(delta, 650.0)], dim=-1)  # (B, H, 2)
    return state, controls


def test_ensemble_rollout_equals_its_members_run_one_by_one(vessel):
    residual = _randomised(GeneralisingResidual(vessel.geometry.L_pp, 5.0, members=3, hidden=6), scale=0.5)
    ensemble = ResidualGreyBox(vessel, DT, residual, members=3)
    state, controls = _inputs()
    with torch.no_grad():
        out = ensemble(state, controls)  # (3, B, H, 6)
        singles = [ResidualGreyBox(vessel, DT, _member(residual, e))(state, controls)[0] for e in range(3)]
    assert out.shape == (3, 4, 30, 6)
    for e in range(3):
        torch.testing.assert_close(out[e], singles[e], rtol=0.0, atol=1e-10)
    # the members differ, so mixing their rows up would fail the comparison above
    assert float((out[0, :, -1, 3:5] - out[1, :, -1, 3:5]).abs().max()) > 0.1


def test_untrained_residual_is_the_grey_box(vessel):
    hybrid = ResidualGreyBox(vessel, DT, GeneralisingResidual(vessel.geometry.L_pp, 5.0, members=2), members=2)
    state, controls = _inputs()
    with torch.no_grad():
        out = hybrid(state, controls)
        grey = GreyBoxRollout(vessel, DT)(state, controls)[0]
    torch.testing.assert_close(out[0], grey, rtol=0.0, atol=0.0)
    torch.testing.assert_close(out[1], grey, rtol=0.0, atol=0.0)


def test_learned_term_never_exceeds_its_bound(vessel):
    residual = _randomised(GeneralisingResidual(vessel.geometry.L_pp, 5.0, members=2, hidden=8), scale=50.0)
    x = torch.randn(2, 2000, F, dtype=torch.float64) * 5.0  # (E, N, F) far and wide
    x[..., 4] = 650.0 + 300.0 * x[..., 4]
    with torch.no_grad():
        residual.z_low.fill_(-math.inf)
        residual.z_high.fill_(math.inf)  # no envelope: the bound alone limits it
        out = residual.nondimensional(x).abs()  # (E, N, 3)
    assert bool((out <= residual.bound * (1.0 + 1e-12)).all())
    assert bool((out.amax(dim=(0, 1)) > 0.95 * residual.bound).all())  # the weights are large: the bound binds


def test_learned_term_vanishes_away_from_the_data(vessel):
    residual = _randomised(GeneralisingResidual(vessel.geometry.L_pp, 5.0, members=1, hidden=8), scale=5.0)
    with torch.no_grad():
        residual.z_low.fill_(-2.0)
        residual.z_high.fill_(2.0)  # the training data spanned +-2 std of every feature
    psi = torch.tensor([0.3, 0.3], dtype=torch.float64)
    u = torch.tensor([5.0, 5.0], dtype=torch.float64)
    v = torch.tensor([0.1, 0.1], dtype=torch.float64)
    r = torch.tensor([0.02, 1.0], dtype=torch.float64)  # r' = 0.06 (seen) and 3 (eight std beyond the data)
    a = torch.tensor([0.1, 0.1], dtype=torch.float64)
    b = torch.tensor([650.0, 650.0], dtype=torch.float64)
    with torch.no_grad():
        z = (residual.features(psi, u, v, r, a, b) - residual.in_mean) / residual.in_std
        envelope = residual.envelope(z)[:, 0]
        extra = residual(psi, u, v, r, a, b)  # (2, 3)
    assert float(envelope[0]) == 1.0
    assert float(extra[0].abs().max()) > 1e-4
    assert float(envelope[1]) < 1e-20
    assert float(extra[1].abs().max()) < 1e-20


@pytest.fixture(scope="module")
def windy_day(vessel):
    """Six manoeuvres in a steady 14 m/s wind from 060 deg (no gusts): a force the calm-water grey box lacks."""
    model, env = ManoeuvringModel(vessel), Environment(wind_speed=14.0, wind_from_deg=60.0)
    manoeuvres = (ZigZag(20.0, 20.0, 650.0, duration_s=70.0), ZigZag(10.0, 10.0, 700.0, duration_s=70.0, side=-1),
                  TurningCircle(25.0, 650.0, duration_s=70.0), TurningCircle(20.0, 700.0, duration_s=70.0, side=-1),
                  RandomManoeuvre(seed=4, duration_s=90.0), ZigZag(15.0, 15.0, 680.0, duration_s=70.0))
    spec = SensorSpec()
    return [recording_from_signals(measure(simulate(model, m, env, seed=i, heading_deg=40.0 * i), env, spec, seed=i),
                                   DT, name=f"{m.name}_{i}") for i, m in enumerate(manoeuvres)]


@pytest.mark.slow
def test_hybrid_predicts_held_out_manoeuvres_better_than_the_grey_box(vessel, windy_day, tmp_path):
    result = idf.identify(vessel, windy_day, structure="mmg", prior="fix")
    config = hybrid_fit.HybridTraining(members=3, hidden=16, epochs=60, patience=15, horizon_s=10.0, stride_s=5.0)
    module, info = hybrid_fit.train_hybrid(result, windy_day, DT, config)
    assert info["monitor"] == "val" and len(info["val_manoeuvres"]) == 2  # 25 % of six, whole manoeuvres
    # held-out 10 s rollouts (the training loss): every member beats the identified grey box by a clear margin
    assert max(info["loss_best"]) < 0.7 * info["loss_grey_box"], info
    art_path = tmp_path / "hybrid.pt"
    hybrid_fit.export_identified(str(art_path), module, result, dt=DT, training_data_sha256="0" * 64,
                                 model_type="hybrid", hybrid=info)
    art = load_artifact(art_path, expect={"model_type": "hybrid"})
    assert art.ensemble_size == 3
    assert info["bound"] == pytest.approx(art.metadata["architecture"]["bound"])
    grey = hybrid_fit.greybox_module(result, DT)
    held_out = [rec for rec in windy_day if rec.name in info["val_manoeuvres"]]
    errors = {"grey": [], "hybrid": []}  # 30 s open-loop track errors (m) every 5 s of the held-out manoeuvres
    for rec in held_out:
        for k in range(0, len(rec) - 150, 25):
            measured = rec.position[k + 150] - rec.position[k]
            with torch.no_grad():
                gb = grey(torch.from_numpy(rec.state()[k:k + 1]), torch.from_numpy(rec.controls[None, k:k + 150]))
            hy = art.predict(rec.state()[k:k + 1], rec.controls[None, k:k + 150])  # (3, 1, 150, 6)
            assert np.isfinite(hy).all()
            errors["grey"].append(float(np.hypot(*(gb[0, 0, -1, 3:5].numpy() - measured))))
            errors["hybrid"].append(float(np.hypot(*(hy[:, 0, -1, 3:5].mean(axis=0) - measured))))
    assert np.mean(errors["hybrid"]) < 0.85 * np.mean(errors["grey"]), errors
    assert float(hy[:, 0, -1, 3:5].std(axis=0).max()) > 0.0  # the members spread


def test_bad_training_settings_are_refused():
    with pytest.raises(Exception, match="members must be >= 1"):
        hybrid_fit.HybridTraining(members=0)
    with pytest.raises(Exception, match="horizon_s must be > 0"):
        hybrid_fit.HybridTraining(horizon_s=0.0)


def test_zero_residual_keeps_the_residual_interface():
    z = ZeroResidual()(*(torch.ones(3, dtype=torch.float64) for _ in range(6)))
    assert z.shape == (3, 3)
    assert float(z.abs().sum()) == 0.0


def test_replay_identify_hybrid_writes_an_ensemble(tmp_path, capsys):
    """`replay identify --hybrid` on the shipped training bags: an artifact of the asked members, the training's record
    in the JSON (early stopping on a quarter of the manoeuvres, held out whole); a bad member count is one line."""
    import json
    from pathlib import Path

    from replay_helpers import replay

    training = Path(__file__).resolve().parents[1] / "bags" / "training"
    out, js = tmp_path / "hybrid.pt", tmp_path / "hybrid.json"
    code, err = replay(capsys, "identify", training, "--vessel", "jari_usv", "--structure", "mmg",
                       "--prior", "fix", "--hybrid", "--hybrid-members", "2", "--hybrid-epochs", "2",
                       "--output", out, "--json", js)
    assert code == 0, err
    info = json.loads(js.read_text())["hybrid"]
    assert info["members"] == 2
    assert info["epochs_run"] == 2
    assert info["segments_train"] > 0
    assert info["monitor"] == "val"
    assert len(info["val_manoeuvres"]) == 1
    art = load_artifact(out, expect={"model_type": "hybrid"})
    assert art.ensemble_size == 2
    assert art.metadata["architecture"]["residual"] == "GeneralisingResidual"
    code, err = replay(capsys, "identify", training, "--vessel", "jari_usv", "--hybrid",
                       "--hybrid-members", "0", "--output", tmp_path / "x.pt")
    assert code == 2
    assert "--hybrid-members" in err
    assert not (tmp_path / "x.pt").exists()


# ---- the hybrid on an extended grey box (`replay identify --hybrid --base`: the physics carries the sea) ----------

CURRENT_NE = (-0.273, -0.213)  # (m/s) north, east: 0.346 m/s toward 218 deg, the shipped sea trial's diagnosed current


def _extended(vessel, dt: float = DT, substeps: int = 2) -> ResidualGreyBox:
    """The calm-water grey box with a current and a wave drift set (what `replay diagnose --export` carries)."""
    module = ResidualGreyBox(vessel, dt, ZeroResidual(), substeps)
    with torch.no_grad():
        module.current_ne.copy_(torch.tensor(CURRENT_NE, dtype=torch.float64))
        module.wave_ne.copy_(torch.tensor([-0.20, 0.17], dtype=torch.float64))
    return module


def _export_grey(path, vessel, module, model_type: str = "greybox+current+wave_drift"):
    from usv_predictor.models.artifact import export_module
    from usv_predictor.models.greybox import greybox_metadata

    return export_module(path, module, greybox_metadata(vessel, module, model_type=model_type), vessel=vessel)


@pytest.fixture(scope="module")
def probe(vessel):
    """A short recorded turn (the base check's probe)."""
    model, env = ManoeuvringModel(vessel), Environment(current_speed=0.35, current_to_deg=218.0)
    sim = simulate(model, TurningCircle(20.0, 650.0, duration_s=20.0), env, seed=1)
    return recording_from_signals(measure(sim, env, SensorSpec(), seed=1), DT, name="probe")


def test_accelerations_at_is_the_derivative_of_the_rollout_with_a_current_and_waves(vessel):
    """The one-step targets of a base with extension terms: d/dt of the measured u, v, r at the heading, the current
    turning in the body frame included (a finite difference of the rollout over 0.01 s)."""
    h = 0.01  # (s)
    module = _extended(vessel, dt=h, substeps=1)
    state = torch.tensor([[5.0, 0.3, 0.05, 0.7], [4.0, -0.2, -0.04, 2.5]], dtype=torch.float64)
    controls = torch.tensor([[[0.2, 650.0]] * 3, [[-0.1, 700.0]] * 3], dtype=torch.float64)
    with torch.no_grad():
        finite = (module(state, controls)[0, :, 0, :3] - state[:, :3]) / h  # (B, 3)
        model = module.accelerations_at(state[:, 3], state[:, :3], controls[:, 0])
        turning = model - ResidualGreyBox(vessel, h, ZeroResidual()).accelerations_at(
            state[:, 3], module.water_velocities(state[:, 3], state[:, :3]), controls[:, 0])
    torch.testing.assert_close(model, finite, rtol=0.0, atol=2e-3)
    assert float(turning[:, :2].abs().max()) > 1e-2  # the current's terms are larger than the tolerance


def test_untrained_residual_on_an_extended_base_is_that_base_exactly(vessel, probe, tmp_path):
    """base_from_artifact rebuilds the file's extended grey box (hull + current + wave drift); a hybrid on it with a
    zero residual rolls out exactly as the file, every member, and not as the calm-water grey box."""
    art = _export_grey(tmp_path / "extended.pt", vessel, _extended(vessel))
    loaded = load_artifact(tmp_path / "extended.pt")
    rebuilt_vessel, base = hybrid_fit.base_from_artifact(loaded, vessel, probe)
    assert base.terms()["current_ne"] == pytest.approx(CURRENT_NE, abs=0.0)
    learned = GeneralisingResidual(vessel.geometry.L_pp, 5.0, members=2)
    hybrid = hybrid_fit.with_terms(ResidualGreyBox(rebuilt_vessel, DT, learned, members=2), base)
    state, controls = _inputs()
    with torch.no_grad():
        out = hybrid(state, controls)  # (2, B, H, 6)
        theirs = art.module(state, controls, None)[0]
        calm = GreyBoxRollout(vessel, DT)(state, controls)[0]
    torch.testing.assert_close(out[0], theirs, rtol=0.0, atol=0.0)
    torch.testing.assert_close(out[1], theirs, rtol=0.0, atol=0.0)
    assert float((theirs[:, -1, 3:5] - calm[:, -1, 3:5]).abs().max()) > 1.0  # 6 s in a 0.35 m/s current


def test_a_base_that_is_no_grey_box_or_cannot_be_rebuilt_is_refused(vessel, probe, tmp_path):
    from usv_predictor.errors import ModelError
    from usv_predictor.models.artifact import export_module
    from usv_predictor.models.greybox import greybox_metadata

    hybrid = ResidualGreyBox(vessel, DT, GeneralisingResidual(vessel.geometry.L_pp, 5.0, members=2), members=2)
    meta = greybox_metadata(vessel, hybrid, model_type="hybrid")
    export_module(tmp_path / "hybrid.pt", hybrid, {**meta, "ensemble_size": 2}, vessel=vessel)
    with pytest.raises(ModelError, match="must be a grey box"):
        hybrid_fit.base_from_artifact(load_artifact(tmp_path / "hybrid.pt"), vessel, probe)
    tampered = _extended(vessel)  # its metadata name the preset's hull, its module carries another
    meta = greybox_metadata(vessel, tampered, model_type="greybox+current+wave_drift")
    with torch.no_grad():
        tampered.hull.mul_(1.5)
    export_module(tmp_path / "tampered.pt", tampered, meta, vessel=vessel)
    with pytest.raises(ModelError, match="could not be rebuilt"):
        hybrid_fit.base_from_artifact(load_artifact(tmp_path / "tampered.pt"), vessel, probe)


@pytest.mark.slow
def test_replay_identify_hybrid_on_an_extended_base(vessel, tmp_path, capsys):
    """`replay identify --hybrid --base extended.pt` on the shipped training bags (in the sea trial's current): a
    hybrid+current artifact that keeps the base's current (which the node's online estimator then updates), loads
    as the node loads a model, and whose residual bound (what the base leaves, 10 s means) is tighter than on the
    calm-water model in sway and yaw; a --base without --hybrid, or not a grey box, is one line, exit 2."""
    import json
    from pathlib import Path

    from replay_helpers import replay

    from usv_predictor.analysis.adaptive import model_terms
    from usv_predictor.fitting import identification
    from usv_predictor.models.loading import load_model
    from usv_predictor.replay.identify import identification_recordings

    bags = Path(__file__).resolve().parents[1] / "bags" / "training"
    training = [bags / "turning_circle_port_20deg_675rpm", bags / "zigzag_20_20_port_700rpm"]  # lean: two manoeuvres
    base = ResidualGreyBox(vessel, DT, ZeroResidual())
    with torch.no_grad():
        base.current_ne.copy_(torch.tensor(CURRENT_NE, dtype=torch.float64))
    _export_grey(tmp_path / "extended.pt", vessel, base, model_type="greybox+current")
    out, js = tmp_path / "hybrid.pt", tmp_path / "hybrid.json"
    code, err = replay(capsys, "identify", *training, "--hybrid", "--base", tmp_path / "extended.pt",
                       "--hybrid-members", "2", "--hybrid-epochs", "2", "--output", out, "--json", js)
    assert code == 0, err
    result = json.loads(js.read_text())
    assert result["model_type"] == "hybrid+current"
    assert result["base"]["model_type"] == "greybox+current"
    info = result["hybrid"]
    assert info["members"] == 2
    assert info["epochs_run"] == 2
    assert info["monitor"] == "val"
    art = load_model(str(out), dt=DT)  # as the node loads it (the check that it runs included)
    assert art.ensemble_size == 2
    assert art.metadata["model_type"] == "hybrid+current"
    assert model_terms(art)["current_ne"] == pytest.approx(CURRENT_NE, abs=1e-12)
    assert art.metadata["training"]["base"]["model_type"] == "greybox+current"
    # the bound: what the extended base leaves against what the calm-water model leaves, on the same data
    recordings = identification_recordings(training, DT)
    data = identification.prepare(vessel, recordings)
    calm = GeneralisingResidual(vessel.geometry.L_pp, info["u_ref_mps"], 1)
    hybrid_fit._residual_statistics(calm, ResidualGreyBox(vessel, DT, ZeroResidual()), data, recordings,
                                    hybrid_fit.HybridTraining().bound_window_s)
    assert np.all(np.array(info["bound"])[1:] < 0.8 * calm.bound.numpy()[1:]), (info["bound"], calm.bound)
    code, err = replay(capsys, "identify", *training, "--base", tmp_path / "extended.pt", "--output", tmp_path / "x.pt")
    assert code == 2
    assert "--hybrid" in err
    assert not (tmp_path / "x.pt").exists()
    code, err = replay(capsys, "identify", *training, "--hybrid", "--base", out, "--output", tmp_path / "x.pt")
    assert code == 2
    assert "must be a grey box" in err
    assert not (tmp_path / "x.pt").exists()
    code, err = replay(capsys, "identify", *training, "--hybrid", "--base", tmp_path / "extended.pt",
                       "--interaction", "identify", "--output", tmp_path / "x.pt")
    assert code == 2
    assert "--interaction do not apply" in err
    assert not (tmp_path / "x.pt").exists()


@pytest.fixture(scope="module")
def short_day(vessel):
    """Two 30 s manoeuvres of the calm-water boat and their inverse dynamics (what a residual is trained on)."""
    model, env = ManoeuvringModel(vessel), Environment()
    runs = (ZigZag(20.0, 20.0, 650.0, duration_s=30.0), TurningCircle(25.0, 650.0, duration_s=30.0))
    recordings = [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), DT,
                                         name=f"{m.name}_{i}") for i, m in enumerate(runs)]
    return recordings, idf.prepare(vessel, recordings)


SHORT_TRAINING = hybrid_fit.HybridTraining(members=2, hidden=8, epochs=4, patience=4, horizon_s=10.0, stride_s=5.0)


def test_a_base_that_diverges_stops_the_residual_training_before_the_first_step(vessel, short_day):
    """A grey box whose yaw damping has the wrong sign (N_r, N_rrr > 0: the yaw rate grows without bound) leaves its
    10 s rollouts NaN: the residual's training loss would be NaN from epoch 0 (as on a catamaran identified with its
    yaw equation held). It stops there, saying the base diverges on how many segments; the same training on the true
    hull runs."""
    import dataclasses

    from usv_predictor.errors import TrainingDiverged

    recordings, data = short_day
    unstable = dataclasses.replace(vessel, hull=dataclasses.replace(vessel.hull, N_r=2.0, N_rrr=20.0))
    base = ResidualGreyBox(unstable, DT, ZeroResidual(), 2)
    with pytest.raises(TrainingDiverged) as err:
        hybrid_fit.train_residual(base, unstable, data, recordings, DT, SHORT_TRAINING)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith("hybrid: the training loss of member 0 is nan at epoch 0")
    assert "the grey box alone diverges (NaN/inf loss) on" in message and "training segments" in message
    module, info = hybrid_fit.train_residual(ResidualGreyBox(vessel, DT, ZeroResidual(), 2), vessel, data, recordings,
                                             DT, SHORT_TRAINING)
    assert all(math.isfinite(x) for x in info["loss_best"])


def test_a_residual_that_turns_the_loss_nan_stops_training_at_that_epoch(vessel, short_day, monkeypatch):
    """On a stable base, a training loss that becomes NaN at the second step stops training there, naming the epoch
    and the cause (the learned term, so the learning rate) instead of carrying NaN through Adam."""
    from usv_predictor.errors import TrainingDiverged

    recordings, data = short_day
    original, calls = hybrid_fit._segment_losses, {"n": 0}

    def losses(module, seg, weights=None, predicted=None):
        value = original(module, seg, weights, predicted)
        if weights is not None:  # the training step's loss (the bootstrap-weighted one)
            calls["n"] += 1
            if calls["n"] >= 2:
                return value * float("nan")
        return value

    monkeypatch.setattr(hybrid_fit, "_segment_losses", losses)
    with pytest.raises(TrainingDiverged, match=r"hybrid: the training loss of member 0 is nan at epoch 2: the learned "
                                               r"residual drove the rollout unstable .*lower the learning rate \(now "
                                               r"0\.003\)"):
        hybrid_fit.train_residual(ResidualGreyBox(vessel, DT, ZeroResidual(), 2), vessel, data, recordings, DT,
                                  SHORT_TRAINING)
    assert calls["n"] == 2


def test_the_early_stopping_monitor_runs_on_the_kernel_and_equals_the_modules_loss(vessel, short_day, monkeypatch):
    """The loss the training monitors each epoch (hybrid_fit._monitored_losses) is rolled out on the compiled kernel
    from the module's weights as they are at that moment: equal to the differentiable module's own loss to rounding,
    changed when the weights change, and made without calling the module (its forward here raises)."""
    recordings, _ = short_day
    train, _, _ = hybrid_fit._split_segments(recordings, SHORT_TRAINING)
    learned = _randomised(GeneralisingResidual(vessel.geometry.L_pp, 3.0, members=2, hidden=8, layers=2), 0.7)
    module = ResidualGreyBox(vessel, DT, SumResidual(ZeroResidual(), learned), members=2)
    with torch.no_grad():
        expected = hybrid_fit._segment_losses(module, train)  # (E,)
        learned.head_bias.mul_(-1.0)
        changed = hybrid_fit._segment_losses(module, train)
        learned.head_bias.mul_(-1.0)
    assert float((expected - changed).abs().min()) > 1e-6 * float(expected.abs().max())  # the weights matter

    def forward(*_):
        raise AssertionError("the monitor called the torch module")

    monkeypatch.setattr(ResidualGreyBox, "forward", forward)
    got = hybrid_fit._monitored_losses(module, train)
    assert got.shape == (2,)
    assert torch.allclose(got, expected, rtol=1e-9, atol=0.0)
    with torch.no_grad():
        learned.head_bias.mul_(-1.0)
    assert torch.allclose(hybrid_fit._monitored_losses(module, train), changed, rtol=1e-9, atol=0.0)

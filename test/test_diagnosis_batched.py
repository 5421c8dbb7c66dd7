"""The Levenberg-Marquardt Jacobian of diagnosis.fit_hypothesis from one kernel call (PerturbedBatch): every
perturbation's residuals equal those of its own rollout bit for bit, and the fit equals the one that rolls each
perturbation out alone."""
from __future__ import annotations

import numpy as np
import pytest

from usv_predictor.analysis import diagnosis as dg
from usv_predictor.data.recording import recording_from_signals
from usv_predictor.physics import effects as fx
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import diagnosis_runs
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

VESSEL = load_vessel("jari_usv")


def _segments(env: Environment) -> dg.Segments:
    model = ManoeuvringModel(VESSEL)
    recordings = []
    for k, manoeuvre in enumerate(diagnosis_runs()[:2]):
        traj = simulate(model, manoeuvre, env, heading_deg=40.0 * k, seed=k)
        recordings.append(recording_from_signals(measure(traj, env, seed=10 + k), 0.5, name=manoeuvre.name))
    return dg.make_segments(recordings)


def test_each_block_of_the_batch_is_its_own_rollout_bit_for_bit():
    seg = _segments(Environment())
    model = dg.compiled_rollout(VESSEL, 0.5)
    settings = [{"current_ne": (0.3, -0.1)}, {"rudder_offset": (0.02,)}, {"current_ne": (-0.2, 0.4),
                                                                          "rudder_offset": (-0.01,)}]
    batched = dg.PerturbedBatch(model, seg, len(settings)).residuals(settings)
    for k, setting in enumerate(settings):
        dg.set_terms(model, setting)
        alone = dg.residuals(model, seg).flatten().numpy()
        assert np.array_equal(batched[k], alone), setting
    assert not np.array_equal(batched[0], batched[1])  # the blocks' terms differ, so do their residuals
    dg.set_terms(model, {})  # the module's own terms are back and still live
    assert np.array_equal(dg.residuals(model, seg).flatten().numpy(),
                          dg.PerturbedBatch(model, seg, 1).residuals([{}])[0])
    with pytest.raises(ValueError, match="2 settings for a batch of 3"):
        dg.PerturbedBatch(model, seg, 3).residuals(settings[:2])


def test_a_fit_with_the_batched_jacobian_is_the_fit_of_the_one_by_one_jacobian(monkeypatch):
    seg = _segments(Environment(current_speed=0.25, current_to_deg=120.0))
    model = dg.compiled_rollout(VESSEL, 0.5)
    batched = dg.fit_hypothesis(model, seg, ["current", "rudder_offset"])
    monkeypatch.setattr(dg, "PerturbedBatch", lambda *_: None)  # the loop of one rollout per parameter
    alone = dg.fit_hypothesis(model, seg, ["current", "rudder_offset"])
    assert batched.iterations == alone.iterations > 1
    assert batched.loss == alone.loss
    assert batched.terms == alone.terms and batched.std == alone.std
    assert np.hypot(*batched.terms["current_ne"]) == pytest.approx(0.25, abs=0.05)
    assert set(batched.terms) == {t.name for name in ("current", "rudder_offset") for t in fx.EFFECTS[name].terms}

"""identify warns when the chosen structure/prior cross-validates far worse than another it can compute
(usv_predictor.fitting.candidates)."""
from __future__ import annotations

import pytest

from usv_predictor.data.recording import recording_from_signals
from usv_predictor.fitting import identification as idf
from usv_predictor.fitting.candidates import FAR_WORSE, Candidate, candidate_scores, cv_warning
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import RandomManoeuvre, TurningCircle, ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel


def test_the_warning_names_the_better_choice_only_when_it_is_far_better():
    chosen = Candidate("mmg", "ridge", 0.12, True)
    better = Candidate("mmg", "fix", 0.012, False)
    refused = Candidate("mmg", "none", None, False)
    warning = cv_warning([chosen, better, refused, Candidate("abkowitz", "fix", 0.05, False)])
    assert warning is not None
    assert "10.0 times worse than --structure mmg --prior fix" in warning
    assert "--prior ridge" in warning
    assert "0.12 vs 0.012" in warning
    close = Candidate("mmg", "fix", 0.12 / FAR_WORSE * 1.01, False)  # just inside the limit
    assert cv_warning([chosen, close]) is None
    assert cv_warning([chosen, refused]) is None  # nothing else scored: nothing to compare with
    assert cv_warning([Candidate("mmg", "none", None, True), better]) is None


def test_every_structure_and_prior_is_scored_on_the_same_forces():
    vessel = load_vessel("jari_usv")
    model, env = ManoeuvringModel(vessel), Environment()
    runs = (ZigZag(20.0, 20.0, 700.0, duration_s=60.0, side=-1), TurningCircle(25.0, 650.0, duration_s=60.0),
            RandomManoeuvre(seed=1, duration_s=90.0))
    recordings = [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), 0.2,
                                         name=m.name) for i, m in enumerate(runs)]
    result = idf.identify(vessel, recordings, structure="mmg", prior="fix")
    candidates = candidate_scores(vessel, list(result.data), result)
    assert {(c.structure, c.prior) for c in candidates} == {(s, p) for s in idf.STRUCTURES for p in idf.PRIORS}
    chosen = [c for c in candidates if c.chosen]
    assert [(c.structure, c.prior) for c in chosen] == [("mmg", "fix")]
    assert chosen[0].score == pytest.approx(result.cross_validation[0].score)
    ridge = next(c for c in candidates if (c.structure, c.prior) == ("mmg", "ridge"))
    assert ridge.score is not None
    assert ridge.score > 0.0
    if result.fit.not_identifiable:  # prior none refuses what the data cannot determine: no score
        assert next(c for c in candidates if (c.structure, c.prior) == ("mmg", "none")).score is None

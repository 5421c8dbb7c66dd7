"""`diagnose` answers `unexplained`: when no physical hypothesis explains what the calm-water model gets
wrong, the learned residual of last resort, with its gain measured on held-out manoeuvres as a cause's is."""
from __future__ import annotations

import dataclasses
import json
import math

import pytest

from usv_predictor.analysis import diagnosis as dg
from usv_predictor.analysis import diagnosis_unexplained as dgu
from usv_predictor.analysis.diagnosis_run import DiagnosisOptions, run_diagnosis
from usv_predictor.atomic import json_text
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import diagnosis_runs
from test_diagnosis import VESSEL, trial

LEAN = dataclasses.replace(dgu.UNEXPLAINED_TRAINING, members=2, epochs=15, patience=5)  # a test's budget


def _mismatch() -> dg.Diagnosis:
    return dg.Diagnosis(cause=dg.MODEL_MISMATCH, parameters={}, uncertainty={}, confounded_with=(), evidence=(),
                        fit=dg.Fit("none", {}, 19.0, {}, 0, 0.0), folds=(("a",), ("b",)),
                        message=f"{dg.MODEL_MISMATCH}: no hypothesis explains it",
                        calm_water_fit=dg.CalmWaterFit(19.0, 2.9, 20.0),
                        mismatch_reasons=("no hypothesis explains it",))


def _found(accepted: bool) -> dgu.UnexplainedGain:
    return dgu.UnexplainedGain(accepted, 1.4 if accepted else 18.0, 19.0, 1 - (1.4 if accepted else 18.0) / 19.0,
                               27.5 if accepted else 1.0, 0.9, 2.9, 0.69, 1.0, 3.5, dg.MODEL_MISMATCH,
                               () if accepted else ("it removes 5.3 % of the calm-water model's held-out loss",))


def test_the_answer_is_unexplained_only_when_the_residual_passes_every_test():
    accepted = dgu.unexplained_answer(_mismatch(), _found(True), 20.0)
    assert accepted.cause == dg.UNEXPLAINED
    assert accepted.hypotheses == ()
    assert accepted.parameters == {}
    assert accepted.message.startswith(f"{dg.UNEXPLAINED}: no physical hypothesis explains")
    assert "93 %" in accepted.message
    assert accepted.mismatch_reasons == ("no hypothesis explains it",)  # what it would have been stays on record
    kept = dgu.unexplained_answer(_mismatch(), _found(False), 20.0)
    assert kept.cause == dg.MODEL_MISMATCH
    assert "the extension of last resort was tried" in kept.message
    assert "5.3 %" in kept.message
    assert _found(True).open_loop_gain == pytest.approx(1.0 - 1.0 / 3.5)


def _never(*args, **kwargs):
    raise AssertionError("the residual of last resort was tried")


def test_run_diagnosis_tries_the_residual_only_without_a_physical_cause_and_unless_switched_off(monkeypatch):
    """model_mismatch + the residual's gain -> `unexplained` in the JSON (cause, message, the gain); with
    unexplained=False (--no-unexplained) it is never tried."""
    recordings = trial(runs=diagnosis_runs()[:2])
    names = tuple(r.name for r in recordings)
    mismatch = dataclasses.replace(_mismatch(), folds=((names[0],), (names[1],)))
    monkeypatch.setattr(dg, "diagnose", lambda *args, **kwargs: mismatch)
    monkeypatch.setattr("usv_predictor.analysis.diagnosis_run.measure_unexplained", _never)
    out = run_diagnosis(recordings, VESSEL, "preset", dt=0.5, options=DiagnosisOptions(unexplained=False))
    assert out["cause"] == dg.MODEL_MISMATCH
    assert out["unexplained"] is None
    monkeypatch.setattr("usv_predictor.analysis.diagnosis_run.measure_unexplained", lambda *a, **k: _found(True))
    out = json.loads(json_text(run_diagnosis(recordings, VESSEL, "preset", dt=0.5)))
    assert out["cause"] == dg.UNEXPLAINED
    assert out["unexplained"]["accepted"]
    assert out["parameters"] == {}
    assert out["unexplained"]["gain"] == pytest.approx(1 - 1.4 / 19.0)
    assert out["unexplained"]["replaced"] == dg.MODEL_MISMATCH


@pytest.mark.slow
def test_a_hidden_physical_cause_is_named_and_the_residual_is_not_tried(monkeypatch):
    """Physical causes stay preferred: a current is named, the learned residual never trained."""
    monkeypatch.setattr("usv_predictor.analysis.diagnosis_run.measure_unexplained", _never)
    recordings = trial(env=Environment(current_speed=0.3, current_to_deg=60.0))
    out = run_diagnosis(recordings, VESSEL, "preset", dt=0.5,
                        options=DiagnosisOptions(hypotheses=("current", "rudder_offset"), max_causes=1))
    assert out["cause"] == "current"
    assert out["unexplained"] is None
    assert out["gain"]["mean_position_error_after_30s_m"] > 0.0


@pytest.mark.slow
def test_an_effect_outside_the_vocabulary_is_unexplained_with_a_positive_gain(monkeypatch, tmp_path):
    """The boat's yaw damping N_r is 30 % weaker than the calm-water model's (no hypothesis models a hull derivative):
    without the residual the answer is model_mismatch; with it `unexplained`, the residual (trained on one fold)
    removing most of the other fold's held-out loss, track error and 30 s open-loop error; --export writes the
    hybrid, report.md and the JSON carry the gain."""
    monkeypatch.setattr(dgu, "UNEXPLAINED_TRAINING", LEAN)
    weak = dataclasses.replace(VESSEL, hull=dataclasses.replace(VESSEL.hull, N_r=VESSEL.hull.N_r * 0.7))
    recordings = trial(vessel=weak)
    out = json.loads(json_text(run_diagnosis(recordings, VESSEL, "preset", dt=0.5,
                                             options=DiagnosisOptions(export=tmp_path / "hybrid.pt",
                                                                      report=tmp_path / "report"))))
    assert out["cause"] == dg.UNEXPLAINED
    assert out["parameters"] == {}
    found = out["unexplained"]
    assert found["accepted"]
    assert found["replaced"] == dg.MODEL_MISMATCH
    assert found["reasons"] == []
    assert found["gain"] >= 0.5
    assert found["evidence"] >= dg.EVIDENCE_CAUSE
    assert found["heldout_loss"] < found["calm_water_loss"] == pytest.approx(out["calm_water_fit"]["heldout_loss"])
    assert found["track_gain"] > 0.2
    assert found["open_loop_gain"] > 0.2
    assert out["mismatch_reasons"]
    assert "no hypothesis explains" in out["mismatch_reasons"][0]
    assert [t["members"] for t in found["training"]] == [2, 2]
    assert all(t["val_manoeuvres"] for t in found["training"])
    from usv_predictor.models.artifact import load_artifact

    artifact = load_artifact(tmp_path / "hybrid.pt")
    assert out["exported_model"]["model_id"] == artifact.model_id
    assert artifact.metadata["model_type"] == "hybrid"
    assert artifact.metadata["ensemble_size"] == 2
    assert artifact.metadata["architecture"]["diagnosis"] == dg.UNEXPLAINED
    report = (tmp_path / "report" / "report.md").read_text()
    assert report.startswith(f"# Diagnosis: {dg.UNEXPLAINED}") and "Accepted: the answer is `unexplained`" in report
    assert not math.isnan(found["heldout_track_error_m"])

"""Diagnosis internals: vocabulary conversions, data checks, discrepancy structure, a model-error hypothesis."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from usv_predictor.analysis.diagnosis import (
    DiagnosisError,
    check_data,
    diagnose,
    discrepancy,
    fit_hypothesis,
    make_segments,
    physical_parameters,
    compiled_rollout,
    withdraw_causes,
)
from usv_predictor.data.recording import Recording, recording_from_signals
from usv_predictor.physics import effects as fx
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import diagnosis_runs
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

VESSEL = load_vessel("jari_usv")


def trial(vessel=VESSEL, env=Environment(), runs=None):
    model = ManoeuvringModel(vessel)
    recordings = []
    for k, manoeuvre in enumerate(runs or diagnosis_runs()):
        traj = simulate(model, manoeuvre, env, heading_deg=40.0 * k, seed=k)
        recordings.append(recording_from_signals(measure(traj, env, seed=10 + k), 0.5, name=manoeuvre.name))
    return recordings


def test_vectors_become_the_design_vocabulary():
    # a current flowing toward the east; wind blowing toward the south comes FROM the north
    assert physical_parameters("current", {"current_ne": (0.0, 0.3)}) == pytest.approx(
        {"speed_mps": 0.3, "direction_to_deg": 90.0})
    wind = physical_parameters("wind", {"wind_ne": (-8.0, 0.0)})
    assert wind["speed_mps"] == pytest.approx(8.0)
    assert wind["direction_from_deg"] == pytest.approx(0.0)
    waves = physical_parameters("wave_drift", {"wave_ne": (0.0, 0.25)})  # zeta_a^2 = 0.25 -> H_s = 1 m from the east
    assert waves == pytest.approx({"significant_height_m": 1.0, "direction_from_deg": 90.0, "head_sea_resistance": 0.0})
    waves = physical_parameters("wave_drift", {"wave_ne": (0.0, 0.25), "wave_resistance": (0.4,)})
    assert waves["head_sea_resistance"] == 0.4  # C_AW (-) as the term holds it
    assert physical_parameters("rudder_offset",
                               {"rudder_offset": (math.radians(2.0),)}) == pytest.approx({"offset_deg": 2.0})
    assert physical_parameters("resistance",
                               {"resistance_change": (0.2,)}) == pytest.approx({"resistance_change_pct": 20.0})


def test_a_single_manoeuvre_is_refused():
    with pytest.raises(DiagnosisError, match="at least two"):
        check_data(trial(runs=diagnosis_runs()[:1]))


def _twin(differential: float, n: int = 40) -> Recording:
    """A twin-thruster recording turning with a held thrust difference (port - starboard), heading all round."""
    controls = np.column_stack([np.full(n, 0.5 + differential / 2), np.full(n, 0.5 - differential / 2)])
    return Recording(name=f"d{differential:g}", source="", t0_ns=0, dt=0.5, t_s=np.arange(n) * 0.5,
                     nu=np.zeros((n, 3)), psi=np.linspace(-math.pi, math.pi, n, endpoint=False), controls=controls,
                     position=np.zeros((n, 2)), layout="twin_thrusters")


def test_check_data_reads_turn_sides_through_the_layouts_steering_signal():
    # both twins have a positive first column (the port command): the rudder column would call them one side
    assert not any("same way" in note for note in check_data([_twin(0.4), _twin(-0.4)]))
    notes = check_data([_twin(0.4), _twin(0.2)])
    assert any("all manoeuvres turn the same way" in note and "thruster imbalance" in note for note in notes)


def test_current_shows_as_a_steady_track_drift():
    recordings = trial(env=Environment(current_speed=0.3, current_to_deg=60.0))
    seg = make_segments(recordings)
    found = discrepancy(compiled_rollout(VESSEL, 0.5), seg, recordings)
    assert found["track_drift_speed_mps"] == pytest.approx(0.3, abs=0.05)
    assert found["track_drift_direction_to_deg"] == pytest.approx(60.0, abs=10.0)


def test_a_resistance_error_of_the_model_is_named_as_such():
    """Data from a fouled hull (+30 % resistance) against the clean preset: not a current, not wind."""
    fouled = dataclasses.replace(VESSEL, hull=dataclasses.replace(VESSEL.hull, R0=VESSEL.hull.R0 * 1.3))
    result = diagnose(trial(vessel=fouled), VESSEL, hypotheses=["current", "wind", "resistance", "rudder_offset"])
    assert result.cause == "resistance"
    assert result.parameters["resistance_change_pct"] == pytest.approx(30.0, abs=3.0)


def test_the_calm_water_model_can_come_from_an_identified_grey_box():
    from usv_predictor.models.greybox import hull_from_metadata

    identified = {"identification": {"structure": "mmg", "extra_terms": {},
                                     "coefficients": [{"name": "R0", "estimate": 0.02},
                                                      {"name": "Y_v", "estimate": -0.3}]},
                  "architecture": {"residual": "ZeroResidual"}}
    assert hull_from_metadata(identified) == {"R0": 0.02, "Y_v": -0.3}
    exported = {"architecture": {"hull": {"R0": 0.03}}}  # `replay diagnose --export`
    assert hull_from_metadata(exported) == {"R0": 0.03}
    # what the MMG grey box cannot carry is refused rather than silently dropped
    assert hull_from_metadata({**identified, "architecture": {"residual": "MlpResidual"}}) is None
    assert hull_from_metadata({"identification": {"structure": "abkowitz", "coefficients": []}}) is None
    assert hull_from_metadata({"architecture": {"width": 100}}) is None  # a DNN


def test_a_diagnosis_run_builds_its_segments_and_grey_box_once_and_shares_them(monkeypatch):
    """diagnose, discrepancy (and the gain) use one set of segments and one scripted grey box; sharing the
    compiled model changes no answer: its discrepancy equals that of a freshly built one."""
    from usv_predictor.analysis import diagnosis as dg
    from usv_predictor.analysis.diagnosis_run import DiagnosisOptions, run_diagnosis

    recordings = trial(env=Environment(current_speed=0.3, current_to_deg=60.0))
    built = {"make_segments": 0, "compiled_rollout": 0}
    for name in built:
        original = getattr(dg, name)

        def counted(*args, _name=name, _original=original, **kwargs):
            built[_name] += 1
            return _original(*args, **kwargs)
        monkeypatch.setattr(dg, name, counted)
    out = run_diagnosis(recordings, VESSEL, "preset", dt=0.5,
                        options=DiagnosisOptions(hypotheses=("current", "rudder_offset"), max_causes=1, gain=False))
    assert built == {"make_segments": 1, "compiled_rollout": 1}
    assert out["cause"] == "current"
    assert out["calm_water_model"] == {"vessel": VESSEL.name, "source": "preset"}
    monkeypatch.undo()
    fresh = discrepancy(compiled_rollout(VESSEL, 0.5), make_segments(recordings), recordings)

    def flat(d: dict) -> dict:
        return {f"{k}.{kk}": vv for k, v in d.items() for kk, vv in (v.items() if isinstance(v, dict) else [("", v)])}
    assert flat(out["discrepancy"]) == pytest.approx(flat(fresh), rel=1e-9, abs=1e-12)


def test_the_calm_water_model_is_a_preset_or_refuses_what_is_not_a_plain_grey_box():
    from pathlib import Path

    from usv_predictor.analysis.diagnosis_run import calm_water_vessel
    from usv_predictor.errors import ModelError

    vessel, source = calm_water_vessel("kvlcc2_model", None)
    assert (vessel.name, source) == ("kvlcc2_model", "preset")
    shipped_dnn = Path(__file__).resolve().parents[1] / "models" / "default.pt"
    with pytest.raises(ModelError, match=r"default\.pt: diagnose needs a grey box .* not model_type"):
        calm_water_vessel(None, shipped_dnn)


class _FakeRollout(torch.nn.Module):
    """Every grey-box term as a buffer; the prediction is the target itself, NaN wherever `wave_ne` is non-zero or
    `broken` is set (a hypothesis whose start diverges; a calm-water model that does)."""

    def __init__(self, target: torch.Tensor, broken: bool = False) -> None:
        super().__init__()
        for name, term in fx.grey_box_terms().items():
            self.register_buffer(name, torch.zeros(term.size, dtype=torch.float64))
        self.target, self.broken = target, broken

    def forward(self, state: torch.Tensor, controls: torch.Tensor, reference: torch.Tensor | None = None
                ) -> tuple[torch.Tensor]:
        bad = self.broken or bool(self.wave_ne.abs().sum() > 0)
        return (self.target * (math.nan if bad else 1.0),)


def test_a_hypothesis_whose_start_diverges_is_a_diverged_fit_but_a_diverging_calm_water_model_is_an_error():
    seg = make_segments(trial(runs=diagnosis_runs()[:1]), 20.0, 20.0)
    fit = fit_hypothesis(_FakeRollout(seg.target), seg, "wave_drift")
    assert fit.loss == math.inf and fit.iterations == 0  # ranks last in diagnose, never named
    assert fit_hypothesis(_FakeRollout(seg.target), seg, "current").loss == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(DiagnosisError, match="not finite.*smaller --dt"):
        fit_hypothesis(_FakeRollout(seg.target, broken=True), seg, "current")


def test_an_undefined_uncertainty_of_a_named_cause_is_written_as_null(monkeypatch) -> None:
    """A parameter fitted at its bound has an infinite standard error (J^T J singular there): the diagnosis writes it as
    null instead of refusing its own JSON (found on rudder_only bags before their engine speed was held per
    manoeuvre: `resistance` +300 %, uncertainty inf, and `replay diagnose --json` stopped)."""
    import json

    from usv_predictor.analysis import diagnosis as dg
    from usv_predictor.analysis.diagnosis_run import DiagnosisOptions, run_diagnosis
    from usv_predictor.atomic import json_text

    recordings = trial(runs=diagnosis_runs()[:2])
    at_bound = dg.Fit("resistance", {"resistance_change": (3.0,)}, 1.0, {"resistance_change": (math.inf,)}, 1, 0.0)
    named = dg.Diagnosis(cause="resistance", parameters={"resistance_change_pct": 300.0},
                         uncertainty={"resistance_change_pct": math.inf}, confounded_with=(), evidence=(), fit=at_bound,
                         folds=((recordings[0].name,), (recordings[1].name,)), message="resistance named")
    monkeypatch.setattr(dg, "diagnose", lambda *args, **kwargs: named)
    written = json.loads(json_text(run_diagnosis(recordings, VESSEL, "preset", dt=0.5,
                                                   options=DiagnosisOptions(gain=False))))
    assert written["cause"] == "resistance"
    assert written["parameters"] == {"resistance_change_pct": 300.0}
    assert written["uncertainty"] == {"resistance_change_pct": None}


def test_a_diverged_hypothesis_is_written_as_null_and_reported() -> None:
    """A hypothesis whose fit diverged has NaN/inf loss and evidence: the strict JSON writer refuses NaN, so the
    diagnosis writes them as null (undefined) and the report says the fit diverged instead of failing."""
    import json

    from usv_predictor.analysis.diagnosis_run import _undefined_as_null
    from usv_predictor.atomic import json_text
    from usv_predictor.errors import OutputError

    record = {"hypothesis": "wave_drift", "heldout_loss": float("nan"), "gain_vs_none": float("-inf"),
              "evidence_vs_none": 1.5, "evidence_of_best": float("inf"),
              "fold_parameters": [{"wave_height_m": float("nan")}, {"wave_height_m": 0.4}]}
    with pytest.raises(OutputError, match="heldout_loss"):
        json_text({"evidence": [record]})  # the writer stays strict
    written = json.loads(json_text({"evidence": [_undefined_as_null(record)]}))["evidence"][0]
    assert written["heldout_loss"] is None
    assert written["gain_vs_none"] is None
    assert written["evidence_of_best"] is None
    assert written["evidence_vs_none"] == 1.5
    assert written["hypothesis"] == "wave_drift"
    assert written["fold_parameters"] == [{"wave_height_m": None}, {"wave_height_m": 0.4}]


def test_a_calm_water_model_that_diverges_on_the_data_is_a_model_mismatch_not_an_error():
    """An identified grey box that blows up in states the data visit (unknown boats: cubic terms fitted on one
    day) cannot say `none` or name a cause: the answer is model_mismatch, with how many segments diverged."""
    from usv_predictor.analysis.diagnosis import MODEL_MISMATCH, diverged_segments

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    assert diverged_segments(_FakeRollout(seg.target), seg) == 0
    assert diverged_segments(_FakeRollout(seg.target, broken=True), seg) == len(seg)
    result = diagnose(recordings, VESSEL, segments=seg, rollout=_FakeRollout(seg.target, broken=True),
                      hypotheses=["current"])
    assert result.cause == MODEL_MISMATCH
    assert result.parameters == {}
    assert result.hypotheses == ()
    assert f"diverges (NaN/inf) on {len(seg)} of {len(seg)} segments" in result.mismatch_reasons[0]
    assert result.calm_water_fit.heldout_loss == math.inf


class _TrackVsLossRollout(torch.nn.Module):
    """A calm-water model whose velocities are off by 4 sigma and whose end position is off by 0.5 m; the `current`
    term k = |current_ne| / 0.3 m/s (<= 1) moves the velocities onto the data and, with `track_cost`, the positions
    away from them (by 2 k m): a cause that lowers the held-out loss but not the track error (track_cost True), or
    both (False). Segments are looked up by their start state, so any selection of them rolls out."""

    def __init__(self, seg, track_cost: bool) -> None:
        super().__init__()
        for name, term in fx.grey_box_terms().items():
            self.register_buffer(name, torch.zeros(term.size, dtype=torch.float64))
        self.states, self.target, self.track_cost = seg.state, seg.target, track_cost

    def forward(self, state: torch.Tensor, controls: torch.Tensor,
                reference: torch.Tensor | None = None) -> tuple[torch.Tensor]:  # reference: rudder_only's (unused)
        index = (state[:, None, :] == self.states[None]).all(-1).to(torch.float64).argmax(1)  # (B,)
        k = torch.clamp(self.current_ne.norm() / 0.3, max=1.0)
        bias = torch.zeros(6, dtype=torch.float64)
        bias[0], bias[1], bias[2] = 0.2 * (1 - k), 0.2 * (1 - k), 0.02 * (1 - k)  # 4 sigma at k = 0
        ramp = torch.linspace(0.0, 1.0, self.target.shape[1], dtype=torch.float64)[:, None]  # (H, 1)
        position = (0.5 + 2.0 * k) if self.track_cost else 0.5 * (1 - k)
        bias[3], bias[4] = position, position
        predicted = self.target[index] + bias * torch.cat([torch.ones(self.target.shape[1], 3, dtype=torch.float64),
                                                            ramp.expand(-1, 2), torch.zeros_like(ramp)], dim=1)
        return (predicted,)


def test_a_cause_that_lowers_the_loss_but_not_the_track_is_inconclusive_not_a_mismatch():
    """Such a cause was once answered model_mismatch with the remedy 'identify this boat first', wrong when the
    model fits. It is `inconclusive`: the candidate, its parameters and why it is not named."""
    from usv_predictor.analysis.diagnosis import INCONCLUSIVE, MODEL_MISMATCH

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    result = diagnose(recordings, VESSEL, segments=seg, rollout=_TrackVsLossRollout(seg, True), hypotheses=["current"])
    assert result.cause == INCONCLUSIVE
    assert result.parameters == {}
    assert result.hypotheses == ()
    assert result.candidate == "current"
    assert result.candidate_parameters["speed_mps"] > 0.1
    assert result.mismatch_reasons == ()
    assert "does not lower the held-out track error" in result.inconclusive_reasons[0]
    assert result.message.startswith(f"{INCONCLUSIVE}: current (speed_mps")
    assert "identify this boat" not in result.message
    top = next(e for e in result.evidence if e.hypothesis == "current")
    assert top.evidence_vs_none >= 5.0 and top.track_gain_vs_none < 0.0  # what makes it a candidate, and not named
    # the same term that also lowers the track error is named; withdrawn after a worse 30 s gain it is inconclusive
    named = diagnose(recordings, VESSEL, segments=seg, rollout=_TrackVsLossRollout(seg, False), hypotheses=["current"])
    assert named.cause == "current"
    rollout = _TrackVsLossRollout(seg, False)
    withdrawn = withdraw_causes(named, "the extension does not lower the 30 s error (1 -> 2 m)", rollout, seg)
    assert withdrawn.cause == INCONCLUSIVE
    assert withdrawn.cause != MODEL_MISMATCH
    assert withdrawn.candidate == "current"
    assert withdrawn.candidate_parameters == named.parameters
    assert withdrawn.parameters == {}
    assert withdrawn.inconclusive_reasons == ("the extension does not lower the 30 s error (1 -> 2 m)",)


class _BiasedRollout(torch.nn.Module):
    """A calm-water model whose u, v, r are off by `sigmas` noise scales whatever the hypothesis terms are."""

    def __init__(self, seg, sigmas: float) -> None:
        super().__init__()
        for name, term in fx.grey_box_terms().items():
            self.register_buffer(name, torch.zeros(term.size, dtype=torch.float64))
        self.states, self.target = seg.state, seg.target
        self.bias = torch.tensor([0.05, 0.05, 0.005, 0.0, 0.0, 0.0], dtype=torch.float64) * sigmas

    def forward(self, state: torch.Tensor, controls: torch.Tensor,
                reference: torch.Tensor | None = None) -> tuple[torch.Tensor]:  # reference: rudder_only's (unused)
        index = (state[:, None, :] == self.states[None]).all(-1).to(torch.float64).argmax(1)  # (B,)
        return (self.target[index] + self.bias,)


@pytest.mark.parametrize("sigmas, expected", [(0.5, "none"), (4.0, "model_mismatch")])
def test_none_needs_a_model_within_the_noise(sigmas, expected):
    """Never a confident `none` from a model that does not fit: errors of 4 sigma in u, v, r (held-out loss 8) that
    no hypothesis explains are model_mismatch (an unknown boat's identified model hid a gyro bias that way)."""
    from usv_predictor.analysis.diagnosis import NONE_LOSS

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    result = diagnose(recordings, VESSEL, segments=seg, rollout=_BiasedRollout(seg, sigmas), hypotheses=["current"])
    assert result.calm_water_fit.heldout_loss == pytest.approx(sigmas**2 / 2, rel=0.01)
    assert result.cause == expected
    assert result.parameters == {}
    if expected == "model_mismatch":
        assert result.calm_water_fit.heldout_loss > NONE_LOSS
        assert "no hypothesis explains the calm-water model's held-out loss of 8" in result.mismatch_reasons[0]


class _PartlyExplainedRollout(torch.nn.Module):
    """A calm-water model whose u, v, r are off by `before` noise scales; the `current` term k = |current_ne| / `full`
    (<= 1, m/s) brings them to `after` noise scales: a cause that removes most of a huge loss and leaves `after`^2 / 2
    (held-out loss: 3 of the 6 channels off). Segments are looked up by their start state."""

    def __init__(self, seg, before: float, after: float, full: float = 0.3) -> None:
        super().__init__()
        for name, term in fx.grey_box_terms().items():
            self.register_buffer(name, torch.zeros(term.size, dtype=torch.float64))
        self.states, self.target, self.full = seg.state, seg.target, full
        self.before, self.after = before, after
        self.sigma = torch.tensor([0.05, 0.05, 0.005, 0.0, 0.0, 0.0], dtype=torch.float64)

    def share(self) -> torch.Tensor:
        """k = |current_ne| / full, at most 1: the share of its error the current explains."""
        return torch.clamp(self.current_ne.norm() / self.full, max=1.0)

    def forward(self, state: torch.Tensor, controls: torch.Tensor,
                reference: torch.Tensor | None = None) -> tuple[torch.Tensor]:  # reference: rudder_only's (unused)
        index = (state[:, None, :] == self.states[None]).all(-1).to(torch.float64).argmax(1)  # (B,)
        return (self.target[index] + self.sigma * (self.before - (self.before - self.after) * self.share()),)


@pytest.mark.parametrize("after, expected", [(10.0, "current"), (20.0, "model_mismatch")])
def test_a_cause_may_not_leave_a_loss_above_the_ceiling_whatever_share_it_removed(after, expected):
    """(An unknown boat's 1.4 m waves named as a 28 m/s wind that left 1190 of 2432 noise units): the
    calm-water model leaves 800 (40 sigma in u, v, r); a current that leaves 50 (10 sigma) is named (it removed more
    than MISMATCH_SHARE, and 50 <= FIT_CEILING_LOSS), one that leaves 200 (20 sigma, 75 % removed) is model_mismatch,
    with the current reported as the best environmental cause."""
    from usv_predictor.analysis.diagnosis import FIT_CEILING_LOSS, MISMATCH_LOSS, MISMATCH_SHARE, MODEL_MISMATCH

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    result = diagnose(recordings, VESSEL, segments=seg, rollout=_PartlyExplainedRollout(seg, 40.0, after),
                      hypotheses=["current"])
    assert result.calm_water_fit.heldout_loss == pytest.approx(800.0, rel=0.01)
    left = next(e for e in result.evidence if e.hypothesis == "current").heldout_loss
    assert left == pytest.approx(after**2 / 2, rel=0.01)
    assert MISMATCH_LOSS < left < MISMATCH_SHARE * result.calm_water_fit.heldout_loss  # the share rule alone lets it by
    assert result.cause == expected
    if expected == MODEL_MISMATCH:
        assert left > FIT_CEILING_LOSS
        assert result.best_environmental_cause == "current"
        assert result.parameters == {}
        assert "current leaves a held-out loss of 200 noise units" in result.mismatch_reasons[0]
        assert "the best environmental cause would be current" in result.message
    else:
        assert left <= FIT_CEILING_LOSS
        assert result.mismatch_reasons == ()
        assert result.parameters["speed_mps"] >= 0.3


def test_a_cause_whose_fitted_parameter_is_not_physical_is_model_mismatch():
    """A current that only explains the data at 4 m/s (beyond the 3 m/s `replay simulate` admits: the effect record's
    range) is the calm-water model's error absorbed by the term, not a current: model_mismatch, current reported as
    the best environmental cause; the same rollout explained at 0.3 m/s names the current."""
    from usv_predictor.analysis.diagnosis import MODEL_MISMATCH

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    far = diagnose(recordings, VESSEL, segments=seg, rollout=_PartlyExplainedRollout(seg, 4.0, 0.0, full=4.0),
                   hypotheses=["current"])
    assert far.cause == MODEL_MISMATCH
    assert far.best_environmental_cause == "current"
    assert far.parameters == {}
    assert len(far.mismatch_reasons) == 1
    assert "current speed_mps 4" in far.mismatch_reasons[0]
    assert "0..3 m/s" in far.mismatch_reasons[0]
    near = diagnose(recordings, VESSEL, segments=seg, rollout=_PartlyExplainedRollout(seg, 4.0, 0.0),
                    hypotheses=["current"])
    assert near.cause == "current"
    assert 0.3 <= near.parameters["speed_mps"] <= 3.0
    assert near.mismatch_reasons == ()


@pytest.mark.parametrize("after, expected", [(0.75, "inconclusive"), (0.9, "none")])
def test_none_is_only_confident_without_a_strong_candidate(after, expected):
    """(An unknown boat's 5.5 m/s wind answered `none`: its identified model showed the wind with evidence
    3.8 and both folds fitted it within 1 m/s): a model within the noise (loss 0.5) that a current brings to
    0.75^2 / 2 (evidence ~3.7: between EVIDENCE_CANDIDATE and EVIDENCE_CAUSE) is `inconclusive` with the current as
    the candidate, not a confident `none`; one it brings to 0.9^2 / 2 (evidence ~1.4, what clean days reach) stays
    `none`."""
    from usv_predictor.analysis.diagnosis import EVIDENCE_CANDIDATE, EVIDENCE_CAUSE, INCONCLUSIVE, MIN_GAIN

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    result = diagnose(recordings, VESSEL, segments=seg, rollout=_PartlyExplainedRollout(seg, 1.0, after),
                      hypotheses=["current"])
    top = next(e for e in result.evidence if e.hypothesis == "current")
    assert top.heldout_loss == pytest.approx(after**2 / 2, rel=0.01)
    assert result.cause == expected
    assert result.parameters == {}
    assert result.mismatch_reasons == ()
    assert top.gain_vs_none >= MIN_GAIN
    if expected == INCONCLUSIVE:
        assert EVIDENCE_CANDIDATE <= top.evidence_vs_none < EVIDENCE_CAUSE
        assert result.candidate == "current"
        assert result.candidate_parameters["speed_mps"] >= 0.3
        assert f"evidence {top.evidence_vs_none:.1f}: more than a `none` allows" in result.inconclusive_reasons[0]
    else:
        assert top.evidence_vs_none < EVIDENCE_CANDIDATE
        assert result.candidate == ""


class _TrackOffRollout(_PartlyExplainedRollout):
    """A calm-water model within the noise: u, v, r off by `floor` noise scales (which the current does not change),
    and a north position error growing linearly to `drift` metres at the segment end (a term seen only in the track,
    as a compass offset is), of which the current removes `removed` x its share()."""

    def __init__(self, seg, floor: float, drift: float, removed: float) -> None:
        super().__init__(seg, floor, floor)
        self.removed = removed
        horizon = seg.target.shape[1]
        self.ramp = torch.zeros(horizon, 6, dtype=torch.float64)  # (H, 6): the north position error (m)
        self.ramp[:, 3] = drift * torch.arange(1, horizon + 1, dtype=torch.float64) / horizon

    def forward(self, state: torch.Tensor, controls: torch.Tensor,
                reference: torch.Tensor | None = None) -> tuple[torch.Tensor]:
        (off,) = super().forward(state, controls, reference)  # (B, H, 6)
        return (off + self.ramp * (1.0 - self.removed * self.share()),)


@pytest.mark.parametrize("drift, removed, gain, expected", [(0.8, 1.0, (0.08, 0.11), "inconclusive"),
                                                             (0.5, 1.0, (0.03, 0.05), "inconclusive"),
                                                             (1.6, 0.15, (0.08, 0.11), "none")])
def test_none_is_not_confident_while_a_hypothesis_halves_the_track_error(drift, removed, gain, expected):
    """(Unknown boats' 6 deg and 2.8 deg compass offsets answered `none`: 8 % and 3.4 % of the loss, 45 % and 41 % of
    the track error): models within the noise where a current removes 3-11 % of the held-out loss with evidence
    under EVIDENCE_CANDIDATE: where it removes the whole track error the answer is `inconclusive` with the current as
    the candidate (NONE_TRACK_GAIN), even under MIN_GAIN of the loss; one whose track error it lowers by 15 % stays
    `none`."""
    from usv_predictor.analysis.diagnosis import EVIDENCE_CANDIDATE, NONE_TRACK_GAIN

    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    result = diagnose(recordings, VESSEL, segments=seg, rollout=_TrackOffRollout(seg, 0.8, drift, removed),
                      hypotheses=["current"])
    top = next(e for e in result.evidence if e.hypothesis == "current")
    assert 0.0 < top.evidence_vs_none < EVIDENCE_CANDIDATE
    assert gain[0] <= top.gain_vs_none <= gain[1]
    assert top.track_gain_vs_none == pytest.approx(removed, abs=0.01)
    assert result.cause == expected
    assert result.parameters == {}
    if expected == "inconclusive":
        assert top.track_gain_vs_none >= NONE_TRACK_GAIN
        assert result.candidate == "current"
        assert "100 % of the held-out track error" in result.inconclusive_reasons[0]
    else:
        assert top.track_gain_vs_none < NONE_TRACK_GAIN
        assert result.candidate == ""


def test_a_fit_starts_where_it_is_told():
    """fit_hypothesis(start=...): the values a larger set's fit gives (diagnose refits a nested set of causes from
    them, select_causes); terms not given start at their record's start, a start beyond a bound at the bound."""
    recordings = trial(runs=diagnosis_runs()[:2])
    seg = make_segments(recordings)
    model = compiled_rollout(VESSEL, 0.5)
    untouched = fit_hypothesis(model, seg, ["current", "rudder_offset"], max_iter=0)
    assert untouched.terms["current_ne"] == fx.EFFECTS["current"].terms[0].start
    told = fit_hypothesis(model, seg, ["current", "rudder_offset"], max_iter=0, start={"current_ne": (0.2, -9.0)})
    assert told.terms["current_ne"] == (0.2, -3.0)  # -9 m/s clipped to the term's bound
    assert told.terms["rudder_offset"] == untouched.terms["rudder_offset"]
    assert told.loss != untouched.loss


def test_a_direction_is_probed_all_round_before_the_descent(monkeypatch):
    """A direction-valued term (Term.probe: the wind's, the waves') is tried toward every 45 deg before the
    Levenberg-Marquardt descent, which starts from the lowest loss: the loss over a direction has more than one
    minimum. The Otter's draw 19 of `bench_diagnosis.py --vessel otter` (seed 2026; 1.17 m waves from 171 deg): from
    the record's start alone the descent ended at 0.64 m from 329 deg, a minimum 14 times the truth's loss, and
    `diagnose` named it with 98 % of the held-out error removed, a confident wrong answer (with the head-sea
    resistance fitted too: 0.60 m from 334 deg, 7.3 times)."""
    from usv_predictor.analysis import diagnosis
    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps
    from usv_predictor.physics.manoeuvres import programme
    from usv_predictor.physics.scenario import make_scenario

    otter = load_vessel("otter")
    steps = diagnosis_steps(otter)
    truth = {"wave_height": 1.1733, "wave_from_deg": 171.1055, "wave_period_s": 3.0}
    scenario = make_scenario(otter, {"wave_drift": truth})
    model, recordings = ManoeuvringModel(otter), []
    for k, manoeuvre in enumerate(programme("diagnosis", otter.actuator_layout)):  # as bench_diagnosis.one_draw
        traj = simulate(model, manoeuvre, scenario.environment, heading_deg=166.1164 + 37.0 * k,
                        faults=scenario.faults, seed=19000 + k)
        signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=19100 + k)
        recordings.append(recording_from_signals(signals, steps.dt, name=manoeuvre.name, layout=otter.actuator_layout))
    seg = make_segments(recordings, steps.horizon_s, steps.stride_s)
    rollout = compiled_rollout(otter, steps.dt)

    def fitted() -> tuple[float, float, float]:
        fit = fit_hypothesis(rollout, seg, "wave_drift")
        found = physical_parameters("wave_drift", fit.terms)
        return found["significant_height_m"], found["direction_from_deg"], fit.loss

    height, direction, found_loss = fitted()
    assert height == pytest.approx(truth["wave_height"], abs=0.05)
    assert abs((direction - truth["wave_from_deg"] + 180.0) % 360.0 - 180.0) < 5.0, direction
    monkeypatch.setattr(diagnosis, "PROBE_DIRECTIONS", 0)  # the start alone: the other basin
    height, direction, start_loss = fitted()
    assert abs((direction - truth["wave_from_deg"] + 180.0) % 360.0 - 180.0) > 90.0, direction
    assert start_loss > 5.0 * found_loss


@pytest.mark.slow
def test_the_otter_sea_trials_current_is_reported_as_the_further_candidate(tmp_path) -> None:
    """The shipped Otter sea trial hides a 0.2 m/s current toward 215 deg beside a 4.5 m/s wind and 0.25 m waves
    (bags/make_bags.sh). Without the wave filter (`--wave-filter off`: the waves' first-order motion counts as the
    model's error), `diagnose` names wave_drift (the wind confounded with it); given the waves the current removes
    39 % of the held-out loss and 65 % of the track error with evidence 4.99, short of the 5 a cause needs (the message
    says 4.99, never a 5.0 rounded up: diagnosis.evidence_text): not named,
    not in the extended model, but reported as the further candidate with why, in the JSON, the message and the report,
    its parameters (fitted beside the waves on all manoeuvres) within the acceptance suite's tolerances of the truth.
    (~40 s.)"""
    import json

    from usv_predictor.analysis.hidden_effects import Draw, within_tolerance
    from usv_predictor.config import package_share_path
    from usv_predictor.replay.cli import main

    out, report = tmp_path / "diagnosis.json", tmp_path / "report"
    assert main(["diagnose", str(package_share_path("bags", "otter", "sea_trial")), "--vessel", "otter",
                 "--wave-filter", "off", "--json", str(out), "--report", str(report)]) == 0
    found = json.loads(out.read_text())
    assert found["wave_filter"]["applied"] is False and found["wave_filter"]["motion_level"] > 1.0
    assert found["cause"] == "wave_drift"
    assert found["additional_causes"] == []
    assert found["rejected_extension"] is None
    further = found["further_candidate"]
    assert further["cause"] == "current"
    assert 3.0 <= further["evidence"] < 5.0
    assert further["gain"] > 0.3
    assert further["track_gain"] > 0.5
    ok, errors = within_tolerance(Draw("current", {"current_speed": 0.2, "current_to_deg": 215.0}),
                                  further["parameters"])
    assert ok, errors
    assert further["reason"].startswith("current not named as a further cause: given wave_drift it adds evidence 4.")
    assert further["reason"] in found["message"]
    assert f"**Further candidate** — {further['reason']}" in (report / "report.md").read_text()


@pytest.mark.slow
def test_through_the_wave_filter_the_otter_sea_trials_waves_and_current_are_both_named(tmp_path) -> None:
    """The same bags with the wave filter the detector decides (their straight running shows 5.9 noise units of
    wave-frequency motion): the waves' first-order motion no longer counts as error, and the current that fell short
    of evidence above is named beside the waves, both within the acceptance suite's tolerances of the truth; the
    notes say the filter was on. (~40 s.)"""
    import json

    from usv_predictor.analysis.hidden_effects import Draw, within_tolerance
    from usv_predictor.config import package_share_path
    from usv_predictor.replay.cli import main

    out = tmp_path / "diagnosis.json"
    assert main(["diagnose", str(package_share_path("bags", "otter", "sea_trial")), "--vessel", "otter",
                 "--no-gain", "--json", str(out)]) == 0
    found = json.loads(out.read_text())
    assert found["wave_filter"]["applied"] is True and found["wave_filter"]["mode"] == "auto"
    assert any(note.startswith("wave filter on (auto)") for note in found["notes"])
    assert found["cause"] == "wave_drift"
    waves = Draw("wave_drift", {"wave_height": 0.25, "wave_from_deg": 140.0, "wave_period_s": 2.0})
    ok, errors = within_tolerance(waves, found["parameters"])
    assert ok, errors
    assert [a["cause"] for a in found["additional_causes"]] == ["current"]
    ok, errors = within_tolerance(Draw("current", {"current_speed": 0.2, "current_to_deg": 215.0}),
                                  found["additional_causes"][0]["parameters"])
    assert ok, errors


def test_a_nearly_diverging_trial_costs_inf_without_a_warning() -> None:
    """Residuals beyond ~1e19 in float32 square to inf: the cost of such a trial (or probe) is inf, silently (CI printed
    numpy's overflow warning from the Otter's wave-drift and an unknown boat's probes), and a finite cost is r . r."""
    import warnings

    from usv_predictor.analysis.diagnosis import _cost

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _cost(np.array([1e20, 3.0], dtype=np.float32)) == math.inf
        assert _cost(np.array([3.0, 4.0])) == 25.0


def test_a_diverged_held_out_loss_is_printed_as_diverged_not_nan() -> None:
    """The progress line of a hypothesis whose held-out rollout left the finite numbers (the Dalian record's
    wave_drift against its assumed vessel file) says `diverged`, in the column's width; finite losses keep 3
    decimals."""
    from usv_predictor.analysis.diagnosis import _loss_text

    assert _loss_text(float("nan")) == " diverged"
    assert _loss_text(float("inf")) == " diverged"
    assert _loss_text(1049.4110420963377) == " 1049.411"
    assert len(_loss_text(2.237)) == len(_loss_text(float("nan"))) == 9


def _delayed_trial(delay_s: float) -> list[Recording]:
    from usv_predictor.physics.scenario import make_scenario

    scenario = make_scenario(VESSEL, {"actuator_delay": {"actuator_delay_s": delay_s}})
    model = ManoeuvringModel(VESSEL)
    recordings = []
    for k, manoeuvre in enumerate(diagnosis_runs()):
        traj = simulate(model, manoeuvre, scenario.environment, heading_deg=40.0 * k, faults=scenario.faults, seed=k)
        signals = measure(traj, scenario.environment, scenario.sensor_spec, scenario.faults, seed=10 + k)
        recordings.append(recording_from_signals(signals, 0.5, name=manoeuvre.name))
    return recordings


def test_a_delay_within_a_quarter_step_is_the_rollouts_timing_not_a_cause() -> None:
    """At the 0.5 s step a fitted delay under 0.125 s (Effect.step_resolution 0.25) is not named: an identified
    model's own timing errors are of that size (a clean rudder_only boat's searched rudder factors fitted 0.024 s at
    0.25 s), so such a delay cannot be told from the calm-water model's error. Here the model is exact and a true
    0.05 s delay fits 0.044-0.045 s in both folds (named with evidence 10.9 without the rule): no candidate, `none`,
    and the note says why (the price of the rule, below the suite's 0.3-1.5 s delays); 0.6 s is named."""
    effect = fx.EFFECTS["actuator_delay"]
    assert effect.unresolved({"delay_s": 0.1}, 0.5) and not effect.unresolved({"delay_s": 0.13}, 0.5)
    assert not effect.unresolved({"delay_s": 0.1}, 0.25) and not fx.EFFECTS["current"].unresolved({}, 0.5)
    small = diagnose(_delayed_trial(0.05), VESSEL, hypotheses=["actuator_delay"])
    assert small.cause == "none", small.message
    assert "actuator_delay" not in [e.hypothesis for e in small.evidence]
    note = next(n for n in small.notes if n.startswith("actuator_delay is not a candidate"))
    assert note.count("under 0.25 of the 0.5 s model step") == 2, note
    large = diagnose(_delayed_trial(0.6), VESSEL, hypotheses=["actuator_delay"])
    assert large.cause == "actuator_delay", large.message
    assert large.parameters["delay_s"] == pytest.approx(0.6, abs=0.2)
    assert not any(n.startswith("actuator_delay is not a candidate") for n in large.notes)


def test_a_gyro_bias_moves_only_the_start_and_is_judged_by_the_track_not_raised():
    """A gyro bias (yaw_rate_bias, Effect.track_neutral) changes what the gyro reports, not where the boat goes: the
    grey box with a bias b predicts the track (x, y, heading) of the plain model started at the yaw rate r - b, and its
    reported yaw rate is that model's plus b. So its extension is not asked to lower the held-out track error, only
    not to raise it by more than TRACK_NEUTRAL; every other cause (a current here) must still lower it."""
    from usv_predictor.analysis import diagnosis as dg
    from usv_predictor.models.greybox import GreyBoxRollout

    vessel = load_vessel("jari_usv")
    biased, plain = GreyBoxRollout(vessel, 0.5), GreyBoxRollout(vessel, 0.5)
    b = math.radians(0.6)
    with torch.no_grad():
        biased.yaw_rate_bias[0] = b
    state = torch.tensor([[5.0, 0.1, 0.05, 0.3], [4.0, -0.2, -0.1, 2.0]], dtype=torch.float64)
    controls = torch.stack([torch.full((2, 40), 0.2), torch.full((2, 40), 650.0)], dim=2).to(torch.float64)
    with torch.no_grad():
        got = biased(state, controls)[0]  # (B, H, 6)
        shifted = state.clone()
        shifted[:, 2] -= b
        expected = plain(shifted, controls)[0]
        unshifted = plain(state, controls)[0]
    assert torch.allclose(got[..., 3:], expected[..., 3:], rtol=0, atol=1e-9)  # x, y, psi
    assert torch.allclose(got[..., 2], expected[..., 2] + b, rtol=0, atol=1e-12)  # the gyro's r
    assert float((unshifted[..., 5] - got[..., 5]).abs().max()) > 1e-3  # the start's yaw rate does move the track
    assert [n for n, e in fx.EFFECTS.items() if e.track_neutral] == ["yaw_rate_bias"]
    raised = -0.5 * dg.TRACK_NEUTRAL  # its extension raised the track error by half the tolerance
    assert dg.lowers_track(raised, ("yaw_rate_bias",)) and not dg.lowers_track(raised, ("current",))
    assert not dg.lowers_track(-2.0 * dg.TRACK_NEUTRAL, ("yaw_rate_bias",))
    assert not dg.lowers_track(raised, ("yaw_rate_bias", "current")) and not dg.lowers_track(raised, ())
    assert dg.Contribution("yaw_rate_bias", (), 0.3, 20.0, 0.6, raised).earns_place
    assert not dg.Contribution("current", (), 0.3, 20.0, 0.6, raised).earns_place


def test_the_head_sea_resistance_is_found_where_the_description_lacks_it(monkeypatch):
    """The unknown boats' waves (docs/results/unknown_boats.md): the truth's drift series pushes hard in head seas
    (jari_usv: C_X(0) = -0.25), the description's short-wave estimate of the same hull (docs/vessel.md) hardly at
    all (-0.02) and 2.4 times harder abeam. With the waves' height alone the fit trades surge against sway; with the
    head-sea resistance C_AW it fits the surge the description lacks: in the description's units the truth's head
    seas are -0.25 / 0.42 (the sway ratio), C_AW about 0.58, staged (the lower loss of the free descent and of the one
    freed from the fit with C_AW held at 0). A model with the truth's series fits none and the height.
    Drift only (no first-order motion)."""
    estimate = dataclasses.replace(VESSEL.wave_drift, a_x=(0.0, -0.138, 0.127, -0.009), b_x=(), a_y=(0.0,),
                                   b_y=(-0.837, -0.127, 0.149), a_n=(0.0,), b_n=(0.010, -0.023, -0.005))
    description = dataclasses.replace(VESSEL, wave_drift=estimate)
    env = Environment(wave_height=1.2, wave_from_deg=30.0, wave_components=0)
    seg = make_segments(trial(env=env))
    rollout = compiled_rollout(description, 0.5)
    full = fit_hypothesis(rollout, seg, "wave_drift")
    found = physical_parameters("wave_drift", full.terms)
    assert abs((found["direction_from_deg"] - 30.0 + 180.0) % 360.0 - 180.0) < 10.0, found
    assert 0.3 < found["head_sea_resistance"] < 0.9, found
    # staged (Term.staged): the lower of the descent with C_AW free and of the one from the fit with it held at 0
    free = fit_hypothesis(rollout, seg, "wave_drift", hold=frozenset())
    held = fit_hypothesis(rollout, seg, "wave_drift", hold=frozenset({"wave_resistance"}))
    assert held.terms["wave_resistance"] == (0.0,) and free.terms["wave_resistance"][0] > 0.3
    assert full.loss <= min(free.loss, held.loss) and full.loss < 0.9 * held.loss
    exact = physical_parameters("wave_drift", fit_hypothesis(compiled_rollout(VESSEL, 0.5), seg, "wave_drift").terms)
    assert exact["head_sea_resistance"] < 0.05, exact  # the truth's own series needs none ...
    assert exact["significant_height_m"] == pytest.approx(1.2, abs=0.05), exact  # ... and gives the height
    waves = fx.EFFECTS["wave_drift"]
    height_only = dataclasses.replace(waves, terms=waves.terms[:1],
                                      readout=dataclasses.replace(waves.readout, resistance_term=""))
    monkeypatch.setattr(fx, "EFFECTS", {**fx.EFFECTS, "wave_drift": height_only})
    with torch.no_grad():
        rollout.module.wave_resistance.zero_()  # no longer a term of the records: set_terms leaves it
    plain = fit_hypothesis(rollout, seg, "wave_drift")
    assert "wave_resistance" not in plain.terms
    assert full.loss < 0.5 * plain.loss, (full.loss, plain.loss)


def test_a_direction_is_probed_at_its_magnitude_and_at_half_of_it():
    """_probes: every PROBE_SHARES share of Term.probe toward every PROBE_DIRECTIONS direction, the other terms as the
    start holds them, a term given a start not probed. Half the magnitude: a wind's load goes with its speed squared,
    and an unknown boat's 5.4 m/s wind probed at 8 m/s alone (2.2 times its load) ended one fold's descent at
    1.4 m/s from 307 deg (benchmarks/bench_unknown_boats.py boat 20; named 5.3 m/s from 108 deg with both)."""
    from usv_predictor.analysis.diagnosis import PROBE_DIRECTIONS, PROBE_SHARES, _probes

    wind, waves = fx.EFFECTS["wind"].terms[0], fx.EFFECTS["wave_drift"].terms
    terms = (wind, *waves)  # wind_ne (2), wave_ne (2), wave_resistance (1)
    theta = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    probes = _probes(terms, [2, 2, 1], theta, {})
    assert PROBE_SHARES == (1.0, 0.5) and len(probes) == 2 * len(PROBE_SHARES) * PROBE_DIRECTIONS
    for term, k, group in ((wind, 0, probes[:16]), (waves[0], 2, probes[16:])):
        magnitudes = sorted({round(float(np.hypot(*p[k:k + 2])) * term.scale, 12) for p in group})
        assert magnitudes == [0.5 * term.probe, term.probe], term.name
        east_of_north = sorted({round(math.degrees(math.atan2(p[k + 1], p[k])) % 360.0, 9) for p in group})
        assert east_of_north == [45.0 * j for j in range(8)], term.name
        others = [j for j in range(5) if j not in (k, k + 1)]
        assert all(np.array_equal(p[others], theta[others]) for p in group), term.name
    assert len(_probes(terms, [2, 2, 1], theta, {"wind_ne": (1.0, 0.0)})) == len(PROBE_SHARES) * PROBE_DIRECTIONS


def test_an_evidence_is_never_printed_rounded_up_to_what_a_cause_needs():
    from usv_predictor.analysis.diagnosis import EVIDENCE_CAUSE, evidence_text

    assert EVIDENCE_CAUSE == 5.0
    assert [evidence_text(x) for x in (4.9, 4.949, 4.95, 4.996, 5.0, 5.04, 12.34, -0.3)] == [
        "4.9", "4.9", "4.95", "4.99", "5.0", "5.0", "12.3", "-0.3"]

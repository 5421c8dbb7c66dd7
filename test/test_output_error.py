"""The output-error (multiple-shooting) stage of identify and its stability check (fitting/output_error.py).

The walkthrough's boat (docs/your_boat.md): the shipped Otter bags (simulated from the otter preset, whose
coefficients are therefore known) identified as an unknown boat from `vessel init`'s description (its thruster
time constant the default 1 s, the truth 0.1 s). The equation-error stage holds N_r and N_rr at the description's
values (the yaw equation comes from the formulas); the output-error stage determines them, finds the motor lag and
predicts the held-out manoeuvres better, so it is kept. A diverging model is regularised towards the description,
and refused when the description diverges too.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from usv_predictor.data.recording import recording_from_signals
from usv_predictor.errors import NotIdentifiableError
from usv_predictor.fitting import identification as idf
from usv_predictor.fitting import hull_models
from usv_predictor.fitting import output_error as oe
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import CommandTurningCircle, CommandZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay import cli
from usv_predictor.replay.identify import identification_recordings

ROOT = Path(__file__).resolve().parents[1]
OTTER_CALM = [ROOT / "bags/otter/training/calm", ROOT / "bags/otter/sea_trial/calm"]
JARI_SEA = [ROOT / "bags/training"]  # the jari_usv preset (the truth) in the shipped sea: current, wind, waves
DT = 0.2
OTTER_INIT = ["vessel", "init", "--name", "my_otter", "--layout", "twin_thrusters", "--lpp", "2.0", "--beam", "1.08",
              "--mass", "80", "--draught", "0.2", "--hulls", "2", "--demihull-beam", "0.25", "--thruster-spacing",
              "0.79", "--thruster-x", "-1.0", "--thrust", "1:119.7", "--thrust=-1:-66.7", "--thrust-unit",
              "normalised", "--speed", "1.11", "--at", "0.6"]  # docs/your_boat.md step 1


@pytest.fixture(scope="module")
def walkthrough(tmp_path_factory):
    """(equation-error result, output-error result, recordings) of the walkthrough's boat."""
    path = tmp_path_factory.mktemp("otter") / "my_otter.yaml"
    assert cli.main([*OTTER_INIT, "--output", str(path)]) == 0
    vessel = load_vessel(path)
    recordings = identification_recordings(OTTER_CALM, DT, layout=vessel.actuator_layout)
    equation_error = hull_models.identify(vessel, recordings, prior="fix")
    return equation_error, oe.refine(equation_error, recordings), recordings


def _coefficients(result) -> dict:
    return {c.name: c for c in result.coefficients()}


def test_the_output_error_stage_determines_the_yaw_equation_the_equation_error_held(walkthrough):
    equation_error, output_error, _ = walkthrough
    before, after = _coefficients(equation_error), _coefficients(output_error)
    truth = load_vessel("otter")
    for name in ("N_r", "N_rr"):
        assert before[name].status == "fixed to prior", name  # the equation error holds the yaw terms
        assert after[name].status == "identified", name
        assert after[name].ci95[0] <= after[name].estimate <= after[name].ci95[1]
    assert "N_r" not in output_error.prior_used() and "N_rr" not in output_error.prior_used()
    # the motor lag: the description says 1 s (vessel init's default), the bags' boat has 0.1 s
    lag = after[oe.LAG_NAMES["twin_thrusters"]]
    assert lag.status == "identified"
    assert lag.estimate == pytest.approx(truth.thrusters.port.time_constant_s, rel=0.3)
    assert lag.prior == pytest.approx(1.0)
    assert output_error.vessel.thrusters.port.time_constant_s == pytest.approx(lag.estimate)
    # the sway damping, which the mass sets the scale of as the description's added mass does (Y_vdot -120 kg here,
    # -82.5 kg in the preset): within 15 %
    assert after["Y_v"].estimate == pytest.approx(truth.small_craft.Y_v, rel=0.15)


def test_the_output_error_model_is_kept_because_it_predicts_held_out_manoeuvres_better(walkthrough):
    _, output_error, _ = walkthrough
    stage = output_error.output_error
    assert stage["kept"] == "output error"
    heldout = stage["heldout_simulation_nmse"]
    assert heldout["output error"] < 0.5 * heldout["equation error"]
    assert stage["fit"]["insample_nmse"] < stage["fit"]["insample_nmse_start"]
    assert any(note.startswith("output error: output error kept") for note in output_error.notes)
    assert output_error.to_json()["output_error"]["kept"] == "output error"
    stability = stage["stability"]  # kept as fitted: at most the course instability of its description (tolerated)
    assert stability["alpha"] == 1.0 and stability["failure"] is None and stability["prior_weight"] == 1.0
    assert all("tolerated" in t for t in stability["tried"])
    for c in output_error.coefficients():
        assert math.isfinite(c.estimate), c.name


def test_the_output_error_grey_box_predicts_the_sea_trial_turns_better(walkthrough):
    equation_error, output_error, recordings = walkthrough
    model = oe.Model(output_error.vessel, output_error.prior, "small_craft", {}, 0.0)
    turns = [r for r in recordings if r.name.startswith("turning_circle")]
    data = {d.name: d for d in output_error.data}
    segments = oe.shooting_segments([data[r.name] for r in turns], turns, 20.0, 5.0, smoothed_start=False)
    def per_segment(vessel):  # (B,) normalised squared error of each 20 s segment
        return np.mean(oe.residuals(model, vessel, segments).reshape(len(segments[0].state), -1) ** 2, axis=1)

    before, after = per_segment(equation_error.vessel), per_segment(output_error.vessel)
    # the typical segment (the turn's steady part): ~10 noise units^2 -> ~1; the approach of the 0.8 turns at 2 m/s
    # is worse (the fitted hull is course-unstable there, as its description: docs/results/identification.md)
    assert np.median(after) < 0.25 * np.median(before)
    assert np.mean(after < before) > 0.75


def _otter_runs(vessel, seconds: float = 40.0):
    runs = (CommandZigZag("twin_thrusters", 0.6, 20.0, 0.7, duration_s=seconds),
            CommandTurningCircle("twin_thrusters", 0.8, 0.6, duration_s=seconds, approach_s=5.0, side=-1))
    model, env = ManoeuvringModel(vessel), Environment()
    return [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), DT,
                                   name=m.name, layout=vessel.actuator_layout) for i, m in enumerate(runs)]


def test_a_diverging_model_is_regularised_towards_the_description_with_its_reason():
    vessel = load_vessel("otter")
    env = oe.envelope(vessel, _otter_runs(vessel))
    model = oe.Model(vessel, vessel, "small_craft", {}, 0.0)
    truth = vessel.small_craft
    params = [oe.Parameter("N_r", truth.N_r, abs(truth.N_r), False, -10.0, 10.0),
              oe.Parameter("N_rr", truth.N_rr, abs(truth.N_rr), False, -10.0, 10.0)]
    described = oe.check_envelope(model, vessel, env)  # the preset: at most course-unstable (the Otter at full thrust)
    assert described is None or described.startswith(oe.COURSE_UNSTABLE)
    wrong = {"N_r": 3.0 * abs(truth.N_r), "N_rr": 2.0 * abs(truth.N_rr)}  # yaw damping of the wrong sign
    reason = oe.check_envelope(model, model.vessel(wrong), env)
    assert reason is not None and ("diverges" in reason or "unstable" in reason)
    kept, alpha, failure, tried = oe.regularise(model, params, wrong, env)
    assert failure == reason
    assert 0.0 <= alpha < 1.0 and tried
    after = oe.check_envelope(model, model.vessel(kept), env)
    assert after is None or (after.startswith(oe.COURSE_UNSTABLE) and described is not None)
    for name, p in zip(("N_r", "N_rr"), params):  # between the description and the diverging fit
        assert p.prior <= kept[name] <= wrong[name] or wrong[name] <= kept[name] <= p.prior


class _GivenRollout:
    """check_envelope's model whose rollout is the given (B, H, 6) output, whatever the vessel and inputs."""

    def __init__(self, out: np.ndarray) -> None:
        self.out = out

    def rollout(self, vessel, dt):  # Model.rollout: the runner of the vessel's grey box
        return _GivenRunner(self.out)


class _GivenRunner:
    def __init__(self, out: np.ndarray) -> None:
        self.out = out

    def rollout(self, state, controls, reference):  # (outputs, ...) as KernelRollout.rollout
        return (self.out,)


def test_sternway_is_held_to_settle_only_when_the_trials_went_astern():
    vessel = load_vessel("otter")
    steps = 40
    wobble = 0.3 * np.sin(np.arange(steps) * 0.7)  # (H,) peak-to-peak 0.6 m/s: 60 % of the envelope's speed
    out = np.zeros((2, steps, 6))
    out[0, :, 0] = 1.0  # row 0: a settled straight run ahead
    out[1, :, 0] = -0.5 + wobble  # row 1: sternway that does not settle
    out[1, :, 1] = wobble
    env = oe.Envelope(np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0]]), np.array([[1.0, 1.0], [-1.0, -1.0]]),
                      np.zeros((2, 4)), 1.0, 0.1, 0.5, steps, astern=False)
    assert oe.check_envelope(_GivenRollout(out), vessel, env) is None
    assert "unstable (does not settle" in oe.check_envelope(_GivenRollout(out), vessel,
                                                            dataclasses.replace(env, astern=True))
    ahead = out.copy()
    ahead[1, :, 0] = 1.0 + wobble  # the same wobble ahead is judged without astern trials too
    assert "unstable (does not settle" in oe.check_envelope(_GivenRollout(ahead), vessel, env)
    diverged = out.copy()
    diverged[1, -1, 0] = np.nan  # sternway still has to stay finite
    assert "diverges" in oe.check_envelope(_GivenRollout(diverged), vessel, env)


def test_the_envelope_knows_whether_the_trials_went_astern():
    vessel = load_vessel("otter")
    runs = _otter_runs(vessel, seconds=20.0)
    assert not oe.envelope(vessel, runs).astern
    backwards = [dataclasses.replace(runs[0], nu=runs[0].nu * np.array([-1.0, 1.0, 1.0]))]
    assert oe.envelope(vessel, [*runs, *backwards]).astern


def test_a_model_whose_description_diverges_too_is_refused():
    vessel = load_vessel("otter")
    env = oe.envelope(vessel, _otter_runs(vessel))
    unstable = dataclasses.replace(vessel, small_craft=dataclasses.replace(
        vessel.small_craft, N_r=abs(vessel.small_craft.N_r) * 3.0, N_rr=abs(vessel.small_craft.N_rr) * 2.0,
        cross_flow_cd=0.0))
    model = oe.Model(unstable, unstable, "small_craft", {}, 0.0)
    params = [oe.Parameter("N_r", unstable.small_craft.N_r, abs(unstable.small_craft.N_r), False, -10.0, 10.0)]
    with pytest.raises(NotIdentifiableError, match="diverge or are unstable"):
        oe.regularise(model, params, {"N_r": unstable.small_craft.N_r}, env)


def test_the_envelope_spans_the_trials_and_a_margin_beyond():
    vessel = load_vessel("otter")
    recordings = _otter_runs(vessel)
    env = oe.envelope(vessel, recordings)
    nu = np.concatenate([r.nu for r in recordings])
    controls = np.concatenate([r.controls for r in recordings])
    assert env.speed == pytest.approx(np.max(np.hypot(nu[:, 0], nu[:, 1])) * (1.0 + oe.ENVELOPE_MARGIN))
    assert np.max(np.abs(env.state[:, 2])) == pytest.approx(np.max(np.abs(nu[:, 2])) * (1.0 + oe.ENVELOPE_MARGIN))
    plausible = [c.plausible[1] for c in vessel.actuator_layout.controls]
    assert env.controls.max(axis=0) == pytest.approx(np.minimum(
        controls.max(axis=0) + oe.ENVELOPE_MARGIN * np.ptp(controls, axis=0), plausible))
    assert env.steps * env.dt >= oe.ENVELOPE_MIN_S


def test_the_segments_start_from_the_smoothed_state_and_the_motor_where_it_was():
    vessel = load_vessel("otter")
    recordings = _otter_runs(vessel)
    data = idf.prepare(vessel, recordings)
    (shooting,) = oe.shooting_segments(data, recordings, oe.SEGMENT_S, oe.STRIDE_S)
    first = shooting.manoeuvre == 0
    starts = shooting.start[first]
    assert np.allclose(shooting.state[first, :3], data[0].nu[starts])
    assert np.allclose(shooting.state[first, 3], recordings[0].psi[starts])
    slow = dataclasses.replace(vessel, thrusters=dataclasses.replace(
        vessel.thrusters, port=dataclasses.replace(vessel.thrusters.port, time_constant_s=2.0)))
    controls = oe.with_lag_state(slow, shooting)
    level = idf.lagged_command(recordings[0].controls[:, 0], 2.0, DT)
    assert np.allclose(controls[first, 0, 0], level[starts])
    assert np.allclose(controls[first, 1:], shooting.controls[first, 1:])  # only the first sample moves
    assert not np.allclose(controls[first, 0, 0], shooting.controls[first, 0, 0])


def test_the_output_error_stage_recovers_the_sway_yaw_coupling_the_equation_error_misses():
    """jari_usv's shipped training day (four manoeuvres in the sea of bags/README.md; the preset is the truth and
    the description, its interaction factors held: the truth's), MMG hull: the sea's forces, which the force fit
    takes for hull forces, put N_v 2 x off the truth; fitted on the motion it and N_r are within 20 %. Y_r is held
    at the description's value by both stages (these four manoeuvres do not determine it). (With the factors searched
    the equation error's start is itself within 40 % on N_v and N_r, and the stage keeps N_r at the description's.)"""
    vessel = load_vessel("jari_usv")
    recordings = identification_recordings(JARI_SEA, DT, layout=vessel.actuator_layout)
    equation_error = hull_models.identify(vessel, recordings, prior="fix", interaction="fix")
    output_error = oe.refine(equation_error, recordings)
    assert output_error.output_error["kept"] == "output error"
    before, after = _coefficients(equation_error), _coefficients(output_error)
    assert before["N_v"].estimate == pytest.approx(0.5 * vessel.hull.N_v, rel=0.2)  # the equation error misses it
    for name in ("N_v", "N_r"):
        assert after[name].status == "identified", name
        assert after[name].estimate == pytest.approx(getattr(vessel.hull, name), rel=0.2), name
    assert before["Y_r"].status == after["Y_r"].status == "fixed to prior"
    assert output_error.vessel.hull.N_r == pytest.approx(after["N_r"].estimate)


def test_a_regularised_coefficient_keeps_the_fits_interval_and_names_what_pulled_it(walkthrough):
    """A model blended towards the description for stability (regularise's alpha < 1) reports the blended estimate
    with the fit's own interval (which need not contain it) under its own status, not as `identified`, and lists it
    among the values the prior set, with the reason and the trial that would determine it."""
    equation_error = walkthrough[0]
    description = equation_error.prior or equation_error.vessel
    model = oe.Model(equation_error.vessel, description, equation_error.vessel.hull_model_name,
                     dict(equation_error.extra_terms), equation_error.fit.u0)
    params, start = oe.parameters(equation_error, list(equation_error.data))
    alpha = 0.25
    blended = {p.name: p.prior + alpha * (start[p.name] - p.prior) for p in params}
    stage = oe.OutputErrorStage("equation error", "not run", {}, None, {"failure": "diverges (a test's words)"})
    result = oe._result(equation_error, model.vessel(blended), params, blended, stage, alpha)
    before, after = _coefficients(equation_error), _coefficients(result)
    moved = [n for n in after if after[n].estimate != before[n].estimate]
    assert "N_v" in moved and "N_r" not in moved  # the equation error identified N_v and held N_r (module docstring)
    for name in moved:
        assert after[name].status == idf.REGULARISED
        assert after[name].ci95 == before[name].ci95  # the fit's interval, not one made to contain the blend
        assert after[name].estimate == pytest.approx(before[name].prior + alpha * (before[name].estimate
                                                                                   - before[name].prior), rel=1e-9)
    for name in set(after) - set(moved):
        assert after[name].status == before[name].status
    held = {h["name"]: h for h in result.held()}
    assert set(moved) <= set(held)
    assert "diverges or does not settle" in held["N_v"]["how"] and held["N_v"]["would_determine"]
    assert any("regularised towards the description (alpha 0.25)" in n for n in result.notes)

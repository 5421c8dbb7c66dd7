"""The interaction factors' search (usv_predictor/fitting/interaction.py): its plausibility check of a candidate's
steady turn and straight run, and the output-error search on a boat whose rudder differs from its description."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from usv_predictor.analysis.hidden_effects import effect_names
from usv_predictor.analysis.unknown_boats import SIZE_CLASSES, TRIAL_RPM, draw_boat
from usv_predictor.data.recording import recording_from_signals
from usv_predictor.errors import ConfigError
from usv_predictor.fitting import hull_models
from usv_predictor.fitting import identification as idf
from usv_predictor.fitting import interaction as ia
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import RandomManoeuvre, TurningCircle, ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

DT = 0.2  # (s) the identification grid


def _straight(vessel):
    return ManoeuvringModel(vessel).straight_speed(TRIAL_RPM)


def test_the_preset_and_the_benchmark_truths_pass_the_steady_check():
    """The check's bounds admit every truth of the unknown-boat benchmark's first boats (seed 2026), which pivot at
    full rudder (their steady speed down to a few % of the straight speed), and jari_usv."""
    preset = load_vessel("jari_usv")
    assert ia.steady_check(preset, TRIAL_RPM, _straight(preset)) is None
    effects = effect_names("rudder_propeller")
    classes = tuple(SIZE_CLASSES)
    for index in range(0, 60, 7):
        rng = np.random.default_rng([2026, index])
        truth = draw_boat(rng, classes[(index // len(effects)) % len(classes)]).truth_vessel()
        assert ia.steady_check(truth, TRIAL_RPM, _straight(truth)) is None, index


def test_the_steady_turn_of_jari_usv_is_its_simulated_turning_circle():
    """steady_turn's RK4 gives the simulator's steady circle (physics/simulator.py, the same equations)."""
    preset = load_vessel("jari_usv")
    model = ManoeuvringModel(preset)
    turn = ia.steady_turn(model, TRIAL_RPM, _straight(preset), 35.0)
    traj = simulate(model, TurningCircle(35.0, TRIAL_RPM, duration_s=400.0), Environment(), dt=0.05)
    tail = traj.nu[-len(traj.nu) // 10:]  # (n, 3) u, v, r over the last 40 s
    assert turn.diverged_after_s is None
    assert turn.yaw_rate == pytest.approx(float(np.mean(tail[:, 2])), rel=0.01)
    speed = float(np.mean(np.hypot(tail[:, 0], tail[:, 1])))
    assert turn.speed_ratio == pytest.approx(speed / _straight(preset), rel=0.01)
    assert turn.yaw_rate_spread < 1e-3 * abs(turn.yaw_rate)  # steady


def test_the_steady_check_names_what_is_implausible():
    preset = load_vessel("jari_usv")
    u0 = _straight(preset)
    # the measured straight-running speed far from the model's
    assert "straight-running speed" in ia.steady_check(preset, TRIAL_RPM, 2.0 * u0)
    # a rudder that hardly turns a course-stable boat: a steady diameter of thousands of ship lengths
    weak = dataclasses.replace(preset, hull=dataclasses.replace(preset.hull, N_r=-0.5, N_v=-0.05),
                               rudder=dataclasses.replace(preset.rudder, lift_factor=1e-3))
    assert "steady diameter" in ia.steady_check(weak, TRIAL_RPM, None)
    # a rudder whose force points the wrong way (jari_usv itself is course-unstable: a turn is not proof enough)
    assert "turns the other way" in ia.steady_check(
        dataclasses.replace(preset, rudder=dataclasses.replace(preset.rudder, lift_factor=-1.0)), TRIAL_RPM, None)
    # cubic terms that make the turn run away (what a wrong rudder split does to the hull regression:
    # docs/results/unknown_boats.md, boat 2)
    runaway = dataclasses.replace(preset, hull=dataclasses.replace(preset.hull, N_r=0.3, N_rrr=0.5, Y_vvv=5.0))
    assert "diverges" in ia.steady_check(runaway, TRIAL_RPM, None)


def test_eta_is_searched_at_most_to_a_full_slipstream():
    preset = load_vessel("jari_usv")  # eta 0.9
    assert ia.with_factors(preset, {"rudder.eta": 2.0}).rudder.eta == pytest.approx(ia.ETA_MAX)
    assert ia.with_factors(preset, {"rudder.eta": 0.5}).rudder.eta == pytest.approx(0.45)
    low, high = ia._bounds(preset, "rudder.eta")
    assert low == 0.5
    assert high == pytest.approx(ia.ETA_MAX / 0.9)
    scaled = ia.with_factors(preset, {"rudder.lift_factor": 1.25, "rudder.gamma_R": 0.75})
    assert scaled.rudder.f_alpha == pytest.approx(1.25 * preset.rudder.f_alpha)
    assert scaled.rudder.gamma_R_minus == pytest.approx(0.75 * preset.rudder.gamma_R_minus)


TRIALS = (ZigZag(10.0, 10.0, 650.0, duration_s=80.0), ZigZag(20.0, 20.0, 700.0, duration_s=80.0, side=-1),
          TurningCircle(25.0, 650.0, duration_s=80.0), RandomManoeuvre(seed=3, duration_s=150.0))


@pytest.mark.slow
def test_the_search_moves_wrong_rudder_factors_toward_the_truth():
    """jari_usv's description, a boat whose rudder lift gradient is 25 % higher and gamma_R 25 % lower (its hull the
    description's): identified from a noisy calm day, the searched lift gradient and gamma_R are both closer to the
    boat's than the description's, and the chosen factors simulate the held-out manoeuvres better."""
    description = load_vessel("jari_usv")
    truth = ia.with_factors(description, {"rudder.lift_factor": 1.25, "rudder.gamma_R": 0.75})
    model, env = ManoeuvringModel(truth), Environment()
    recordings = [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), DT,
                                         name=m.name) for i, m in enumerate(TRIALS)]
    result = hull_models.identify(description, recordings, structure="mmg", prior="fix", interaction="identify")
    searched = result.interaction
    assert searched["accepted"], result.notes
    factors = {c.name: c.estimate for c in result.actuator_coefficients}
    for name in ("rudder.lift_factor", "rudder.gamma_R"):
        true, prior = ia.factor_value(truth, name), ia.factor_value(description, name)
        assert abs(factors[name] - true) < 0.5 * abs(prior - true), (name, factors[name], true, prior)
    heldout = searched["heldout_simulation_nmse"]
    assert heldout[searched["chosen"]] < ia.ACCEPT_RATIO * heldout["description"]
    assert result.vessel.rudder.f_alpha == pytest.approx(factors["rudder.lift_factor"] * description.rudder.f_alpha /
                                                         description.rudder.lift_factor)
    assert not math.isnan(result.fit.values()["N_r"])


RUDDER_ONLY_TRIALS = (ZigZag(10.0, 10.0, 650.0, duration_s=80.0), ZigZag(20.0, 20.0, 700.0, duration_s=80.0, side=-1),
                      TurningCircle(25.0, 650.0, duration_s=80.0), TurningCircle(15.0, 700.0, duration_s=80.0, side=-1))


def test_every_layout_with_interaction_factors_has_its_searched_factors():
    """identification searches the layouts of INTERACTION_LAYOUTS, interaction.py knows the factors of each (and of
    rudder_only); a rudder_only boat (engine speed not recorded) keeps the propeller's: they set its equivalent engine
    speed."""
    assert set(idf.INTERACTION_LAYOUTS) <= set(ia.SEARCHED_FACTORS)
    for factors in ia.SEARCHED_FACTORS.values():
        assert set(factors.equation_error) <= set(factors.output_error) <= set(ia.INTERACTION_BOUNDS)
        assert len(factors.output_error) <= len(ia.HALTON_BASES)
    assert not any(n.startswith("propeller.") for n in ia.SEARCHED_FACTORS["rudder_only"].output_error)
    otter = load_vessel("otter")
    with pytest.raises(ConfigError, match="twin_thrusters"):
        ia.identify_interaction(otter, [], [], "mmg", "fix", 1.0)


@pytest.mark.slow
def test_the_search_moves_wrong_rudder_factors_toward_the_truth_without_the_engine_speed():
    """rudder_only (the engine speed not recorded): jari_usv's description, a boat whose rudder lift gradient is 25 %
    higher and gamma_R 25 % lower: the search varies the rudder's factors (not the propeller's, which define the
    equivalent engine speed), both closer to the boat's than the description's."""
    description = dataclasses.replace(load_vessel("jari_usv"), layout="rudder_only")
    truth = ia.with_factors(description, {"rudder.lift_factor": 1.25, "rudder.gamma_R": 0.75})
    model, env = ManoeuvringModel(truth), Environment()
    recordings = [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), DT,
                                         name=m.name, layout=truth.actuator_layout)
                  for i, m in enumerate(RUDDER_ONLY_TRIALS)]
    assert recordings[0].controls.shape[1] == 1
    data = idf.prepare(description, recordings)
    u0 = float(np.median(np.concatenate([d.nu[:, 0] for d in data])))
    fit = ia.identify_interaction(description, data, recordings, "mmg", "fix", u0, held=("R0",))
    assert fit.accepted, fit.note()
    factors = {c.name: c.estimate for c in fit.coefficients}
    assert set(factors) == set(ia.SEARCHED_FACTORS["rudder_only"].output_error)
    for name in ("rudder.lift_factor", "rudder.gamma_R"):
        true, prior = ia.factor_value(truth, name), ia.factor_value(description, name)
        assert abs(factors[name] - true) < 0.5 * abs(prior - true), (name, factors[name], true, prior)
    assert fit.vessel.propeller == description.propeller
    assert fit.scale["propeller.w_P0"] == fit.scale["propeller.t_P"] == 1.0
    assert fit.simulation[fit.chosen] < ia.ACCEPT_RATIO * fit.simulation["description"]
    # identify's default for rudder_only too (identification.INTERACTION_LAYOUTS), and `fix` holds the description's
    assert hull_models.identify(description, recordings, structure="mmg", prior="fix", interaction="identify",
                                data=data).interaction is not None
    assert hull_models.identify(description, recordings, structure="mmg", prior="fix", interaction="fix",
                                data=data).interaction is None


def test_without_a_segment_long_enough_the_description_stays():
    """Manoeuvres shorter than a segment give no simulation error: the description's factors stay, said in one line
    (no NaN in the JSON)."""
    description = load_vessel("jari_usv")
    model, env = ManoeuvringModel(description), Environment()
    short = (ZigZag(10.0, 10.0, 650.0, duration_s=15.0), ZigZag(20.0, 20.0, 700.0, duration_s=15.0, side=-1),
             TurningCircle(25.0, 650.0, duration_s=15.0))
    recordings = [recording_from_signals(measure(simulate(model, m, env, seed=i), env, SensorSpec(), seed=i), DT,
                                         name=m.name) for i, m in enumerate(short)]
    data = idf.prepare(description, recordings)
    u0 = float(np.median(np.concatenate([d.nu[:, 0] for d in data])))
    fit = ia.identify_interaction(description, data, recordings, "mmg", "fix", u0)
    assert not fit.accepted
    assert fit.scale == {n: 1.0 for n in ia.INTERACTION_BOUNDS}
    assert fit.vessel.rudder == description.rudder
    assert fit.simulation == {}
    assert "no candidate could be simulated (no manoeuvre longer than 20 s)" in fit.note()
    json.dumps(fit.to_json(), allow_nan=False)


def test_a_manoeuvre_no_candidate_predicts_held_out_leaves_the_decision():
    """A manoeuvre on which every candidate diverges when it is held out tells none from another: it leaves both
    held-out errors (and is named); one on which only one candidate diverges stays and counts against it."""
    diverged = ia.Fold(10 * ia.DIVERGED, 10, True)  # 10 segments, every one diverged
    folds = {"description": {"random": diverged, "turn": ia.Fold(80.0, 20, False), "zigzag": ia.Fold(30.0, 10, False)},
             "candidate": {"random": diverged, "turn": ia.Fold(20.0, 20, False), "zigzag": diverged}}
    assert ia.uncovered_manoeuvres(folds) == ("random",)
    assert ia.heldout_simulation_error(folds["description"], ("random",)) == pytest.approx(110.0 / 30)
    assert ia.heldout_simulation_error(folds["candidate"], ("random",)) == pytest.approx((20.0 + 10 * ia.DIVERGED) / 30)
    assert ia.heldout_simulation_error(folds["description"]) == pytest.approx((110.0 + 10 * ia.DIVERGED) / 40)
    assert ia.uncovered_manoeuvres({"candidate": folds["candidate"]}) == ()  # alone it cannot tell
    assert math.isnan(ia.heldout_simulation_error({"random": diverged}, ("random",)))


@pytest.mark.parametrize("argv, expected", [([], "identify"), (["--interaction", "fix"], "fix")])
def test_replay_identify_searches_the_interaction_factors_by_default(monkeypatch, tmp_path, argv, expected):
    """`replay identify` searches the interaction factors unless told `--interaction fix`; with `--base` nothing is
    identified and the option does not apply. (The default since a whole 50-boat unknown-boat run
    without a confident wrong answer: docs/results/unknown_boats.md.)"""
    from usv_predictor.replay import cli
    from usv_predictor.replay import identify as replay_identify

    seen = {}

    class Stop(Exception):
        pass

    def identify(vessel, recordings, **kwargs):
        seen.update(kwargs)
        raise Stop

    monkeypatch.setattr(replay_identify, "identification_recordings", lambda *a, **k: ["a recording"])
    monkeypatch.setattr(idf, "identify", identify)
    (tmp_path / "bags").mkdir()
    with pytest.raises(Stop):
        cli.main(["identify", str(tmp_path / "bags"), "--vessel", "jari_usv", "--prior", "fix", "--output",
                  str(tmp_path / "m.pt"), *argv])
    assert seen["interaction"] == expected
    with pytest.raises(Exception, match="--interaction do not apply"):
        replay_identify.IdentifyRequest((tmp_path / "bags",), tmp_path / "m.pt", base=tmp_path / "x.pt",
                                        hybrid=object(), interaction=expected)


def test_identify_offers_the_interaction_modes_of_the_search():
    """`replay identify --interaction` offers what fitting/interaction.py knows (INTERACTION_MODES): the command keeps
    its own literal list so that parsing it does not import the search (torch), and this proves the two the same."""
    import argparse

    from usv_predictor.replay import cmd_identify

    parser = argparse.ArgumentParser()
    cmd_identify.add_arguments(parser)
    option = next(a for a in parser._actions if "--interaction" in a.option_strings)
    assert tuple(option.choices) == ia.INTERACTION_MODES

"""A rudder boat without propulsion data (layout rudder_only) through `replay diagnose`, evaluate and the fit check.

Its grey box runs at an equivalent engine speed. It used to hold, in every prediction, the engine speed of the
prediction's START speed, so a prediction started inside a turn (where the boat has slowed down at the same engine
setting) ran slow, and a diagnosis of the boat's own bags found no fit (before this change: held-out loss 1.5e3 noise
units, a `resistance` of +300 % named). Now every prediction holds the engine speed of its manoeuvre's approach
(models/greybox.py `reference`, data.recording.approach_state), the one `replay identify` estimates per manoeuvre.

The boat is the jari_usv preset as rudder_only (650 rpm, not recorded), the trial programme of the hidden-effect
suite (turning circles and zig-zags both ways, --blind). The current's parameters are drawn from a seed this module
keeps to itself, as in test_hidden_effects.py. The numbers before / after: benchmarks/rudder_only_engine_speed.py.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from replay_helpers import replay, write_layout_variant

from usv_predictor.analysis.evaluation import WithoutReference, evaluate
from usv_predictor.analysis.fit_check import check_fit
from usv_predictor.analysis.hidden_effects import draw, within_tolerance
from usv_predictor.models.loading import physics_predictor
from usv_predictor.physics.actuators import actuator_layout
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay.recordings import load_recordings

_SECRET = int.from_bytes(hashlib.sha256(b"usv_predictor rudder_only diagnosis, 2026").digest()[:8], "little")
DT = 0.5  # (s) diagnose's model step for jari_usv (analysis/diagnosis_steps.py)
HORIZONS_S = (10.0, 30.0, 60.0)  # (s) open-loop horizons of evaluate


@pytest.fixture(scope="module")
def boat(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_layout_variant(tmp_path_factory.mktemp("rudder_only"), "rudder_only")


def trial(capsys: pytest.CaptureFixture[str], out: Path, boat: Path, seed: int, flags: list[str]) -> Path:
    """The diagnosis programme of the rudder_only boat, blind, into out/bags."""
    code, err = replay(capsys, "simulate", "--programme", "diagnosis", "--vessel", boat, *flags, "--blind",
                       "--seed", seed, "--heading", seed % 360, "--output", out / "bags")
    assert code == 0, err
    return out / "bags"


def diagnose(capsys: pytest.CaptureFixture[str], bags: Path, boat: Path, out: Path, *extra: str) -> dict:
    code, err = replay(capsys, "diagnose", bags, "--vessel", boat, "--json", out / "diagnosis.json", *extra)
    assert code == 0, err[-2000:]
    return json.loads((out / "diagnosis.json").read_text())




@pytest.mark.slow
def test_own_bags_are_diagnosed_none_and_predicted_to_the_noise(boat, tmp_path, capsys):
    """No hidden effect: cause `none` (was: a +300 % resistance, then model_mismatch), the calm-water model at the
    noise before any hypothesis; evaluate's open-loop error and the fit check with the approach's engine speed against
    the start's on the same bags."""
    bags = trial(capsys, tmp_path, boat, seed=int(np.random.default_rng([_SECRET, 0]).integers(0, 2**31)), flags=[])
    result = diagnose(capsys, bags, boat, tmp_path)
    assert result["cause"] == "none", result["message"]
    assert result["mismatch_reasons"] == []
    assert result["fit_check"]["verdict"] == "fits"
    assert result["calm_water_fit"]["heldout_loss"] < 1.0, result["calm_water_fit"]  # noise units (was 1.5e3)

    vessel = load_vessel(str(boat))
    recordings = load_recordings([bags], DT, layout=actuator_layout("rudder_only"), warn=lambda _: None)
    approach = physics_predictor(vessel, DT)
    errors = {}
    for label, predictor in (("start", WithoutReference(approach)), ("approach", approach)):
        summary = evaluate(predictor, recordings, reference="truth", horizons_s=HORIZONS_S).summary
        errors[label] = [summary[f"mean_position_error_after_{h:g}s_m"] for h in HORIZONS_S]
    assert all(new < 1.0 for new in errors["approach"]), errors  # (m) its own boat, calm water
    assert all(new < 0.2 * old for new, old in zip(errors["approach"], errors["start"])), errors
    fit = check_fit(approach, recordings, vessel=vessel)
    assert fit.verdict == "fits"
    assert fit.speed_ratio == pytest.approx(1.0, abs=0.01)
    assert fit.yaw_rate_ratio == pytest.approx(1.0, abs=0.02)  # held turns at the approach's engine speed


@pytest.mark.slow
@pytest.mark.parametrize("effect", ["current", "wave_drift"])
def test_a_hidden_effect_is_named_with_its_parameters(boat, tmp_path, capsys, effect):
    """A current or waves in the rudder_only bags: named, parameters within the effect record's tolerance. The engine
    holds the approach's speed through the WATER (the grey box takes the current's share out of the measured approach)
    against the sea's surge force there (a head sea slows the approach at the same engine setting), so neither is
    absorbed into the engine speed."""
    rng = np.random.default_rng([_SECRET, 1 + ["current", "wave_drift"].index(effect)])
    truth = draw(rng, effect, layout="rudder_only")
    bags = trial(capsys, tmp_path, boat, seed=int(rng.integers(0, 2**31)), flags=truth.cli_flags())
    result = diagnose(capsys, bags, boat, tmp_path, "--no-gain", "--max-causes", "1")
    assert result["cause"] == effect, (truth, result["message"])
    ok, errors = within_tolerance(truth, result["parameters"])
    assert ok, f"{truth}: errors {errors} beyond the tolerances"

"""The mission's acceptance test: a hidden effect in simulated trial bags, found through the public commands.

Each case draws an effect's parameters from a seed this module keeps to itself; the bags are written with
--blind, so the only way to the answer is through the data. `replay diagnose` must name the cause, estimate
the parameters within the stated tolerances (usv_predictor.analysis.hidden_effects.TOLERANCES) and, for a real cause,
improve the held-out track error. The clean control must come out `none`.

The twin-thruster preset (otter) has its own lean part: one draw of every effect that applies to its layout
(clean control included), diagnosed at the steps that suit the vessel (analysis.diagnosis_steps: 0.25 s, 10 s
segments every 2.5 s), with one cause at most (`--max-causes 1`: the primary cause is what is tested) and the gain
measured on the twin's own effect; the confusion matrix over more draws is benchmarks/bench_diagnosis.py --vessel otter.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from usv_predictor.analysis.hidden_effects import EFFECTS, draw, effect_names, within_tolerance
from usv_predictor.replay.bagio import read_custom_data
from usv_predictor.replay.cli import main

_SECRET = int.from_bytes(hashlib.sha256(b"usv_predictor hidden-effect suite, 2026").digest()[:8], "little")


def run_cli(*argv: str) -> None:
    assert main(list(argv)) == 0, f"replay {' '.join(argv)} failed"


def simulate_trial(tmp_path: Path, flags: list[str], seed: int, programme: str = "diagnosis",
                   vessel: str = "jari_usv") -> Path:
    bags = tmp_path / "bags"
    run_cli("simulate", "--programme", programme, "--vessel", vessel, *flags, "--blind", "--seed", str(seed),
            "--heading", str(seed % 360), "--output", str(bags))
    for bag in bags.iterdir():  # blind: nothing in the bag says what is in the water
        assert "scenario" not in read_custom_data(bag)
    return bags


def diagnose(tmp_path: Path, bags: Path, *extra: str) -> dict:
    out = tmp_path / "diagnosis.json"
    run_cli("diagnose", str(bags), "--json", str(out), *extra)
    return json.loads(out.read_text())


@pytest.mark.parametrize("draw_index", [0, 1])
@pytest.mark.parametrize("effect", EFFECTS)
def test_diagnose_finds_the_hidden_effect(tmp_path, effect, draw_index):
    rng = np.random.default_rng([_SECRET, EFFECTS.index(effect), draw_index])
    truth = draw(rng, effect)
    seed = int(rng.integers(0, 2**31))
    bags = simulate_trial(tmp_path, truth.cli_flags(), seed)
    # the gain needs extra rollouts: measure it on the first draw of each effect
    result = diagnose(tmp_path, bags, *(() if draw_index == 0 else ("--no-gain",)))
    assert result["cause"] == effect, (truth, result["message"], result["evidence"][:3])
    ok, errors = within_tolerance(truth, result["parameters"])
    assert ok, f"{truth}: errors {errors} beyond the tolerances"
    if effect == "none":
        assert result["parameters"] == {}
        assert result["gain"] == {}
    elif draw_index == 0:
        gain = result["gain"]
        assert gain["mean_position_error_after_30s_m"] > 0.05, gain  # the extension predicts held-out tracks better
        key = "mean_position_error_after_30s_m"
        assert result["extended"][key] < result["baseline"][key]


TWIN_VESSEL = "otter"
TWIN_EFFECTS = effect_names("twin_thrusters")
# Known limits on the 2 m boat, found by this suite (docs/results/diagnosis_matrices.md, the otter's matrix).
# Strict: the day these cases pass, the marks must go.
TWIN_NOT_FOUND = {
    # the preset's windage and wave-drift coefficients are estimates with similar heading dependence: the 10 m/s
    # wind of this draw is named wave_drift (0.45 m from 47 deg, evidence 16): confounded, a wrong cause (re-run
    # since: refused by the fit check instead, yaw-rate ratio -11.8, with the former wave coefficients too)
    "wind": "wind on the Otter preset is taken for wave drift (similar estimated coefficients)",
}
# (the wave_drift draw was refused by the fit check while its limits were the 15 m jari_usv's: its 0.81 m waves stopped
# the 2 m boat's port turn, 0.21 m/s where the calm-water preset makes 1.2 m/s; the limits now follow what the
# strongest causes do to the boat, analysis/fit_check.py, and test_fit_check.py keeps this draw's bags fitting; since
# the preset's wave-drift yaw turns toward beam seas, the boat still does not turn but makes 0.81 m/s,
# within the calm-water allowance)
# Not run in CI, to keep it near its 30 min budget (each case is a ~1.5 min diagnosis): the wind case, a known wrong
# answer (above), and the sensor/actuator faults the jari_usv draws above already cover for the same hypotheses
# (their otter results: docs/results/diagnosis_matrices.md, benchmarks/bench_diagnosis.py --vessel otter). CI keeps
# the clean control, the current, the waves and the twin's own thruster imbalance.
TWIN_NOT_IN_CI = ("wind", "yaw_rate_bias", "heading_offset", "actuator_delay")
TWIN_CASES = [pytest.param(e, marks=pytest.mark.xfail(reason=TWIN_NOT_FOUND[e], raises=AssertionError,
                                                           strict=True))
              if e in TWIN_NOT_FOUND else e for e in TWIN_EFFECTS if e not in TWIN_NOT_IN_CI]


@pytest.mark.slow
@pytest.mark.parametrize("effect", TWIN_CASES)
def test_diagnose_finds_the_hidden_effect_of_a_twin_thruster_boat(tmp_path, effect):
    rng = np.random.default_rng([_SECRET, 2, TWIN_EFFECTS.index(effect)])  # stream 2: not the jari_usv draws
    truth = draw(rng, effect, "twin_thrusters")
    seed = int(rng.integers(0, 2**31))
    bags = simulate_trial(tmp_path, truth.cli_flags(), seed, vessel=TWIN_VESSEL)
    measure_gain = effect == "thruster_imbalance"  # the twin's own effect; the others' gain is the jari_usv suite's
    result = diagnose(tmp_path, bags, "--vessel", TWIN_VESSEL, "--max-causes", "1",
                      *(() if measure_gain else ("--no-gain",)))
    assert (result["steps"]["dt_s"], result["steps"]["horizon_s"], result["steps"]["stride_s"]) == (0.25, 10.0, 2.5)
    assert result["cause"] == effect, (truth, result["message"], result["evidence"][:3])
    ok, errors = within_tolerance(truth, result["parameters"])
    assert ok, f"{truth}: errors {errors} beyond the tolerances"
    if effect == "none":
        assert result["parameters"] == {}
        assert result["gain"] == {}
    elif measure_gain:
        assert result["gain"]["mean_position_error_after_30s_m"] > 0.05, result["gain"]
        key = "mean_position_error_after_30s_m"
        assert result["extended"][key] < result["baseline"][key]


def test_heading_offset_and_current_are_told_apart(tmp_path):
    """Both bend the GNSS track away from the dead-reckoned one; the over-ground velocities separate them."""
    bags = simulate_trial(tmp_path, ["--effect", "heading_offset", "--heading-offset", "4"], 11)
    result = diagnose(tmp_path, bags, "--no-gain", "--hypotheses", "current", "heading_offset")
    assert result["cause"] == "heading_offset"
    current = next(e for e in result["evidence"] if e["hypothesis"] == "current")
    assert current["evidence_of_best"] > 5.0  # decisively worse, not a close call


@pytest.mark.parametrize("effect, flags", [
    ("rudder_offset", ["--effect", "rudder_offset", "--rudder-offset", "2"]),
    ("propeller_asymmetry", ["--effect", "propeller_asymmetry", "--propeller-side-force-pct", "4"]),
])
def test_rudder_offset_and_propeller_asymmetry_are_told_apart(tmp_path, effect, flags):
    """Both turn a boat with a centred rudder; with turns and zig-zags both ways their scalings differ
    (rudder inflow against thrust) and the tool names the right one decisively."""
    bags = simulate_trial(tmp_path, flags, 23)
    result = diagnose(tmp_path, bags, "--no-gain", "--hypotheses", "rudder_offset", "propeller_asymmetry")
    assert result["cause"] == effect
    assert result["confounded_with"] == []
    other = next(e for e in result["evidence"] if e["hypothesis"] not in (effect, "none"))
    assert other["evidence_of_best"] > 5.0


def test_one_manoeuvre_is_refused_with_what_to_add(tmp_path, capsys):
    bags = tmp_path / "one"
    run_cli("simulate", "--manoeuvre", "turning-circle", "--duration", "60", "--output", str(bags))
    assert main(["diagnose", str(bags)]) == 2
    err = capsys.readouterr().err
    assert "a diagnosis needs at least two" in err
    assert "turning circle each way" in err


def test_turns_one_way_only_are_flagged(tmp_path):
    bags = tmp_path / "bags"
    for seed, side in ((1, "starboard"), (2, "starboard")):
        run_cli("simulate", "--manoeuvre", "turning-circle", "--rudder", str(15 + 5 * seed), "--duration", "80",
                "--side", side, "--effect", "rudder_offset", "--rudder-offset", "2", "--seed", str(seed),
                "--output", str(bags))
    result = diagnose(tmp_path, bags, "--no-gain", "--hypotheses", "rudder_offset", "current")
    assert any("turn the same way" in note for note in result["notes"])

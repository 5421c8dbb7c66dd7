"""The fit check (usv_predictor.analysis.fit_check): refuse a model that cannot describe the bags, pass every model on
its own bags, whatever the hidden effect, for every actuator layout."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import yaml

from usv_predictor.analysis.fit_check import SPEED_RATIO_LIMIT, YAW_RATE_RATIO_LIMIT, check_fit
from usv_predictor.data.recording import recording_from_signals
from usv_predictor.models.loading import physics_predictor
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import programme
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel, vessel_dir, vessel_from_dict
from usv_predictor.replay.cli import main
from usv_predictor.replay.recordings import load_recordings

ROOT = Path(__file__).resolve().parents[1]


def raw_preset(name: str) -> dict:
    return yaml.safe_load((vessel_dir() / f"{name}.yaml").read_text())


def scaled_preset(name: str, new_name: str, scale: float, *, froude_actuators: bool) -> dict:
    """Preset `name` with every length times `scale` (areas scale^2, mass scale^3; non-dimensional coefficients kept).
    froude_actuators: engine speeds / sqrt(scale), rates / sqrt(scale) and time constants * sqrt(scale) (the
    Froude-similar ship); otherwise the actuators are left as they are (another boat with the same engine)."""
    raw = raw_preset(name)
    g = raw["geometry"]
    for key in ("L_pp", "L_oa", "B", "d", "x_G"):
        g[key] *= scale  # (m)
    g["displacement_kg"] *= scale ** 3  # (kg)
    raw["propeller"]["D_P"] *= scale  # (m)
    raw["rudder"]["A_R"] *= scale ** 2  # (m^2)
    for key in ("A_F", "A_L"):
        raw["windage"][key] *= scale ** 2  # (m^2)
    if froude_actuators:
        a, root = raw["actuators"], math.sqrt(scale)
        a["rpm_min"], a["rpm_max"] = a["rpm_min"] / root, a["rpm_max"] / root  # (rpm)
        a["rudder_rate_deg_s"] /= root  # (deg/s)
        a["rudder_time_constant_s"] *= root  # (s)
        a["engine_time_constant_s"] *= root  # (s)
    raw["name"] = new_name
    return raw


def write_vessel(tmp_path: Path, raw: dict) -> Path:
    path = tmp_path / f"{raw['name']}.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def small_single_screw(tmp_path: Path) -> Path:
    """A 4.5 m single-screw USV: the jari_usv hull at one third of its size, with the same engine (so 700 rpm drives
    it at about 2 m/s, where the 15 m preset runs at 5.9 m/s)."""
    return write_vessel(tmp_path, scaled_preset("jari_usv", "usv_4m5", 4.5 / 13.5, froude_actuators=False))


def trial(vessel, env: Environment = Environment()) -> list:
    """The diagnosis programme of the vessel's layout, simulated and measured (recordings at 0.5 s)."""
    model = ManoeuvringModel(vessel)
    recordings = []
    for k, manoeuvre in enumerate(programme("diagnosis", vessel.actuator_layout)):
        traj = simulate(model, manoeuvre, env, heading_deg=50.0 * k, seed=k)
        recordings.append(recording_from_signals(measure(traj, env, seed=20 + k), 0.5, name=manoeuvre.name,
                                                 layout=vessel.actuator_layout))
    return recordings


def run(*argv: str) -> int:
    return main([str(a) for a in argv])


# ---- what must pass --------------------------------------------------------------------------------------------

def test_the_shipped_bags_fit_their_own_preset():
    vessel = load_vessel("jari_usv")
    for bags in ("sea_trial", "training"):  # simulated with current, wind and waves: they still fit
        check = check_fit(physics_predictor(vessel, 0.5), load_recordings([ROOT / "bags" / bags], 0.5), vessel=vessel)
        assert check.verdict == "fits", check.summary()
        assert check.speed_windows == "straight"
        assert abs(check.speed_ratio - 1.0) < 0.1
        assert abs(check.yaw_rate_ratio - 1.0) < 0.1
        assert check.froude_measured == pytest.approx(check.froude_model, rel=0.1)
        assert check.froude_scale == pytest.approx(1.0, abs=0.2)


VARIANT_THROTTLE = {"forward_N": 9000.0, "reverse_N": 3500.0, "exponent": 2.0, "dead_band": 0.05,  # (N), (N), (-), (-)
                    "time_constant_s": 1.2}  # (s)


def layout_variants() -> dict:
    """One vessel per actuator layout (the jari hull as each rudder layout, the Otter for twin thrusters)."""
    jari = raw_preset("jari_usv")
    return {
        "rudder_propeller": load_vessel("jari_usv"),
        "rudder_throttle": vessel_from_dict({**jari, "actuator_layout": "rudder_throttle",
                                             "throttle": VARIANT_THROTTLE}, "jari as rudder_throttle"),
        "rudder_only": vessel_from_dict({**jari, "actuator_layout": "rudder_only"}, "jari as rudder_only"),
        "twin_thrusters": load_vessel("otter"),
    }


@pytest.mark.parametrize("layout", ["rudder_propeller", "rudder_throttle", "rudder_only", "twin_thrusters"])
def test_every_layout_fits_its_own_bags_and_a_slower_turner_is_refused(layout):
    from usv_predictor.physics.actuators import ACTUATOR_LAYOUTS

    assert set(ACTUATOR_LAYOUTS) == {"rudder_propeller", "rudder_throttle", "rudder_only", "twin_thrusters"}
    vessel = layout_variants()[layout]
    recordings = trial(vessel)
    own = check_fit(physics_predictor(vessel, 0.5), recordings, vessel=vessel)
    assert own.verdict == "fits", own.summary()
    assert abs(own.yaw_rate_ratio - 1.0) < 0.15
    if layout == "rudder_only":  # its engine speed holds the approach speed: only straight running is compared
        assert own.speed_windows == "straight"
    assert abs(own.speed_ratio - 1.0) < 0.1
    # a model that turns far too slowly for the recorded turn commands: eight times the yaw damping of the MMG hull,
    # a tenth of the twin's thruster spacing (a tenth of the yaw moment of a thrust difference)
    import dataclasses

    if vessel.hull_model_name == "mmg":
        stiff = dataclasses.replace(vessel, hull=dataclasses.replace(vessel.hull, N_r=vessel.hull.N_r * 8.0))
    else:
        stiff = dataclasses.replace(vessel, thrusters=dataclasses.replace(vessel.thrusters,
                                                                          spacing=vessel.thrusters.spacing / 10.0))
    wrong = check_fit(physics_predictor(stiff, 0.5), recordings, vessel=stiff)
    assert wrong.verdict == "mismatch", wrong.summary()
    assert wrong.yaw_rate_ratio < 1.0 / YAW_RATE_RATIO_LIMIT, wrong.summary()
    assert "deg/s for a held turn command" in wrong.refusal()


# the hidden-effect suite's effects at the top of their ranges (and beyond: a 0.6 m/s current, 15 m/s wind) all pass
@pytest.mark.parametrize("flags", [
    ["--effect", "current", "--current-speed", "0.6", "--current-to", "30"],
    ["--effect", "wind", "--wind-speed", "15", "--wind-from", "100"],
    ["--effect", "wave_drift", "--wave-height", "1.5", "--wave-from", "45"],
    ["--effect", "rudder_offset", "--rudder-offset", "-4"],
    ["--effect", "yaw_rate_bias", "--yaw-rate-bias", "1"],
    ["--effect", "propeller_asymmetry", "--propeller-side-force-pct", "6"],
], ids=["current", "wind", "waves", "rudder_offset", "yaw_rate_bias", "propeller_asymmetry"])
def test_no_hidden_effect_fails_the_check(tmp_path, flags):
    bags = tmp_path / "bags"
    assert run("simulate", "--programme", "diagnosis", *flags, "--seed", "5", "--heading", "37", "--output", bags) == 0
    vessel = load_vessel("jari_usv")
    check = check_fit(physics_predictor(vessel, 0.5), load_recordings([bags], 0.5), vessel=vessel)
    assert check.verdict == "fits", check.summary()
    if check.speed_ratio is not None:  # measured: within 5 % (docs/commands.md "The fit check")
        assert abs(check.speed_ratio - 1.0) < 0.1 < SPEED_RATIO_LIMIT - 1.0
    if check.yaw_rate_ratio is not None:
        assert abs(check.yaw_rate_ratio - 1.0) < 0.1


# ---- what must be refused: the two cases -----------------------------------------------------------------

def test_a_small_boat_diagnosed_with_the_default_preset_is_refused_in_one_line(tmp_path, capsys):
    boat = small_single_screw(tmp_path)
    bags = tmp_path / "bags"
    assert run("simulate", "--programme", "diagnosis", "--vessel", boat, "--effect", "current", "--current-speed",
               "0.3", "--seed", "3", "--blind", "--output", bags) == 0
    capsys.readouterr()
    assert run("diagnose", bags) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("replay diagnose: error: the preset jari_usv does not fit these bags: it runs at 5.5 m/s at "
                          "650 rpm, these bags at "), err
    measured = float(err.split("these bags at ")[1].split(" m/s")[0])
    assert 1.6 < measured < 2.3  # (m/s) the small boat's 1.8 m/s at 650 rpm, +-0.3 m/s of current over ground
    # the limit is the 13.5 m boat's: what the strongest cause of the vocabulary does to it, below the ratio
    limit = float(err.split("limit ")[1].split(" for the 13.5 m boat it describes: the most any one cause")[0])
    assert SPEED_RATIO_LIMIT < limit < float(err.split("(ratio ")[1].split(",")[0]), err
    assert "identify this boat first (docs/your_boat.md)" in err
    assert "--no-fit-check" in err
    # the expert proceeds: the answer is model_mismatch, never a confident environmental cause or `none`
    out = tmp_path / "d.json"
    assert run("diagnose", bags, "--no-fit-check", "--no-gain", "--hypotheses", "current", "resistance",
               "--max-causes", "1", "--json", out) == 0
    result = json.loads(out.read_text())
    assert result["cause"] == "model_mismatch"
    assert result["parameters"] == {}
    assert result["fit_check"]["verdict"] == "mismatch"
    assert result["fit_check"]["speed_ratio"] > SPEED_RATIO_LIMIT
    assert any("fit check failed" in r for r in result["mismatch_reasons"])
    assert result["calm_water_fit"]["heldout_loss"] > 1.0
    assert "identify this boat first" in result["message"]


def test_the_kvlcc2_model_evaluated_on_full_scale_bags_is_refused(tmp_path, capsys):
    ship = write_vessel(tmp_path, scaled_preset("kvlcc2_model", "kvlcc2_full_scale", 45.714, froude_actuators=True))
    bags = tmp_path / "bags"
    for side in ("starboard", "port"):
        assert run("simulate", "--vessel", ship, "--manoeuvre", "turning-circle", "--rudder", "35", "--rpm", "76",
                   "--side", side, "--duration", "400", "--seed", "4", "--output", bags) == 0
    capsys.readouterr()
    assert run("evaluate", bags, "--model", "physics:kvlcc2_model") == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("replay evaluate: error: the preset kvlcc2_model does not fit these bags: it runs at 0.69 "
                          "m/s at 76 rpm, these bags at 5.8 m/s"), err
    assert "times its top speed" in err
    assert "Froude-similar to a hull" in err
    assert "docs/your_boat.md" in err
    out = tmp_path / "e.json"
    assert run("evaluate", bags, "--model", "physics:kvlcc2_model", "--no-fit-check", "--json", out) == 0
    assert json.loads(out.read_text())["fit_check"]["verdict"] == "mismatch"
    # its own (full-scale) description fits the same bags
    vessel = load_vessel(ship)
    assert check_fit(physics_predictor(vessel, 0.5), load_recordings([bags], 0.5), vessel=vessel).verdict == "fits"


# ---- the limits follow the boat: what the strongest causes can do to it -----------------------------------------

def test_waves_that_stop_a_two_metre_boat_do_not_fail_the_check(tmp_path):
    """The Otter acceptance draw: 0.81 m waves from 119 deg stop its held turns. With the preset's
    former wave-drift yaw (toward head seas, 2x the present one) its port turn made 0.21 m/s where the calm-water
    preset makes 1.2 m/s (ratio 5.8); since the yaw turns toward beam seas the boat still does not turn
    in any window but makes 0.81 m/s: ratio 1.48, within the calm-water allowance. The same draw with waves at the
    top of the suite's range (1.5 m) stops it to 0.28 m/s and beyond (port turn: pushed astern): far beyond the
    allowance, but a right model in some sea of the vocabulary, so no refusal."""
    seed = 1601067103
    vessel = load_vessel("otter")

    def check_at(wave_height: str):
        bags = tmp_path / wave_height
        assert run("simulate", "--programme", "diagnosis", "--vessel", "otter", "--effect", "wave_drift",
                   "--wave-height", wave_height, "--wave-from", "119.3769", "--wave-period", "3", "--blind", "--seed",
                   seed, "--heading", seed % 360, "--output", bags) == 0
        return check_fit(physics_predictor(vessel, 0.25),
                         load_recordings([bags], 0.25, layout=vessel.actuator_layout), vessel=vessel)

    check = check_at("0.8101")  # the acceptance draw
    assert check.verdict == "fits" and check.speed_ratio > 1.2, check.summary()  # slowed, not refused
    assert all(abs(w.measured_yaw_rate_rad_s) < 0.1 * abs(w.predicted_yaw_rate_rad_s) for w in check.windows
               if w.kind == "turn")  # it does not turn
    check = check_at("1.5")
    assert check.speed_ratio > 2.5 * SPEED_RATIO_LIMIT, check.summary()  # far beyond the allowance ...
    assert check.verdict == "fits", check.summary()  # ... and still a right model
    explained = check.speed_explanation
    assert explained.explained
    assert explained.cause.effect == "wave_drift"
    assert explained.limits[1] == math.inf
    assert explained.cause.parameters["wave_height"] == 1.5  # the top of the suite's range


def test_the_limits_follow_the_size_of_the_boat():
    """On each preset's own calm diagnosis programme: a cause at the top of the vocabulary can stop the 2 m Otter and
    the 4.9 m WAM-V in their held turns (their upper speed limit is unbounded) and carry them faster than a 0.6 m/s
    current does the 13.5 m jari_usv, whose straight speed no cause moves by half (so the 4.5 m boat's ratio 2.7
    above is refused)."""
    from usv_predictor.analysis.diagnosis_steps import diagnosis_steps

    limits = {}
    for name in ("jari_usv", "wamv", "otter"):
        vessel = load_vessel(name)
        dt = diagnosis_steps(vessel).dt  # (s) 0.5 for the jari_usv, 0.25 for the small boats
        check = check_fit(physics_predictor(vessel, dt), _trial_at(vessel, dt), vessel=vessel, explain_always=True)
        assert check.verdict == "fits", (name, check.summary())
        assert check.speed_explanation.explained
        assert check.yaw_rate_explanation.explained
        limits[name] = check.speed_explanation.limits
    assert SPEED_RATIO_LIMIT < limits["jari_usv"][1] < 2.5, limits
    assert limits["wamv"][1] == limits["otter"][1] == math.inf, limits
    assert limits["otter"][0] < limits["jari_usv"][0], limits
    assert limits["wamv"][0] < limits["jari_usv"][0], limits


def _trial_at(vessel, dt: float) -> list:
    model = ManoeuvringModel(vessel)
    recordings = []
    for k, manoeuvre in enumerate(programme("diagnosis", vessel.actuator_layout)):
        traj = simulate(model, manoeuvre, Environment(), heading_deg=50.0 * k, seed=k)
        recordings.append(recording_from_signals(measure(traj, Environment(), seed=20 + k), dt, name=manoeuvre.name,
                                                 layout=vessel.actuator_layout))
    return recordings


# each sea effect at the top of the suite's range on the two twin-thruster presets: the right model is never refused.
# The WAM-V's waves were a strict expected failure until its preset had the floats' cross-flow drag:
# VRX's 40 N s/m of linear sway damping alone let 1.5 m waves push the beam-on boat sideways at ~41 m/s, beyond
# what the bag reader takes as plausible (15 m/s), so no recording was left to check.


@pytest.mark.parametrize("vessel_name", ["otter", "wamv"])
@pytest.mark.parametrize("flags", [
    ["--effect", "current", "--current-speed", "0.6", "--current-to", "30"],
    ["--effect", "wind", "--wind-speed", "15", "--wind-from", "100"],
    ["--effect", "wave_drift", "--wave-height", "1.5", "--wave-from", "45"],
], ids=["current", "wind", "waves"])
def test_no_sea_at_the_top_of_its_range_fails_a_small_boat(tmp_path, vessel_name, flags):
    bags = tmp_path / "bags"
    assert run("simulate", "--programme", "diagnosis", "--vessel", vessel_name, *flags, "--seed", "5", "--heading",
               "37", "--output", bags) == 0
    vessel = load_vessel(vessel_name)
    recordings = load_recordings([bags], 0.25, layout=vessel.actuator_layout)
    assert len(recordings) == 4, [r.name for r in recordings]  # every manoeuvre of the programme read back
    check = check_fit(physics_predictor(vessel, 0.25), recordings, vessel=vessel)
    assert check.verdict == "fits", check.summary()
    for ratio, limit, explained in ((check.speed_ratio, SPEED_RATIO_LIMIT, check.speed_explanation),
                                    (check.yaw_rate_ratio, YAW_RATE_RATIO_LIMIT, check.yaw_rate_explanation)):
        if ratio is not None and not (1.0 / limit <= ratio <= limit):  # beyond the allowance: a cause explains it
            assert explained.explained, check.summary()
            assert explained.cause is not None, check.summary()


def test_the_causes_of_a_rudder_only_window_hold_its_approach_engine_speed():
    """cause_changes rolls the causes out as the check's prediction was: a rudder_only grey box holds the engine
    speed of the window's approach (Rolled.reference), not the one of the rollout's start. Here the approach ran
    north at 5.5 m/s into a 15 m/s wind from the north (its engine works against it) and the window runs south,
    started at 3 m/s: with that engine speed and the wind astern, a right model runs faster than the calm one; held
    at the start's engine speed (tailwind already in it), the wind changes almost nothing."""
    import numpy as np
    import torch

    from usv_predictor.analysis import fit_check as fc
    from usv_predictor.models.greybox import GreyBoxRollout

    vessel = layout_variants()["rudder_only"]
    dt = 0.5
    steps, averaged = int(fc.SETTLE_S / dt), int(fc.STEADY_S / dt)
    start = np.array([3.0, 0.0, 0.0, math.pi])  # (4,) heading south
    approach = np.array([5.5, 0.0, 0.0, 0.0])  # (4,) heading north
    wind = fc.Cause("wind", {"wind_speed": 15.0, "wind_from_deg": 0.0}, {"wind_ne": (-15.0, 0.0)})  # from north

    def window(kind: str, rudder_rad: float, reference) -> fc.Rolled:
        controls = np.full((steps, 1), rudder_rad)  # (H, 1) rudder only
        return fc.Rolled(fc.SteadyWindow("r", kind, 0.0, 1.0, rudder_rad, 0.0, 3.0, 3.0, 0.0, 0.0), start, controls,
                         averaged, reference)

    du, _ = fc.cause_changes(vessel, dt, [window("straight", 0.0, approach), window("straight", 0.0, None)], [wind])
    assert du[0, 0] > 0.3, du
    assert abs(du[0, 1]) < 0.1, du
    # a turn (sway and yaw free) is exactly the vessel's grey box with that reference
    turn = window("turn", math.radians(15.0), approach)
    du, dr = fc.cause_changes(vessel, dt, [turn], [wind])
    model = GreyBoxRollout(vessel, dt, substeps=fc.cause_substeps(vessel, dt))
    state, controls, ref = (torch.as_tensor(a[None]) for a in (start, turn.controls, approach))
    with torch.no_grad():
        calm = model(state, controls, ref)[0, 0, -averaged:].mean(dim=0)  # (6,)
        model.wind_ne[:] = torch.tensor([-15.0, 0.0], dtype=torch.float64)
        windy = model(state, controls, ref)[0, 0, -averaged:].mean(dim=0)  # (6,)
    assert du[0, 0] == pytest.approx(float(windy[0] - calm[0]), abs=1e-9)
    assert dr[0, 0] == pytest.approx(float(windy[2] - calm[2]), abs=1e-12)


def test_the_scripted_causes_are_the_eager_ones_bit_for_bit_and_the_compiled_ones_to_rounding():
    """cause_changes runs its steered grey box as TorchScript without the executor's optimisation (half eager's
    time) and reduced to u and r (fit_check._causes_rollout: the positions not integrated, the sea terms and hull
    coefficients once per rollout): the same numbers bit for bit as the steered grey box's whole rollout, eager, on
    random straight windows and turns of different lengths in one batch, with and without a rudder_only reference,
    for every strongest cause of both layouts, at the node's substeps and at others; the scripted module, kept per
    vessel and step, gives the same numbers again after another batch."""
    import numpy as np

    from usv_predictor.analysis import fit_check as fc

    rng = np.random.default_rng(7)
    for vessel, dt in ((load_vessel("jari_usv"), 0.5), (layout_variants()["rudder_only"], 0.25)):
        layout = vessel.actuator_layout
        causes = fc.strongest_causes(layout.name)
        rolled = []
        for kind, steps in (("straight", 40), ("turn", 17), ("turn", 29)):
            held = [0.0 if kind == "straight" else 0.2, 600.0][:2 if layout.propulsion else 1]  # rudder (rad), rpm
            controls = np.tile(held, (steps, 1)) + rng.normal(0.0, 0.01, (steps, len(held)))  # (H, C)
            state = np.array([4.0, 0.1, 0.02, 1.0]) + rng.normal(0.0, 0.1, 4)  # (4,)
            reference = None if layout.propulsion else np.array([4.5, 0.0, 0.0, 0.3])
            rolled.append(fc.Rolled(fc.SteadyWindow("r", kind, 0.0, 1.0, 0.0, 0.0, 4.0, 4.0, 0.0, 0.0), state,
                                    controls, min(steps, 12), reference))
        for substeps in (None, 3):
            whole = fc.cause_changes(vessel, dt, rolled, causes, compiled=False, scripted=False, lean=False,
                                     substeps=substeps)
            assert np.isfinite(whole[0]).all() and np.abs(whole[0]).max() > 0.01  # the causes change something
            assert np.abs(whole[1]).max() > 1e-3
            for scripted, lean in ((False, True), (True, True), (True, False)):
                out = fc.cause_changes(vessel, dt, rolled, causes, compiled=False, scripted=scripted, lean=lean,
                                       substeps=substeps)
                np.testing.assert_array_equal(out[0], whole[0])
                np.testing.assert_array_equal(out[1], whole[1])
            # the compiled kernel (the default) equals them to float rounding: du (m/s), dr (rad/s)
            compiled = fc.cause_changes(vessel, dt, rolled, causes, substeps=substeps)
            np.testing.assert_allclose(compiled[0], whole[0], rtol=0.0, atol=1e-10)
            np.testing.assert_allclose(compiled[1], whole[1], rtol=0.0, atol=1e-12)
        fc.cause_changes(vessel, dt, rolled[:1], causes[:3], compiled=False)  # another batch through the kept module
        again = fc.cause_changes(vessel, dt, rolled, causes, compiled=False)
        np.testing.assert_array_equal(again[0], fc.cause_changes(vessel, dt, rolled, causes, compiled=False,
                                                                 scripted=False)[0])
        fc.cause_changes(vessel, dt, rolled[:1], causes[:3])  # another batch through the kept kernel: its terms reset
        np.testing.assert_allclose(fc.cause_changes(vessel, dt, rolled, causes)[0], again[0], rtol=0.0, atol=1e-10)


@pytest.mark.slow
def test_the_causes_substeps_scale_with_the_boat_and_keep_du_and_dr():
    """fit_check.cause_substeps: the causes' RK4 substep grows with sqrt(L_pp / 2 m) (Froude: a hull's time scales
    go with sqrt(L / g)). On every preset and layout whose substeps it changes (dt 0.5 s: jari_usv and its
    rudder_throttle and rudder_only variants 4 -> 2, kvlcc2_model and wamv 4 -> 3), every strongest cause's du and
    dr of a straight window (steered, SETTLE_S) and two held turns at full and half propulsion stay within 1e-3 m/s
    and 2e-3 deg/s of 16 substeps, the accuracy the 2 m otter gets from the rule at 4 substeps (7.3e-4 m/s, 1.4e-3
    deg/s); the otter keeps its substeps."""
    import numpy as np

    from usv_predictor.analysis import fit_check as fc
    from usv_predictor.physics.dynamics import ManoeuvringModel

    dt = 0.5
    assert fc.cause_substeps(load_vessel("otter"), dt) == 4
    assert fc.cause_substeps(load_vessel("otter"), 0.2) == 2
    variants = layout_variants()
    vessels = {"jari_usv": (variants["rudder_propeller"], 2), "rudder_throttle": (variants["rudder_throttle"], 2),
               "rudder_only": (variants["rudder_only"], 2), "kvlcc2_model": (load_vessel("kvlcc2_model"), 3),
               "wamv": (load_vessel("wamv"), 3)}
    for name, (vessel, substeps) in vessels.items():
        assert fc.cause_substeps(vessel, dt) == substeps, name
        layout = vessel.actuator_layout
        full = layout.propulsion_input.limits(vessel)[1] * layout.propulsion_input.to_command \
            if layout.propulsion_input else 0.0
        turn = layout.turn_input.limits(vessel)[1] * layout.turn_input.to_command
        rolled = []
        for kind, propulsion, steering, steps in (("straight", full, 0.0, int(fc.SETTLE_S / dt)),
                                                  ("turn", full, turn, int(30.0 / dt)),
                                                  ("turn", 0.5 * full, 0.3 * turn, int(30.0 / dt))):
            command = np.array(layout.to_commands(steering, propulsion), dtype=float)[:len(layout.controls)]
            speed = ManoeuvringModel(vessel).straight_speed(propulsion) if layout.propulsion_input else 3.0
            state = np.array([max(speed, 0.5), 0.0, 0.0, 0.3])  # (4,)
            rolled.append(fc.Rolled(fc.SteadyWindow("r", kind, 0.0, 1.0, steering, propulsion, 1.0, 1.0, 0.0, 0.0),
                                    state, np.repeat(command[None], steps, axis=0), int(fc.STEADY_S / dt),
                                    None if layout.propulsion else state))
        causes = fc.strongest_causes(layout.name)
        du, dr = fc.cause_changes(vessel, dt, rolled, causes)
        fine_du, fine_dr = fc.cause_changes(vessel, dt, rolled, causes, substeps=16)
        assert np.isfinite(fine_du).all(), name
        assert np.abs(fine_du).max() > 0.5, name
        assert np.abs(fine_dr).max() > 0.03, name
        assert np.abs(du - fine_du).max() < 1e-3, (name, np.abs(du - fine_du).max())
        assert np.degrees(np.abs(dr - fine_dr).max()) < 2e-3, (name, np.degrees(np.abs(dr - fine_dr).max()))


def test_the_causes_are_rolled_out_for_the_windows_of_a_ratio_beyond_its_allowance_only():
    """judge_windows rolls the causes out for the windows whose ratio needs them: a straight window whose speed
    ratio lies within the allowance (1.0) is not rolled out (SETTLE_S of rollout) when only the yaw-rate ratio of
    the turn (6.0) is beyond; the turn's explanation is the one of all windows rolled out in one batch, bit for bit;
    with both ratios beyond, both windows go in one batch."""
    import numpy as np

    from usv_predictor.analysis import fit_check as fc

    vessel = load_vessel("jari_usv")
    dt = 0.5
    straight = fc.Rolled(fc.SteadyWindow("r", "straight", 0.0, 30.0, 0.0, 650.0, 5.0, 5.0, 0.0, 0.0),
                         np.array([5.0, 0.0, 0.0, 0.0]), np.tile([0.0, 650.0], (int(fc.SETTLE_S / dt), 1)), 20)
    turn = fc.Rolled(fc.SteadyWindow("r", "turn", 40.0, 50.0, 0.1, 650.0, 5.0, 5.0, math.radians(1.0),
                                     math.radians(6.0)), np.array([5.0, 0.0, 0.0, 0.0]), np.tile([0.1, 650.0], (20, 1)),
                     20)
    calls = []

    def changes_of(rolled, causes):
        calls.append([r.window.kind for r in rolled])
        return fc.cause_changes(vessel, dt, rolled, causes)

    layout = vessel.actuator_layout
    check = fc.judge_windows("m", layout, [straight, turn], np.array([5.0]), dt, vessel=vessel, changes_of=changes_of)
    assert calls == [["turn"]]
    assert check.speed_ratio == 1.0
    assert check.speed_explanation is None
    assert check.yaw_rate_ratio == pytest.approx(6.0)
    assert check.yaw_rate_explanation is not None
    causes = fc.strongest_causes(layout.name)
    _, dr = fc.cause_changes(vessel, dt, [straight, turn], causes)  # every window in one batch
    assert check.yaw_rate_explanation == fc._explain(check.yaw_rate_ratio, np.array([math.radians(6.0)]), dr[:, 1:],
                                                     fc.YAW_RATE_RATIO_LIMIT, fc.MIN_YAW_RATE, causes)
    slow = fc.Rolled(fc.SteadyWindow("r", "straight", 0.0, 30.0, 0.0, 650.0, 2.0, 5.0, 0.0, 0.0), straight.state,
                     straight.controls, 20)  # speed ratio 2.5: beyond
    calls.clear()
    check = fc.judge_windows("m", layout, [slow, turn], np.array([2.0]), dt, vessel=vessel, changes_of=changes_of)
    assert calls == [["straight", "turn"]]
    assert check.speed_explanation is not None

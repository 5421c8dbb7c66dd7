"""The effect records (usv_predictor.physics.effects): complete and consistent, read the same way by the
simulator, the grey box, the diagnosis and the acceptance suite, and adding one touches one record."""
from __future__ import annotations

import ast
import dataclasses
import math
from pathlib import Path
from types import MappingProxyType

import numpy as np
import pytest
import torch

from usv_predictor.analysis import diagnosis, hidden_effects
from usv_predictor.analysis.evaluation import angle_error_deg
from usv_predictor.data import segments
from usv_predictor.errors import ConfigError
from usv_predictor.frames import angle_difference_deg, compass_deg
from usv_predictor.models.greybox import GreyBoxRollout
from usv_predictor.physics import effects
from usv_predictor.physics.effects import (
    DEG_TO_RAD,
    EFFECTS,
    Effect,
    EffectParameter,
    ScalarReadout,
    SimulatorField,
    Term,
    Uniform,
    VelocityReadout,
)
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.scenario import make_scenario
from usv_predictor.physics.sensors import SensorSpec
from usv_predictor.physics.simulator import ActuatorFaults
from usv_predictor.physics.vessel import load_vessel

ROOT = Path(__file__).resolve().parents[1]
VESSEL = load_vessel("jari_usv")
SIMULATED = tuple(effects.simulated())
PRESET_OF_LAYOUT = {"rudder_propeller": "jari_usv", "twin_thrusters": "otter"}  # a preset of each simulated layout


def preset_for(name: str) -> str:
    """A vessel preset whose layout the effect applies to (the 15 m rudder boat unless the effect needs another)."""
    layouts = EFFECTS[name].layouts
    return "jari_usv" if layouts is None or "rudder_propeller" in layouts else PRESET_OF_LAYOUT[layouts[0]]


def layout_for(name: str) -> str:
    return load_vessel(preset_for(name)).layout


def rollout_inputs(vessel) -> tuple[torch.Tensor, torch.Tensor]:
    """A turn after a straight start for the vessel's layout: state (1, 4), controls (1, H, C)."""
    steps = 30
    turning = torch.arange(steps) >= 10
    if vessel.layout == "twin_thrusters":
        port = torch.where(turning, 0.8, 0.6).to(torch.float64)
        controls = torch.stack([port, 1.2 - port], dim=-1)[None]  # (1, H, 2)
        return torch.tensor([[1.8, 0.0, 0.0, 0.3]], dtype=torch.float64), controls
    delta = torch.where(turning, math.radians(20.0), 0.0).to(torch.float64)
    controls = torch.stack([delta, torch.full((steps,), 650.0, dtype=torch.float64)], dim=-1)[None]  # (1, H, 2)
    return torch.tensor([[2.5, 0.0, 0.0, 0.3]], dtype=torch.float64), controls  # (1, 4)


# ---- every record is complete and consistent ---------------------------------------------------------

@pytest.mark.parametrize("name", tuple(EFFECTS))
def test_every_record_is_complete_and_consistent(name):
    effect = EFFECTS[name]
    assert effect.name == name
    assert effect.help
    assert effect.terms
    term_names = {t.name for t in effect.terms}
    assert set(effect.readout.terms) <= term_names, "the readout reads a term the hypothesis does not fit"
    start = {t.name: t.start for t in effect.terms}
    assert tuple(effect.readout.read(start)) == effect.readout.keys
    std = {t.name: (0.1,) * t.size for t in effect.terms}
    assert tuple(effect.readout.uncertainty(start, std)) == effect.readout.keys
    for t in effect.terms:
        assert t.low <= min(t.start), t
        assert max(t.start) <= t.high, t
        assert 0.0 < t.scale < t.high - t.low, t
    # the acceptance suite compares exactly what it has tolerances for
    assert set(effect.readout.error_keys) == set(effect.tolerance)
    assert all(tol > 0.0 for tol in effect.tolerance.values())
    if not effect.simulated:
        assert effect.not_simulated
        assert not effect.tolerance
        assert not effect.readout.comparisons
        return
    names = {p.name for p in effect.parameters}
    assert {c.parameter for c in effect.readout.comparisons} <= names
    assert {c.key for c in effect.readout.comparisons} <= set(effect.readout.keys)
    for p in effect.parameters:
        assert p.low <= p.default <= p.high, p
        assert p.unit, p
        assert p.help, p
        assert p.sets.target in effects.SIMULATOR_TARGETS
        assert p.sets.name in {f.name for f in dataclasses.fields(p.sets.target)}, \
            f"{p.name} sets {p.sets.target.__name__}.{p.sets.name}, which does not exist"
        if p.draw is not None:
            assert all(p.low <= x <= p.high for x in p.draw.extremes), f"{p.name}: draw {p.draw} outside its range"


def test_names_flags_and_terms_are_unique():
    parameters = [p for e in EFFECTS.values() for p in e.parameters]
    assert len({p.name for p in parameters}) == len(parameters)
    assert len({p.flag for p in parameters}) == len(parameters)
    fields = [(p.sets.target, p.sets.name) for p in parameters]
    assert len(set(fields)) == len(fields), "two parameters set the same simulator field"
    with pytest.raises(ValueError, match="taken"):
        effects._registry(EFFECTS["wind"], EFFECTS["wind"])
    with pytest.raises(ValueError, match="start"):
        Term("x", 2, 1.0, -1.0, 1.0, (0.0,))
    with pytest.raises(ValueError, match="probe 0.5 needs a 2-D term"):  # a direction needs two components
        Term("x", 1, 1.0, -1.0, 1.0, (0.0,), probe=0.5)
    with pytest.raises(ValueError, match=r"within its bounds \[-1, 1\]"):
        Term("x", 2, 1.0, -1.0, 1.0, (0.0, 0.0), probe=1.5)
    assert Term("x", 2, 1.0, -1.0, 1.0, (0.0, 0.0), probe=1.0).probe == 1.0
    assert {name for name, e in EFFECTS.items() for t in e.terms if t.probe} == {"wind", "wave_drift"}


def test_the_tolerances_and_draw_ranges_are_the_published_ones():
    """The acceptance suite's contract (docs/results/diagnosis_matrices.md) is unchanged by moving it into the
    records."""
    assert dict(hidden_effects.TOLERANCES) == {
        "current": {"speed_mps": 0.05, "direction_deg": 10.0}, "wind": {"speed_mps": 2.0, "direction_deg": 20.0},
        "wave_drift": {"significant_height_m": 0.4, "direction_deg": 30.0}, "rudder_offset": {"offset_deg": 0.5},
        "yaw_rate_bias": {"bias_deg_s": 0.1}, "heading_offset": {"offset_deg": 1.0}, "actuator_delay": {"delay_s": 0.2},
        "propeller_asymmetry": {"side_force_pct": 0.5}, "thruster_imbalance": {"imbalance_pct": 1.5}, "none": {}}
    assert hidden_effects.EFFECTS == ("none", "current", "wind", "wave_drift", "rudder_offset", "yaw_rate_bias",
                                      "heading_offset", "actuator_delay", "propeller_asymmetry")
    assert hidden_effects.effect_names() == hidden_effects.EFFECTS  # a rudder boat's suite is unchanged
    assert tuple(diagnosis.HYPOTHESES) == ("none", *hidden_effects.EFFECTS[1:8], "resistance", "propeller_asymmetry",
                                           "thruster_imbalance")
    twin = hidden_effects.effect_names("twin_thrusters")
    assert twin == ("none", "current", "wind", "wave_drift", "yaw_rate_bias", "heading_offset", "actuator_delay",
                    "thruster_imbalance")
    draws = [hidden_effects.draw(np.random.default_rng(k), "thruster_imbalance", "twin_thrusters") for k in range(40)]
    assert all(5.0 <= abs(d.parameters["thruster_imbalance_pct"]) <= 15.0 for d in draws)
    assert {math.copysign(1.0, d.parameters["thruster_imbalance_pct"]) for d in draws} == {-1.0, 1.0}
    rng = np.random.default_rng(7)
    for _ in range(200):
        truth = hidden_effects.draw(rng, "rudder_offset")
        assert 1.0 <= abs(truth.parameters["rudder_offset_deg"]) <= 4.0
    signs = {math.copysign(1.0, hidden_effects.draw(rng, "heading_offset").parameters["heading_offset_deg"])
             for _ in range(50)}
    assert signs == {-1.0, 1.0}
    assert hidden_effects.draw(rng, "wind").parameters["gust_std"] == 1.0
    assert set(hidden_effects.draw(rng, "current").parameters) == {"current_speed", "current_to_deg"}
    with pytest.raises(ValueError, match="unknown effect 'resistance'"):
        hidden_effects.draw(rng, "resistance")


@pytest.mark.parametrize("layout", list(PRESET_OF_LAYOUT))
@pytest.mark.parametrize("term", tuple(effects.grey_box_terms().values()), ids=lambda t: t.name)
def test_every_grey_box_term_exists_and_acts_where_its_effects_apply(term, layout):
    """The attribute exists with the record's size on every rollout, and the equations use it: setting it changes
    the prediction of a boat whose layout its effects apply to, and only there (a rudder offset does nothing to a
    twin-thruster boat, a thrust imbalance nothing to a rudder boat). A term that scales another of its effect's
    (the head-sea resistance, the waves') is set with the others at their start."""
    vessel = load_vessel(PRESET_OF_LAYOUT[layout])
    rollout = GreyBoxRollout(vessel, dt=0.5)
    assert tuple(getattr(rollout, term.name).shape) == (term.size,)
    state, controls = rollout_inputs(vessel)
    with torch.no_grad():
        for sibling in {t for e in EFFECTS.values() if term in e.terms for t in e.terms} - {term}:
            getattr(rollout, sibling.name)[:] = torch.tensor(sibling.start, dtype=torch.float64)
        calm = rollout(state, controls)  # (1, 1, H, 6)
        value = min(term.high, max(term.low, max(abs(x) for x in term.start) + 5.0 * term.scale))
        getattr(rollout, term.name)[:] = value
        extended = rollout(state, controls)
    applies = any(e.applies_to(layout) for e in EFFECTS.values() if term in e.terms)
    change = float((extended - calm).abs().max())
    assert (change > 1e-6) == applies, f"{term.name} on {layout}: change {change:g}, applies {applies}"


CHANNELED = tuple(n for n, e in EFFECTS.items() if e.channels)


def test_a_record_that_declares_channels_exists():
    """The compass offset is measured on the two positions (analysis/diagnosis.evidence_channels)."""
    assert EFFECTS["heading_offset"].channels == effects.POSITIONS == (3, 4)
    assert [effects.CHANNELS[c] for c in effects.POSITIONS] == ["x_n", "y_e"]
    # the diagnosis' residual channels in data/segments' order (SIGMA; VELOCITY_HEADING the u, v, r, psi among them)
    assert tuple(effects.CHANNELS.index(c) for c in ("u", "v", "r", "psi")) == segments.VELOCITY_HEADING
    assert len(effects.CHANNELS) == len(segments.SIGMA)
    with pytest.raises(ValueError, match="not distinct indices"):
        dataclasses.replace(EFFECTS["heading_offset"], channels=(3, 6))


@pytest.mark.parametrize("layout", list(PRESET_OF_LAYOUT))
@pytest.mark.parametrize("name", CHANNELED)
def test_an_effect_alone_moves_only_the_channels_it_declares(name, layout):
    """Effect.channels is what the diagnosis measures its evidence on: the rollout with the effect's terms alone
    predicts every other channel exactly as the calm-water one (the likelihood of those is the same with and without
    it), and the declared ones not (a compass offset of 0.1 rad moves the positions by metres)."""
    vessel = load_vessel(PRESET_OF_LAYOUT[layout])
    rollout = GreyBoxRollout(vessel, dt=0.5)
    state, controls = rollout_inputs(vessel)
    with torch.no_grad():
        calm = rollout(state, controls)[0, 0]  # (H, 6) [u, v, r, x_n, y_e, psi]
        for term in EFFECTS[name].terms:
            getattr(rollout, term.name)[:] = min(term.high, 10.0 * term.scale)
        extended = rollout(state, controls)[0, 0]
    change = (extended - calm).abs().amax(dim=0)  # (6,) largest change of each channel
    declared = list(EFFECTS[name].channels)
    others = [c for c in range(len(effects.CHANNELS)) if c not in declared]
    assert float(change[others].max()) < 1e-12, f"{name} moves {change.tolist()}"
    assert float(change[declared].min()) > 0.1, f"{name} moves {change.tolist()}"


def test_the_grey_box_terms_are_the_records_terms_in_order():
    rollout = GreyBoxRollout(VESSEL, dt=0.5)
    assert tuple(rollout.terms()) == rollout.term_names == tuple(effects.grey_box_terms()) == (
        "current_ne", "wind_ne", "wave_ne", "wave_resistance", "rudder_offset", "yaw_rate_bias", "heading_offset",
        "actuator_delay", "resistance_change", "propeller_side_force", "thrust_imbalance")
    # the hypothesis and the term keep their own public names; the record links them
    assert [t.name for t in EFFECTS["propeller_asymmetry"].terms] == ["propeller_side_force"]


# ---- round trip: simulated truth -> grey-box terms -> vocabulary -> errors ------------------------------

@pytest.mark.parametrize("name", SIMULATED)
def test_truth_to_terms_to_vocabulary_round_trips(name):
    effect = EFFECTS[name]
    rng = np.random.default_rng(list(EFFECTS).index(name))
    for _ in range(20):
        truth = hidden_effects.draw(rng, name, layout_for(name))
        terms = effect.readout.terms_from_truth(truth.parameters)
        found = diagnosis.physical_parameters(name, terms)
        errors = hidden_effects.parameter_errors(truth, found)
        assert set(errors) == set(hidden_effects.TOLERANCES[name])
        assert all(abs(e) < 1e-9 for e in errors.values()), (truth, terms, found, errors)
        assert hidden_effects.within_tolerance(truth, found)[0]


@pytest.mark.parametrize("name", SIMULATED)
def test_a_fitted_value_beyond_its_parameters_range_is_not_physical(name):
    """diagnose turns a named cause into model_mismatch when a fitted value lies outside the range `replay simulate`
    admits for the parameter it estimates: every drawn truth is within, 1.5 x the range's end is not, and the reason
    names the key and the range; directions are never out of range."""
    effect = EFFECTS[name]
    rng = np.random.default_rng(7 + list(EFFECTS).index(name))
    truth = hidden_effects.draw(rng, name, layout_for(name))
    found = diagnosis.physical_parameters(name, effect.readout.terms_from_truth(truth.parameters))
    assert effect.outside_range(found) == ()
    ranges = {p.name: p for p in effect.parameters}
    for c in effect.readout.comparisons:
        beyond = dict(found)
        if c.angle:
            beyond[c.key] = found[c.key] + 720.0
            assert effect.outside_range(beyond) == (), c
            continue
        p = ranges[c.parameter]
        beyond[c.key] = 1.5 * p.high if p.high > 0 else 1.5 * p.low
        (reason,) = effect.outside_range(beyond)
        assert c.key in reason
        assert f"{p.low:g}..{p.high:g} {p.unit}" in reason
        assert p.name in reason


def test_scalar_terms_are_what_the_simulator_is_given():
    """For a scalar effect the grey-box term (SI) is the simulator's field (SI): a wrong factor fails here."""
    rng = np.random.default_rng(3)
    checked = 0
    for name in SIMULATED:
        effect = EFFECTS[name]
        if not isinstance(effect.readout, ScalarReadout):
            continue
        truth = hidden_effects.draw(rng, name, layout_for(name))
        scenario = make_scenario(load_vessel(preset_for(name)), {name: truth.parameters})
        (term, (value,)), = effect.readout.terms_from_truth(truth.parameters).items()
        (parameter,) = effect.parameters
        simulator = {Environment: scenario.environment, ActuatorFaults: scenario.faults,
                     SensorSpec: scenario.sensor_spec}[parameter.sets.target]
        assert value == pytest.approx(getattr(simulator, parameter.sets.name), rel=1e-12, abs=1e-15), name
        checked += 1
    assert checked == 6


def test_vector_conventions():
    """Current TOWARD, wind FROM (its term is the velocity toward), waves FROM (zeta_a^2 = (H_s / 2)^2)."""
    current = EFFECTS["current"].readout.terms_from_truth({"current_speed": 0.3, "current_to_deg": 90.0})
    assert current["current_ne"] == pytest.approx((0.0, 0.3), abs=1e-12)
    env = make_scenario(VESSEL, {"current": {"current_speed": 0.3, "current_to_deg": 90.0}}).environment
    assert env.current_ned(0.0) == pytest.approx(current["current_ne"], abs=1e-12)  # the simulator agrees
    wind = EFFECTS["wind"].readout.terms_from_truth({"wind_speed": 8.0, "wind_from_deg": 90.0})
    assert wind["wind_ne"] == pytest.approx((0.0, -8.0), abs=1e-12)  # from the east = toward the west
    waves = EFFECTS["wave_drift"].readout.terms_from_truth({"wave_height": 1.0, "wave_from_deg": 90.0})
    assert waves["wave_ne"] == pytest.approx((0.0, 0.25), abs=1e-12)
    assert EFFECTS["propeller_asymmetry"].readout.terms_from_truth({"propeller_side_force_pct": 4.0}) == {
        "propeller_side_force": pytest.approx((0.04,))}
    # a thruster imbalance of +8 %: the starboard thruster is weaker; the simulator's fault is the term (k = 0.08)
    assert EFFECTS["thruster_imbalance"].readout.terms_from_truth({"thruster_imbalance_pct": 8.0}) == {
        "thrust_imbalance": pytest.approx((0.08,))}
    faults = make_scenario(load_vessel("otter"), {"thruster_imbalance": {"thruster_imbalance_pct": 8.0}}).faults
    assert faults.thruster_imbalance == pytest.approx(0.08)


def test_a_wrong_convention_fails_the_round_trip():
    """The round trip can fail: a wind read as TOWARD is 180 deg off."""
    wrong = VelocityReadout("wind_ne", "wind_speed", "wind_from_deg", toward=True)
    truth = {"wind_speed": 8.0, "wind_from_deg": 30.0}
    found = {"speed_mps": 8.0, "direction_from_deg": wrong.read(EFFECTS["wind"].readout.terms_from_truth(truth))[
        "direction_to_deg"]}
    assert EFFECTS["wind"].readout.errors(found, truth)["direction_deg"] == pytest.approx(180.0)


def test_uncertainties_follow_the_readout():
    fit = diagnosis.Fit("wave_drift", {"wave_ne": (0.0, 0.25), "wave_resistance": (0.3,)}, 1.0,
                        {"wave_ne": (0.01, 0.0), "wave_resistance": (0.05,)}, 1, 0.0)
    sd = diagnosis._physical_uncertainty("wave_drift", fit)
    assert sd == pytest.approx({"significant_height_m": 0.02, "direction_from_deg": math.degrees(0.04),
                                "head_sea_resistance": 0.05})
    fit = diagnosis.Fit("rudder_offset", {"rudder_offset": (0.0,)}, 1.0, {"rudder_offset": (0.001,)}, 1, 0.0)
    assert diagnosis._physical_uncertainty("rudder_offset", fit) == pytest.approx({"offset_deg": math.degrees(0.001)})
    fit = diagnosis.Fit("resistance", {"resistance_change": (0.1,)}, 1.0, {"resistance_change": (0.02,)}, 1, 0.0)
    assert diagnosis._physical_uncertainty("resistance", fit) == pytest.approx({"resistance_change_pct": 2.0})
    assert diagnosis._physical_uncertainty("none", fit) == {}


# ---- the scenario applies any effect from its record -------------------------------------------------

def test_the_scenario_applies_effects_generically():
    scenario = make_scenario(VESSEL, {"rudder_offset": {"rudder_offset_deg": 2.0},
                                          "heading_offset": {"heading_offset_deg": -3.0},
                                          "current": {"current_speed": 0.4, "current_to_deg": 135.0},
                                          "propeller_asymmetry": {"propeller_side_force_pct": 4.0}})
    assert scenario.faults.rudder_offset_rad == math.radians(2.0)
    assert scenario.faults.propeller_side_force == pytest.approx(0.04)
    assert scenario.sensor_spec.heading_offset == math.radians(-3.0)
    assert scenario.environment.current_speed == 0.4
    assert scenario.environment.current_to_deg == 135.0
    assert scenario.sensor_spec.gyro_bias == 0.0
    assert scenario.environment.wind_speed == 0.0
    assert set(scenario.calm_twin().effects) == {"rudder_offset", "heading_offset", "propeller_asymmetry"}
    # a field an effect governs is the effect's value or the field's default, whatever the given sensors say
    biased = make_scenario(VESSEL, {}, SensorSpec(gyro_bias=0.01, gyro_noise_std=0.1))
    assert biased.sensor_spec.gyro_bias == 0.0
    assert biased.sensor_spec.gyro_noise_std == 0.1


@pytest.mark.parametrize("name", SIMULATED)
def test_every_parameter_reaches_its_simulator_field(name):
    effect = EFFECTS[name]
    values = {p.name: (p.low + p.high) / 2.0 + 0.1 for p in effect.parameters}  # off every default
    scenario = make_scenario(load_vessel(preset_for(name)), {name: values})
    built = {Environment: scenario.environment, ActuatorFaults: scenario.faults, SensorSpec: scenario.sensor_spec}
    for p in effect.parameters:
        assert getattr(built[p.sets.target], p.sets.name) == pytest.approx(p.sets.value(values[p.name])), p.name
    assert SimulatorField(ActuatorFaults, "rudder_offset_rad", "rad",
                          multiply=DEG_TO_RAD).value(2.0) == math.radians(2.0)


# ---- adding an effect touches one record -------------------------------------------------------------

STEERING = Effect(
    "steering_offset", "a test effect: a rudder offset under another name",
    terms=(Term("rudder_offset", 1, 0.01, -0.2, 0.2, (0.0,), "rad"),),
    readout=ScalarReadout("rudder_offset", "steering_deg", 180.0 / math.pi, "steering_offset_deg"),
    parameters=(EffectParameter("steering_offset_deg", 1.0, -5.0, 5.0, "deg", "steering offset",
                                SimulatorField(ActuatorFaults, "rudder_offset_rad", "rad", multiply=DEG_TO_RAD),
                                Uniform(1.0, 2.0, random_sign=True)),),
    tolerance={"steering_deg": 0.5},
)


def test_adding_an_effect_touches_one_record(monkeypatch, capsys):
    from usv_predictor.replay import cmd_simulate
    from usv_predictor.replay.cli import build_parser

    monkeypatch.setattr(effects, "EFFECTS", MappingProxyType({**EFFECTS, STEERING.name: STEERING}))
    # the diagnosis vocabulary
    assert diagnosis.HYPOTHESES["steering_offset"] == STEERING.terms
    assert diagnosis.physical_parameters("steering_offset", {"rudder_offset": (math.radians(1.5),)}) == pytest.approx(
        {"steering_deg": 1.5})
    with pytest.raises(SystemExit):
        build_parser(["diagnose"]).parse_args(["diagnose", "--help"])
    assert "steering_offset" in " ".join(capsys.readouterr().out.split())
    # the simulator's flags and scenario
    args = build_parser(["simulate"]).parse_args(["simulate", "--effect", "steering_offset", "--steering-offset",
                                                  "1.5"])
    chosen = cmd_simulate._effects(args)
    assert chosen == {"steering_offset": {"steering_offset_deg": 1.5}}
    assert make_scenario(VESSEL, chosen).faults.rudder_offset_rad == math.radians(1.5)
    # the acceptance suite's draws and tolerances
    assert hidden_effects.effect_names()[-1] == "steering_offset"
    rng = np.random.default_rng(0)
    truth = hidden_effects.draw(rng, "steering_offset")
    assert 1.0 <= abs(truth.parameters["steering_offset_deg"]) <= 2.0
    assert truth.cli_flags()[:3] == ["--effect", "steering_offset", "--steering-offset"]
    assert hidden_effects.TOLERANCES["steering_offset"] == {"steering_deg": 0.5}
    found = {"steering_deg": truth.parameters["steering_offset_deg"] + 0.3}
    assert hidden_effects.within_tolerance(truth, found) == (True, {"steering_deg": pytest.approx(0.3)})
    assert any(hidden_effects.draw(rng).effect == "steering_offset" for _ in range(200))
    # a shared grey-box term is one attribute
    assert GreyBoxRollout(VESSEL, dt=0.5).term_names == tuple(effects.grey_box_terms())
    monkeypatch.undo()
    assert "steering_offset" not in diagnosis.HYPOTHESES
    assert "steering_offset" not in hidden_effects.TOLERANCES


# ---- one home for the per-effect logic and the angle helpers ---------------------------------------------

def test_no_module_below_physics_spells_an_effect():
    """Models, fitting, analysis and the CLI name no effect, term or simulator parameter as a string: they read
    the records (the grey box's equations use its terms as attributes)."""
    spelled = set(EFFECTS) | set(effects.grey_box_terms()) | {p.name for e in EFFECTS.values() for p in e.parameters}
    found = []
    for folder in ("data", "models", "fitting", "analysis", "node", "replay"):
        for path in sorted((ROOT / "usv_predictor" / folder).glob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.Constant) and node.value in spelled:
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.value!r}")
    assert found == []


def test_the_effects_module_needs_no_torch_and_no_model():
    tree = ast.parse((ROOT / "usv_predictor" / "physics" / "effects.py").read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not {m for m in imported if m.split(".")[0] == "torch" or m.startswith("usv_predictor.models")}


def test_angle_helpers():
    assert angle_difference_deg(350.0, 10.0) == -20.0
    assert angle_difference_deg(10.0, 350.0) == 20.0
    assert angle_difference_deg(180.0, 0.0) == -180.0
    assert angle_difference_deg(0.0, 180.0) == -180.0
    assert angle_difference_deg(725.0, -5.0) == pytest.approx(10.0)
    assert angle_error_deg(350.0, 10.0) == -20.0
    assert angle_error_deg(None, 10.0) is None
    assert [compass_deg(n, e) for n, e in ((1, 0), (0, 1), (-1, 0), (0, -1))] == [0.0, 90.0, 180.0, 270.0]


def test_effects_apply_to_their_layouts():
    """A rudder boat keeps its hypotheses; a twin-thruster boat has no rudder offset or propeller walk but a
    thruster imbalance; the simulator and the diagnosis refuse an effect of another layout, naming it."""
    assert effects.hypothesis_names("rudder_propeller") == ("none", *[n for n in EFFECTS if n != "thruster_imbalance"])
    assert effects.hypothesis_names() == ("none", *EFFECTS)
    twin = effects.hypothesis_names("twin_thrusters")
    assert "thruster_imbalance" in twin
    assert not {"rudder_offset", "propeller_asymmetry"} & set(twin)
    assert set(effects.simulated("twin_thrusters")) == set(twin) - {"none", "resistance"}
    with pytest.raises(ConfigError, match=r"effect 'rudder_offset' does not apply to vessel otter \(actuator layout "
                                          r"twin_thrusters\); it applies to rudder_propeller, "
                                          r"rudder_throttle, rudder_only"):
        make_scenario(load_vessel("otter"), {"rudder_offset": {"rudder_offset_deg": 2.0}})
    with pytest.raises(ConfigError, match=r"hypotheses \['propeller_asymmetry'\] do not apply to vessel otter"):
        diagnosis.diagnose([], load_vessel("otter"), hypotheses=["current", "propeller_asymmetry"])

"""Actuator layouts (physics/actuators.py): one record names the controls, and every layer reads it.

A layout of three controls made up for the test goes through the features, the learned model's folded
TorchScript rollout and its artifact metadata without any other change: the package is built for N controls.
"""
from __future__ import annotations

import math
from types import MappingProxyType

import numpy as np
import pytest
import torch

import msg_adapters
from usv_predictor.data.features import feature_names, feature_units, features
from usv_predictor.data.recording import REQUIRED_ROLES, required_roles
from usv_predictor.errors import ConfigError
from usv_predictor.models.dnn import DnnConfig, DnnModel, DnnRollout, fit_normalisation
from usv_predictor.node.live import state_fields
from usv_predictor.physics.actuators import ACTUATOR_LAYOUTS, DEFAULT_LAYOUT, ActuatorLayout, Control, actuator_layout
from usv_predictor.physics.vessel import load_vessel, vessel_from_dict

THREE = ActuatorLayout(
    name="test_three", description="a made-up layout: a rudder, an engine and a bow thruster",
    controls=(Control("delta", "rad", "rudder_angle", "delta", (-1.0, 1.0), "rudder"),
              Control("rpm", "rpm", "engine_rpm", "rpm", (-5000.0, 5000.0), "engine"),
              Control("bow", "N", "bow_thruster", "thrust", (-500.0, 500.0), "bow thruster, + pushes to starboard")),
    steering=MappingProxyType({"delta": 1.0, "bow": 0.001}), propulsion=MappingProxyType({"rpm": 1.0}),
    forces="none (test)", straight_below=0.03, hold_tolerance=0.02,
)


@pytest.mark.parametrize("layout", list(ACTUATOR_LAYOUTS.values()), ids=list(ACTUATOR_LAYOUTS))
def test_every_control_is_measured_by_a_known_role_and_field(layout):
    for control in layout.controls:
        assert control.role in msg_adapters.ROLE_FIELDS, f"{layout.name}.{control.name}: unknown role {control.role}"
        assert control.field in msg_adapters.ROLE_FIELDS[control.role]
        low, high = control.plausible
        assert low < high
        assert control.unit


def test_the_default_layout_is_todays_rudder_and_rpm():
    assert DEFAULT_LAYOUT.control_names == ("delta", "rpm")
    assert DEFAULT_LAYOUT.control_units == ("rad", "rpm")
    assert REQUIRED_ROLES == ("imu", "velocity", "heading", "rudder_angle", "engine_rpm")
    assert state_fields()["rudder_angle"] == ("delta",)
    assert state_fields()["engine_rpm"] == ("rpm",)
    assert load_vessel("jari_usv").actuator_layout is DEFAULT_LAYOUT


def test_steering_and_propulsion_are_weighted_sums_of_the_controls():
    controls = np.array([[0.2, 650.0, 100.0], [-0.1, 700.0, -300.0]])
    assert THREE.steering_signal(controls) == pytest.approx([0.2 + 0.1, -0.1 - 0.3])
    assert THREE.propulsion_signal(controls) == pytest.approx([650.0, 700.0])
    assert DEFAULT_LAYOUT.steering_signal(np.array([math.radians(20.0), 650.0])) == pytest.approx(math.radians(20.0))
    with pytest.raises(ConfigError, match=r"controls need 3 columns \('delta', 'rpm', 'bow'\)"):
        THREE.steering_signal(np.zeros((4, 2)))


@pytest.fixture
def registered_three(monkeypatch):
    """THREE in the registry for one test: adding a layout is one record and one registry line."""
    import usv_predictor.physics.actuators as actuators

    monkeypatch.setattr(actuators, "ACTUATOR_LAYOUTS", MappingProxyType({**ACTUATOR_LAYOUTS, THREE.name: THREE}))
    return THREE


def test_a_layout_with_three_controls_flows_through_features_and_the_learned_rollout(registered_three):
    assert feature_names("NTF", THREE) == ("u", "v", "r", "delta", "rpm", "bow", "sin_psi", "cos_psi")
    assert feature_units("F0", THREE) == ("m/s", "m/s", "rad/s", "rad", "rpm", "N")
    assert required_roles(THREE) == ("imu", "velocity", "heading", "rudder_angle", "engine_rpm", "bow_thruster")
    rng = np.random.default_rng(0)
    n = 300
    state = np.column_stack([rng.normal(5, 1, n), rng.normal(0, .3, n), rng.normal(0, .1, n), rng.uniform(-9, 9, n)])
    controls = np.column_stack([rng.normal(0, .3, n), rng.normal(650, 30, n), rng.normal(0, 100, n)])
    x = features("NTF", state, controls, THREE)
    assert x.shape == (n, 8)
    assert np.array_equal(x[:, 5], controls[:, 2])
    y = state[:, :3] + rng.normal(0, .05, (n, 3))
    config = DnnConfig.for_features("NTF", THREE, width=8)
    assert config.layout == "test_three"
    assert config.n_features == 8
    torch.manual_seed(0)
    model = DnnModel(config, fit_normalisation(x, y, True)).double().eval()
    # the folded rollout of this layout reproduces the eager network step by step
    rollout = DnnRollout([model], dt=0.5, dtype=torch.float64)
    start, plan = state[:2], np.repeat(controls[:2, None], 6, axis=1)  # (2, 4), (2, 6, 3)
    out = rollout(torch.from_numpy(start), torch.from_numpy(plan))[0].numpy()  # (2, 6, 6)
    nu, psi = start[:, :3].copy(), start[:, 3].copy()
    with torch.no_grad():
        for k in range(6):
            nxt = model(torch.from_numpy(features("NTF", np.column_stack([nu, psi]), plan[:, k], THREE))).numpy()
            psi = psi + 0.25 * (nu[:, 2] + nxt[:, 2])
            nu = nxt
            np.testing.assert_allclose(out[:, k, :3], nu, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(out[:, k, 5], psi, rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match=r"controls must be \(B, H, C\)"):
        rollout(torch.from_numpy(start), torch.zeros(2, 6, 2, dtype=torch.float64))


def test_twin_thrusters_turn_with_the_thrust_difference():
    """port = p + d/2, starboard = p - d/2 (clipped to [-1, 1]); the steering signal is port - starboard (+ turns
    to starboard, the port thruster sits at y = -b/2), the propulsion the mean."""
    twin = actuator_layout("twin_thrusters")
    assert twin.control_names == ("port", "starboard")
    assert twin.roles == ("thruster_port", "thruster_starboard")
    assert twin.to_commands(0.4, 0.6) == pytest.approx((0.8, 0.4))
    assert twin.to_commands(2.0, 0.0) == (1.0, -1.0)
    assert twin.to_commands(0.6, 0.9) == pytest.approx((1.0, 0.6))
    commands = np.array([twin.to_commands(0.4, 0.6), twin.to_commands(-0.3, 0.5)])
    assert twin.steering_signal(commands) == pytest.approx([0.4, -0.3])
    assert twin.propulsion_signal(commands) == pytest.approx([0.6, 0.5])
    assert twin.reported_commands == ("port", "starboard")
    assert DEFAULT_LAYOUT.reported_commands == ()


def test_rudder_only_reports_no_propulsion_and_every_layout_can_be_simulated():
    only = actuator_layout("rudder_only")
    assert only.control_names == ("delta",)
    assert only.commands == ("delta", "rpm")
    assert only.propulsion_signal(np.zeros((5, 1))).tolist() == [0.0] * 5  # nothing reported: a constant level
    assert required_roles(only) == ("imu", "velocity", "heading", "rudder_angle")
    assert actuator_layout("rudder_throttle").control_names == ("delta", "throttle")
    for layout in ACTUATOR_LAYOUTS.values():
        assert len(layout.to_commands(0.1, 0.5)) == len(layout.commands) == 2
        assert set(layout.control_names) <= set(layout.commands)
        assert layout.sections
        assert layout.supports
        assert layout.turn_input is not None
        assert layout.propulsion_input is not None


def test_a_vessel_leaves_the_control_roles_of_other_layouts_alone():
    from usv_predictor.physics.actuators import unused_roles

    assert unused_roles(DEFAULT_LAYOUT) == {"throttle", "thruster_port", "thruster_starboard"}
    assert unused_roles(actuator_layout("twin_thrusters")) == {"rudder_angle", "engine_rpm", "throttle"}
    assert unused_roles(actuator_layout("rudder_only")) == {"engine_rpm", "throttle", "thruster_port",
                                                            "thruster_starboard"}


def test_unknown_layouts_and_bad_records_are_refused():
    with pytest.raises(ConfigError, match="unknown actuator layout 'twin'; known: rudder_propeller, rudder_throttle"):
        actuator_layout("twin")
    with pytest.raises(ConfigError, match="source 'guess'"):
        Control("x", "-", "throttle", "command", (-1.0, 1.0), "x", "guess")
    with pytest.raises(ConfigError, match="steering weights"):
        ActuatorLayout("bad", "", THREE.controls, MappingProxyType({"nothing": 1.0}), MappingProxyType({"rpm": 1.0}),
                       "", 0.1, 0.1)
    with pytest.raises(ConfigError, match="control names repeat"):
        ActuatorLayout("bad", "", THREE.controls[:1] * 2, MappingProxyType({"delta": 1.0}),
                       MappingProxyType({"delta": 1.0}), "", 0.1, 0.1)


def test_a_vessel_names_its_layout_and_an_unknown_one_is_refused():
    import dataclasses

    import yaml

    from usv_predictor.physics.vessel import vessel_dir

    raw = yaml.safe_load((vessel_dir() / "jari_usv.yaml").read_text())
    assert vessel_from_dict({**raw, "actuator_layout": "rudder_propeller"}).layout == "rudder_propeller"
    with pytest.raises(ConfigError, match=r"boat\.yaml: actuator_layout: unknown actuator layout 'jet'"):
        vessel_from_dict({**raw, "actuator_layout": "jet"}, source="boat.yaml")
    assert dataclasses.replace(load_vessel("jari_usv")).actuator_layout.control_names == ("delta", "rpm")

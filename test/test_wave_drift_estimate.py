"""`vessel init`'s wave-drift coefficients: the short-wave asymptote of Faltinsen 1990 sec. 5 integrated numerically
on the waterline (physics/empirical.py short_wave_drift), its closed forms on a rectangle, its symmetry, its signs
against the jari_usv preset (the yaw toward beam seas in both), every preset's yaw toward beam seas (the twin-hull
presets' yaw the estimate on their own waterlines times their sway's fraction of it), and the diagnosis' wave_drift
term moving the prediction of a boat made by `vessel init` (with all-zero coefficients, as `vessel init` wrote them
before, it moved nothing)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from usv_predictor.analysis.diagnosis import loss, make_segments, compiled_rollout, set_terms
from usv_predictor.data.recording import recording_from_signals
from usv_predictor.physics.dynamics import ManoeuvringModel, SeaLoads, fourier, fourier_terms
from usv_predictor.physics.empirical import (
    OwnerData,
    estimate_vessel,
    fourier_fit,
    short_wave_drift,
    vessel_from_dict,
    waterline_polygon,
)
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import diagnosis_runs
from usv_predictor.physics.sensors import measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import WaveDrift, available_vessels, load_vessel

L, B = 10.0, 2.0  # (m) a rectangular waterline
RECTANGLE = [waterline_polygon(L, B, 1.0)]
# jari_usv's principal dimensions (config/vessels/jari_usv.yaml) as an owner would give them
JARI = OwnerData(name="jari_init", layout="rudder_propeller", L_pp=13.5, B=3.6, d=0.8, mass_kg=21750.0, x_G=-0.6,
                 L_oa=15.0, rudder_area=0.6, rudder_span=0.8, propeller_diameter=0.6,
                 thrust_points=((700.0, 9000.0),), thrust_unit="rpm", rpm_max=900.0)
SMALL = OwnerData(name="small_usv", layout="rudder_propeller", L_pp=4.5, B=1.6, d=0.3, mass_kg=700.0,
                  rudder_area=0.06, rudder_span=0.25, propeller_diameter=0.25, thrust_points=((3000.0, 700.0),),
                  thrust_unit="rpm", rpm_max=3600.0, speed_m_s=2.5, speed_command=2400.0)

# the twin-hull presets' dimensions (config/vessels/otter.yaml, wamv.yaml) as an owner would give them: the Otter's
# pontoons 0.25 m wide (Fossen's B_pont, C_b 0.4 from the mass at its draught), the WAM-V's 0.2 m radius floats cut at
# its 0.1 m draught (0.346 m wide at the waterline, centred +-1.03 m as VRX's floats)
OTTER = OwnerData(name="otter_init", layout="twin_thrusters", L_pp=2.0, B=1.08, d=0.195122, mass_kg=80.0, hulls=2,
                  demihull_beam=0.25, thruster_spacing=0.79, thrust_points=((1.0, 119.682),))
WAMV = OwnerData(name="wamv_init", layout="twin_thrusters", L_pp=4.9, B=2.4, d=0.1, mass_kg=180.0, hulls=2,
                 demihull_beam=0.346, thruster_spacing=2.05427, thrust_points=((1.0, 242.67),))


def test_rectangle_reproduces_the_closed_forms():
    chi = np.radians([0.0, 90.0, 180.0, -90.0, 45.0, 30.0])
    cx, cy, cn = short_wave_drift(RECTANGLE, L, chi)
    # head seas: the bow (width B) reflects everything: F_X = -0.5 rho g zeta^2 B -> C_X = -B/L; following: +B/L
    assert cx[0] == pytest.approx(-B / L, abs=1e-9)
    assert cx[2] == pytest.approx(B / L, abs=1e-9)
    # beam seas from starboard push to port with |C_Y| = 1 (the whole side L reflects), from port to starboard
    assert cy[1] == pytest.approx(-1.0, abs=1e-9)
    assert cy[3] == pytest.approx(1.0, abs=1e-9)
    assert cy[0] == pytest.approx(0.0, abs=1e-9)
    assert cx[1] == pytest.approx(0.0, abs=1e-9)
    # oblique: the bow sees sin^2 of the incidence cos^2 chi, the side sin^2 chi: C_X = -B/L cos^2, C_Y = -sin^2
    for k in (4, 5):
        assert cx[k] == pytest.approx(-B / L * math.cos(chi[k]) ** 2, rel=1e-6)
        assert cy[k] == pytest.approx(-math.sin(chi[k]) ** 2, rel=1e-6)
    assert np.abs(cn).max() < 1e-9  # fore-aft symmetric: no yaw moment


def test_rectangle_fourier_projection_is_the_analytic_series():
    # C_X = -(B/L) cos(chi)|cos(chi)| = -(B/L) (8/(3 pi) cos chi + 8/(15 pi) cos 3 chi + ...)
    chi = np.radians(np.arange(0.0, 360.0, 2.0))
    cx, cy, _ = short_wave_drift(RECTANGLE, L, chi)
    a, b = fourier_fit(chi, cx, 3)
    assert a[1] == pytest.approx(-B / L * 8 / (3 * math.pi), rel=2e-3)
    assert a[3] == pytest.approx(-B / L * 8 / (15 * math.pi), rel=2e-2)
    assert a[0] == pytest.approx(0.0, abs=1e-6)
    assert a[2] == pytest.approx(0.0, abs=1e-6)
    assert b == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)


@pytest.mark.parametrize("owner", [JARI, SMALL], ids=lambda o: o.name)
def test_symmetry_of_the_estimate(owner):
    chi = np.radians(np.arange(0.0, 180.0, 7.0))
    c_b = owner.mass_kg / 1025.0 / (owner.L_pp * owner.B * owner.d)
    from usv_predictor.physics.empirical import waterplane_coefficient

    poly = [waterline_polygon(owner.L_pp, owner.B, waterplane_coefficient(c_b))]
    plus = short_wave_drift(poly, owner.L_pp, chi)
    minus = short_wave_drift(poly, owner.L_pp, -chi)
    assert np.allclose(plus[0], minus[0], atol=1e-12)  # C_X even
    assert np.allclose(plus[1], -minus[1], atol=1e-12) and np.allclose(plus[2], -minus[2], atol=1e-12)  # odd
    assert np.abs(plus[1]).max() > 0.1 and np.abs(plus[2]).max() > 1e-3  # not trivially zero
    section = estimate_vessel(owner).sections["wave_drift"]
    for key in ("b_x", "a_y", "a_n"):
        assert all(v == 0.0 for v in section[key].value), key


def _series(section: dict, axis: str, chi_deg: float) -> float:
    return fourier(fourier_terms(section[f"a_{axis}"].value, section[f"b_{axis}"].value), math.radians(chi_deg))


def test_jari_dimensions_give_the_signs_of_the_preset():
    preset = load_vessel("jari_usv").wave_drift
    est = estimate_vessel(JARI).sections["wave_drift"]
    a_x, b_y = est["a_x"].value, est["b_y"].value
    # main harmonics: surge cos(chi) (head seas push astern), sway sin(chi) (waves from starboard push to port)
    assert np.sign(a_x[1]) == np.sign(preset.a_x[1]) == -1.0
    assert np.sign(b_y[0]) == np.sign(preset.b_y[0]) == -1.0
    assert abs(b_y[0]) > abs(b_y[1]) and abs(b_y[0]) > abs(b_y[2])  # the first harmonic leads in sway
    assert _series(est, "x", 0.0) < 0.0 < _series(est, "x", 180.0)  # head seas astern, following seas ahead
    assert _series(est, "y", 90.0) < 0.0 < _series(est, "y", -90.0)
    # yaw: with a pointed bow the lit bow flank outweighs the side, bow-quarter seas turn the bow away from the
    # waves and quarter seas the stern: toward beam seas (a drifting ship lies beam-on, docs/vessel.md). The preset
    # agrees (its former generic b_n [0, 0.05] turned the bow toward head seas)
    assert _series(est, "n", 45.0) < 0.0 < _series(est, "n", -45.0)
    assert _series(est, "n", -135.0) < 0.0 < _series(est, "n", 135.0)
    chi = np.radians(np.arange(-180.0, 180.0, 1.0))
    preset_n = np.array([fourier(fourier_terms(preset.a_n, preset.b_n), c) for c in chi])
    est_n = np.array([_series(est, "n", math.degrees(c)) for c in chi])
    assert np.all(np.sign(preset_n[np.abs(est_n) > 0.003]) == np.sign(est_n[np.abs(est_n) > 0.003]))
    # the estimate is total reflection, an upper bound: the preset's yaw is that shape times the fraction of the
    # bound its sway has (0.35 / 0.837 = 0.418), so it stays below the bound everywhere
    ratio = preset.b_y[0] / b_y[0]
    assert ratio == pytest.approx(0.418, abs=0.002)
    assert np.max(np.abs(preset_n - ratio * est_n)) < 0.002  # the preset's rounding to 1e-3
    assert np.max(np.abs(preset_n)) < np.max(np.abs(est_n))


@pytest.mark.parametrize("name", available_vessels())
def test_every_preset_turns_toward_beam_seas(name):
    """docs/vessel.md, the sign of the yaw moment: bow-quarter seas turn the bow away from the waves, stern-quarter
    seas the stern (the Otter's former b_n [0, 0.01] and the WAM-V's [0, 0.02] turned them toward head
    seas). A preset without any wave drift force (kvlcc2_model) has no moment either."""
    w = load_vessel(name).wave_drift

    def c_n(chi_deg: float) -> float:
        return fourier(fourier_terms(w.a_n, w.b_n), math.radians(chi_deg))

    if not any(w.a_x + w.b_x + w.a_y + w.b_y):
        assert not any(w.a_n + w.b_n), w
        return
    assert c_n(45.0) < 0.0 < c_n(-45.0), w  # waves on the starboard bow turn the bow to port, away from them
    assert c_n(-135.0) < 0.0 < c_n(135.0), w  # waves on the starboard quarter turn the stern to port
    assert c_n(0.0) == pytest.approx(0.0, abs=1e-12) and c_n(180.0) == pytest.approx(0.0, abs=1e-12)  # symmetric


@pytest.mark.parametrize("owner, name, ratio", [(OTTER, "otter", 0.070), (WAMV, "wamv", 0.119)],
                         ids=["otter", "wamv"])
def test_twin_hull_presets_yaw_is_the_estimate_times_their_sway_fraction(owner, name, ratio):
    """As jari_usv's (0.418): the yaw of the estimate on the boat's own pontoons (total reflection, the inner hull's
    side lit only near the bow in oblique seas) times the fraction of the estimate's beam-sea sway the preset's generic
    sway has (Otter 0.07 / 0.999, WAM-V 0.12 / 1.012); the preset's surge and sway are left as they were."""
    preset = load_vessel(name).wave_drift
    est = estimate_vessel(owner).sections["wave_drift"]
    assert est["b_y"].value[0] < -0.9  # one pontoon's side reflects in beam seas (the other lies in its shadow)
    exact = preset.b_y[0] / est["b_y"].value[0]
    assert exact == pytest.approx(ratio, abs=0.001)
    # the estimate's yaw is mostly sin(2 chi) and toward beam seas, up to ~0.06 (the shadowed inner side)
    assert est["b_n"].value[1] < -0.05
    assert abs(est["b_n"].value[0]) < 0.01
    assert abs(est["b_n"].value[2]) < 0.01
    assert _series(est, "n", 45.0) < 0.0 < _series(est, "n", 135.0)
    assert np.allclose(preset.b_n, [exact * b for b in est["b_n"].value], atol=5e-5)  # the preset's 1e-4 rounding
    assert not any(preset.a_n)
    chi = np.radians(np.arange(-180.0, 180.0, 1.0))
    preset_n = np.array([fourier(fourier_terms(preset.a_n, preset.b_n), c) for c in chi])
    est_n = np.array([_series(est, "n", math.degrees(c)) for c in chi])
    assert np.all(np.sign(preset_n[np.abs(est_n) > 0.003]) == np.sign(est_n[np.abs(est_n) > 0.003]))
    # as far below the bound as its sway
    assert np.max(np.abs(preset_n)) == pytest.approx(exact * np.max(np.abs(est_n)), rel=0.03)


def test_the_yaml_carries_the_estimate_and_says_it_is_an_upper_bound():
    e = estimate_vessel(SMALL)
    vessel = vessel_from_dict(e.as_dict(), source="test")
    assert vessel.wave_drift.b_y[0] < -0.5
    assert "UPPER BOUND" in e.sections["wave_drift"]["a_x"].source
    assert any("UPPER BOUND" in w and "UNDERESTIMATE" in w for w in e.warnings)


def test_wave_drift_term_moves_the_prediction_of_an_init_vessel():
    vessel = vessel_from_dict(estimate_vessel(SMALL).as_dict(), source="test")
    model = ManoeuvringModel(vessel)
    beam = model.loads(2.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 2400.0, SeaLoads(wave_amplitude=0.5, wave_from=math.pi / 2))
    assert beam.waves[1] < -100.0  # (N) 0.5 m amplitude from starboard on a 4.5 m boat: ~0.5 kN to port
    recordings = []
    for k, manoeuvre in enumerate(diagnosis_runs()[:2]):
        traj = simulate(model, manoeuvre, Environment(), heading_deg=40.0 * k, seed=k)
        recordings.append(recording_from_signals(measure(traj, Environment(), seed=10 + k), 0.5, name=manoeuvre.name))
    seg = make_segments(recordings)

    def losses(v) -> tuple[float, float]:
        rollout = compiled_rollout(v, 0.5)
        set_terms(rollout, {})
        calm = loss(rollout, seg)
        set_terms(rollout, {"wave_ne": (0.15, 0.15)})  # zeta_a^2 (m^2) from the north-east
        return calm, loss(rollout, seg)

    calm, waves = losses(vessel)
    assert waves > 2.0 * calm  # the wave term now changes the prediction (calm data: away from the truth)
    zero = WaveDrift((0.0,), (), (0.0,), (), (0.0,), ())  # what `vessel init` wrote before
    calm0, waves0 = losses(dataclasses.replace(vessel, wave_drift=zero))
    assert waves0 == pytest.approx(calm0, rel=1e-12)


def test_catamaran_inner_hull_lies_in_the_outer_ones_shadow():
    b, off = 0.5, 1.5  # (m) pontoon beam, centre off the centreline
    hulls = [waterline_polygon(L, b, 1.0, -off), waterline_polygon(L, b, 1.0, off)]
    cx, cy, _ = short_wave_drift(hulls, L, np.radians([0.0, 90.0]))
    assert cx[0] == pytest.approx(-2 * b / L, abs=1e-9)  # head seas: both bows
    assert cy[1] == pytest.approx(-1.0, abs=1e-9)  # beam seas: the starboard pontoon only (2 without the shadow)


def test_a_fine_hull_is_all_bow_and_still_finite():
    # C_b 0.24 -> C_wp clamped to 0.5: the wedge starts at the transom (a zero-length parallel body)
    owner = OwnerData(name="fine", layout="twin_thrusters", L_pp=4.0, B=1.6, d=0.25, mass_kg=400.0,
                      thruster_spacing=0.9, thrust_points=((1.0, 300.0),))
    section = estimate_vessel(owner).sections["wave_drift"]
    values = [v for k in ("a_x", "b_y", "b_n") for v in section[k].value]
    assert all(math.isfinite(v) for v in values)
    assert section["b_y"].value[0] < -0.5

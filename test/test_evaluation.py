"""Offline evaluation: closed loop, manoeuvre classification, seed 000 metrics plumbing, open-loop errors."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from usv_predictor.analysis import evaluation as ev
from usv_predictor.atomic import jsonable as _jsonable
from usv_predictor.data.recording import Recording, recording_from_signals
from usv_predictor.errors import ModelError
from usv_predictor.physics.dynamics import ManoeuvringModel
from usv_predictor.physics.environment import Environment
from usv_predictor.physics.manoeuvres import PullOut, RandomManoeuvre, TurningCircle, ZigZag
from usv_predictor.physics.sensors import SensorSpec, measure
from usv_predictor.physics.simulator import simulate
from usv_predictor.physics.vessel import load_vessel

DT = 0.5  # s
CURRENT = Environment(current_speed=0.4, current_to_deg=215.0)  # flows toward south-west (m/s, deg)


@pytest.fixture(scope="module")
def vessel_model() -> ManoeuvringModel:
    return ManoeuvringModel(load_vessel("jari_usv"))


def simulated(model: ManoeuvringModel, manoeuvre, env: Environment = Environment(), noisy: bool = False,
              heading_deg: float = 30.0, dt: float = DT) -> Recording:
    traj = simulate(model, manoeuvre, env, heading_deg=heading_deg)
    spec = SensorSpec() if noisy else SensorSpec().noiseless()
    return recording_from_signals(measure(traj, env, spec, seed=3), dt, name=manoeuvre.name, source="sim")


@pytest.fixture(scope="module")
def turn(vessel_model) -> Recording:
    """A starboard turning circle drifting in a 0.4 m/s current: radius and drift are known by construction."""
    return simulated(vessel_model, TurningCircle(25.0, 650.0, duration_s=100.0), CURRENT)


class TruthReplay:
    """A 'perfect' model: it finds its start state in the ground truth and replays what followed.

    With `scale` != 1 it replays a track `scale` times larger about the start (same headings, u and v scaled),
    so every length metric of the prediction is off by exactly that factor and every angle is exact.
    """

    def __init__(self, recording: Recording, scale: float = 1.0, dt: float = DT) -> None:
        x_n, y_e, psi, u, v, r = recording.truth.T
        self.truth = np.column_stack([u, v, r, x_n, y_e, np.unwrap(psi)])
        self.scale = scale
        self.metadata = {"dt": dt, "model_id": f"truth-replay-x{scale:g}", "model_type": "test replay",
                         "feature_set": "none", "normalisation": list(range(100))}

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        horizon = controls.shape[1]
        out = np.empty((1, len(state), horizon, 6))
        for b, s in enumerate(state):
            i = int(np.argmin(np.abs(self.truth[:, [0, 1, 2, 5]] - s).sum(axis=1)))
            future = self.truth[i + 1:i + 1 + horizon].copy()
            future[:, 3:5] = self.scale * (future[:, 3:5] - self.truth[i, 3:5])
            future[:, 0:2] *= self.scale
            out[0, b] = future
        return out


class StandStill:
    """Predicts that the vessel stays where it is: open-loop errors must grow with the horizon."""

    metadata = {"dt": DT, "model_id": "stand-still", "model_type": "test"}

    def predict(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        out = np.zeros((2, len(state), controls.shape[1], 6))  # two identical members
        out[..., 5] = state[None, :, None, 3]
        return out


# ------------------------------------------------------------------ closed loop


def test_closed_loop_of_a_perfect_model_has_zero_error(turn):
    prediction = ev.closed_loop(TruthReplay(turn), turn, reference="truth")
    assert prediction.predicted.shape == prediction.measured.shape == (len(turn), 6)
    np.testing.assert_allclose(prediction.predicted, prediction.measured, atol=1e-9)
    assert np.all(prediction.predicted_std == 0.0)
    rmse = ev.state_rmse(prediction)
    assert all(value == pytest.approx(0.0, abs=1e-9) for value in rmse.values())


def test_closed_loop_places_the_track_at_the_measured_start_and_uses_the_controls(turn, vessel_model):
    physics = ev.physics_predictor(vessel_model.vessel, DT)
    prediction = ev.closed_loop(physics, turn, reference="gnss")
    np.testing.assert_allclose(prediction.predicted[0], prediction.measured[0])
    # in calm-water physics the turn happens (the recorded rudder drives it) but the current is unknown
    assert np.degrees(prediction.predicted[-1, ev.PSI] - prediction.predicted[0, ev.PSI]) > 720.0
    np.testing.assert_array_equal(prediction.controls, turn.controls)


def test_model_with_another_dt_is_refused_with_both_steps_named(turn):
    with pytest.raises(ModelError, match=r"dt=0.1 s but recording .* has dt=0.5 s"):
        ev.closed_loop(TruthReplay(turn, dt=0.1), turn)


def test_truth_reference_needs_ground_truth(turn):
    import dataclasses

    without = dataclasses.replace(turn, truth=None)
    with pytest.raises(ev.EvaluationError, match="no ground truth"):
        ev.closed_loop(TruthReplay(turn), without, reference="truth")


def test_model_output_of_the_wrong_shape_is_a_model_error(turn):
    class Broken:
        metadata = {"dt": DT}

        def predict(self, state, controls):
            return np.zeros((len(state), controls.shape[1], 6))  # ensemble axis missing

    with pytest.raises(ModelError, match=r"returned shape .* expected \(E, 1,"):
        ev.closed_loop(Broken(), turn)


# ------------------------------------------------------------------ classification


def _controls_recording(delta_deg: np.ndarray, rpm: np.ndarray) -> Recording:
    n = len(delta_deg)
    noise = np.random.default_rng(0).normal(0.0, 0.1, n)  # feedback noise (deg)
    return Recording(name="c", source="", t0_ns=0, dt=DT, t_s=np.arange(n) * DT, nu=np.zeros((n, 3)),
                     psi=np.zeros(n), controls=np.column_stack([np.radians(delta_deg + noise), rpm]),
                     position=np.zeros((n, 2)))


@pytest.mark.parametrize(("manoeuvre", "kind", "side", "rudder"), [
    (TurningCircle(15.0, 650.0, duration_s=60.0), "turning_circle", "starboard", 15.0),
    (TurningCircle(20.0, 700.0, duration_s=60.0, side=-1), "turning_circle", "port", 20.0),
    (ZigZag(20.0, 20.0, 650.0, duration_s=80.0), "zigzag", "starboard", 20.0),
    (ZigZag(10.0, 10.0, 700.0, duration_s=80.0, side=-1), "zigzag", "port", 10.0),
    (RandomManoeuvre(seed=7, rpm=675.0, duration_s=80.0), "other", None, None),
    (PullOut(20.0, 650.0, duration_s=80.0), "other", None, None),
])
def test_classify_reads_the_manoeuvre_from_the_controls(vessel_model, manoeuvre, kind, side, rudder):
    rec = simulated(vessel_model, manoeuvre, noisy=True)
    found = ev.classify(rec)
    assert found.kind == kind
    if side is not None:
        assert found.side == side
        assert found.rudder_deg == pytest.approx(rudder, abs=0.5)
        assert found.execute_time_s == pytest.approx(manoeuvre.approach_s, abs=1.0)


def test_classify_straight_run_and_random_rudder_at_fixed_rpm_are_other():
    n = 200
    assert ev.classify(_controls_recording(np.zeros(n), np.full(n, 650.0))).kind == "other"
    steps = np.repeat(np.random.default_rng(1).uniform(-25, 25, 20), 10)  # random amplitudes, both sides
    assert ev.classify(_controls_recording(steps, np.full(n, 650.0))).kind == "other"


# ------------------------------------------------------------------ seed 000 metrics plumbing


def _twin_recording(differential: np.ndarray, mean: float) -> Recording:
    """Controls of a twin-thruster boat: port = mean + d/2, starboard = mean - d/2 (normalised commands)."""
    n = len(differential)
    noise = np.random.default_rng(2).normal(0.0, 0.002, n)  # command quantisation and logging noise (-)
    controls = np.column_stack([mean + 0.5 * differential + noise, mean - 0.5 * differential - noise])
    return Recording(name="twin", source="", t0_ns=0, dt=DT, t_s=np.arange(n) * DT, nu=np.zeros((n, 3)),
                     psi=np.zeros(n), controls=controls, position=np.zeros((n, 2)), layout="twin_thrusters")


def test_classify_twin_thrusters_reports_the_normalised_differential():
    held = np.concatenate([np.zeros(20), np.full(180, 0.4)])  # 10 s straight, then port 0.8 / starboard 0.4
    found = ev.classify(_twin_recording(held, 0.6))
    assert (found.kind, found.side) == ("turning_circle", "starboard")
    assert found.turn_command == pytest.approx(0.4, abs=0.01) and found.turn_unit == "-"  # not degrees of 0.4 rad
    assert found.propulsion == pytest.approx(0.6, abs=0.01)
    assert found.propulsion_unit == "-"
    assert found.execute_time_s == pytest.approx(10.0, abs=DT)
    assert math.isnan(found.rudder_deg)
    assert math.isnan(found.rpm)
    record = found.to_json()
    assert record["rudder_deg"] is None and record["rpm"] is None  # the rudder keys stay, null: there is no rudder
    assert (record["turn_command"], record["turn_unit"]) == (pytest.approx(0.4, abs=0.01), "-")
    assert found.label() == "turning circle, starboard, differential 0.40, throttle 0.60"
    zigzag = np.concatenate([np.zeros(20), np.repeat(np.tile([-0.3, 0.3], 6), 15)])  # port first
    found = ev.classify(_twin_recording(zigzag, 0.5))
    assert (found.kind, found.side, found.turn_unit) == ("zigzag", "port", "-")
    assert found.turn_command == pytest.approx(0.3, abs=0.01)
    assert ev.classify(_twin_recording(np.full(200, 0.01), 0.5)).kind == "other"  # below straight_below (0.02)


def test_classify_rudder_boat_keeps_degrees_and_rpm():
    found = ev.classify(_controls_recording(np.concatenate([np.zeros(20), np.full(180, 15.0)]), np.full(200, 650.0)))
    assert (found.kind, found.turn_unit, found.propulsion_unit) == ("turning_circle", "deg", "rpm")
    assert found.rudder_deg == pytest.approx(15.0, abs=0.1)
    assert found.rpm == pytest.approx(650.0)
    record = found.to_json()
    assert record["rudder_deg"] == pytest.approx(record["turn_command"])
    assert record["rpm"] == record["propulsion"]
    assert found.label() == "turning circle, starboard, 15 deg, 650 rpm"


def test_turning_metrics_are_exact_for_a_perfect_model(turn):
    result = ev.evaluate_recording(TruthReplay(turn), turn, reference="truth")
    assert result.manoeuvre.kind == "turning_circle"
    measured, predicted, errors = result.turning.measured, result.turning.predicted, result.turning.errors
    # the drift is the current: 0.4 m/s toward 215 deg (seed 000 eq. 27, 28)
    assert measured["drift_direction_deg"] == pytest.approx(215.0, abs=1.0)
    assert measured["drift_speed_mps"] == pytest.approx(0.4, abs=0.01)
    # eq. 29 averages the first circle too, whose entry transient is wider than the steady circle
    assert 1.0 < measured["turning_radius_m"] / measured["steady_turning_radius_m"] < 1.12
    assert measured == predicted
    assert all(value == pytest.approx(0.0, abs=1e-9) for value in errors.values())


@pytest.mark.parametrize("scale", [1.1, 0.93])
def test_a_model_off_by_a_radius_factor_shows_that_relative_error(turn, scale):
    result = ev.evaluate_recording(TruthReplay(turn, scale), turn, reference="truth")
    errors = result.turning.errors
    expected_pct = 100.0 * (scale - 1.0)
    for key in ("turning_radius_rel_pct", "steady_turning_radius_rel_pct", "drift_distance_rel_pct",
                "advance_rel_pct", "transfer_rel_pct", "tactical_diameter_rel_pct"):
        assert errors[key] == pytest.approx(expected_pct, abs=1e-3), key
    assert errors["drift_direction_abs_deg"] == pytest.approx(0.0, abs=1e-6)  # same shape, same direction


def test_physics_baseline_misses_the_current_drift(turn, vessel_model):
    result = ev.evaluate_recording(ev.physics_predictor(vessel_model.vessel, DT), turn, reference="truth")
    errors = result.turning.errors
    assert errors["drift_distance_rel_pct"] < -80.0  # calm-water physics cannot know the current
    assert abs(errors["steady_turning_radius_rel_pct"]) < 5.0  # but it knows the hull
    assert any("not meaningful" in note for note in result.turning.notes)


def test_zigzag_overshoots_are_compared(vessel_model):
    rec = simulated(vessel_model, ZigZag(20.0, 20.0, 650.0, duration_s=80.0))
    perfect = ev.evaluate_recording(TruthReplay(rec), rec, reference="truth")
    assert perfect.zigzag is not None
    assert perfect.turning is None
    assert perfect.zigzag.measured["first_overshoot_deg"] > 1.0
    assert perfect.zigzag.errors == {"first_overshoot_abs_deg": 0.0, "second_overshoot_abs_deg": 0.0}


# ------------------------------------------------------------------ open loop


def test_open_loop_shapes_horizons_and_start_points(turn):
    loop = ev.open_loop(TruthReplay(turn), turn, reference="truth", horizons_s=(10.0, 30.0, 60.0), stride_s=5.0)
    steps = int(60.0 / DT)
    expected_starts = len(range(0, len(turn) - steps, int(5.0 / DT)))
    assert loop.starts == expected_starts
    assert loop.horizon_s == 60.0
    assert [h.horizon_s for h in loop.horizons] == [10.0, 30.0, 60.0]
    assert all(h.count == expected_starts and h.mean_m == pytest.approx(0.0, abs=1e-9) for h in loop.horizons)
    assert loop.mean_error_by_step_m.shape == (steps,)


def test_open_loop_error_grows_with_horizon_and_drops_horizons_that_do_not_fit(vessel_model):
    rec = simulated(vessel_model, ZigZag(10.0, 10.0, 650.0, duration_s=80.0))  # makes way: ~5 m/s
    loop = ev.open_loop(StandStill(), rec, reference="truth", horizons_s=(10.0, 30.0, 500.0), stride_s=10.0)
    assert [h.horizon_s for h in loop.horizons] == [10.0, 30.0]  # 500 s does not fit in 80 s
    ten, thirty = loop.horizons
    assert thirty.mean_m > 2.5 * ten.mean_m > 2.5 * 40.0  # standing still misses the distance run
    assert np.all(np.diff(loop.mean_error_by_step_m) > 0.0)
    assert ev.open_loop(StandStill(), rec, horizons_s=(500.0,)) is None


def test_gnss_reference_counts_only_start_points_with_a_fix(vessel_model):
    rec = simulated(vessel_model, TurningCircle(25.0, 650.0, duration_s=100.0), CURRENT, noisy=True)
    position = rec.position.copy()
    position[40:60] = np.nan  # a GNSS outage of 10 s
    import dataclasses

    rec = dataclasses.replace(rec, position=position)
    loop = ev.open_loop(TruthReplay(rec), rec, reference="gnss", horizons_s=(10.0,), stride_s=5.0)
    all_starts = len(range(0, len(rec) - 20, 10))
    assert loop.starts == all_starts - 2  # starts at steps 40 and 50 have no position
    assert loop.horizons[0].count < loop.starts  # ends inside the outage are left out too
    result = ev.evaluate_recording(TruthReplay(rec), rec, reference="gnss")
    assert result.turning.measured["drift_distance_m"] is not None  # metrics skip the outage


# ------------------------------------------------------------------ the whole evaluation


def test_evaluate_summary_and_json_carry_units(turn, vessel_model):
    zigzag = simulated(vessel_model, ZigZag(20.0, 20.0, 650.0, duration_s=80.0))
    model = TruthReplay(turn, 1.05)
    result = ev.evaluate(model, [turn], reference="truth")
    assert result.summary["max_abs_turning_radius_rel_error_pct"] == pytest.approx(5.0, abs=1e-3)
    assert result.summary["max_abs_drift_distance_rel_error_pct"] == pytest.approx(5.0, abs=1e-3)
    assert result.summary["max_abs_drift_direction_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert result.summary["mean_position_error_after_30s_m"] > 0.0
    data = json.loads(json.dumps(_jsonable(result.to_json())))
    assert data["model"]["model_id"] == "truth-replay-x1.05"
    assert "normalisation" not in data["model"]  # long arrays of metadata stay out of the report
    rec = data["recordings"][0]
    assert set(rec["turning"]["errors"]) == {"turning_radius_rel_pct", "steady_turning_radius_rel_pct",
                                             "drift_distance_rel_pct", "drift_direction_abs_deg",
                                             "advance_rel_pct", "transfer_rel_pct", "tactical_diameter_rel_pct"}
    assert {"position_error_after_10s_m", "position_error_after_30s_m", "position_error_after_60s_m"} <= set(
        rec["open_loop"])
    assert set(rec["closed_loop_rmse"]) >= {"u_mps", "v_mps", "r_deg_s", "psi_deg", "position_m"}
    # pooled open-loop means weigh recordings by their start points
    both = ev.evaluate(StandStill(), [turn, zigzag], reference="truth")
    loops = [r.open_loop.horizons[0] for r in both.recordings]
    pooled = sum(h.mean_m * h.count for h in loops) / sum(h.count for h in loops)
    assert both.summary["mean_position_error_after_10s_m"] == pytest.approx(pooled)
    with pytest.raises(ev.EvaluationError, match="no recordings"):
        ev.evaluate(model, [])


def test_series_round_trip_for_the_report(turn):
    result = ev.evaluate(TruthReplay(turn), [turn], reference="truth")
    back = ev.predictions_from_arrays(ev.series_arrays(result), [turn.name], "truth")[0]
    np.testing.assert_array_equal(back.predicted, result.recordings[0].prediction.predicted)
    with pytest.raises(ev.EvaluationError, match="no array"):
        ev.predictions_from_arrays({}, [turn.name], "truth")


def test_physics_predictor_reproduces_calm_water(vessel_model):
    """The simulator's own hull in calm water: what is left is the 0.5 s sampling of the controls."""
    manoeuvre = ZigZag(20.0, 20.0, 650.0, duration_s=60.0)
    errors = []
    for dt in (0.5, 0.1):
        rec = simulated(vessel_model, manoeuvre, dt=dt)
        loop = ev.open_loop(ev.physics_predictor(vessel_model.vessel, dt), rec, reference="truth", horizons_s=(10.0,))
        errors.append(loop.horizons[0].mean_m)
    assert errors[0] < 0.5 and errors[1] < 0.5  # ~50 m run in 10 s
    assert math.isclose(ev.physics_predictor(load_vessel("jari_usv"), 0.25).metadata["dt"], 0.25)


# ------------------------------------------------------------------ the smoothed reference

SEA_TRIAL_TURN = Path(__file__).resolve().parents[1] / "bags" / "sea_trial" / "turning_circle_stbd_20deg_650rpm"


@pytest.fixture(scope="module")
def sea_turn() -> Recording:
    """Seed 000 Table 3 (c) of the shipped sea trial at 0.2 s: GNSS noise 0.3 m per axis at 5 Hz plus the waves'
    first-order motion, and the ground truth."""
    from usv_predictor.replay.recordings import load_recordings

    return load_recordings([SEA_TRIAL_TURN], 0.2, jobs=1, warn=lambda _: None)[0]


def test_smoothed_reference_takes_the_gnss_noise_out_of_eq_27_29(sea_turn):
    """The true track scored as a prediction: against the raw GNSS track eq. 27 (drift distance) is off by 6 % on this
    turn (a few single noisy samples per circle decide it), against the smoothed measurements within 2.5 %, and eq.
    29's radius, which noise biases upward, within 1 %; the rollout still starts from the raw measured state."""
    truth = ev.reference_series(sea_turn, "truth")
    execute = ev.classify(sea_turn).execute_time_s - float(sea_turn.t_s[0])
    errors = {}
    for reference in ("gnss", "smoothed"):
        tracks = ev.reference_tracks(sea_turn, reference)
        prediction = ev.Prediction(name=sea_turn.name, reference=reference, t_s=sea_turn.t_s - sea_turn.t_s[0],
                                   controls=sea_turn.controls, measured=tracks.measured, predicted=truth,
                                   predicted_std=np.zeros_like(truth), layout=sea_turn.layout)
        errors[reference] = ev.compare_turning(prediction, execute).errors
    assert abs(errors["gnss"]["drift_distance_rel_pct"]) > 4.0  # what the smoothing is for, on this turn
    assert abs(errors["smoothed"]["drift_distance_rel_pct"]) < 2.5
    assert abs(errors["smoothed"]["turning_radius_rel_pct"]) < 1.0
    assert abs(errors["smoothed"]["drift_direction_abs_deg"]) < 2.0
    gnss = ev.reference_series(sea_turn, "gnss")
    tracks = ev.reference_tracks(sea_turn, "smoothed")
    np.testing.assert_array_equal(tracks.start, gnss)  # nothing after a start point enters its state
    assert float(np.abs(tracks.measured[:, [ev.X_N, ev.Y_E]] - truth[:, [ev.X_N, ev.Y_E]]).mean()) < 0.5 * float(
        np.abs(gnss[:, [ev.X_N, ev.Y_E]] - truth[:, [ev.X_N, ev.Y_E]]).mean())
    prediction = ev.closed_loop(ev.physics_predictor(load_vessel("jari_usv"), 0.2), sea_turn, "smoothed", tracks)
    np.testing.assert_allclose(prediction.predicted[0], gnss[0])
    np.testing.assert_array_equal(prediction.measured, tracks.measured)


def test_the_command_line_offers_the_references_the_evaluation_knows():
    """replay.evaluate spells REFERENCES itself (the parser stays light); it must be the analysis' own tuple."""
    from usv_predictor.replay import evaluate as replay_evaluate

    assert replay_evaluate.REFERENCES == ev.REFERENCES


def _unstable(vessel_model: ManoeuvringModel, N_r: float = 1.0):
    """The boat's grey box with a yaw damping of the wrong sign (N_r > 0): the yaw rate grows until the rollout is
    NaN within seconds of the turning circle."""
    import dataclasses

    vessel = vessel_model.vessel
    return ev.physics_predictor(dataclasses.replace(vessel, hull=dataclasses.replace(vessel.hull, N_r=N_r)), DT)


def test_a_diverging_model_is_reported_as_diverged_never_as_a_metric(turn, vessel_model):
    """Closed loop: the recording says when and in which manoeuvre the rollout went NaN, its RMSEs and predicted
    turning metrics are undefined (null, not computed over the part before), the measured ones stay; open loop: the
    diverged windows are counted per horizon and the first named; the JSON is strict (no NaN)."""
    model = _unstable(vessel_model)
    result = ev.evaluate(model, [turn], horizons_s=(10.0, 30.0))
    rec = result.recordings[0]
    assert rec.diverged_at_s is not None and 0.0 < rec.diverged_at_s < 40.0
    out = json.loads(json.dumps(_jsonable(result.to_json()), allow_nan=False))
    record = out["recordings"][0]
    assert record["diverged"] == {"at_s": rec.diverged_at_s, "duration_s": pytest.approx(turn.duration_s, abs=DT),
                                  "manoeuvre": rec.manoeuvre.label()}
    assert set(record["closed_loop_rmse"].values()) == {None}
    assert set(record["turning"]["predicted"].values()) == {None}
    assert set(record["turning"]["errors"].values()) == {None}
    assert record["turning"]["measured"]["turning_radius_m"] > 0.0
    assert any(n.startswith(f"closed loop: the model's rollout diverged (NaN/inf) at {rec.diverged_at_s:.1f} s")
               for n in record["notes"])
    loop = record["open_loop"]
    assert 0 < loop["diverged_start_points"] <= loop["start_points"]
    by_h = {h["horizon_s"]: h for h in loop["horizons"]}
    assert 0 < by_h[30.0]["diverged"] and by_h[10.0]["diverged"] <= by_h[30.0]["diverged"]
    assert by_h[30.0]["count"] + by_h[30.0]["diverged"] <= loop["start_points"]
    assert loop["first_diverged"]["after_s"] <= 30.0
    assert any(n.startswith(f"open loop: {loop['diverged_start_points']} of {loop['start_points']} rollouts diverged")
               for n in record["notes"])
    assert out["summary"]["diverged_recordings"] == 1.0
    assert out["summary"]["open_loop_diverged_windows"] == float(loop["diverged_start_points"])
    assert out["summary"]["max_abs_turning_radius_rel_error_pct"] is None  # no radius error from the part before


def test_a_stable_model_reports_no_divergence(turn, vessel_model):
    result = ev.evaluate(ev.physics_predictor(vessel_model.vessel, DT), [turn], horizons_s=(10.0, 30.0))
    record = result.to_json()["recordings"][0]
    assert record["diverged"] is None and record["open_loop"]["diverged_start_points"] == 0
    assert record["open_loop"]["first_diverged"] is None
    assert all(h["diverged"] == 0 for h in record["open_loop"]["horizons"])
    assert result.summary["diverged_recordings"] == 0.0 and result.summary["open_loop_diverged_windows"] == 0.0
    assert record["closed_loop_rmse"]["position_m"] is not None
    assert record["turning"]["errors"]["turning_radius_rel_pct"] is not None

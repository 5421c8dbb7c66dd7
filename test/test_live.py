"""usv_predictor.node.live without ROS: the online state equals the replay tool's Recording; every bad input is
refused."""
from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import msg_adapters
from usv_predictor.config import load_predictor_config, package_share_path
from usv_predictor.data.recording import NS, window_resample
from usv_predictor.errors import ModelError
from usv_predictor.models.artifact import load_artifact
from usv_predictor.node import live
from usv_predictor.physics.vessel import load_vessel
from usv_predictor.replay.bagio import read_bag
from usv_predictor.replay.recordings import bag_metadata, load_recordings, topic_specs

BAG = Path(__file__).resolve().parents[1] / "bags" / "sea_trial" / "turning_circle_stbd_20deg_700rpm"
DT = 0.5
CHECKED_S = 40.0  # seconds of the bag compared step by step (s)


def fields_by_role() -> dict[str, tuple[str, ...]]:
    return {entry.role: msg_adapters.ROLE_FIELDS[entry.role] for entry in load_predictor_config().inputs}


def make_inputs(**settings: object) -> live.InputSet:
    cfg = load_predictor_config()
    options = {"dt": DT, "horizon_steps": 120, **settings}
    return live.InputSet(fields_by_role(), {e.role: e.max_age_s for e in cfg.inputs}, live.LiveSettings(**options))


@pytest.fixture(scope="module")
def bag_samples() -> list[tuple[int, str, tuple[float, ...]]]:
    """Every input sample of the bag, as the replay tool reads it, in stamp order (role order within a stamp)."""
    specs = [s for s in topic_specs() if s.role != "odometry"]
    signals = read_bag(BAG, specs)
    rows = []
    for spec in specs:
        sig = signals[spec.topic]
        rows += [(int(t), spec.role, tuple(v)) for t, v in zip(sig.t_ns, sig.values)]
    return sorted(rows, key=lambda row: row[0])


@pytest.fixture(scope="module")
def recording():
    return load_recordings([BAG], DT, jobs=1, warn=lambda _: None)[0]


def test_online_state_equals_the_recording_at_every_grid_time(bag_samples, recording) -> None:
    """Fed message by message, the live state at t_c is Recording.state()/controls/position at t_c."""
    inputs = make_inputs(datum=recording.datum)
    dt_ns = int(DT * NS)
    grid_end = recording.t0_ns + dt_ns // 2  # window end of the recording's first grid point
    n, checked = 0, 0
    for stamp, role, values in bag_samples:
        while stamp > grid_end and n < len(recording):  # every sample <= grid_end is in: evaluate there
            state = inputs.assemble(grid_end)
            assert state.t_c_ns == recording.t0_ns + n * dt_ns
            np.testing.assert_allclose(state.state[:3], recording.state()[n, :3], rtol=0, atol=1e-12)
            assert math.remainder(state.state[3] - recording.psi[n], 2 * math.pi) == pytest.approx(0, abs=1e-12)
            np.testing.assert_allclose(state.controls, recording.controls[n], rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(state.position, recording.position[n], rtol=0, atol=1e-6)
            n, checked, grid_end = n + 1, checked + 1, grid_end + dt_ns
        if n * DT > CHECKED_S:
            break
        inputs.add(role, stamp, values, now_ns=stamp)
    assert checked >= CHECKED_S / DT


def test_prediction_equals_the_artifact_on_the_recording_state(bag_samples, recording) -> None:
    artifact = load_artifact(package_share_path("models", "default.pt"))
    rollout = live.Rollout(artifact, horizon_steps=120)
    inputs = make_inputs(datum=recording.datum)
    n = 40  # 20 s into the turn
    end = recording.t0_ns + n * int(DT * NS) + int(DT * NS) // 2
    for stamp, role, values in bag_samples:
        if stamp > end:
            break
        inputs.add(role, stamp, values, now_ns=stamp)
    prediction = live.predict(inputs, rollout, end)
    reference = artifact.predict(recording.state()[n:n + 1], np.repeat(recording.controls[n:n + 1, None], 120, axis=1))
    mean = reference.mean(axis=0)[0]  # (H, 6)
    np.testing.assert_allclose(prediction.eta[:, :2], mean[:, 3:5] + recording.position[n], atol=1e-3)
    np.testing.assert_allclose(prediction.nu, mean[:, :3], atol=1e-5)
    assert prediction.anchored
    assert prediction.eta_members.shape == (artifact.ensemble_size, 120, 3)
    assert prediction.t_ns[0] == recording.t0_ns + (n + 1) * int(DT * NS)
    cov = live.enu_covariance(prediction.eta_members)
    assert cov.shape == (120, 3, 3)
    assert np.all(np.diagonal(cov, axis1=1, axis2=2) >= 0)
    assert cov[-1, 0, 0] > cov[0, 0, 0]  # the members drift apart with the horizon


# ----------------------------------------------------------------------------- refusals


def feed_all(inputs: live.InputSet, t0: int, seconds: float, heading: float = 0.3) -> int:
    """Plausible inputs at 20 Hz for `seconds`; returns the last stamp."""
    stamp = t0
    for k in range(int(seconds * 20)):
        stamp = t0 + k * 50_000_000
        inputs.add("imu", stamp, (0.01, 0.0, 0.0, -9.81, math.nan), stamp)
        inputs.add("velocity", stamp, (5.0, 0.1, 0.01), stamp)
        inputs.add("heading", stamp, (heading,), stamp)
        inputs.add("rudder_angle", stamp, (0.1,), stamp)
        inputs.add("engine_rpm", stamp, (650.0,), stamp)
    return stamp


def test_no_input_and_stale_input_skip_the_cycle() -> None:
    inputs = make_inputs()
    with pytest.raises(live.CycleSkipped, match="no message yet"):
        inputs.assemble(10 * NS)
    last = feed_all(inputs, 10 * NS, 2.0)
    assert inputs.assemble(last).position is None  # no GNSS: relative path
    with pytest.raises(live.CycleSkipped, match="stale"):
        inputs.assemble(last + 5 * NS)


@pytest.mark.parametrize(
    ("role", "values", "kind"),
    [
        ("velocity", (math.nan, 0.0, 0.0), "non_finite"),
        ("imu", (math.inf, 0.0, 0.0, -9.81, math.nan), "non_finite"),
        ("engine_rpm", (65000.0,), "range"),  # absurd rpm
        ("rudder_angle", (20.0,), "range"),  # degrees read as radians
        ("gnss", (math.nan, math.nan, math.nan), "no_fix"),
    ],
)
def test_bad_values_are_refused_and_counted(role: str, values: tuple[float, ...], kind: str) -> None:
    inputs = make_inputs()
    with pytest.raises(live.InputRejected) as refused:
        inputs.add(role, NS, values, NS)
    assert refused.value.kind == kind
    assert inputs.tracks[role].rejected == {kind: 1}
    assert len(inputs.tracks[role].buffer) == 0


def test_heading_in_degrees_configured_as_rad_is_refused() -> None:
    with pytest.raises(live.InputRejected, match="degrees configured as rad"):
        live.check_raw_heading(215.0, "rad")
    live.check_raw_heading(215.0, "deg")
    live.check_raw_heading(-3.0, "rad")


def test_backwards_duplicate_and_future_stamps_are_refused() -> None:
    inputs = make_inputs(max_future_s=0.5)
    inputs.add("heading", 2 * NS, (0.1,), 2 * NS)
    for stamp, kind in ((2 * NS, "duplicate"), (NS, "backwards"), (4 * NS, "future")):
        with pytest.raises(live.InputRejected) as refused:
            inputs.add("heading", stamp, (0.2,), 2 * NS)
        assert refused.value.kind == kind
    assert len(inputs.tracks["heading"].buffer) == 1


def test_a_header_less_sample_at_the_same_clock_supersedes_the_previous_one() -> None:
    """A header-less message is stamped with the node's clock at its arrival; two arriving at one clock reading (sim
    time moves in /clock steps, and a busy node takes queued messages at one reading) are no repeat: the newer value
    replaces the latest sample, nothing is refused. A repeated header stamp stays a refused duplicate."""
    inputs = make_inputs()
    inputs.add("heading", 2 * NS, (0.1,), 2 * NS, at_arrival=True)
    inputs.add("heading", 2 * NS, (0.2,), 2 * NS, at_arrival=True)
    track = inputs.tracks["heading"]
    t, values = track.buffer.samples()
    assert t.tolist() == [2 * NS]
    assert values[:, 0].tolist() == [0.2]
    assert (track.received, track.superseded, track.rejected) == (2, 1, {})
    with pytest.raises(live.InputRejected, match="heading: stamp 1.000 s before"):  # backwards stays refused
        inputs.add("heading", NS, (0.3,), 2 * NS, at_arrival=True)
    with pytest.raises(live.InputRejected, match="heading.psi is nan"):  # a bad newer value keeps the older
        inputs.add("heading", 2 * NS, (math.nan,), 2 * NS, at_arrival=True)
    assert track.buffer.samples()[1][:, 0].tolist() == [0.2]
    with pytest.raises(live.InputRejected, match=r"velocity: header stamp 2\.000000000 s repeats") as refused:
        inputs.add("velocity", 2 * NS, (5.0, 0.0, 0.0), 2 * NS)
        inputs.add("velocity", 2 * NS, (5.0, 0.0, 0.0), 2 * NS)
    assert refused.value.kind == "duplicate"
    assert inputs.tracks["velocity"].superseded == 0


def test_clock_jump_back_clears_the_buffers() -> None:
    inputs = make_inputs()
    last = feed_all(inputs, 100 * NS, 1.0)
    assert not inputs.observe_clock(last)
    assert inputs.observe_clock(NS)
    assert all(len(track.buffer) == 0 for track in inputs.tracks.values())


def test_a_1khz_burst_keeps_memory_bounded_and_the_state_right() -> None:
    inputs = make_inputs(capacity=1024)
    nbytes = {role: track.buffer.nbytes for role, track in inputs.tracks.items()}
    last = feed_all(inputs, 100 * NS, 3.0)
    t0 = last + 1_000_000
    for k in range(3000):  # 3 s of IMU at 1 kHz, yaw rate 0.05 rad/s
        inputs.add("imu", t0 + k * 1_000_000, (0.05, 0.0, 0.0, -9.81, math.nan), t0 + k * 1_000_000)
    imu = inputs.tracks["imu"].buffer
    assert len(imu) == 1024
    assert imu.overwritten == 60 + 3000 - 1024
    assert {role: track.buffer.nbytes for role, track in inputs.tracks.items()} == nbytes  # nothing grew
    now = t0 + 2999 * 1_000_000
    assert imu.rate_hz(now) == pytest.approx(1000.0, rel=1e-3)
    with pytest.raises(live.CycleSkipped, match="stale"):  # the 20 Hz inputs stopped 3 s ago
        inputs.assemble(now)
    inputs.tracks["velocity"].max_age_s = inputs.tracks["heading"].max_age_s = 60.0
    inputs.tracks["rudder_angle"].max_age_s = inputs.tracks["engine_rpm"].max_age_s = 60.0
    with pytest.raises(live.CycleSkipped, match="no sample in the averaging window"):
        inputs.assemble(now)  # stale data is never averaged into a state either


def test_rollout_refuses_more_members_than_the_model_has() -> None:
    artifact = load_artifact(package_share_path("models", "default.pt"))
    with pytest.raises(ModelError, match="ensemble_size 9 requested"):
        live.Rollout(artifact, 120, ensemble_size=9)
    assert live.Rollout(artifact, 120, ensemble_size=2)(np.array([5.0, 0, 0, 0]),
                                                        np.array([0.0, 650.0])).shape == (2, 120, 6)


# ----------------------------------------------------------------------------- redundant inputs


def _bag_rows(bag: Path, heading: Callable[[np.ndarray], np.ndarray] | None = None,
              velocity_scale: float = 1.0) -> list[tuple[int, str, tuple[float, ...]]]:
    """Every input sample of a bag in stamp order, with the decoded heading (and velocity) changed as a wrong
    configuration would change it."""
    vessel = bag_metadata(bag)[1].get("vessel", load_predictor_config().vessel)  # the boat the bag was recorded on
    specs = [s for s in topic_specs(layout=load_vessel(vessel).actuator_layout) if s.role != "odometry"]
    signals = read_bag(bag, specs)
    rows = []
    for spec in specs:
        sig = signals[spec.topic]
        values = sig.values.copy()
        if spec.role == "heading" and heading is not None:
            values[:, 0] = heading(values[:, 0])
        if spec.role == "velocity":
            values[:, :2] *= velocity_scale
        rows += [(int(t), spec.role, tuple(v)) for t, v in zip(sig.t_ns, values)]
    return sorted(rows, key=lambda row: row[0])


def _replay_live(rows: list[tuple[int, str, tuple[float, ...]]]) -> list[tuple[float, dict[str, tuple[str, str]]]]:
    """Feed the samples as the node receives them; every second: (seconds since the start, the refusals)."""
    inputs = make_inputs()
    t0 = rows[0][0]
    next_check, seen = t0 + NS, []
    for stamp, role, values in rows:
        if stamp > next_check:
            inputs.check_consistency(next_check)
            seen.append(((next_check - t0) / NS, dict(inputs.refusals)))
            next_check += NS
        try:
            inputs.add(role, stamp, values, stamp)
        except live.InputRejected:
            pass
    return seen


SHIPPED = sorted(p.parent for p in (Path(__file__).resolve().parents[1] / "bags").rglob("metadata.yaml"))


@pytest.mark.parametrize("bag", SHIPPED, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_shipped_bags_are_never_refused_as_inconsistent(bag: Path) -> None:
    """Current, wind, waves (their yaw motion included) and sensor noise: all consistent, nothing refused."""
    rows = _bag_rows(bag)
    seen = _replay_live(rows)
    assert len(seen) >= (rows[-1][0] - rows[0][0]) / NS - 2  # a check every second of the bag (60-240 s)
    assert all(refusals == {} for _, refusals in seen), [s for s in seen if s[1]][:3]


def test_a_heading_in_radians_configured_as_degrees_is_refused_with_the_reason() -> None:
    """The heading published in radians, read as degrees: it never leaves +-6.3 'deg' while the gyro
    turns circles. The adapter's decode of such a value is radians(mod(psi, 2 pi))."""
    seen = _replay_live(_bag_rows(BAG, heading=lambda psi: np.radians(np.mod(psi, 2 * math.pi))))
    refused = [(t, r) for t, r in seen if r]
    assert refused and refused[0][0] <= 10.0  # within 10 s of the start
    assert len(refused) >= len(seen) - 10  # and from then on
    reasons = {why for _, r in refused for role, why in r.values() if role == "heading"}
    assert any("never leaves a" in why and "radians with units deg" in why for why in reasons), reasons
    inputs = make_inputs()
    for stamp, role, values in _bag_rows(BAG, heading=lambda psi: np.radians(np.mod(psi, 2 * math.pi)))[:60000]:
        try:
            inputs.add(role, stamp, values, stamp)
        except live.InputRejected:
            pass
    with pytest.raises(live.CycleSkipped, match="input heading refused: the heading disagrees"):
        inputs.assemble(stamp)
    assert inputs.tracks["heading"].refused.startswith("the heading disagrees")
    assert not inputs.observe_clock(stamp)
    assert inputs.observe_clock(0) and inputs.refusals == {} and inputs.tracks["heading"].refused == ""  # a restart


@pytest.mark.parametrize(("mistake", "role", "words"), [
    ("convention", "heading", "the heading"),  # counter-clockwise read as clockwise
    ("offset", "heading", "the heading disagrees with the GNSS track"),  # a compass mounted 90 deg off
    ("km/h", "velocity", "the velocity disagrees with the GNSS track"),  # km/h read as m/s
])
def test_other_unit_and_sign_mistakes_are_refused(mistake: str, role: str, words: str) -> None:
    heading = {"convention": lambda psi: -psi, "offset": lambda psi: psi + math.pi / 2}.get(mistake)
    seen = _replay_live(_bag_rows(BAG, heading=heading, velocity_scale=3.6 if mistake == "km/h" else 1.0))
    refused = [r for _, r in seen if r]
    assert len(refused) >= len(seen) - 10
    assert any(who == role and why.startswith(words) for r in refused for who, why in r.values())


def test_consistency_checks_need_evidence() -> None:
    """Straight running at rest, or a short turn: no verdict (nothing refused, nothing cleared)."""
    t = np.linspace(0.0, 20.0, 401)
    calm = live.heading_vs_gyro(t, np.full_like(t, 0.01), t, np.full_like(t, 0.3), 0.0, 20.0)
    assert not calm.judged and not calm.problem  # 11 deg of turning: not enough to judge, and it says so
    assert calm.why_not == "the gyro turned 11 deg, less than the 60 deg that tell a heading's units"
    turning = live.heading_vs_gyro(t, np.full_like(t, 0.2), t, 0.2 * t, 0.0, 20.0)
    assert turning.judged
    assert turning.problem == ""
    biased = live.heading_vs_gyro(t, np.full_like(t, 0.2 + math.radians(0.5)), t, 0.2 * t, 0.0, 20.0)
    assert biased.judged and biased.problem == ""  # a 0.5 deg/s gyro bias passes
    slow = live.track_vs_gnss(t, np.full_like(t, 1.0), np.zeros_like(t), t, np.zeros_like(t), t, 1.0 * t,
                              np.zeros_like(t), 0.0, 20.0)
    assert slow[0] == "velocity" and not slow[1].judged  # below TRACK_MIN_SPEED over ground
    assert slow[1].why_not == "slower than 2 m/s over ground (GNSS)"
    drift = live.track_vs_gnss(t, np.full_like(t, 5.0), np.zeros_like(t), t, np.zeros_like(t), t, 5.0 * t,
                               1.5 * t, 0.0, 20.0)
    assert drift == ("velocity", live.Consistency(True))  # a current of 30 % of the speed across the track passes


def _state_as_before(inputs: live.InputSet, now_ns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(state, controls, position) computed as assemble's former form computed them: every ring copied whole,
    recording.window_resample over all of it, the heading unwrapped from the ring's first sample."""
    t_c = now_ns - inputs.settings.dt_ns // 2
    grid = np.array([t_c], dtype=np.int64)
    means = {}
    for role in inputs.required:
        buffer = inputs.tracks[role].buffer
        t, values = buffer.samples()
        chosen = values[:, [buffer.fields.index(c) for c in inputs.fields[role]]]
        if role == "heading":
            chosen = np.unwrap(chosen, axis=0)
        means[role] = window_resample(t, chosen, grid, inputs.settings.dt_ns)[0]
    state = np.array([means["velocity"][0], means["velocity"][1], means["imu"][0], means["heading"][0]])
    controls = np.array([means[c.role][inputs.layout.fields_of(c.role).index(c.field)] for c in inputs.layout.controls])
    buffer = inputs.tracks["gnss"].buffer
    t, values = buffer.samples()
    x_n, y_e = inputs._plane.to_ned(values[:, buffer.fields.index("lat")], values[:, buffer.fields.index("lon")])
    position = np.array([window_resample(t, x_n, grid, inputs.settings.dt_ns)[0],
                         window_resample(t, y_e, grid, inputs.settings.dt_ns)[0]])
    return state, controls, position


def test_state_from_the_window_equals_the_whole_ring_average_bit_for_bit() -> None:
    """assemble reads each ring's used columns up to the window's end only (window_mean): on wrapped rings of
    random samples, a heading that crosses +-180 deg many times, and GNSS at 1 Hz (windows with no fix: interpolated),
    its state, controls and position are those of the whole-ring window_resample, bit for bit, every cycle."""
    rng = np.random.default_rng(13)
    inputs = make_inputs(capacity=150)
    rates = {"imu": 200.0, "velocity": 20.0, "heading": 20.0, "rudder_angle": 10.0, "engine_rpm": 10.0, "gnss": 1.0}
    start = 50 * NS
    stamps = sorted((int(start + k * NS / hz + rng.integers(0, 1000)), role)
                    for role, hz in rates.items() for k in range(int(18 * hz)))
    psi = 3.0  # rad
    compared, interpolated = 0, 0
    next_cycle = start + 3 * NS
    for stamp, role in stamps:
        if stamp > next_cycle:
            got = inputs.assemble(next_cycle)
            state, controls, position = _state_as_before(inputs, next_cycle)
            np.testing.assert_array_equal(got.state, state)
            np.testing.assert_array_equal(got.controls, controls)
            np.testing.assert_array_equal(got.position, position)
            compared += 1
            interpolated += got.samples["gnss"] == 0
            next_cycle += NS // 10
        if role == "heading":
            psi = (psi + math.radians(rng.normal(4.0, 3.0)) + math.pi) % (2 * math.pi) - math.pi  # turning through pi
            values = (psi,)
        elif role == "gnss":
            values = (35.0 + rng.normal(0, 1e-5), 120.0 + rng.normal(0, 1e-5), 0.0)
        else:
            values = tuple(float(x) for x in 0.1 * rng.normal(size=len(inputs.tracks[role].buffer.fields)))
            values = {"velocity": (5.0 + values[0], *values[1:]), "engine_rpm": (650.0 + 100 * values[0],),
                      "imu": (values[0], 0.0, 0.0, -9.81, math.nan)}.get(role, values)
        inputs.add(role, stamp, values, now_ns=stamp)
    assert compared > 80
    assert 0 < interpolated < compared
    assert all(inputs.tracks[role].buffer.overwritten > 0 for role in rates if role != "gnss")  # the rings wrapped
    heading = inputs.tracks["heading"].buffer.samples()[1][:, 0]
    assert np.abs(np.diff(heading)).max() > math.pi  # the ring itself crosses the branch cut


def _track_record(inputs: live.InputSet, role: str) -> tuple:
    track = inputs.tracks[role]
    t, values = track.buffer.samples()
    return (t.tobytes(), values.tobytes(), track.buffer.overwritten, track.buffer.size, track.received,
            dict(track.rejected), track.last_reject, track.last_reject_ns, track.last_accept_ns, track.superseded,
            inputs.datum)


@pytest.mark.parametrize("role, at_arrival", [("imu", False), ("velocity", False), ("gnss", False),
                                              ("rudder_angle", False), ("rudder_angle", True), ("engine_rpm", True)])
def test_add_many_equals_add_one_at_a_time(role: str, at_arrival: bool) -> None:
    """The node buffers a decoded batch with add_many: in bulk when every sample passes, else add() one by one. On
    random batches (all good, a non-finite or implausible value, a duplicate, a backwards and a future stamp, batches
    longer than the ring; arrival-stamped: runs of equal stamps, also at the buffer's latest) buffers, counts,
    refusals and the datum are those of add() called sample by sample."""
    rng = np.random.default_rng(len(role))
    bulk, single = make_inputs(capacity=64), make_inputs(capacity=64)
    width = len(bulk.tracks[role].buffer.fields)
    base = {"imu": [0.01, 0.0, 0.0, -9.81, math.nan], "velocity": [5.0, 0.1, 0.01], "gnss": [35.0, 120.0, 0.0],
            "rudder_angle": [0.1], "engine_rpm": [650.0]}[role]
    stamp, bulk_batches = 100 * NS, 0
    for batch in range(60):
        count = int(rng.choice([1, 2, 5, 20, 100]))
        stamps = stamp + np.cumsum(rng.integers(1_000_000, 10_000_000, count))
        noise = 1e-7 if role == "gnss" else 1e-3  # deg for GNSS (1 cm): a fix 100 m off in 5 ms is refused as a jump
        values = np.array(base, dtype=float)[None, :] + rng.normal(0.0, noise, (count, width))
        arrivals = stamps + rng.integers(0, 2_000_000, count)
        if at_arrival:  # the node's clock at each arrival: runs of equal readings, the first maybe the latest's
            stamps = stamp + np.cumsum(rng.integers(0, 3, count)) * 10_000_000  # 10 ms /clock steps
            arrivals = stamps.copy()
        spoil = batch % 6
        if spoil == 1:
            values[rng.integers(count), 0] = math.nan
        elif spoil == 2:
            values[rng.integers(count), 0] = 1e9  # implausible
        elif spoil == 3 and count > 1:
            stamps[-1] = stamps[-2]  # duplicate
        elif spoil == 4:
            stamps[0] = stamp - 5_000_000  # before the buffer's latest
        elif spoil == 5:
            arrivals[-1] = stamps[-1] - 2 * NS  # a stamp 2 s ahead of its arrival clock
        refused = bulk.add_many(role, stamps, values, arrivals, at_arrival=at_arrival)
        expected = []
        for t, row, now in zip(stamps.tolist(), values.tolist(), arrivals.tolist()):
            try:
                single.add(role, t, tuple(row), now, at_arrival=at_arrival)
            except live.InputRejected as err:
                expected.append((err.kind, str(err)))
        assert [(err.kind, str(err)) for err in refused] == expected
        assert _track_record(bulk, role) == _track_record(single, role)
        bulk_batches += not expected
        stamp = int(stamps.max())
    assert bulk.tracks[role].buffer.overwritten > 0
    assert 10 < bulk_batches < 60
    value_refusal = "range" if role != "gnss" else "no_fix"
    assert set(bulk.tracks[role].rejected) >= {"backwards", "future", value_refusal}
    # arrival-stamped: equal stamps supersede, never a refused duplicate
    assert ("duplicate" in bulk.tracks[role].rejected) is not at_arrival
    assert (bulk.tracks[role].superseded > 0) is at_arrival


def test_raw_headings_within_a_turn_is_check_raw_heading_on_every_sample() -> None:
    for units, raws in [("deg", [10.0, 359.0, -359.0]), ("deg", [10.0, 361.0]), ("rad", [3.0, 7.0]),
                        ("rad", [math.nan, 1.0]), ("rad", [])]:
        passes = True
        for raw in raws:
            try:
                live.check_raw_heading(raw, units)
            except live.InputRejected:
                passes = False
        assert live.raw_headings_within_a_turn(np.array(raws), units) is passes


# ----------------------------------------------------------------------------- a model that diverges


def _diverging_rollout(horizon: int = 120) -> Callable[..., np.ndarray]:
    """The jari_usv grey box with a yaw damping of the wrong sign (N_r, N_rrr > 0): its yaw rate grows without
    bound, so a 60 s rollout from a turning state ends NaN/inf."""
    import dataclasses

    from usv_predictor.models.loading import physics_predictor

    vessel = load_vessel("jari_usv")
    model = physics_predictor(dataclasses.replace(vessel, hull=dataclasses.replace(vessel.hull, N_r=1.0, N_rrr=5.0)),
                              DT)

    def rollout(state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
        held = np.repeat(np.asarray(controls, dtype=float)[None, None, :], horizon, axis=1)  # (1, H, C)
        with np.errstate(all="ignore"):
            return model.predict(np.asarray(state, dtype=float)[None, :], held)[:, 0]  # (E, H, 6)

    return rollout


def test_a_model_whose_rollout_diverges_skips_the_cycle_and_says_why() -> None:
    """No Path with NaN poses: a rollout that leaves the numbers skips the cycle with the reason (what the node puts
    on /diagnostics as `skipped: ...`); the same inputs with the true hull predict a finite path."""
    inputs = make_inputs()
    last = feed_all(inputs, 10 * NS, 2.0)
    rollout = _diverging_rollout()
    out = rollout(inputs.assemble(last).state, inputs.assemble(last).controls)
    assert not np.isfinite(out).all()  # the model really diverges on this state
    with pytest.raises(live.CycleSkipped, match=r"model output is not finite \(NaN/inf\): nothing published"):
        live.predict(inputs, rollout, last)
    from usv_predictor.models.loading import physics_predictor

    stable = physics_predictor(load_vessel("jari_usv"), DT)
    prediction = live.predict(inputs, lambda s, c, r=None: stable.predict(
        s[None, :], np.repeat(np.asarray(c)[None, None, :], 120, axis=1))[:, 0], last)
    assert np.isfinite(prediction.eta).all() and prediction.eta.shape == (120, 3)


def test_a_non_finite_position_never_anchors_a_path() -> None:
    out = np.zeros((1, 5, 6))
    with pytest.raises(live.CycleSkipped, match="the anchored path is not finite"):
        live._anchored(out, np.array([np.nan, 1.0]))
    assert np.array_equal(live._anchored(out, np.array([2.0, 1.0]))[0, :, :2], np.tile([2.0, 1.0], (5, 1)))


def _straight_run(inputs: live.InputSet, seconds: float, bad_fix_at: dict[int, tuple[float, float]] | None = None,
                  falling_behind: float = 0.0, turn_rate: float = 0.0) -> list[str]:
    """Feed `seconds` of a boat at 5 m/s (turning at `turn_rate` rad/s): imu at 100 Hz, velocity and heading at 20 Hz,
    GNSS at 5 Hz along the track, checking consistency on every IMU sample as the node's timer does. bad_fix_at:
    GNSS sample index -> (lat, lon) sent instead. falling_behind: s per s the node falls behind its inputs (a loaded
    machine taking messages slower than they come), the header-less heading getting the late arrival as its stamp.
    Returns the refusals' reasons seen."""
    plane = live.LocalTangentPlane(35.38, 119.56)
    t0, speed, seen = 1_700_000_000 * NS, 5.0, []
    north = east = 0.0
    psi = 0.5
    for k in range(int(seconds * 100)):
        t = t0 + k * 10_000_000
        late = t + int(falling_behind * k * 10_000_000)
        psi += turn_rate * 0.01
        north, east = north + speed * math.cos(psi) * 0.01, east + speed * math.sin(psi) * 0.01
        inputs.add("imu", t, (turn_rate, 0.0, 0.0, -9.81, math.nan), late)
        if k % 5 == 0:
            inputs.add("velocity", t, (speed, 0.0, turn_rate), late)
            inputs.add("heading", late, (psi,), late, at_arrival=True)
            inputs.add("rudder_angle", late, (0.0,), late, at_arrival=True)
            inputs.add("engine_rpm", late, (650.0,), late, at_arrival=True)
        if k % 20 == 0:
            lat, lon = (bad_fix_at or {}).get(k // 20, plane.to_geodetic(north, east))
            try:
                inputs.add("gnss", t, (float(lat), float(lon), 0.0), late)
            except live.InputRejected:
                pass
        inputs.check_consistency(late)
        seen += [why for _, why in inputs.refusals.values()]
    return seen


def test_one_bad_gnss_fix_never_refuses_the_right_heading() -> None:
    """Was: one fix of null island among right ones entered the track check, which then refused the (right)
    heading for 20 s ("GNSS 3925324 m toward 180 deg"). Now it is refused as a jump before any check."""
    inputs = make_inputs()
    assert _straight_run(inputs, 60.0, bad_fix_at={150: (0.0, 0.0)}) == []
    assert inputs.tracks["gnss"].rejected == {"jump": 1}
    assert "fix" in inputs.tracks["gnss"].last_reject and "faster than 40 m/s" in inputs.tracks["gnss"].last_reject
    assert "track_vs_gnss" not in inputs.unjudged  # judged (and passed) on the right fixes


def test_a_wrong_first_fix_is_outvoted() -> None:
    """A wrong first fix would make every right one a jump: three right ones in a row that agree restart the GNSS
    buffer (and the automatic datum) from them."""
    inputs = make_inputs()
    assert _straight_run(inputs, 30.0, bad_fix_at={0: (0.0, 0.0)}) == []
    assert inputs.tracks["gnss"].rejected == {"jump": 2}
    assert abs(inputs.datum[0] - 35.38) < 0.01 and abs(inputs.datum[1] - 119.56) < 0.01


def test_a_node_behind_its_inputs_does_not_judge_a_headerless_heading() -> None:
    """Was: on a loaded machine the heading-vs-gyro check refused the Otter bag's right heading ("it turned 133
    deg while the imu yaw rate integrates to 234 deg"): the heading has no header, so the node stamps it when it takes
    it, late. Now a check over an input stamped on arrival does not judge while stamped messages arrive more than
    CONSISTENCY_LAG_LIMIT_S late; it says so and refuses nothing. On time, the same run is judged and passes."""
    behind = make_inputs()
    assert _straight_run(behind, 40.0, falling_behind=0.75, turn_rate=0.2) == []
    assert "behind its inputs" in behind.unjudged["heading_vs_gyro"] and "heading has no header" in \
        behind.unjudged["heading_vs_gyro"]
    on_time = make_inputs()
    assert _straight_run(on_time, 40.0, turn_rate=0.2) == []
    assert "heading_vs_gyro" not in on_time.unjudged

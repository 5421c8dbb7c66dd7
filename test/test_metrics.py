"""Manoeuvring metrics against tracks whose answers are known in closed form.

Drifting circle (marine convention, heading psi = psi0 + r t, course chi = psi + beta):
    x_n = x0 + (U / r) (sin chi - sin chi0) + V_n t,   y_e = y0 - (U / r) (cos chi - cos chi0) + V_e t
so R = U / |r|, one turn lasts T = 2 pi / |r| and every eq. 27 displacement is V T.
Tolerances come from the sampling: a chord of angle r dt misses the arc by R (r dt)^2 / 8.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from usv_predictor.analysis.metrics import (
    drift,
    heading_change_positions,
    open_loop_errors,
    position_error,
    rmse,
    seed_drift_angle_deg,
    steady_turning_radius,
    turning_circle_criteria,
    turning_radius,
    unwrap_heading,
    zigzag_overshoots,
)
from usv_predictor.frames import wrap_angle


@dataclass(frozen=True)
class Circle:
    """A steady turn in a uniform current; the analytic answers are properties."""

    speed_mps: float = 2.0  # U through the water (m/s)
    yaw_rate: float = 0.1  # r (rad/s), + starboard
    psi0: float = 0.3  # initial heading (rad)
    current_n: float = 0.2  # V_n (m/s)
    current_e: float = -0.15  # V_e (m/s)
    beta: float = 0.0  # course minus heading (rad)
    duration_s: float = 160.0
    dt: float = 0.02

    @property
    def radius(self) -> float:
        return self.speed_mps / abs(self.yaw_rate)

    @property
    def period(self) -> float:
        return 2.0 * math.pi / abs(self.yaw_rate)

    @property
    def chord_error(self) -> float:
        return self.radius * (self.yaw_rate * self.dt) ** 2 / 8.0

    def track(self, rng: np.random.Generator | None = None, pos_noise: float = 0.0, psi_noise: float = 0.0):
        t = np.arange(0.0, self.duration_s, self.dt)
        psi = self.psi0 + self.yaw_rate * t
        chi, chi0 = psi + self.beta, self.psi0 + self.beta
        k = self.speed_mps / self.yaw_rate
        x_n = 10.0 + k * (np.sin(chi) - math.sin(chi0)) + self.current_n * t
        y_e = -5.0 - k * (np.cos(chi) - math.cos(chi0)) + self.current_e * t
        if rng is not None:
            x_n = x_n + rng.normal(0.0, pos_noise, t.shape)
            y_e = y_e + rng.normal(0.0, pos_noise, t.shape)
            psi = psi + rng.normal(0.0, psi_noise, t.shape)
        return t, x_n, y_e, wrap_angle(psi)


# ------------------------------------------------------------------------------ heading points
def test_unwrap_heading_undoes_wrapping() -> None:
    psi = np.linspace(-3.0, 40.0, 2000)  # starts inside [-pi, pi), so unwrapping restores it exactly
    np.testing.assert_allclose(unwrap_heading(wrap_angle(psi)), psi, atol=1e-9)
    offset = unwrap_heading(wrap_angle(psi - 30.0)) - (psi - 30.0)  # whole turns lost, nothing else
    np.testing.assert_allclose(offset, offset[0], atol=1e-9)
    assert offset[0] / (2 * math.pi) == pytest.approx(round(offset[0] / (2 * math.pi)), abs=1e-9)


@pytest.mark.parametrize("yaw_rate", [0.1, -0.1])
def test_heading_change_positions_on_a_circle(yaw_rate: float) -> None:
    circle = Circle(yaw_rate=yaw_rate, current_n=0.0, current_e=0.0)
    t, x_n, y_e, psi = circle.track()
    points = heading_change_positions(t, x_n, y_e, psi, (90.0, 180.0, 360.0))
    for point in points:
        expected_t = math.radians(point.change_deg) / abs(yaw_rate)
        assert point.t_s == pytest.approx(expected_t, abs=1e-9)
        chi = circle.psi0 + yaw_rate * expected_t
        k = circle.speed_mps / yaw_rate
        tol = circle.chord_error + 1e-9
        assert point.x_n_m == pytest.approx(10.0 + k * (math.sin(chi) - math.sin(circle.psi0)), abs=tol)
        assert point.y_e_m == pytest.approx(-5.0 - k * (math.cos(chi) - math.cos(circle.psi0)), abs=tol)
    # After a full turn with no current the vessel is back where it started.
    assert points[2].x_n_m == pytest.approx(x_n[0], abs=circle.chord_error + 1e-9)


def test_heading_change_positions_explains_a_short_track() -> None:
    t, x_n, y_e, psi = Circle(duration_s=50.0).track()  # 0.1 rad/s * 50 s = 286 deg
    with pytest.raises(ValueError, match=r"turns only 28\d\.\d deg .*360 deg is needed"):
        heading_change_positions(t, x_n, y_e, psi, (180.0, 360.0))


def test_inputs_are_validated() -> None:
    t, x_n, y_e, psi = Circle().track()
    with pytest.raises(ValueError, match="y_e has shape"):
        drift(t, x_n, y_e[:-1], psi)
    with pytest.raises(ValueError, match="strictly increasing"):
        drift(t[::-1], x_n, y_e, psi)
    with pytest.raises(ValueError, match="NaN"):
        drift(t, np.where(t > 3.0, np.nan, x_n), y_e, psi)


# ------------------------------------------------------------------------------------- drift
@pytest.mark.parametrize("yaw_rate", [0.1, -0.12])
@pytest.mark.parametrize("psi0", [0.0, 2.5, -1.7])
def test_drift_of_a_drifting_circle(yaw_rate: float, psi0: float) -> None:
    circle = Circle(yaw_rate=yaw_rate, psi0=psi0, beta=-0.2 * math.copysign(1.0, yaw_rate))
    result = drift(*circle.track())
    speed = math.hypot(circle.current_n, circle.current_e)
    assert result.period_s == pytest.approx(circle.period, rel=1e-9)
    assert result.speed_mps == pytest.approx(speed, abs=2 * circle.chord_error / circle.period)
    assert result.distance_m == pytest.approx(speed * circle.period, abs=2 * circle.chord_error)
    expected = math.degrees(math.atan2(circle.current_e, circle.current_n)) % 360.0
    tolerance = math.degrees(2 * circle.chord_error / (speed * circle.period))
    assert result.direction_deg == pytest.approx(expected, abs=tolerance + 1e-9)


def test_drift_direction_is_averaged_across_north() -> None:
    """Drift toward 0 deg, averaged from displacements either side of north, must not read 180 deg."""
    rng = np.random.default_rng(11)
    for _ in range(20):
        direction = math.radians(rng.uniform(-2.0, 2.0))  # near north, either side
        circle = Circle(current_n=0.3 * math.cos(direction), current_e=0.3 * math.sin(direction), dt=0.05)
        result = drift(*circle.track())
        difference = (result.direction_deg - math.degrees(direction) + 180.0) % 360.0 - 180.0
        assert abs(difference) < 0.01
        assert 0.0 <= result.direction_deg < 360.0


def test_drift_direction_random_currents() -> None:
    rng = np.random.default_rng(7)
    for _ in range(25):
        speed, direction = rng.uniform(0.05, 0.6), rng.uniform(0.0, 2.0 * math.pi)
        circle = Circle(
            yaw_rate=rng.choice([-1.0, 1.0]) * rng.uniform(0.08, 0.25),
            psi0=rng.uniform(-math.pi, math.pi),
            current_n=speed * math.cos(direction),
            current_e=speed * math.sin(direction),
            duration_s=2.0 * math.pi / 0.08 * 2.2,
            dt=0.05,
        )
        result = drift(*circle.track())
        difference = (result.direction_deg - math.degrees(direction) + 180.0) % 360.0 - 180.0
        assert abs(difference) < 0.05
        assert result.speed_mps == pytest.approx(speed, rel=1e-3)


def test_seed_drift_angle_reading() -> None:
    # Toward south-west: compass 225 deg is 225 deg from east toward north as well (symmetric case),
    # toward east (compass 90) is 0 deg in the seed's X-east / Y-north angle.
    assert seed_drift_angle_deg(225.0) == pytest.approx(225.0)
    assert seed_drift_angle_deg(90.0) == pytest.approx(0.0)
    assert seed_drift_angle_deg(0.0) == pytest.approx(90.0)
    assert seed_drift_angle_deg(236.46) == pytest.approx(213.54)


def test_drift_needs_two_turns() -> None:
    t, x_n, y_e, psi = Circle(duration_s=100.0).track()  # 573 deg
    with pytest.raises(ValueError, match=r"needs 720 deg .* turns only 57\d\.\d deg .* 720 deg is needed"):
        drift(t, x_n, y_e, psi)


def test_drift_of_noisy_tracks() -> None:
    """GPS noise 0.1 m and heading noise 0.5 deg: distance within 0.5 m, direction within 3 deg."""
    circle = Circle(yaw_rate=0.15, current_n=-0.25, current_e=-0.17, dt=0.1, duration_s=110.0)
    speed = math.hypot(circle.current_n, circle.current_e)
    expected = math.degrees(math.atan2(circle.current_e, circle.current_n)) % 360.0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        result = drift(*circle.track(rng, pos_noise=0.1, psi_noise=math.radians(0.5)))
        assert result.distance_m == pytest.approx(speed * circle.period, abs=0.5)
        assert abs((result.direction_deg - expected + 180.0) % 360.0 - 180.0) < 3.0


# ---------------------------------------------------------------------------- turning radius
@pytest.mark.parametrize("yaw_rate", [0.1, -0.1])
@pytest.mark.parametrize("psi0", [0.0, 1.2, -2.9])
def test_turning_radius_eq29_of_a_drifting_circle(yaw_rate: float, psi0: float) -> None:
    circle = Circle(yaw_rate=yaw_rate, psi0=psi0, beta=0.15)
    result = turning_radius(*circle.track())
    assert len(result.per_circle_m) == int(circle.duration_s * abs(yaw_rate) / (2 * math.pi))
    assert result.radius_m == pytest.approx(circle.radius, abs=circle.chord_error + 1e-6)
    for per_circle in result.per_circle_m:
        assert per_circle == pytest.approx(circle.radius, abs=circle.chord_error + 1e-6)


def test_turning_radius_eq29_axis_matters_under_drift() -> None:
    """Across the drift the extent is 2R; along it the drift distorts each circle's extent."""
    circle = Circle(current_n=0.4, current_e=0.0)
    t, x_n, y_e, psi = circle.track()
    across = turning_radius(t, x_n, y_e, psi, drift_direction_deg=0.0)
    along = turning_radius(t, x_n, y_e, psi, drift_direction_deg=90.0)
    assert across.radius_m == pytest.approx(circle.radius, abs=circle.chord_error + 1e-6)
    assert abs(along.radius_m - circle.radius) > 1.0


def test_turning_radius_one_circle_with_given_axis() -> None:
    circle = Circle(current_n=0.0, current_e=0.0, duration_s=70.0)  # 401 deg
    result = turning_radius(*circle.track(), drift_direction_deg=0.0)
    assert result.per_circle_m == pytest.approx((circle.radius,), abs=circle.chord_error + 1e-6)
    assert result.note == ""
    with pytest.raises(ValueError, match="360 deg"):
        turning_radius(*Circle(duration_s=40.0).track(), drift_direction_deg=0.0)
    with pytest.raises(ValueError, match="360 deg"):
        turning_radius(*Circle(duration_s=40.0).track())


@pytest.mark.parametrize("duration_s", [70.0, 100.0, 120.0])  # 401, 573, 688 deg
def test_turning_radius_of_one_to_two_turns_uses_the_first_circle_with_a_note(duration_s: float) -> None:
    calm = Circle(current_n=0.0, current_e=0.0, duration_s=duration_s)
    result = turning_radius(*calm.track())  # no axis given, too short for the eq. 27 drift
    assert len(result.per_circle_m) == 1
    assert result.radius_m == pytest.approx(calm.radius, abs=calm.chord_error + 1e-6)
    assert "first full circle" in result.note
    assert "< 720" in result.note
    drifting = Circle(duration_s=duration_s)  # 0.25 m/s of current: the half-extent is off by <= drift / 2
    off = turning_radius(*drifting.track()).radius_m - drifting.radius
    assert abs(off) <= 0.5 * math.hypot(drifting.current_n, drifting.current_e) * drifting.period + 1e-6
    two = Circle(current_n=0.0, current_e=0.0, duration_s=140.0)  # 802 deg: eq. 27 drift, no note
    assert turning_radius(*two.track()).note == ""


def test_turning_circle_reports_the_imo_transfer() -> None:
    calm = Circle(current_n=0.0, current_e=0.0, duration_s=70.0)
    imo = turning_circle_criteria(*calm.track(), 0.0)
    assert imo.transfer_m == pytest.approx(calm.radius, rel=1e-3)  # a circle from execute: transfer = R at 90 deg
    assert imo.advance_m == pytest.approx(calm.radius, rel=1e-3)


@pytest.mark.parametrize("yaw_rate", [0.1, -0.1])
def test_steady_turning_radius_of_a_drifting_circle(yaw_rate: float) -> None:
    circle = Circle(yaw_rate=yaw_rate, psi0=-2.0, beta=0.1)
    result = steady_turning_radius(*circle.track())
    assert result.radius_m == pytest.approx(circle.radius, abs=1e-6)
    assert result.drift_north_mps == pytest.approx(circle.current_n, abs=1e-6)
    assert result.drift_east_mps == pytest.approx(circle.current_e, abs=1e-6)
    assert result.rms_residual_m < 1e-6


def test_steady_turning_radius_without_drift_refinement_uses_eq27_velocity() -> None:
    circle = Circle()
    result = steady_turning_radius(*circle.track(), refine_drift=False)
    assert result.radius_m == pytest.approx(circle.radius, abs=circle.chord_error + 1e-6)
    assert result.drift_north_mps == pytest.approx(circle.current_n, abs=1e-4)


def test_steady_turning_radius_beats_eq29_on_noise() -> None:
    """GPS noise 0.2 m: eq. 29 picks extremes (biased up), the fit uses every sample."""
    circle = Circle(yaw_rate=0.12, speed_mps=2.4, dt=0.1, duration_s=160.0)
    eq29_errors, fit_errors = [], []
    for seed in range(12):
        track = circle.track(np.random.default_rng(100 + seed), pos_noise=0.2, psi_noise=math.radians(0.3))
        eq29_errors.append(turning_radius(*track).radius_m - circle.radius)
        fit = steady_turning_radius(*track)
        fit_errors.append(fit.radius_m - circle.radius)
        assert fit.rms_residual_m == pytest.approx(0.2 * math.sqrt(1.0), rel=0.25)  # ~ one-axis sigma
    assert max(abs(e) for e in fit_errors) < 0.05
    assert max(abs(e) for e in eq29_errors) < 1.0
    assert np.mean(eq29_errors) > 0.1  # the extreme-value bias
    assert np.mean(np.abs(fit_errors)) < 0.25 * np.mean(np.abs(eq29_errors))


# ------------------------------------------------------------------------------ turning circle
@pytest.mark.parametrize("yaw_rate", [0.1, -0.1])
@pytest.mark.parametrize("psi0", [0.0, 3.0, -2.2])
def test_turning_circle_of_a_pure_circle_from_execute(yaw_rate: float, psi0: float) -> None:
    circle = Circle(yaw_rate=yaw_rate, psi0=psi0, current_n=0.0, current_e=0.0, duration_s=40.0)
    t, x_n, y_e, psi = circle.track()
    result = turning_circle_criteria(t, x_n, y_e, psi, t_execute=0.0)
    tol = circle.chord_error + 1e-9
    assert result.advance_m == pytest.approx(circle.radius, abs=tol)
    assert result.transfer_m == pytest.approx(circle.radius, abs=tol)
    assert result.tactical_diameter_m == pytest.approx(2 * circle.radius, abs=tol)
    assert result.time_to_90_s == pytest.approx(0.5 * math.pi / abs(yaw_rate), abs=1e-9)
    assert result.time_to_180_s == pytest.approx(math.pi / abs(yaw_rate), abs=1e-9)
    assert result.turn_direction == (1 if yaw_rate > 0 else -1)
    assert result.execute_heading_deg == pytest.approx(math.degrees(psi0) % 360.0, abs=1e-9)


@pytest.mark.parametrize("t_e", [20.0, 20.3])
@pytest.mark.parametrize("yaw_rate", [0.15, -0.15])
def test_turning_circle_entered_after_a_straight_run(yaw_rate: float, t_e: float) -> None:
    """Straight at heading psi0 until rudder execute at t_e (on a sample or between two), then a circle."""
    speed, psi0, dt = 3.0, math.radians(350.0), 0.04
    t = np.arange(1500) * dt
    turning = np.maximum(t - t_e, 0.0)
    psi = psi0 + yaw_rate * turning
    k = speed / yaw_rate
    straight = np.minimum(t, t_e) * speed
    x_n = straight * math.cos(psi0) + k * (np.sin(psi) - math.sin(psi0))
    y_e = straight * math.sin(psi0) - k * (np.cos(psi) - math.cos(psi0))
    result = turning_circle_criteria(t, x_n, y_e, wrap_angle(psi), t_execute=t_e)
    radius = speed / abs(yaw_rate)
    tol = radius * (yaw_rate * dt) ** 2 / 8 + 1e-9
    if not np.any(t == t_e):
        # Between samples the heading at execute is interpolated across the kink: off by up to
        # r dt / 2, which delays the 90 deg point by up to dt / 2, i.e. speed * dt / 2 of track.
        tol += speed * dt / 2
    assert result.advance_m == pytest.approx(radius, abs=tol)
    assert result.transfer_m == pytest.approx(radius, abs=tol)
    assert result.tactical_diameter_m == pytest.approx(2 * radius, abs=tol)
    # Measured from the execute instant, not from the start of the record.
    t_tol = 1e-9 if np.any(t == t_e) else dt / 2
    assert result.time_to_90_s == pytest.approx(0.5 * math.pi / abs(yaw_rate), abs=t_tol)


def test_turning_circle_in_a_current() -> None:
    """Over ground the current adds V t along and across the original heading."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        circle = Circle(
            yaw_rate=rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.3),
            psi0=rng.uniform(-math.pi, math.pi),
            current_n=rng.uniform(-0.3, 0.3),
            current_e=rng.uniform(-0.3, 0.3),
            duration_s=40.0,
        )
        t, x_n, y_e, psi = circle.track()
        result = turning_circle_criteria(t, x_n, y_e, psi, t_execute=0.0)
        along = circle.current_n * math.cos(circle.psi0) + circle.current_e * math.sin(circle.psi0)
        across = -circle.current_n * math.sin(circle.psi0) + circle.current_e * math.cos(circle.psi0)
        side = math.copysign(1.0, circle.yaw_rate)
        t90, t180 = result.time_to_90_s, result.time_to_180_s
        tol = circle.chord_error + 1e-9
        assert result.advance_m == pytest.approx(circle.radius + along * t90, abs=tol)
        assert result.transfer_m == pytest.approx(abs(side * circle.radius + across * t90), abs=tol)
        assert result.tactical_diameter_m == pytest.approx(abs(side * 2 * circle.radius + across * t180), abs=tol)


def test_turning_circle_errors() -> None:
    t, x_n, y_e, psi = Circle(duration_s=40.0).track()  # 229 deg
    with pytest.raises(ValueError, match=r"after execute at 25.0 s: track turns only"):
        turning_circle_criteria(t, x_n, y_e, psi, t_execute=25.0)
    with pytest.raises(ValueError, match="outside the track"):
        turning_circle_criteria(t, x_n, y_e, psi, t_execute=-1.0)


# ---------------------------------------------------------------------------------- zigzag
@dataclass(frozen=True)
class SyntheticZigZag:
    """Heading deviation A_k sin(w t) on half-cycle k, rudder reversed where it reaches the check angle.

    Half-cycle k spans [k pi / w, (k + 1) pi / w]; the heading reaches +-check on its rising part at
    t_k = (k pi + asin(check / A_k)) / w, peaks at A_k, so overshoot k = A_k - check.
    """

    amplitudes_deg: tuple[float, ...] = (17.0, 21.0, 19.0, 16.0)
    check_deg: float = 10.0
    omega: float = 2 * math.pi / 40.0  # rad/s
    base_deg: float = 355.0  # wraps through north
    first_side: int = 1
    rudder_deg: float = 10.0
    rudder_rate_deg_s: float | None = 5.0  # None: step rudder
    rudder_offset_deg: float = 0.0  # added to the whole rudder record (a miscalibrated sensor)
    approach_s: float = 15.0
    dt: float = 0.05

    def reversal_times(self) -> np.ndarray:
        k = np.arange(len(self.amplitudes_deg))
        return (k * math.pi + np.arcsin(self.check_deg / np.array(self.amplitudes_deg))) / self.omega

    def series(self, rng: np.random.Generator | None = None, psi_noise_deg: float = 0.0, rudder_noise_deg: float = 0.0):
        t = np.arange(-self.approach_s, len(self.amplitudes_deg) * math.pi / self.omega, self.dt)
        half = np.clip((t * self.omega // math.pi).astype(int), 0, len(self.amplitudes_deg) - 1)
        dev = np.where(t < 0.0, 0.0, self.first_side * np.array(self.amplitudes_deg)[half] * np.sin(self.omega * t))
        executes = np.concatenate([[0.0], self.reversal_times()])
        targets = self.first_side * self.rudder_deg * (-1.0) ** np.arange(len(executes))
        rudder = np.zeros_like(t)
        previous = 0.0
        for t_exec, target in zip(executes, targets):
            if self.rudder_rate_deg_s is None:
                moved = (t >= t_exec).astype(float)
            else:
                moved = np.clip((t - t_exec) * self.rudder_rate_deg_s / abs(target - previous), 0.0, 1.0)
            rudder += moved * (target - previous)
            previous = target
        rudder += self.rudder_offset_deg
        psi = self.base_deg + dev
        if rng is not None:
            psi = psi + rng.normal(0.0, psi_noise_deg, t.shape)
            rudder = rudder + rng.normal(0.0, rudder_noise_deg, t.shape)
        return t, wrap_angle(np.radians(psi)), np.radians(rudder)

    def expected_overshoots(self) -> np.ndarray:
        return np.array(self.amplitudes_deg) - self.check_deg


@pytest.mark.parametrize("first_side", [1, -1])
@pytest.mark.parametrize("rudder_rate", [None, 5.0])
def test_zigzag_overshoots_of_a_synthetic_heading(first_side: int, rudder_rate: float | None) -> None:
    zigzag = SyntheticZigZag(first_side=first_side, rudder_rate_deg_s=rudder_rate, dt=0.01)
    result = zigzag_overshoots(*zigzag.series())
    expected = zigzag.expected_overshoots()
    # A step rudder is only located to within a sample: heading error up to the yaw rate * dt.
    max_rate = max(zigzag.amplitudes_deg) * zigzag.omega
    tol = max_rate * zigzag.dt + 0.01
    np.testing.assert_allclose(result.overshoot_angles_deg, expected, atol=tol)
    assert result.first_overshoot_deg == pytest.approx(expected[0], abs=tol)
    assert result.second_overshoot_deg == pytest.approx(expected[1], abs=tol)
    reversals = zigzag.reversal_times()
    np.testing.assert_allclose(result.reversal_times_s, reversals, atol=zigzag.dt)
    np.testing.assert_allclose(np.abs(result.check_headings_deg), zigzag.check_deg, atol=tol)
    assert np.all(np.sign(result.check_headings_deg) == first_side * (-1.0) ** np.arange(len(reversals)))
    peaks = (np.arange(len(reversals)) + 0.5) * math.pi / zigzag.omega
    np.testing.assert_allclose(result.peak_times_s, peaks, atol=0.05)
    np.testing.assert_allclose(result.time_to_check_yaw_s, peaks - reversals, atol=0.05)
    assert result.initial_turning_time_s == pytest.approx(reversals[0], abs=zigzag.dt)
    executes = np.concatenate([[0.0], reversals])
    assert result.period_s == pytest.approx(np.mean(executes[2:] - executes[:-2]), abs=zigzag.dt)
    assert result.execute_time_s == pytest.approx(0.0, abs=zigzag.dt)
    assert result.base_heading_deg == pytest.approx(zigzag.base_deg, abs=0.01)
    assert result.rudder_amplitude_deg == pytest.approx(zigzag.rudder_deg, abs=1e-9)


@pytest.mark.parametrize("offset_deg", [2.5, -3.0])
def test_zigzag_overshoots_with_a_rudder_offset(offset_deg: float) -> None:
    """A rudder held off-centre (e.g. +12.5 / -7.5 deg) still reverses at the same instants."""
    zigzag = SyntheticZigZag(rudder_offset_deg=offset_deg, dt=0.02)
    result = zigzag_overshoots(*zigzag.series())
    np.testing.assert_allclose(result.reversal_times_s, zigzag.reversal_times(), atol=zigzag.dt)
    np.testing.assert_allclose(result.overshoot_angles_deg, zigzag.expected_overshoots(), atol=0.05)


def test_zigzag_overshoots_raw_samples_match_the_smoothed_ones_without_noise() -> None:
    zigzag = SyntheticZigZag(dt=0.01)
    smoothed = zigzag_overshoots(*zigzag.series())
    raw = zigzag_overshoots(*zigzag.series(), smoothing_fraction=0.0)
    np.testing.assert_allclose(raw.overshoot_angles_deg, zigzag.expected_overshoots(), atol=0.01)
    np.testing.assert_allclose(smoothed.overshoot_angles_deg, raw.overshoot_angles_deg, atol=0.02)


def test_zigzag_overshoots_of_noisy_signals() -> None:
    """Heading noise 0.2 deg, rudder noise 0.3 deg: RMS error below 0.2 deg, every overshoot within
    0.5 deg, and the local fits at least halve the error of raw samples."""
    zigzag = SyntheticZigZag(dt=0.1)
    expected = zigzag.expected_overshoots()
    smoothed_errors, raw_errors = [], []
    for seed in range(15):
        series = zigzag.series(np.random.default_rng(seed), psi_noise_deg=0.2, rudder_noise_deg=0.3)
        result = zigzag_overshoots(*series)
        assert len(result.overshoot_angles_deg) == len(expected)
        smoothed_errors.append(np.array(result.overshoot_angles_deg) - expected)
        raw_errors.append(np.array(zigzag_overshoots(*series, smoothing_fraction=0.0).overshoot_angles_deg) - expected)
    assert np.max(np.abs(smoothed_errors)) < 0.5
    assert np.sqrt(np.mean(np.square(smoothed_errors))) < 0.2
    assert np.sqrt(np.mean(np.square(smoothed_errors))) < 0.5 * np.sqrt(np.mean(np.square(raw_errors)))


def test_zigzag_leaves_out_an_unfinished_swing() -> None:
    zigzag = SyntheticZigZag()
    t, psi, rudder = zigzag.series()
    last_peak = (len(zigzag.amplitudes_deg) - 0.5) * math.pi / zigzag.omega
    keep = t < last_peak - 1.0  # the record stops before the last heading peak
    result = zigzag_overshoots(t[keep], psi[keep], rudder[keep])
    assert len(result.reversal_times_s) == len(zigzag.amplitudes_deg)
    assert len(result.overshoot_angles_deg) == len(zigzag.amplitudes_deg)  # aligned with the reversals
    np.testing.assert_allclose(result.overshoot_angles_deg[:-1], zigzag.expected_overshoots()[:-1], atol=0.05)
    assert math.isnan(result.overshoot_angles_deg[-1])
    assert math.isnan(result.peak_times_s[-1])
    assert math.isnan(result.time_to_check_yaw_s[-1])


def test_zigzag_needs_a_reversal() -> None:
    t = np.arange(0.0, 30.0, 0.1)
    rudder = np.where(t > 5.0, math.radians(10.0), 0.0)
    with pytest.raises(ValueError, match="at least one reversal"):
        zigzag_overshoots(t, 0.01 * t, rudder)
    with pytest.raises(ValueError, match="never leaves zero"):
        zigzag_overshoots(t, 0.01 * t, np.zeros_like(t))


# --------------------------------------------------------------------------- prediction errors
def test_rmse_per_column_and_wrapped_angles() -> None:
    rng = np.random.default_rng(5)
    a = rng.normal(size=(200, 3))
    offsets = np.array([0.5, -2.0, 0.0])
    b = a + offsets
    np.testing.assert_allclose(rmse(a, b), np.abs(offsets), atol=1e-12)
    heading_a = np.full(10, math.radians(359.0))
    heading_b = np.full(10, math.radians(1.0))
    assert rmse(heading_a, heading_b, angle_columns=(0,)) == pytest.approx(math.radians(2.0))
    assert rmse(heading_a, heading_b) == pytest.approx(math.radians(358.0))
    states_a = np.column_stack([np.zeros(10), heading_a])
    states_b = np.column_stack([np.ones(10), heading_b])
    np.testing.assert_allclose(rmse(states_a, states_b, angle_columns=(1,)), [1.0, math.radians(2.0)])
    with pytest.raises(ValueError, match="one shape"):
        rmse(a, b[:, :2])


def test_position_error_is_euclidean() -> None:
    np.testing.assert_allclose(position_error([3.0, 0.0], [4.0, 1.0], [0.0, 0.0], [0.0, 0.0]), [5.0, 1.0])


def test_open_loop_errors_at_horizons() -> None:
    """A prediction that drifts at a known speed per start point: error at h is speed_s * h."""
    rng = np.random.default_rng(9)
    starts, dt, steps = 400, 0.5, 130
    lead = (np.arange(steps) + 1) * dt  # step k is (k + 1) dt after the start
    measured = rng.normal(size=(starts, steps, 2)) * 50.0
    speed = rng.uniform(0.0, 0.2, starts)  # (starts,) m/s error growth
    angle = rng.uniform(0.0, 2 * math.pi, starts)
    offset = speed[:, None, None] * lead[None, :, None] * np.stack([np.cos(angle), np.sin(angle)], -1)[:, None, :]
    predicted = measured + offset  # (starts, steps, 2)
    predicted[:5, 19, 0] = np.nan  # missing values at 10 s are left out
    results = open_loop_errors(predicted, measured, horizons_s=(10.0, 30.0, 60.0), dt=dt)
    assert [r.horizon_s for r in results] == [10.0, 30.0, 60.0]
    for result in results:
        errors = speed * result.horizon_s
        if result.horizon_s == 10.0:
            errors = errors[5:]
        assert result.count == len(errors)
        assert result.mean_m == pytest.approx(errors.mean(), rel=1e-9)
        assert result.p50_m == pytest.approx(np.median(errors), rel=1e-9)
        assert result.p95_m == pytest.approx(np.percentile(errors, 95.0), rel=1e-9)
        assert result.max_m == pytest.approx(errors.max(), rel=1e-9)
    with pytest.raises(ValueError, match="within the rollout"):
        open_loop_errors(predicted, measured, horizons_s=(70.0,), dt=dt)
    with pytest.raises(ValueError, match="multiple of dt"):
        open_loop_errors(predicted, measured, horizons_s=(10.2,), dt=dt)
    with pytest.raises(ValueError, match="starts, steps, 2"):
        open_loop_errors(predicted[0], measured[0], dt=dt)


def test_evaluation_turning_metrics_of_one_and_a_half_turns() -> None:
    """A measured turning circle of 540 deg: no eq. 27 drift, yet a radius from the first circle (with a note),
    and the IMO transfer beside advance and tactical diameter."""
    from usv_predictor.analysis import evaluation

    calm = Circle(current_n=0.0, current_e=0.0, duration_s=100.0)
    t, x_n, y_e, psi = calm.track()
    series = np.zeros((len(t), 6))  # (T, 6) u v r x_n y_e psi
    series[:, evaluation.X_N], series[:, evaluation.Y_E], series[:, evaluation.PSI] = x_n, y_e, psi
    notes: list[str] = []
    values = evaluation.turning_metrics(t, series, 0.0, None, notes, "measured")
    assert values["drift_distance_m"] is None
    assert values["turning_radius_m"] == pytest.approx(calm.radius, abs=calm.chord_error + 1e-6)
    assert values["transfer_m"] == pytest.approx(calm.radius, rel=1e-3)
    assert any("first full circle" in n for n in notes)
    assert any("drift (eq. 27" in n for n in notes)

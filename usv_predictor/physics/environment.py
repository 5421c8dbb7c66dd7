"""Sea environment: current, wind with gusts, waves (mean drift + first-order motion).

Directions are compass angles in degrees at the interface (DESIGN.md vocabulary) and radians inside:
current flows TOWARD `current_to_deg`; wind blows FROM `wind_from_deg`; waves come FROM `wave_from_deg`.
Current enters the dynamics through the relative velocity nu_r = nu - nu_c (seed 000 eq. 20-22);
wind loads use the apparent wind (seed 000 eq. 12-18); wave drift is seed 000 eq. 19.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from usv_predictor.config import Range


@dataclass(frozen=True)
class Environment:
    current_speed: float = 0.0  # (m/s)
    current_to_deg: float = 0.0  # direction the current flows toward, clockwise from north (deg)
    current_turn_rate_deg_s: float = 0.0  # slow rotation of the current direction (deg/s), e.g. tidal
    current_step_time_s: float = 0.0  # time the current changes to the step's speed and direction (s); 0 = no step
    current_step_speed: float = 0.0  # current speed after the step (m/s)
    current_step_to_deg: float = 0.0  # direction the current flows toward after the step (deg)
    current_step_ramp_s: float = 10.0  # the change is a linear blend of the two velocities over this time (s)
    wind_speed: float = 0.0  # mean true wind speed at 10 m (m/s)
    wind_from_deg: float = 0.0  # direction the wind blows from (deg)
    gust_std: float = 0.0  # standard deviation of the gust speed (m/s)
    gust_time_constant_s: float = 20.0  # correlation time of the gusts (first-order Gauss-Markov) (s)
    wave_height: float = 0.0  # significant wave height H_s (m); drift uses zeta_a = H_s / 2
    wave_from_deg: float = 0.0  # direction the waves come from (deg)
    wave_period_s: float = 3.0  # peak period T_p (s), first-order motion only
    wave_components: int = 8  # number of harmonic components of the first-order motion (-)

    def __post_init__(self) -> None:
        checks = {
            "current_speed": (self.current_speed, Range(0.0, 5.0, "m/s")),
            "wind_speed": (self.wind_speed, Range(0.0, 40.0, "m/s")),
            "gust_std": (self.gust_std, Range(0.0, 15.0, "m/s")),
            "gust_time_constant_s": (self.gust_time_constant_s, Range(0.1, 3600.0, "s")),
            "wave_height": (self.wave_height, Range(0.0, 6.0, "m")),
            "wave_period_s": (self.wave_period_s, Range(0.5, 25.0, "s")),
            "current_turn_rate_deg_s": (self.current_turn_rate_deg_s, Range(-1.0, 1.0, "deg/s")),
            "current_step_time_s": (self.current_step_time_s, Range(0.0, 86400.0, "s")),
            "current_step_speed": (self.current_step_speed, Range(0.0, 5.0, "m/s")),
            "current_step_ramp_s": (self.current_step_ramp_s, Range(0.1, 600.0, "s")),
        }
        for name, (value, allowed) in checks.items():
            allowed.check(name, value, "environment")

    @property
    def is_calm(self) -> bool:
        return (self.current_speed == 0.0 and not self.has_current_step and self.wind_speed == 0.0
                and self.wave_height == 0.0 and self.gust_std == 0.0)

    def calm(self) -> "Environment":
        """The calm-water twin: same settings, no current, wind or waves."""
        return replace(self, current_speed=0.0, current_step_time_s=0.0, current_step_speed=0.0, wind_speed=0.0,
                       gust_std=0.0, wave_height=0.0)

    @property
    def has_current_step(self) -> bool:
        """Whether the current changes speed and direction during the run (current_step_time_s > 0)."""
        return self.current_step_time_s > 0.0

    def current_ned(self, t_s: float) -> tuple[float, float]:
        """Current velocity (north, east) in m/s at time t (s)."""
        if self.has_current_step and t_s > self.current_step_time_s:
            return tuple(float(x) for x in self.current_arrays(np.array([t_s]))[0][0])  # type: ignore[return-value]
        direction = math.radians(self.current_to_deg + self.current_turn_rate_deg_s * t_s)
        return self.current_speed * math.cos(direction), self.current_speed * math.sin(direction)

    def current_accel_ned(self, t_s: float) -> tuple[float, float]:
        """Time derivative of the current velocity (m/s^2): non-zero for a turning current and during a step."""
        if self.has_current_step and t_s > self.current_step_time_s:
            return tuple(float(x) for x in self.current_arrays(np.array([t_s]))[1][0])  # type: ignore[return-value]
        omega = math.radians(self.current_turn_rate_deg_s)
        direction = math.radians(self.current_to_deg) + omega * t_s
        return -self.current_speed * omega * math.sin(direction), self.current_speed * omega * math.cos(direction)

    def current_arrays(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 2) current velocity (north, east, m/s) and (N, 2) its time derivative (m/s^2) at the times t_s (s).

        Before the step (or without one): speed V toward chi_0 + omega t (omega the turn rate), derivative
        V omega (-sin, cos). After the step at t_1, the step's speed V_1 toward chi_1 + omega (t - t_1); during the
        ramp t_1 < t < t_1 + T the velocity is the linear blend (1 - w) c_0(t) + w c_1(t), w = (t - t_1) / T, whose
        derivative adds (c_1 - c_0) / T: the water accelerates at a finite rate, and the rigid body feels it
        (dynamics.ManoeuvringModel.accelerations, Fossen 2021 sec. 10.3)."""
        t_s = np.asarray(t_s, dtype=float)
        omega = math.radians(self.current_turn_rate_deg_s)
        direction = math.radians(self.current_to_deg) + omega * t_s
        c, s = np.cos(direction), np.sin(direction)
        speed = self.current_speed
        velocity = np.column_stack([speed * c, speed * s])
        accel = np.column_stack([-speed * omega * s, speed * omega * c])
        if not self.has_current_step:
            return velocity, accel
        after = t_s > self.current_step_time_s
        if not after.any():
            return velocity, accel
        t1, ramp, speed1 = self.current_step_time_s, self.current_step_ramp_s, self.current_step_speed
        direction1 = math.radians(self.current_step_to_deg) + omega * (t_s - t1)
        c1, s1 = np.cos(direction1), np.sin(direction1)
        velocity1 = np.column_stack([speed1 * c1, speed1 * s1])
        accel1 = np.column_stack([-speed1 * omega * s1, speed1 * omega * c1])
        w = np.clip((t_s - t1) / ramp, 0.0, 1.0)[:, None]  # (N, 1) blend weight
        ramping = ((t_s > t1) & (t_s < t1 + ramp))[:, None]  # (N, 1)
        blend_v = (1.0 - w) * velocity + w * velocity1
        blend_a = (1.0 - w) * accel + w * accel1 + np.where(ramping, (velocity1 - velocity) / ramp, 0.0)
        return (np.where(after[:, None], blend_v, velocity), np.where(after[:, None], blend_a, accel))


def gust_series(env: Environment, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Wind speed (m/s) on the time grid t_s: mean + first-order Gauss-Markov gusts, never negative.

    Exact discretisation of dg = -g/T dt + sigma sqrt(2/T) dW, stationary from the first sample.
    """
    speed = np.full(t_s.shape, env.wind_speed)
    if env.gust_std == 0.0 or env.wind_speed == 0.0 or len(t_s) == 0:
        return speed
    gust = np.empty_like(speed)
    gust[0] = rng.normal(0.0, env.gust_std)
    steps = np.diff(t_s)
    phi = np.exp(-steps / env.gust_time_constant_s)
    shocks = rng.normal(0.0, 1.0, len(steps)) * env.gust_std * np.sqrt(1.0 - phi**2)
    for i in range(1, len(t_s)):
        gust[i] = phi[i - 1] * gust[i - 1] + shocks[i - 1]
    return np.maximum(speed + gust, 0.0)


@dataclass(frozen=True)
class WaveComponents:
    """Harmonic components of a JONSWAP-like sea for the first-order (wave-frequency) motion."""

    omega: np.ndarray  # (K,) wave frequencies (rad/s)
    amplitude: np.ndarray  # (K,) wave amplitudes zeta_k (m)
    phase: np.ndarray  # (K,) random phases (rad)


def wave_components(env: Environment, rng: np.random.Generator) -> WaveComponents:
    """Sample K components from a JONSWAP spectrum (gamma 3.3) so that 4 sqrt(m0) = H_s."""
    k = env.wave_components
    if env.wave_height == 0.0 or k == 0:
        empty = np.zeros(0)
        return WaveComponents(empty, empty, empty)
    omega_p = 2.0 * math.pi / env.wave_period_s
    omega = np.linspace(0.6 * omega_p, 2.5 * omega_p, k)
    sigma = np.where(omega <= omega_p, 0.07, 0.09)
    peak = 3.3 ** np.exp(-((omega - omega_p) ** 2) / (2.0 * sigma**2 * omega_p**2))
    shape = omega**-5 * np.exp(-1.25 * (omega_p / omega) ** 4) * peak
    d_omega = omega[1] - omega[0]
    m0_shape = float(np.sum(shape) * d_omega)
    spectrum = shape * (env.wave_height / 4.0) ** 2 / m0_shape  # scaled so that m0 = (H_s/4)^2
    amplitude = np.sqrt(2.0 * spectrum * d_omega)
    phase = rng.uniform(0.0, 2.0 * math.pi, k)
    return WaveComponents(omega, amplitude, phase)

"""Sensor models: what the boat's IMU, INS/DVL, compass, GNSS and actuator feedback report.

Every source of error is a named parameter of SensorSpec (units in the comment). The measured motions also
carry the first-order (wave-frequency) oscillation of the hull in waves (seed 000 sec. 2.3: "the
high-frequency part accounts for the oscillations of the measured motion states"), built from the
Environment's JONSWAP components with the encounter frequency of the moving, turning vessel.

Outputs are Signals in the roles of msg_adapters.ROLE_FIELDS (marine frames, SI):
  imu (yaw_rate, accel_x, accel_y, accel_z, heading=NaN: no orientation, REP-145), velocity (u, v, r),
  heading (psi), the controls of the vessel's actuator layout (rudder_angle (delta) and engine_rpm (rpm) of a
  rudder_propeller boat, thruster_port and thruster_starboard (command) of twin thrusters, ...: a control of
  source "state" reports the true actuator level, one of source "command" the command sent, each with the noise
  and resolution fields its Control record names), gnss (lat, lon, alt), odometry (ground truth).
Values are quantised to each sensor's resolution (a power of two, like an ADC's LSB) which also makes
the bags compress well.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping

import numpy as np

from usv_predictor.config import Range
from usv_predictor.errors import ConfigError
from usv_predictor.frames import LocalTangentPlane, wrap_angle
from usv_predictor.physics.actuators import ACTUATOR_LAYOUTS, ActuatorLayout, actuator_layout
from usv_predictor.physics.environment import Environment, wave_components
from usv_predictor.physics.simulator import ActuatorFaults, Trajectory
from usv_predictor.physics.vessel import GRAVITY
from usv_predictor.records import NS_PER_S, Signal

RATE_RANGE = Range(0.1, 1000.0, "Hz")  # output rate of every sensor
DELAY_RANGE = Range(0.0, 5.0, "s")  # hull response after the reported actuator values


@dataclass(frozen=True)
class SensorSpec:
    imu_rate_hz: float = 100.0
    velocity_rate_hz: float = 20.0
    heading_rate_hz: float = 20.0
    actuator_rate_hz: float = 10.0
    gnss_rate_hz: float = 5.0
    truth_rate_hz: float = 20.0
    gyro_noise_std: float = 0.0017  # white noise on the yaw rate (rad/s), ~0.1 deg/s
    gyro_bias: float = 0.0  # constant yaw-rate bias (rad/s); hidden effect `yaw_rate_bias`
    gyro_lsb: float = 2.0**-14  # yaw-rate resolution (rad/s)
    accel_noise_std: float = 0.05  # white noise per axis (m/s^2)
    accel_lsb: float = 2.0**-10  # acceleration resolution (m/s^2)
    velocity_noise_std: float = 0.03  # INS/DVL white noise on u and v (m/s)
    velocity_lsb: float = 2.0**-10  # velocity resolution (m/s)
    heading_noise_std: float = 0.0035  # compass white noise (rad), ~0.2 deg
    heading_offset: float = 0.0  # compass misalignment, reported = true + offset (rad); `heading_offset`
    heading_lsb_deg: float = 2.0**-7  # compass resolution (deg)
    rudder_noise_std: float = 0.0017  # rudder feedback noise (rad)
    rudder_lsb: float = 2.0**-12  # rudder feedback resolution (rad)
    rpm_noise_std: float = 2.0  # engine speed noise (rpm)
    rpm_lsb: float = 0.25  # engine speed resolution (rpm)
    command_noise_std: float = 0.0  # noise on a logged normalised command (-): a log holds what was sent
    command_lsb: float = 2.0**-9  # resolution of a normalised command (-): ~1 us of a 1000-2000 us PWM
    actuator_delay_s: float = 0.0  # the hull responds this long after the reported actuator values (s)
    gnss_noise_std: float = 0.3  # horizontal position noise per axis (m)
    gnss_lsb_deg: float = 2.0**-26  # latitude/longitude resolution (deg), ~1.7 mm
    datum_lat_deg: float = 35.38  # trial area datum: off Rizhao, Shandong (seed 000 sec. 3.1)
    datum_lon_deg: float = 119.56
    wave_motion_gain: float = 0.6  # horizontal hull velocity / wave orbital velocity at encounter (-)
    wave_yaw_gain: float = 0.1  # yaw amplitude / wave slope (-)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not math.isfinite(value):
                raise ConfigError(f"sensor parameter {f.name}={value} must be finite")
            if f.name.endswith("_hz"):
                RATE_RANGE.check(f.name, value, "sensors")
            if (f.name.endswith("_std") or f.name.endswith("_lsb") or f.name.endswith("_lsb_deg")) and value < 0.0:
                raise ConfigError(f"sensor parameter {f.name}={value} must be >= 0")
        DELAY_RANGE.check("actuator_delay_s", self.actuator_delay_s, "sensors")

    def noiseless(self) -> "SensorSpec":
        """Same rates, biases and offsets, no random noise and no quantisation."""
        zero = {f.name: 0.0 for f in fields(self) if f.name.endswith("_std") or "lsb" in f.name}
        return replace(self, **zero)

    def describe(self, layout: ActuatorLayout) -> dict[str, float]:
        """The parameters that shape a recording of a boat of this layout: all but the noise and resolution of
        other layouts' controls (a rudder boat's recording says nothing of thruster commands)."""
        others = {name for other in ACTUATOR_LAYOUTS.values() for c in other.controls
                  for name in (c.noise, c.resolution)}
        own = {name for c in layout.controls for name in (c.noise, c.resolution)}
        return {k: v for k, v in asdict(self).items() if k not in others - own}

    @classmethod
    def from_mapping(cls, raw: Mapping[str, Any], source: str = "<sensors>") -> "SensorSpec":
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(raw) - names)
        if unknown:
            raise ConfigError(f"{source}: unknown sensor parameters {unknown}; known: {sorted(names)}")
        return cls(**{k: float(v) for k, v in raw.items()})


def _quantise(x: np.ndarray, lsb: float) -> np.ndarray:
    return x if lsb <= 0.0 else np.round(x / lsb) * lsb


def _grid(traj: Trajectory, rate_hz: float) -> np.ndarray:
    """Sample times (ns) at rate_hz over the trajectory span, starting at its first sample."""
    span = int(traj.t_ns[-1] - traj.t_ns[0])
    step = NS_PER_S / rate_hz
    return traj.t_ns[0] + np.round(np.arange(int(span // step) + 1) * step).astype(np.int64)


def _at(traj: Trajectory, t_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of (N,) or (N, k) values onto t_ns (clamped at the ends)."""
    t = (t_ns - traj.t_ns[0]).astype(float)
    tt = (traj.t_ns - traj.t_ns[0]).astype(float)
    if values.ndim == 1:
        return np.interp(t, tt, values)
    return np.column_stack([np.interp(t, tt, values[:, k]) for k in range(values.shape[1])])


def _hold(traj: Trajectory, t_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Zero-order hold of (N,) values onto t_ns (a command holds until the next one; clamped at the ends)."""
    index = np.searchsorted(traj.t_ns, t_ns, side="right") - 1
    return values[np.clip(index, 0, len(values) - 1)]


@dataclass(frozen=True)
class WaveMotion:
    """First-order wave-induced motion on the trajectory's time grid (body frame, SI)."""

    u: np.ndarray
    v: np.ndarray
    r: np.ndarray
    psi: np.ndarray
    u_dot: np.ndarray
    v_dot: np.ndarray
    x_n: np.ndarray
    y_e: np.ndarray


def wave_motion(traj: Trajectory, env: Environment, spec: SensorSpec, rng: np.random.Generator) -> WaveMotion:
    """Sum of harmonic responses at the encounter frequency omega_e = |omega - omega^2 U cos(mu) / g|."""
    n = len(traj.t_ns)
    zeros = np.zeros(n)
    comps = wave_components(env, rng)
    if len(comps.omega) == 0:
        return WaveMotion(zeros, zeros, zeros, zeros, zeros, zeros, zeros, zeros)
    t = traj.t_s
    psi = traj.psi_unwrapped
    propagation = math.radians(env.wave_from_deg) + math.pi  # waves travel away from where they come from
    mu = propagation - psi  # (N,) angle between heading and wave propagation
    speed = np.hypot(traj.nu[:, 0], traj.nu[:, 1])
    vel_n, vel_e = np.zeros(n), np.zeros(n)
    yaw, yaw_rate = np.zeros(n), np.zeros(n)
    acc_n, acc_e = np.zeros(n), np.zeros(n)
    disp_n, disp_e = np.zeros(n), np.zeros(n)
    cos_p, sin_p = math.cos(propagation), math.sin(propagation)
    for omega, zeta, phase0 in zip(comps.omega, comps.amplitude, comps.phase):
        omega_e = np.maximum(np.abs(omega - omega**2 * speed * np.cos(mu) / GRAVITY), 0.2 * omega)
        phase = phase0 + np.concatenate([[0.0], np.cumsum(0.5 * (omega_e[1:] + omega_e[:-1]) * np.diff(t))])
        amp_v = spec.wave_motion_gain * omega * zeta  # orbital velocity response (m/s)
        c, s = np.cos(phase), np.sin(phase)
        vel_n += amp_v * c * cos_p
        vel_e += amp_v * c * sin_p
        acc_n -= amp_v * omega_e * s * cos_p
        acc_e -= amp_v * omega_e * s * sin_p
        disp_n += amp_v / omega_e * s * cos_p
        disp_e += amp_v / omega_e * s * sin_p
        amp_yaw = spec.wave_yaw_gain * omega**2 / GRAVITY * zeta * np.sin(2.0 * mu)
        yaw += amp_yaw * s
        yaw_rate += amp_yaw * omega_e * c
    c, s = np.cos(psi), np.sin(psi)
    u = vel_n * c + vel_e * s
    v = -vel_n * s + vel_e * c
    # body-frame derivative of an earth-fixed oscillation: R^T a - r x (u, v)
    u_dot = acc_n * c + acc_e * s + traj.nu[:, 2] * v
    v_dot = -acc_n * s + acc_e * c - traj.nu[:, 2] * u
    return WaveMotion(u, v, yaw_rate, yaw, u_dot, v_dot, disp_n, disp_e)


def measure(traj: Trajectory, env: Environment, spec: SensorSpec = SensorSpec(),
            faults: ActuatorFaults = ActuatorFaults(), seed: int = 0) -> dict[str, Signal]:
    """All sensor signals of one run, keyed by role (plus 'odometry' = ground truth).

    The controls are those of the trajectory's actuator layout. A feedback reports what the crew believes: the
    true level minus the fault's offset of that actuator (the rudder offset); a command log reports the command
    as sent.
    """
    layout = actuator_layout(traj.layout)
    rng = np.random.default_rng(seed)
    waves = wave_motion(traj, env, spec, rng)
    u = traj.nu[:, 0] + waves.u
    v = traj.nu[:, 1] + waves.v
    r = traj.nu[:, 2] + waves.r
    # specific force of the hull in FRD: a = nu_dot + omega x nu, minus gravity (z down)
    a_x = traj.nu_dot[:, 0] + waves.u_dot - r * v
    a_y = traj.nu_dot[:, 1] + waves.v_dot + r * u
    out: dict[str, Signal] = {}

    t = _grid(traj, spec.imu_rate_hz)
    yaw_rate = _at(traj, t, r) + spec.gyro_bias
    imu = np.column_stack([
        _quantise(yaw_rate + rng.normal(0, spec.gyro_noise_std, len(t)), spec.gyro_lsb),
        _quantise(_at(traj, t, a_x) + rng.normal(0, spec.accel_noise_std, len(t)), spec.accel_lsb),
        _quantise(_at(traj, t, a_y) + rng.normal(0, spec.accel_noise_std, len(t)), spec.accel_lsb),
        _quantise(-GRAVITY + rng.normal(0, spec.accel_noise_std, len(t)), spec.accel_lsb),
        np.full(len(t), np.nan),
    ])
    out["imu"] = Signal(t, imu, ("yaw_rate", "accel_x", "accel_y", "accel_z", "heading"))

    t = _grid(traj, spec.velocity_rate_hz)
    vel = np.column_stack([
        _quantise(_at(traj, t, u) + rng.normal(0, spec.velocity_noise_std, len(t)), spec.velocity_lsb),
        _quantise(_at(traj, t, v) + rng.normal(0, spec.velocity_noise_std, len(t)), spec.velocity_lsb),
        # the INS yaw rate comes from the same gyro: same bias, its own noise
        _quantise(_at(traj, t, r) + spec.gyro_bias + rng.normal(0, spec.gyro_noise_std, len(t)), spec.gyro_lsb),
    ])
    out["velocity"] = Signal(t, vel, ("u", "v", "r"))

    t = _grid(traj, spec.heading_rate_hz)
    psi = _at(traj, t, traj.psi_unwrapped
              + waves.psi) + spec.heading_offset + rng.normal(0, spec.heading_noise_std, len(t))
    lsb = math.radians(spec.heading_lsb_deg)
    out["heading"] = Signal(t, wrap_angle(_quantise(psi, lsb))[:, None], ("psi",))

    # Actuator feedback and command logs lead the hull's response by actuator_delay_s (sampled that much later
    # in truth), in the layout's control order (the random numbers come in that order).
    t = _grid(traj, spec.actuator_rate_hz)
    t_true = t + int(round(spec.actuator_delay_s * NS_PER_S))
    columns: dict[str, list[np.ndarray]] = {}
    for control in layout.controls:
        if control.source == "state":
            value = _at(traj, t_true, traj.actuator(control.name)) - faults.offset(control.name)
        else:
            value = _hold(traj, t_true, traj.command(control.name))
        value = value + rng.normal(0, getattr(spec, control.noise), len(t))
        columns.setdefault(control.role, []).append(_quantise(value, getattr(spec, control.resolution)))
    for role, values in columns.items():
        out[role] = Signal(t, np.column_stack(values), layout.fields_of(role))

    t = _grid(traj, spec.gnss_rate_hz)
    plane = LocalTangentPlane(spec.datum_lat_deg, spec.datum_lon_deg)
    x_n = _at(traj, t, traj.eta[:, 0] + waves.x_n) + rng.normal(0, spec.gnss_noise_std, len(t))
    y_e = _at(traj, t, traj.eta[:, 1] + waves.y_e) + rng.normal(0, spec.gnss_noise_std, len(t))
    lat, lon = plane.to_geodetic(x_n, y_e)
    gnss = np.column_stack([_quantise(lat, spec.gnss_lsb_deg), _quantise(lon, spec.gnss_lsb_deg), np.zeros(len(t))])
    out["gnss"] = Signal(t, gnss, ("lat", "lon", "alt"))

    t = _grid(traj, spec.truth_rate_hz)
    truth = np.column_stack([
        _at(traj, t, traj.eta[:, 0]), _at(traj, t, traj.eta[:, 1]), wrap_angle(_at(traj, t, traj.psi_unwrapped)),
        _at(traj, t, traj.nu[:, 0]), _at(traj, t, traj.nu[:, 1]), _at(traj, t, traj.nu[:, 2]),
    ])
    out["odometry"] = Signal(t, truth, ("x_n", "y_e", "psi", "u", "v", "r"))
    return out


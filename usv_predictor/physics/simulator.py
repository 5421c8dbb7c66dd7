"""Time-domain simulation: fixed-step RK4 on the manoeuvring model, dense output at any rate.

The autopilot (a Manoeuvre) is sampled once per integration step (zero-order hold, like a digital
controller). Between steps the solution is reconstructed with cubic Hermite interpolation from the states
and derivatives at the step ends (4th-order accurate, as RK4 itself), so sensors can sample at 100 Hz while
the integrator takes 0.05 s steps: ship dynamics have time constants of seconds.

The autopilot returns a turn command and a propulsion command in the layout's steering and propulsion units
(physics/actuators.py); the layout's command_map turns them into the boat's commands (rudder layouts: the rudder
angle and the engine speed or throttle; twin thrusters: port = p + d/2, starboard = p - d/2).

Output Trajectory (marine convention, SI): eta = [x_n, y_e, psi], nu = [u, v, r] over ground (body FRD),
nu_dot its time derivative, nu_r the velocity through the water, plus the true actuator levels and the commands
(named by the layout's `commands`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from usv_predictor.errors import ConfigError
from usv_predictor.frames import wrap_angle
from usv_predictor.physics.dynamics import ManoeuvringModel, SeaLoads
from usv_predictor.physics.environment import Environment, gust_series
from usv_predictor.records import NS_PER_S

NS = NS_PER_S  # the name tests import from here


Controller = Callable[[float, float, float], "tuple[float, float]"]


class Manoeuvre(Protocol):
    """An autopilot programme (a frozen spec); controller() makes a fresh stateful autopilot for one run."""

    name: str
    duration_s: float
    propulsion: float  # propulsion command of the straight approach (the layout's propulsion unit: rpm, -)

    def controller(self) -> Controller:
        """f(t_s, psi_unwrapped_rad, r) -> (turn command, propulsion command) in the layout's steering and
        propulsion units (rudder layouts: rudder rad and rpm or throttle; twin thrusters: differential, mean)."""


@dataclass(frozen=True)
class ActuatorFaults:
    """Faults between command and hull; the sensors still report what the crew believes."""

    rudder_offset_rad: float = 0.0  # true rudder = reported rudder + offset (mechanical misalignment)
    propeller_side_force: float = 0.0  # transverse propeller force / thrust (-), + to starboard (propeller walk)
    thruster_imbalance: float = 0.0  # k (-): port delivers (1 + k), starboard (1 - k) of its map; + = starboard weaker

    def offset(self, command: str) -> float:
        """What the actuator adds to the command named `command` (the rudder offset to the rudder angle)."""
        return self.rudder_offset_rad if command == "delta" else 0.0


@dataclass(frozen=True)
class Trajectory:
    t_ns: np.ndarray  # (N,) int64
    eta: np.ndarray  # (N, 3) x_n (m), y_e (m), psi (rad, wrapped)
    nu: np.ndarray  # (N, 3) u, v (m/s) over ground, r (rad/s)
    nu_dot: np.ndarray  # (N, 3) du/dt, dv/dt (m/s^2), dr/dt (rad/s^2)
    nu_r: np.ndarray  # (N, 3) velocity relative to the water
    actuators: np.ndarray  # (N, 2) true actuator levels, named by `names` (delta rad, rpm; port, starboard -)
    commands: np.ndarray  # (N, 2) the commands, as the autopilot sent them (zero-order hold)
    names: tuple[str, ...]  # the layout's commands: names of the columns of actuators and commands
    layout: str  # the vessel's actuator layout (physics/actuators.py): which controls its sensors report
    psi_unwrapped: np.ndarray  # (N,) continuous heading (rad)
    info: dict = field(default_factory=dict)

    @property
    def t_s(self) -> np.ndarray:
        return (self.t_ns - self.t_ns[0]) / NS_PER_S

    def actuator(self, name: str) -> np.ndarray:
        """(N,) true level of the actuator `name` (ConfigError naming the layout's otherwise)."""
        return self.actuators[:, self._column(name)]

    def command(self, name: str) -> np.ndarray:
        """(N,) the command `name` as sent."""
        return self.commands[:, self._column(name)]

    def _column(self, name: str) -> int:
        if name not in self.names:
            raise ConfigError(f"the trajectory's actuators are {self.names}, not {name!r}")
        return self.names.index(name)

    # the rudder layouts' columns by their names
    rudder = property(lambda self: self.actuator("delta"), doc="(N,) true rudder angle (rad)")
    rpm = property(lambda self: self.actuator("rpm"), doc="(N,) true engine speed (rpm)")
    rudder_cmd = property(lambda self: self.command("delta"), doc="(N,) rudder command (rad)")
    rpm_cmd = property(lambda self: self.command("rpm"), doc="(N,) engine command (rpm)")


def initial_state(model: ManoeuvringModel, command: float, heading_rad: float) -> list[float]:
    """Steady straight running at the propulsion command through the water: [x_n, y_e, psi, u_r, v_r, r, a, b]."""
    return model.initial_state(command, heading_rad)


def sea_loads(env: Environment, t_s: np.ndarray, wind_speed: np.ndarray) -> list[SeaLoads]:
    """The environment resolved at each time of t_s (one SeaLoads per time)."""
    current = [env.current_ned(t) for t in t_s]
    accel = [env.current_accel_ned(t) for t in t_s]
    wind_from, wave_from = math.radians(env.wind_from_deg), math.radians(env.wave_from_deg)
    amplitude = 0.5 * env.wave_height
    return [SeaLoads(c[0], c[1], a[0], a[1], float(w), wind_from, amplitude, wave_from)
            for c, a, w in zip(current, accel, wind_speed)]


def simulate(model: ManoeuvringModel, manoeuvre: Manoeuvre, env: Environment | None = None, *,
             heading_deg: float = 0.0, dt: float = 0.05, output_rate_hz: float = 100.0,
             faults: ActuatorFaults = ActuatorFaults(), seed: int = 0, start_ns: int = 0) -> Trajectory:
    """Integrate one manoeuvre from steady straight running; return the trajectory at output_rate_hz."""
    env = env or Environment()
    if not (0.0 < dt <= 0.2):
        raise ConfigError(f"integration step dt={dt} s is outside (0, 0.2]")
    if manoeuvre.duration_s <= 0.0:
        raise ConfigError(f"manoeuvre {manoeuvre.name}: duration must be > 0 s")
    steps = int(round(manoeuvre.duration_s / dt))
    rng = np.random.default_rng(seed)
    t_nodes = np.arange(steps + 1) * dt
    # The sea is held over each step (gusts and a turning current vary over tens of seconds).
    sea = sea_loads(env, t_nodes, gust_series(env, t_nodes, rng))

    model = model.with_faults(faults.propeller_side_force, faults.thruster_imbalance)
    layout = model.vessel.actuator_layout
    x = initial_state(model, manoeuvre.propulsion, math.radians(heading_deg))
    states, derivs, commands = [], [], []
    offset_a, offset_b = (faults.offset(name) for name in layout.commands)
    to_commands = layout.to_commands
    f = model.derivative
    command = manoeuvre.controller()
    for i in range(steps + 1):
        t = i * dt
        cmd_a, cmd_b = to_commands(*command(t, x[2], x[5]))
        true_a, true_b = cmd_a + offset_a, cmd_b + offset_b  # what the actuators are driven to
        k1 = f(x, true_a, true_b, sea[i])
        states.append(x)
        derivs.append(k1)
        commands.append((cmd_a, cmd_b))
        if i == steps:
            break
        h2 = 0.5 * dt
        k2 = f([a + h2 * b for a, b in zip(x, k1)], true_a, true_b, sea[i])
        k3 = f([a + h2 * b for a, b in zip(x, k2)], true_a, true_b, sea[i])
        k4 = f([a + dt * b for a, b in zip(x, k3)], true_a, true_b, sea[i])
        h6 = dt / 6.0
        x = [a + h6 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(x, k1, k2, k3, k4)]
        if not all(map(math.isfinite, x)):
            raise ConfigError(f"simulation of {manoeuvre.name} diverged at t={t:.2f} s (state {x})")
    traj = _dense_output(model, env, np.array(states), np.array(derivs), np.array(commands), dt, output_rate_hz,
                         manoeuvre.duration_s, start_ns)
    traj.info.update(manoeuvre=manoeuvre.name, dt=dt, output_rate_hz=output_rate_hz, seed=seed)
    return traj


def current_arrays(env: Environment, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Current velocity and its time derivative (north, east) at the times t_s, vectorised."""
    if env.has_current_step:
        return env.current_arrays(t_s)
    omega = math.radians(env.current_turn_rate_deg_s)
    direction = math.radians(env.current_to_deg) + omega * t_s
    c, s = np.cos(direction), np.sin(direction)
    speed = env.current_speed
    return np.column_stack([speed * c, speed * s]), np.column_stack([-speed * omega * s, speed * omega * c])


def _hermite(y0, y1, f0, f1, theta, h):
    """Cubic Hermite value and derivative; arrays broadcast over (M, k)."""
    t2, t3 = theta * theta, theta * theta * theta
    value = (2 * t3 - 3 * t2 + 1) * y0 + (t3 - 2 * t2 + theta) * h * f0 + (-2 * t3 + 3 * t2) * y1 + (t3 - t2) * h * f1
    slope = ((6 * t2 - 6 * theta) * y0 + (-6 * t2 + 6 * theta) * y1) / h + (3 * t2 - 4 * theta + 1) * f0 \
        + (3 * t2 - 2 * theta) * f1
    return value, slope


def _dense_output(model, env, states, derivs, commands, dt, rate_hz, duration_s, start_ns) -> Trajectory:
    n_out = int(math.floor(duration_s * rate_hz + 1e-9)) + 1
    t_out_ns = np.round(np.arange(n_out) * (NS_PER_S / rate_hz)).astype(np.int64)
    t_out = t_out_ns / NS_PER_S
    idx = np.minimum((t_out / dt).astype(np.int64), len(states) - 2)
    theta = ((t_out - idx * dt) / dt)[:, None]
    x, x_dot = _hermite(states[idx], states[idx + 1], derivs[idx], derivs[idx + 1], theta, dt)
    psi = x[:, 2]
    r, r_dot = x[:, 5], x_dot[:, 5]
    c, s = np.cos(psi), np.sin(psi)
    cur, cur_dot = current_arrays(env, t_out)  # (N, 2) each
    u_c = cur[:, 0] * c + cur[:, 1] * s
    v_c = -cur[:, 0] * s + cur[:, 1] * c
    # d/dt of the current seen in the rotating body frame: R^T dVc/dt + r * [v_c, -u_c]
    u_c_dot = cur_dot[:, 0] * c + cur_dot[:, 1] * s + r * v_c
    v_c_dot = -cur_dot[:, 0] * s + cur_dot[:, 1] * c - r * u_c
    nu_r = x[:, 3:6]
    nu = np.column_stack([nu_r[:, 0] + u_c, nu_r[:, 1] + v_c, r])
    nu_dot = np.column_stack([x_dot[:, 3] + u_c_dot, x_dot[:, 4] + v_c_dot, r_dot])
    cmd = commands[idx]  # zero-order hold, as the autopilot sent it
    return Trajectory(
        t_ns=t_out_ns + start_ns,
        eta=np.column_stack([x[:, 0], x[:, 1], wrap_angle(psi)]),
        nu=nu, nu_dot=nu_dot, nu_r=nu_r.copy(),
        actuators=model.actuator_levels(x[:, 6:8], cmd), commands=cmd, names=model.vessel.actuator_layout.commands,
        layout=model.vessel.layout, psi_unwrapped=psi, info={},
    )

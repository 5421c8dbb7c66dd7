"""The low-order manoeuvring model: Nomoto's yaw response with a speed equation and a drift proportional to r.

What a record of one zig-zag at one speed, without propulsion data, can determine. Yaw (Nomoto et al. 1957;
Fossen 2021 eq. 7.38 and 7.31), on the layout's turn command s (physics/actuators.py `steering`: the rudder angle
delta of a rudder boat, port - starboard of a twin-thruster boat; + turns to starboard):

    first order   T r_dot + r = K (s - s_0 - s_p p)
    second order  T1 T2 r_ddot + (T1 + T2) r_dot + r = K (s - s_0 - s_p p + T3 s_dot),   T1 > T2 > 0

s_0 + s_p p is the command of no turn: a rudder's offset angle s_0 (s_p = 0), or, where the turn command is a
difference of the propulsion controls (twin thrusters), a thrust imbalance, which grows with the thrust: s_p p with p
the propulsion level (s_0 = 0), so a model identified at one speed keeps its offset right at another.

The second order runs as its partial fractions K (1 + T3 p) / ((1 + T1 p)(1 + T2 p)) = A / (1 + T1 p) + B / (1 + T2 p),
A = K (T1 - T3) / (T1 - T2), B = K (T3 - T2) / (T1 - T2): two first-order modes r = r_1 + r_2, the measured start
rate split between them as a steady turn splits it (r_1 / r = A / K). Speed, a first-order response to a speed set
point less the speed lost in a turn (the drag of the drift and of the rudder, which grows as r^2):

    u_dot = (u_c - u) / T_u - k_r r^2
    u_c   = u_0 + u_p p        "command": the layout's propulsion level p (rpm, throttle, the mean thruster command)
    u_c   = u_ref              "reference": no propulsion data (rudder_only), or a propulsion level the data do not
                               vary: the surge speed of the reference state (forward's third argument: the
                               manoeuvre's approach, whose engine setting the boat holds; None: the start state)

Sway: a drift proportional to the yaw rate, v = k_v r (k_v in m: minus the distance of the pivot point ahead of
the origin, the steady linear model's v / r = const at any speed), so the track is predicted. Kinematics: Fossen 2021
eq. 2.40, x_n_dot = u cos psi - v sin psi, y_e_dot = u sin psi + v cos psi.

Discretisation (never diverges for T_i, T_u > 0): each yaw mode is integrated exactly over a step for the turn
command moving linearly between samples (first-order hold, as models/greybox.py: controls[:, k] at step k, the last
one held): with g(t) = g0 + b t the mode's target, r(dt) = g1 - b T + (r0 - g0 + b T) exp(-dt / T) and the heading
gained int_0^dt r = g0 dt + b (dt^2 / 2 - T dt) + (r0 - g0 + b T) T (1 - exp(-dt / T)); the speed by the exponential
integrator for the mean of the step's u_c and r^2; the position by the trapezoidal rule.

Interface (the model artifact's, models/artifact.py):
    forward(state (B, 4) [u, v, r, psi], controls (B, H, C) in the layout's columns, reference (B, 4) | None)
      -> (1, B, H, 6) [u, v, r, x_n, y_e, psi] at dt, 2 dt, ... H dt, positions relative to the start (NED, m).
NomotoRollout is the TorchScript form the file carries; numpy_rollout the same arithmetic in numpy (what the fit
runs, and what predictions run once loading.py checked it equal to the file's); fitting: fitting/nomoto_fit.py.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, List, Mapping, Optional, Sequence

import numpy as np
import torch
from numba import njit
from torch import Tensor, nn

from usv_predictor.errors import ModelError
from usv_predictor.physics.actuators import ActuatorLayout, actuator_layout
from usv_predictor.physics.kernel import CACHED

FAMILY = "nomoto"
ORDERS = (1, 2)
SPEED_MODES = ("reference", "command")
MIN_TIME_CONSTANT_S = 1e-3  # (s) time constants are kept above this (exp(-dt / T) stays a number)
SECOND_ORDER_GAP = 1e-6  # (-) T2 <= T1 (1 - this): the partial fractions stay finite
NUMPY_FORM = "compiled numpy (models/nomoto.NumpyNomotoRollout, checked equal to the file's rollout)"


@dataclass(frozen=True)
class NomotoCoefficients:
    """The identified constants of the low-order model (module docstring)."""

    order: int  # 1 or 2
    K: float  # (rad/s per turn-command unit) steady yaw rate gain
    T1: float  # (s) the (first) yaw time constant
    T2: float  # (s) second order: the second time constant (0 for first order)
    T3: float  # (s) second order: the turn command's lead (0 for first order)
    s_0: float  # (turn-command unit) the command of no turn (a rudder offset: delta_0)
    T_u: float  # (s) surge time constant
    k_r: float  # (m / rad^2) speed loss in a turn: u_dot gets -k_r r^2
    k_v: float  # (m) drift: v = k_v r
    speed_mode: str  # "reference" or "command"
    u_0: float = 0.0  # (m/s) command: u_c = u_0 + u_p p
    u_p: float = 0.0  # (m/s per propulsion unit) command
    s_p: float = 0.0  # (turn-command unit per propulsion unit) the offset's share proportional to the propulsion level

    def __post_init__(self) -> None:
        if self.order not in ORDERS:
            raise ModelError(f"Nomoto order {self.order}: expected one of {ORDERS}")
        if self.speed_mode not in SPEED_MODES:
            raise ModelError(f"Nomoto speed mode {self.speed_mode!r}: expected one of {SPEED_MODES}")
        values = asdict(self)
        bad = [k for k, v in values.items() if isinstance(v, float) and not math.isfinite(v)]
        if bad:
            raise ModelError(f"Nomoto coefficients {bad} are not finite")
        if self.T1 < MIN_TIME_CONSTANT_S or self.T_u < MIN_TIME_CONSTANT_S:
            raise ModelError(f"Nomoto time constants T1 {self.T1:g} s and T_u {self.T_u:g} s must be >= "
                             f"{MIN_TIME_CONSTANT_S:g} s")
        if self.order == 2 and not MIN_TIME_CONSTANT_S <= self.T2 <= self.T1 * (1.0 - SECOND_ORDER_GAP):
            raise ModelError(f"second-order Nomoto: T2 {self.T2:g} s must lie in [{MIN_TIME_CONSTANT_S:g}, T1 = "
                             f"{self.T1:g}) s")

    def modes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(time constants (M,) s, gains (M,), shares (M,)): the first-order modes whose sum is r (module
        docstring's partial fractions); shares split a measured r between them."""
        if self.order == 1:
            return np.array([self.T1]), np.array([self.K]), np.array([1.0])
        gap = self.T1 - self.T2
        shares = np.array([(self.T1 - self.T3) / gap, (self.T3 - self.T2) / gap])
        return np.array([self.T1, self.T2]), self.K * shares, shares

    def steady_turn(self, steering: float, u_c: float, propulsion: float = 0.0) -> dict[str, float]:
        """The steady turn of a held command: r = K (s - s_0 - s_p p), u = u_c - T_u k_r r^2, v = k_v r; radius
        U / |r| (m) and drift angle atan2(v, u) (deg)."""
        r = self.K * (steering - self.s_0 - self.s_p * propulsion)
        u = u_c - self.T_u * self.k_r * r * r
        v = self.k_v * r
        speed = math.hypot(u, v)
        return {"r_rad_s": r, "u_mps": u, "v_mps": v, "radius_m": speed / abs(r) if r != 0.0 else math.inf,
                "drift_deg": math.degrees(math.atan2(v, u))}

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, raw: Mapping[str, Any], source: str) -> NomotoCoefficients:
        try:
            return cls(**{k: (str(raw[k]) if k == "speed_mode" else int(raw[k]) if k == "order" else float(raw[k]))
                          for k in cls.__dataclass_fields__})
        except (KeyError, TypeError, ValueError) as err:
            raise ModelError(f"{source}: the Nomoto coefficients are incomplete or not numbers ({err})") from err


def layout_weights(layout: ActuatorLayout) -> tuple[np.ndarray, np.ndarray]:
    """(steering (C,), propulsion (C,)) weights over the layout's control columns (physics/actuators.py)."""
    names = list(layout.control_names)
    steering = np.array([float(layout.steering.get(n, 0.0)) for n in names])
    propulsion = np.array([float(layout.propulsion.get(n, 0.0)) for n in names])
    return steering, propulsion


# ---------------------------------------------------------------------------------------------- numpy

def numpy_rollout(c: NomotoCoefficients, steering_w: np.ndarray, propulsion_w: np.ndarray, dt: float,
                  state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """(1, B, H, 6) [u, v, r, x_n, y_e, psi] from state (B, 4) and controls (B, H, C): the module docstring's
    discretisation, the same arithmetic as NomotoRollout.forward (float64), its steps compiled (_steps)."""
    tau, gains, shares = c.modes()  # (M,)
    batch, steps = controls.shape[0], controls.shape[1]
    p = controls @ propulsion_w  # (B, H) the propulsion level (0 without one)
    s = controls @ steering_w - c.s_0 - c.s_p * p  # (B, H) turn command less its offset
    nxt = np.concatenate([s[:, 1:], s[:, -1:]], axis=1)  # (B, H) the command at the step's end (last held)
    if c.speed_mode == "command":
        u_set = c.u_0 + c.u_p * 0.5 * (p + np.concatenate([p[:, 1:], p[:, -1:]], axis=1))  # (B, H) the step's mean
    else:
        ref = state if reference is None else reference
        u_set = np.broadcast_to(ref[:, 0:1], (batch, steps))  # (B, H)
    out = np.empty((1, batch, steps, 6))
    _steps(tau, gains, shares, np.ascontiguousarray(s, dtype=np.float64), np.ascontiguousarray(nxt, dtype=np.float64),
           np.ascontiguousarray(u_set, dtype=np.float64), np.ascontiguousarray(state, dtype=np.float64), float(dt),
           float(c.T_u), float(c.k_r), float(c.k_v), out[0])
    return out


@njit(cache=CACHED, nogil=True)
def _steps(tau: np.ndarray, gains: np.ndarray, shares: np.ndarray, s: np.ndarray, nxt: np.ndarray, u_set: np.ndarray,
           state: np.ndarray, dt: float, t_u: float, k_r: float, k_v: float, out: np.ndarray) -> None:
    """out (B, H, 6) of the rollout: each row's steps, as NomotoRollout.forward computes them."""
    modes = tau.shape[0]
    decay = np.exp(-dt / tau)
    decay_u = math.exp(-dt / t_u)
    r_modes = np.empty(modes)
    for b in range(s.shape[0]):
        u, psi = state[b, 0], state[b, 3]
        r = 0.0
        for m in range(modes):
            r_modes[m] = state[b, 2] * shares[m]
            r += r_modes[m]
        v = k_v * r
        x, y = 0.0, 0.0
        for k in range(s.shape[1]):
            gained, r_next = 0.0, 0.0
            for m in range(modes):
                g0 = gains[m] * s[b, k]
                g1 = gains[m] * nxt[b, k]
                slope = (g1 - g0) / dt
                lead = r_modes[m] - g0 + slope * tau[m]
                r_modes[m] = g1 - slope * tau[m] + lead * decay[m]
                gained += g0 * dt + slope * (0.5 * dt * dt - tau[m] * dt) + lead * tau[m] * (1.0 - decay[m])
                r_next += r_modes[m]
            psi_next = psi + gained
            target = u_set[b, k] - t_u * k_r * 0.5 * (r * r + r_next * r_next)
            u_next = target + (u - target) * decay_u
            v_next = k_v * r_next
            cos0, sin0, cos1, sin1 = math.cos(psi), math.sin(psi), math.cos(psi_next), math.sin(psi_next)
            x = x + 0.5 * dt * (u * cos0 - v * sin0 + u_next * cos1 - v_next * sin1)
            y = y + 0.5 * dt * (u * sin0 + v * cos0 + u_next * sin1 + v_next * cos1)
            u, v, r, psi = u_next, v_next, r_next, psi_next
            out[b, k, 0], out[b, k, 1], out[b, k, 2] = u, v, r
            out[b, k, 3], out[b, k, 4], out[b, k, 5] = x, y, psi


class NumpyNomotoRollout:
    """The file's rollout run by numpy_rollout (what `replay evaluate` and the node call once loading.py checked it
    equal to the file's module): called as the module is, tensors (B, 4), (B, H, C), (B, 4) | None -> tensor
    (1, B, H, 6); `rollout` takes and gives numpy arrays."""

    def __init__(self, coefficients: NomotoCoefficients, steering_w: np.ndarray, propulsion_w: np.ndarray,
                 dt: float) -> None:
        self.coefficients, self.dt = coefficients, float(dt)
        self.steering_w, self.propulsion_w = np.asarray(steering_w, float), np.asarray(propulsion_w, float)

    def rollout(self, state: np.ndarray, controls: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
        return numpy_rollout(self.coefficients, self.steering_w, self.propulsion_w, self.dt, state, controls, reference)

    def __call__(self, state: Tensor, controls: Tensor, reference: Optional[Tensor] = None) -> Tensor:
        out = self.rollout(state.detach().double().numpy(), controls.detach().double().numpy(),
                           None if reference is None else reference.detach().double().numpy())
        return torch.from_numpy(out)


# ---------------------------------------------------------------------------------------------- torch

class NomotoRollout(nn.Module):
    """The TorchScript rollout of the artifact (module docstring; numpy_rollout's arithmetic in torch)."""

    def __init__(self, coefficients: NomotoCoefficients, layout: ActuatorLayout, dt: float) -> None:
        super().__init__()
        tau, gains, shares = coefficients.modes()
        steering, propulsion = layout_weights(layout)
        f64 = torch.float64
        self.dt = float(dt)
        self.register_buffer("tau", torch.tensor(tau, dtype=f64))  # (M,) s
        self.register_buffer("gains", torch.tensor(gains, dtype=f64))  # (M,)
        self.register_buffer("shares", torch.tensor(shares, dtype=f64))  # (M,)
        self.register_buffer("steering_w", torch.tensor(steering, dtype=f64))  # (C,)
        self.register_buffer("propulsion_w", torch.tensor(propulsion, dtype=f64))  # (C,)
        self.register_buffer("constants", torch.tensor(  # s_0, T_u (s), k_r (m/rad^2), k_v (m), u_0 (m/s), u_p, s_p
            [coefficients.s_0, coefficients.T_u, coefficients.k_r, coefficients.k_v, coefficients.u_0,
             coefficients.u_p, coefficients.s_p], dtype=f64))
        self.command_speed = coefficients.speed_mode == "command"

    def forward(self, state: Tensor, controls: Tensor, reference: Optional[Tensor] = None) -> Tensor:
        dt = self.dt
        s_0, t_u, k_r, k_v = self.constants[0], self.constants[1], self.constants[2], self.constants[3]
        state = state.to(torch.float64)
        controls = controls.to(torch.float64)
        batch, steps = controls.shape[0], controls.shape[1]
        p = torch.matmul(controls, self.propulsion_w)  # (B, H)
        s = torch.matmul(controls, self.steering_w) - s_0 - self.constants[6] * p  # (B, H)
        nxt = torch.cat([s[:, 1:], s[:, -1:]], dim=1)  # (B, H)
        if self.command_speed:
            u_set = self.constants[4] + self.constants[5] * 0.5 * (p + torch.cat([p[:, 1:], p[:, -1:]], dim=1))
        else:
            ref = state if reference is None else reference.to(torch.float64)
            u_set = ref[:, 0:1].expand(batch, steps)  # (B, H)
        tau = self.tau[None, :]  # (1, M)
        decay = torch.exp(-dt / tau)
        decay_u = torch.exp(-dt / t_u)
        u = state[:, 0]
        r_modes = state[:, 2:3] * self.shares[None, :]  # (B, M)
        psi = state[:, 3]
        r = r_modes.sum(dim=1)
        v = k_v * r
        x = torch.zeros_like(u)
        y = torch.zeros_like(u)
        rows: List[Tensor] = []
        for k in range(steps):
            g0 = self.gains[None, :] * s[:, k:k + 1]  # (B, M)
            g1 = self.gains[None, :] * nxt[:, k:k + 1]
            slope = (g1 - g0) / dt
            lead = r_modes - g0 + slope * tau
            r_next_modes = g1 - slope * tau + lead * decay
            psi_next = psi + (g0 * dt + slope * (0.5 * dt * dt - tau * dt) + lead * tau * (1.0 - decay)).sum(dim=1)
            r_next = r_next_modes.sum(dim=1)
            target = u_set[:, k] - t_u * k_r * 0.5 * (r * r + r_next * r_next)
            u_next = target + (u - target) * decay_u
            v_next = k_v * r_next
            cos0, sin0, cos1, sin1 = torch.cos(psi), torch.sin(psi), torch.cos(psi_next), torch.sin(psi_next)
            x = x + 0.5 * dt * (u * cos0 - v * sin0 + u_next * cos1 - v_next * sin1)
            y = y + 0.5 * dt * (u * sin0 + v * cos0 + u_next * sin1 + v_next * cos1)
            u, v, r, psi, r_modes = u_next, v_next, r_next, psi_next, r_next_modes
            rows.append(torch.stack([u, v, r, x, y, psi], dim=1))  # (B, 6)
        return torch.stack(rows, dim=1).unsqueeze(0)  # (1, B, H, 6)


# ---------------------------------------------------------------------------------------------- artifact

def nomoto_metadata(coefficients: NomotoCoefficients, layout: ActuatorLayout, dt: float, *, vessel_name: str,
                    training_data_sha256: str, identification: Mapping[str, Any],
                    horizon_steps: int = 120) -> dict[str, Any]:
    """The artifact metadata (models/artifact.py REQUIRED_KEYS) of a low-order model; `identification` the fit's
    record (fitting/nomoto_fit.NomotoFit.to_json: estimates, intervals, data)."""
    from usv_predictor.models.artifact import OUTPUT_LAYOUT, UNITS

    return {
        "model_type": FAMILY, "feature_set": f"Nomoto order {coefficients.order}", "feature_names": [],
        "state_layout": ["u", "v", "r", "psi"], "control_layout": list(layout.control_names),
        "actuator_layout": layout.name, "output_layout": list(OUTPUT_LAYOUT), "dt": float(dt),
        "horizon_steps": int(horizon_steps), "normalisation": {}, "vessel": vessel_name,
        "training_data_sha256": training_data_sha256, "ensemble_size": 1,
        "architecture": {"order": coefficients.order, "coefficients": coefficients.to_json(),
                         "speed_reference": ("the reference state's surge speed (forward's third argument: the "
                                             "manoeuvre's approach; none: the start state)"
                                             if coefficients.speed_mode == "reference"
                                             else "u_0 + u_p x the layout's propulsion level")},
        "training": {"identification": dict(identification)},
        "units": {**UNITS, "K": "rad/s per turn-command unit", "T1": "s", "T2": "s", "T3": "s", "T_u": "s",
                  "k_r": "m/rad^2", "k_v": "m", "u_0": "m/s", "u_p": "m/s per propulsion unit"},
    }


def export_nomoto(path: str, coefficients: NomotoCoefficients, vessel: Any, dt: float, *, training_data_sha256: str,
                  identification: Mapping[str, Any], horizon_steps: int = 120) -> Any:
    """Write the TorchScript NomotoRollout with its metadata and the vessel file embedded (artifact.export_module);
    the loaded ModelArtifact."""
    from usv_predictor.models.artifact import export_module

    layout = vessel.actuator_layout
    module = NomotoRollout(coefficients, layout, dt)
    meta = nomoto_metadata(coefficients, layout, dt, vessel_name=vessel.name, training_data_sha256=training_data_sha256,
                           identification=identification, horizon_steps=horizon_steps)
    return export_module(path, module, meta, vessel=vessel)


def coefficients_of(metadata: Mapping[str, Any], source: str) -> NomotoCoefficients:
    """The coefficients a Nomoto artifact's metadata carries (ModelError naming `source` when absent)."""
    architecture = metadata.get("architecture")
    raw = architecture.get("coefficients") if isinstance(architecture, Mapping) else None
    if not isinstance(raw, Mapping):
        raise ModelError(f"{source}: a {FAMILY} model without architecture.coefficients")
    return NomotoCoefficients.from_json(raw, source)


def numpy_form(metadata: Mapping[str, Any], source: str) -> NumpyNomotoRollout:
    """The numpy rollout of a Nomoto artifact, from its metadata's coefficients and its layout's weights."""
    layout = actuator_layout(str(metadata.get("actuator_layout", "")))
    steering, propulsion = layout_weights(layout)
    return NumpyNomotoRollout(coefficients_of(metadata, source), steering, propulsion, float(metadata["dt"]))


def probe_inputs(control_count: int, steps: int = 60, batch: int = 3,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(state (B, 4), controls (B, H, C), reference (B, 4)): varied inputs on which two forms of a rollout are compared
    (moving commands, turning starts)."""
    rng = np.random.default_rng(seed)
    state = np.column_stack([rng.uniform(0.5, 2.0, batch), rng.uniform(-0.1, 0.1, batch),
                             rng.uniform(-0.2, 0.2, batch), rng.uniform(-3.0, 3.0, batch)])
    t = np.arange(steps)[None, :, None]
    controls = 0.4 * np.sin(0.15 * t + rng.uniform(0, 6, (batch, 1, control_count))) \
        + rng.uniform(0.2, 0.6, (batch, 1, control_count))
    reference = state + np.column_stack([rng.uniform(0.0, 0.3, batch), np.zeros((batch, 3))])
    return state, controls, reference


def check_equal(fast: NumpyNomotoRollout, module: Any, tolerance: float = 1e-9) -> None:
    """ModelError when the numpy form differs from the file's module on probe_inputs by more than `tolerance`
    (m, m/s, rad)."""
    state, controls, reference = probe_inputs(len(fast.steering_w))
    with torch.inference_mode():
        want = module(torch.from_numpy(state), torch.from_numpy(controls), torch.from_numpy(reference)).double().numpy()
    have = fast.rollout(state, controls, reference)
    worst = float(np.max(np.abs(have - want))) if have.shape == want.shape else math.inf
    if not worst <= tolerance:
        raise ModelError(f"the numpy Nomoto rollout differs from the file's by {worst:.3g} (> {tolerance:g})")


def describe(coefficients: NomotoCoefficients, intervals: Mapping[str, Sequence[float]] | None = None) -> str:
    """One line: the order, K, T's, s_0, speed and drift constants (with their 95 % intervals when given)."""
    def part(name: str, value: float, unit: str) -> str:
        ci = (intervals or {}).get(name)
        shown = f"{name} {value:.4g}{unit}"
        return shown + (f" [{ci[0]:.4g}, {ci[1]:.4g}]" if ci is not None else "")

    c = coefficients
    parts = [part("K", c.K, " 1/s"), part("T1", c.T1, " s")]
    if c.order == 2:
        parts += [part("T2", c.T2, " s"), part("T3", c.T3, " s")]
    parts += [part("s_p", c.s_p, "") if c.s_p else part("s_0", c.s_0, ""), part("T_u", c.T_u, " s"),
              part("k_r", c.k_r, " m"), part("k_v", c.k_v, " m")]
    if c.speed_mode == "command":
        parts += [part("u_0", c.u_0, " m/s"), part("u_p", c.u_p, "")]
    return f"Nomoto order {c.order} (speed set point: {c.speed_mode}): " + ", ".join(parts)

"""The one-step motion network of seed 000 sec. 2.1 (Fig. 1), in one readable file.

    features x (B, F)                      F from a feature set (features.py: F0 eq. 11, NAF eq. 24, NTF eq. 26)
      -> global normalisation              (x - mean) / std, statistics of the training data, stored as buffers
      -> [Linear(W) -> BatchNorm1d (eq. 3-4) -> activation] x depth
      -> Linear(3)                         normalised target
      -> de-normalisation                  next state nu_{k+1} = [u, v, r] (B, 3)

Activations: tanh (eq. 2) or clippedReLU (eq. 1: 0 below 0, x up to `ceiling`, `ceiling` above).

Target (`predict_increment`, default True): the network predicts the normalised increment
(nu_{k+1} - nu_k - mean) / std and forward() adds nu_k (the first three features, always u, v, r)
back. Why: at 2 Hz nu_{k+1} differs from nu_k by a few per cent, so an absolute target spends the
network's capacity on copying its input and its loss is dominated by the (easy) surge speed; the
increment is the dynamics proper (seed 000 eq. 8 error). benchmarks/bench_train.py compares both: on
the shipped sea trial (500 epochs, NTF) the validation one-step RMSE of u is 0.100 m/s against 0.107 m/s
for the absolute target (v and r about equal; most of what is left is sensor and wave noise).
`predict_increment=False` is the paper's absolute target [u, v, r]_{k+1} (eq. 7).

Units are SI (m/s, rad/s, rad) and rpm; the model works in float32 like the paper's toolbox.
`fold_batch_norm()` folds the running statistics into the preceding Linear for inference;
`affine_layers()` goes further (normalisation folded as well) for the TorchScript rollout.

The closed-loop rollout (DnnRollout, the artifact's module) is seed 000 Fig. 3: the predicted [u, v, r] is
fed back and the features (data/features.py) are recomputed each step from it and the integrated heading. Kinematics
(Fossen 2021 eq. 2.40, 3-DOF) integrated with the trapezoidal rule over each step:

    psi_{k+1} = psi_k + dt/2 (r_k + r_{k+1})
    [x_n, y_e]_{k+1} = [x_n, y_e]_k + dt/2 (R(psi_k) [u_k, v_k] + R(psi_{k+1}) [u_{k+1}, v_{k+1}]),
    R(psi) [u, v] = [u cos psi - v sin psi, u sin psi + v cos psi]   (north, east)

Seed 000 eq. 9 is the rectangle-rule version of the same sums, T sum R(psi_i) [u_i, v_i], written with
x east and y north and with the measured psi_i; for constant velocity and heading both give the same
track, the trapezoidal rule is second-order accurate where eq. 9 is first-order (and a turn at 2 Hz
is coarse). Here psi is not measured but integrated from the predicted r.

For speed (node budget: p99 <= 1.5 ms for B=1, H=120) the network is folded into plain affine maps
(normalisation and batch norm folded, models.dnn.DnnModel.affine_layers) and each step is a few
batched matrix products over the ensemble: the controls' share of the first layer is computed for all
steps before the loop, the state update z_{k+1} = z_k A + c + h W (z = [u, v, r, psi]) folds the
increment and the heading integration into the output layer, positions are integrated after the loop
(they do not feed back). The node and `replay evaluate` run this network fused once more at load time, from
the artifact's buffers: stepped with numpy (NumpyDnnRollout: bias units, block-diagonal layers for one state,
numpy's fast tanh and AVX-512 BLAS), else with TorchScript (FusedDnnRollout: tanh as sigmoid with its shift and
scale folded into the weights, no allocation or slicing op in the step loop); the artifact keeps DnnRollout.
"""
from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any, List, Mapping, Sequence

import numpy as np
import torch
from torch import nn

from usv_predictor.data.features import HEADING_COLUMNS, HEADING_SETS, STATE_NAMES, feature_names, feature_units
from usv_predictor.errors import ConfigError, ModelError
from usv_predictor.models.artifact import (DEFAULT_HORIZON_STEPS, MODEL_RUN_ERRORS, OUTPUT_LAYOUT, UNITS, ModelArtifact,
                                          export_module, failure_reason, quiet_jit)
from usv_predictor.physics.actuators import DEFAULT_LAYOUT, ActuatorLayout, actuator_layout
from usv_predictor.physics.vessel import Vessel

ACTIVATIONS = ("tanh", "clipped_relu")
MIN_STD = 1e-6  # a (nearly) constant input, e.g. one engine speed in the data, is centred, not scaled


@dataclass(frozen=True)
class DnnConfig:
    """Everything that rebuilds the network (saved in the artifact as `architecture`)."""

    feature_set: str = "NTF"
    n_features: int = 7
    width: int = 100  # hidden units per layer (seed 000 Table 5)
    depth: int = 2  # hidden layers (seed 000 Table 5)
    activation: str = "tanh"  # "tanh" (eq. 2) | "clipped_relu" (eq. 1)
    ceiling: float = 10.0  # clippedReLU ceiling (eq. 1), in normalised units
    batch_norm: bool = True
    predict_increment: bool = True
    layout: str = DEFAULT_LAYOUT.name  # actuator layout of the control columns (physics/actuators.py)

    def __post_init__(self) -> None:
        if self.feature_set not in HEADING_SETS:
            raise ConfigError(f"DnnConfig.feature_set={self.feature_set!r}; known: {sorted(HEADING_SETS)}")
        expected = len(feature_names(self.feature_set, self.actuator_layout))
        if self.n_features != expected:
            raise ConfigError(f"DnnConfig.n_features={self.n_features} but feature set {self.feature_set} has "
                              f"{expected} features")
        if self.activation not in ACTIVATIONS:
            raise ConfigError(f"DnnConfig.activation={self.activation!r}; expected one of {list(ACTIVATIONS)}")
        if not (1 <= self.width <= 4096 and 1 <= self.depth <= 16):
            raise ConfigError(f"DnnConfig width={self.width} / depth={self.depth}: expected 1..4096 / 1..16")
        if not (self.ceiling > 0.0 and math.isfinite(self.ceiling)):
            raise ConfigError(f"DnnConfig.ceiling={self.ceiling}: expected a finite value > 0")

    @classmethod
    def for_features(cls, feature_set: str, layout: ActuatorLayout = DEFAULT_LAYOUT, **kwargs: Any) -> "DnnConfig":
        if feature_set not in HEADING_SETS:
            raise ConfigError(f"feature set {feature_set!r}; known: {sorted(HEADING_SETS)}")
        return cls(feature_set=feature_set, n_features=len(feature_names(feature_set, layout)), layout=layout.name,
                   **kwargs)

    @property
    def actuator_layout(self) -> ActuatorLayout:
        return actuator_layout(self.layout)

    @property
    def feature_names(self) -> tuple[str, ...]:
        return feature_names(self.feature_set, self.actuator_layout)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any]) -> "DnnConfig":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(raw) - known)
        if unknown:
            raise ConfigError(f"architecture: unknown DnnConfig field(s) {unknown}; known: {sorted(known)}")
        return cls(**raw)


@dataclass(frozen=True)
class Normalisation:
    """Global statistics of the training data (seed 000: 'global data normalisation')."""

    feature_mean: np.ndarray  # (F,)
    feature_std: np.ndarray  # (F,)
    target_mean: np.ndarray  # (3,) of the increment or of nu_{k+1}, see DnnConfig.predict_increment
    target_std: np.ndarray  # (3,)

    def to_dict(self) -> dict[str, list[float]]:
        names = ("feature_mean", "feature_std", "target_mean", "target_std")
        return {k: [float(x) for x in getattr(self, k)] for k in names}


def fit_normalisation(x: np.ndarray, y: np.ndarray, predict_increment: bool) -> Normalisation:
    """Statistics of features x (N, F) and next states y (N, 3); the target is y - x[:, :3] if increment."""
    x = np.asarray(x, dtype=np.float64)
    target = np.asarray(y, dtype=np.float64) - (x[:, :3] if predict_increment else 0.0)  # (N, 3)

    def std(a: np.ndarray) -> np.ndarray:
        s = a.std(axis=0)
        return np.where(s > MIN_STD, s, 1.0)

    return Normalisation(x.mean(axis=0), std(x), target.mean(axis=0), std(target))


class ClippedReLU(nn.Module):
    """Seed 000 eq. 1: 0 for x < 0, x for 0 <= x <= ceiling, ceiling above."""

    def __init__(self, ceiling: float) -> None:
        super().__init__()
        self.ceiling = float(ceiling)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.clamp(x, 0.0, self.ceiling)


def make_activation(config: DnnConfig) -> nn.Module:
    return nn.Tanh() if config.activation == "tanh" else ClippedReLU(config.ceiling)


class DnnModel(nn.Module):
    """features (B, F) -> next [u, v, r] (B, 3), seed 000 Fig. 1."""

    def __init__(self, config: DnnConfig, normalisation: Normalisation | None = None) -> None:
        super().__init__()
        self.config = config
        f = config.n_features
        self.register_buffer("x_mean", torch.zeros(f))
        self.register_buffer("x_std", torch.ones(f))
        self.register_buffer("y_mean", torch.zeros(3))
        self.register_buffer("y_std", torch.ones(3))
        blocks = []
        width_in = f
        for _ in range(config.depth):
            norm = nn.BatchNorm1d(config.width) if config.batch_norm else nn.Identity()
            blocks.append(nn.Sequential(nn.Linear(width_in, config.width), norm, make_activation(config)))
            width_in = config.width
        self.hidden = nn.ModuleList(blocks)
        self.head = nn.Linear(width_in, 3)
        if normalisation is not None:
            self.set_normalisation(normalisation)

    def set_normalisation(self, norm: Normalisation) -> None:
        for name, value in (("x_mean", norm.feature_mean), ("x_std", norm.feature_std),
                            ("y_mean", norm.target_mean), ("y_std", norm.target_std)):
            buf = getattr(self, name)
            buf.copy_(torch.as_tensor(np.asarray(value), dtype=buf.dtype))

    def normalisation(self) -> Normalisation:
        as_np = lambda t: t.detach().cpu().double().numpy().copy()  # noqa: E731
        return Normalisation(as_np(self.x_mean), as_np(self.x_std), as_np(self.y_mean), as_np(self.y_std))

    def forward_normalised(self, x: torch.Tensor) -> torch.Tensor:
        h = (x - self.x_mean) / self.x_std  # (B, F)
        for block in self.hidden:
            h = block(h)  # (B, W)
        return self.head(h)  # (B, 3) normalised target

    def normalised_target(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """The training target (B, 3) of features x (B, F) and next states y (B, 3)."""
        if self.config.predict_increment:
            y = y - x[:, :3]
        return (y - self.y_mean) / self.y_std

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.forward_normalised(x) * self.y_std + self.y_mean  # (B, 3)
        return y + x[:, :3] if self.config.predict_increment else y

    def fold_batch_norm(self) -> "DnnModel":
        """An eval-mode copy with each BatchNorm's running statistics folded into its Linear."""
        folded = copy.deepcopy(self).eval()
        with torch.no_grad():
            for block in folded.hidden:
                linear, norm = block[0], block[1]
                if isinstance(norm, nn.BatchNorm1d):
                    scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)  # (W,)
                    linear.weight.mul_(scale[:, None])
                    linear.bias.copy_((linear.bias - norm.running_mean) * scale + norm.bias)
                    block[1] = nn.Identity()
        return folded

    def affine_layers(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """[(weight (out, in), bias (out,))] in physical units, float64, for inference:

        forward(x) == (x[:, :3] if predict_increment else 0) + L_n(act(... act(L_1(x)))),
        with input normalisation folded into L_1, batch norm into each hidden L and the output
        de-normalisation into L_n.
        """
        folded = copy.deepcopy(self).double().fold_batch_norm()  # fold in float64, not in the float32 of training
        layers = [(b[0].weight.detach().clone(), b[0].bias.detach().clone()) for b in folded.hidden]
        layers.append((folded.head.weight.detach().clone(), folded.head.bias.detach().clone()))
        w1, b1 = layers[0]
        w1 = w1 / folded.x_std  # (W, F): column j scaled by 1/std_j
        layers[0] = (w1, b1 - w1 @ folded.x_mean)
        wn, bn = layers[-1]
        layers[-1] = (wn * folded.y_std[:, None], bn * folded.y_std + folded.y_mean)
        return layers


# ----------------------------------------------------------------------------- the closed-loop rollout

# how the heading columns of a feature set (data/features.py HEADING_COLUMNS) are folded: each column is an
# argument psi + phase updated in the step matrices, then sin() of it, or its remainder modulo 2 pi
_FOLD = {"sin": ("sin", 0.0), "cos": ("sin", 0.5 * math.pi), "wrap": ("wrap", math.pi)}  # cos x = sin(x + pi/2)
_HEADING_MODE = {"none": 0, "wrap": 1, "sin": 2}  # TorchScript constant: how _psi_features_ treats the columns


def _heading_fold(feature_set: str) -> tuple[int, list[float]]:
    """(mode, phases (rad)) of the heading columns of a feature set, for DnnRollout."""
    folds = [_FOLD[HEADING_COLUMNS[name]] for name in HEADING_SETS[feature_set]]
    kinds = {kind for kind, _ in folds}
    if len(kinds) > 1:
        raise ModelError(f"feature set {feature_set}: heading columns {HEADING_SETS[feature_set]} mix sin and wrap; "
                         "the folded rollout takes one kind")
    return _HEADING_MODE[kinds.pop() if kinds else "none"], [phase for _, phase in folds]

def _members_of(buffers: Mapping[str, torch.Tensor], feature_set: str, activation: str, members: int | None
                ) -> tuple[int, int, int, dict[str, torch.Tensor]]:
    """The checks every fused form of DnnRollout makes of the artifact's network, and its first `members` members:
    (trig_mode, heading columns, members kept, {buffer: float64 tensor (E, ...)}); ModelError naming what is off."""
    missing = [name for name in ROLLOUT_BUFFERS if name not in buffers]
    if missing:
        raise ModelError(f"not a DnnRollout's network: buffers {missing} missing")
    if activation not in ACTIVATIONS:
        raise ModelError(f"activation {activation!r}; expected one of {list(ACTIVATIONS)}")
    trig_mode, phases = _heading_fold(feature_set)
    available = int(buffers["m_s"].shape[0])
    kept = available if members is None else int(members)
    if not 1 <= kept <= available:
        raise ModelError(f"{kept} member(s) asked for, the network has {available}")
    params = {k: buffers[k].detach()[:kept].to(torch.float64) for k in ROLLOUT_BUFFERS}
    if params["m_s"].shape[1] != 4 + len(phases) or params["phase"].shape[-1] != len(phases):
        raise ModelError(f"feature set {feature_set} has {len(phases)} heading column(s), the network's step "
                         f"matrix is {tuple(params['m_s'].shape)}")
    return trig_mode, len(phases), kept, params



class DnnRollout(nn.Module):
    """Closed-loop rollout of an ensemble of folded seed-000 networks (see the module docstring).

    Step state s = [u, v, r, psi, t] (E, B, 4 + T) where t are the heading columns (T = 0 for F0,
    1 wrapped psi for NAF, 2 sin/cos psi for NTF). Controls (B, H, C) in the layout's columns. One step is
    three batched products:
        [s_lin | pre] = s M + per_step[k]        s_lin: the linear part of the next s (4 + T)
        h = act(pre); h = act(h W_i + b_i) ...   hidden layers (W units)
        s' = s_lin + h head                      next [u, v, r, psi] and the psi-feature argument
        t' = sin(.) or remainder(., 2 pi)        in place on the last T columns
    """

    __constants__ = ["trig_mode", "n_trig", "n_controls", "clipped", "ceiling", "dt", "ensemble_size"]

    def __init__(self, members: Sequence[DnnModel], dt: float, dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        config = members[0].config
        if any(m.config != config for m in members):
            raise ModelError("ensemble members must share one architecture (DnnConfig)")
        self.trig_mode, phases = _heading_fold(config.feature_set)  # 0 none, 1 wrapped psi, 2 sin(psi + phase)
        self.n_trig = len(phases)  # = T, the number of heading columns
        self.n_controls = len(config.actuator_layout.controls)  # = C
        self.clipped = config.activation == "clipped_relu"
        self.ceiling = float(config.ceiling)
        self.dt = float(dt)
        self.ensemble_size = len(members)
        parts = [self._member_tensors(m, config, float(dt)) for m in members]
        for name in parts[0]:
            self.register_buffer(name, torch.stack([p[name] for p in parts]).to(dtype))

    @staticmethod
    def _member_tensors(model: DnnModel, config: DnnConfig, dt: float) -> dict[str, torch.Tensor]:
        layers = model.affine_layers()  # float64 [(out, in), (out,)] in physical units
        col = {n: i for i, n in enumerate(config.feature_names)}
        w1, b1 = layers[0]  # (W, F), (W,)
        w_out, b_out = layers[-1]  # (3, W), (3,)
        width = w1.shape[0]
        mode, phase = _heading_fold(config.feature_set)
        n_trig = len(phase)
        controls = config.actuator_layout.control_names
        s = 4 + n_trig
        inc = 1.0 if config.predict_increment else 0.0
        m_s = torch.zeros(s, s + width, dtype=torch.float64)  # s (1, S) @ m_s -> [s_lin (S) | pre (W)]
        bias = torch.zeros(1, s + width, dtype=torch.float64)
        w_c = torch.zeros(len(controls), s + width, dtype=torch.float64)  # controls (1, C) @ w_c: share of pre
        head = torch.zeros(width, s, dtype=torch.float64)
        # next nu = inc * nu + b_out + h w_out; next psi = psi + dt/2 (r + next r)
        m_s[0, 0] = m_s[1, 1] = m_s[2, 2] = inc
        m_s[3, 3] = 1.0
        m_s[2, 3] = (1.0 + inc) * 0.5 * dt
        bias[0, :3] = b_out
        bias[0, 3] = 0.5 * dt * b_out[2]
        head[:, :3] = w_out.T
        head[:, 3] = 0.5 * dt * w_out[2]
        # the heading-column arguments: copies of the next psi (+ a phase): NAF psi + pi; NTF sin(psi + [0, pi/2])
        for j, p in enumerate(phase):
            m_s[:, 4 + j] = m_s[:, 3]
            bias[0, 4 + j] = bias[0, 3] + p
            head[:, 4 + j] = head[:, 3]
        # first layer: state, control and psi-feature columns of w1
        first_bias = b1.clone()
        for i, name in enumerate(("u", "v", "r")):
            m_s[i, s:] = w1[:, col[name]]
        for i, name in enumerate(controls):
            w_c[i, s:] = w1[:, col[name]]
        for j, name in enumerate(HEADING_SETS[config.feature_set]):
            m_s[4 + j, s:] = w1[:, col[name]]
            if mode == _HEADING_MODE["wrap"]:  # wrapped psi = remainder(psi + pi, 2 pi) - pi: the -pi to the bias
                first_bias = first_bias - math.pi * w1[:, col[name]]
        bias[0, s:] = first_bias
        hidden = layers[1:-1]
        no_hidden = torch.zeros(0, width, width, dtype=torch.float64), torch.zeros(0, 1, width, dtype=torch.float64)
        return {
            "m_s": m_s, "w_c": w_c, "bias": bias, "head": head,
            "phase": torch.tensor(phase, dtype=torch.float64).reshape(1, n_trig),
            "hidden_w": torch.stack([w.T for w, _ in hidden]) if hidden else no_hidden[0],  # (depth-1, W, W)
            "hidden_b": torch.stack([b[None, :] for _, b in hidden]) if hidden else no_hidden[1],  # (depth-1, 1, W)
        }

    def _activation_(self, h: torch.Tensor) -> torch.Tensor:
        """In place: h is a fresh intermediate, so no new tensor is needed."""
        if self.clipped:
            return h.clamp_(0.0, self.ceiling)
        return h.tanh_()

    def _psi_features_(self, s: torch.Tensor) -> None:
        """In place: the last T columns of s, psi + phase, become the psi features."""
        if self.trig_mode == 2:
            s.narrow(2, 4, self.n_trig).sin_()
        elif self.trig_mode == 1:
            s.narrow(2, 4, self.n_trig).remainder_(2.0 * math.pi)

    def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
        if state.dim() != 2 or state.size(1) != 4:
            raise ValueError("state must be (B, 4) [u, v, r, psi]")
        if controls.dim() != 3 or controls.size(2) != self.n_controls or controls.size(0) != state.size(0):
            raise ValueError("controls must be (B, H, C) in the model's control_layout, with the B of state")
        e = self.ensemble_size
        b = state.size(0)
        horizon = controls.size(1)
        n_s = 4 + self.n_trig
        z0 = state.to(self.m_s.dtype).unsqueeze(0).expand(e, b, 4)  # (E, B, 4)
        s = torch.cat([z0, z0[:, :, 3:4] + self.phase], dim=2)  # (E, B, S)
        self._psi_features_(s)
        ctrl = controls.to(self.m_s.dtype).reshape(1, b * horizon, self.n_controls)
        # the controls' share of every step's first layer, before the loop: H x (E, B, S + W)
        per_step = (torch.matmul(ctrl, self.w_c).reshape(e, b, horizon, -1) + self.bias.unsqueeze(2)).unbind(2)
        hidden_w = self.hidden_w.unbind(1)  # buffers are (E, depth-1, ...): one (E, W, W) per hidden layer
        hidden_b = self.hidden_b.unbind(1)
        sections = [n_s, self.m_s.size(2) - n_s]
        steps: List[torch.Tensor] = []
        for k in range(horizon):
            s_lin, pre = torch.baddbmm(per_step[k], s, self.m_s).split(sections, dim=2)  # (E, B, S), (E, B, W)
            h = self._activation_(pre)
            for i in range(len(hidden_w)):
                h = self._activation_(torch.baddbmm(hidden_b[i], h, hidden_w[i]))  # (E, B, W)
            s = torch.baddbmm(s_lin, h, self.head)  # (E, B, S): [u, v, r, psi] at k+1, psi-feature arguments
            self._psi_features_(s)
            steps.append(s)
        path = torch.stack(steps, dim=2)[..., 0:4]  # (E, B, H, 4)
        full = torch.cat([z0.unsqueeze(2), path], dim=2)  # (E, B, H+1, 4)
        cos_psi = torch.cos(full[..., 3])
        sin_psi = torch.sin(full[..., 3])
        v_north = full[..., 0] * cos_psi - full[..., 1] * sin_psi  # (E, B, H+1)
        v_east = full[..., 0] * sin_psi + full[..., 1] * cos_psi
        velocity = torch.stack([v_north, v_east], dim=-1)  # (E, B, H+1, 2)
        position = torch.cumsum(0.5 * self.dt * (velocity[:, :, 1:] + velocity[:, :, :-1]), dim=2)  # (E, B, H, 2)
        return torch.cat([path[..., 0:3], position, path[..., 3:4]], dim=-1)  # (E, B, H, 6)


def export(path: str | Path, members: Sequence[DnnModel], config: DnnConfig, *, dt: float, vessel: str | Vessel,
           training_data_sha256: str, training: Mapping[str, Any] | None = None,
           horizon_steps: int = DEFAULT_HORIZON_STEPS, dtype: str = "float32",
           extra: Mapping[str, Any] | None = None) -> ModelArtifact:
    """Export trained seed-000 networks (one, or an ensemble sharing normalisation) as one artifact; vessel: the
    vessel the bags were recorded on, embedded (a Vessel) or named only (a preset name)."""
    if not members:
        raise ModelError(f"model {path}: no trained network to export")
    if not (dt > 0.0 and math.isfinite(dt)):
        raise ModelError(f"model {path}: dt={dt} s must be > 0")
    if dtype not in ("float32", "float64"):
        raise ModelError(f"model {path}: dtype {dtype!r}, expected 'float32' or 'float64'")
    norm = members[0].normalisation()
    for m in members[1:]:
        other = m.normalisation()
        if not all(np.allclose(a, b) for a, b in zip(norm.to_dict().values(), other.to_dict().values())):
            raise ModelError(f"model {path}: ensemble members were trained with different normalisations")
    module = DnnRollout([m.eval() for m in members], dt, getattr(torch, dtype))
    metadata = {
        "model_type": "dnn",
        "feature_set": config.feature_set,
        "feature_names": list(config.feature_names),
        "feature_units": list(feature_units(config.feature_set, config.actuator_layout)),
        "state_layout": list(STATE_NAMES),
        "control_layout": list(config.actuator_layout.control_names),
        "actuator_layout": config.layout,
        "output_layout": list(OUTPUT_LAYOUT),
        "dt": float(dt),
        "horizon_steps": int(horizon_steps),
        "normalisation": {**norm.to_dict(), "target": "increment" if config.predict_increment else "absolute"},
        "vessel": vessel if isinstance(vessel, str) else vessel.name,
        "training_data_sha256": training_data_sha256,
        "ensemble_size": len(members),
        "architecture": config.to_dict(),
        "training": dict(training or {}),
        "units": UNITS,
        "dtype": dtype,
        **dict(extra or {}),
    }
    return export_module(path, module, metadata, vessel=None if isinstance(vessel, str) else vessel)


# ----------------------------------------------------------------------------- the node's fused rollout

ROLLOUT_BUFFERS = ("m_s", "w_c", "bias", "head", "phase", "hidden_w", "hidden_b")  # a DnnRollout's folded network
FUSED_CHECK_RTOL = 1e-4  # fused vs the artifact's own rollout at load: relative to the output's scale (float32 ~1e-7)


def sigmoid_form(params: Mapping[str, torch.Tensor], n_state: int) -> dict[str, torch.Tensor]:
    """A tanh DnnRollout's buffers (float64) rewritten so that every activation is a sigmoid, same function:

        tanh(z) = 2 sigmoid(2 z) - 1
    layer 1     z = s M + c W_c + b                  ->  2 z = s (2 M) + c (2 W_c) + 2 b,        g_1 = sigmoid(2 z)
    hidden i    z = h W + b, h = 2 g - 1             ->  2 z = g (4 W) + 2 (b - 1 W),          g_i = sigmoid(2 z)
    output      s' = s_lin + h head, h = 2 g - 1     ->  s' = s_lin + g (2 head) - 1 head     (the -1 head to the bias)

    with 1 W the column sums (over the input units). The scalings by 2 and 4 are exact; only the folded biases are
    rounded once more. Why: torch's float tanh kernel costs ~4 ns per element on this machine, its sigmoid ~0.2 ns
    (benchmarks/bench_node.py), and the rollout's activations are every step's elementwise cost (the 64-candidate
    batch: 2 x 32000 per step). The shift and scale ride on products the rollout computes anyway: no extra op.
    """
    p = {k: v.clone() for k, v in params.items()}
    p["m_s"][..., n_state:] *= 2.0  # (E, S, S + W): the pre-activation columns
    p["w_c"][..., n_state:] *= 2.0  # (E, C, S + W)
    p["bias"][..., n_state:] *= 2.0  # (E, 1, S + W)
    if p["hidden_w"].numel():
        # (E, depth-1, W_in, W_out), (E, depth-1, 1, W_out)
        p["hidden_b"] = 2.0 * (p["hidden_b"] - p["hidden_w"].sum(dim=2, keepdim=True))
        p["hidden_w"] = 4.0 * p["hidden_w"]
    p["bias"][..., :n_state] -= p["head"].sum(dim=1, keepdim=True)  # (E, 1, S) - (E, 1, S)
    p["head"] = 2.0 * p["head"]  # (E, W, S)
    return p


class FusedDnnRollout(DnnRollout):
    """TorchScript's fused rollout of a DNN artifact, what the node runs when NumpyDnnRollout cannot be built (a
    clippedReLU ceiling below 1): the artifact's folded network (its DnnRollout buffers), fused once more at load
    time. Same interface and function as DnnRollout (forward: (B, 4), (B, H, C) -> (E, B, H, 6));
    equal to the artifact's own rollout within float rounding (test_dnn_fused.py). What differs, per step:

    * tanh activations run as sigmoids of the same products (sigmoid_form: the affine shift and scale folded into
      the neighbouring layers, no extra op);
    * the steps are written into one preallocated (H, E, B, S) tensor by the output product itself (`out=`), no
      list of 120 tensors stacked after the loop, and the hidden activations work on a view of the step's product;
    * only the members asked for are kept (the node's `ensemble_size`), so a smaller ensemble costs less.

    The ensemble is one batched product per layer (E the batch of baddbmm), as in DnnRollout; the candidates'
    batch B rides in the same products. The artifact format is unchanged: old artifacts are fused when loaded.
    """

    __constants__ = DnnRollout.__constants__ + ["sigmoid", "width", "n_hidden"]

    def __init__(self, buffers: Mapping[str, torch.Tensor], *, feature_set: str, activation: str, ceiling: float,
                 dt: float, members: int | None = None) -> None:
        nn.Module.__init__(self)
        self.trig_mode, self.n_trig, self.ensemble_size, params = _members_of(buffers, feature_set, activation, members)
        dtype = buffers["m_s"].dtype
        n_s = 4 + self.n_trig
        self.n_controls = int(params["w_c"].shape[1])
        self.width = int(params["m_s"].shape[2]) - n_s
        self.n_hidden = int(params["hidden_w"].shape[1])  # hidden layers after the first (depth - 1)
        self.clipped = activation == "clipped_relu"
        self.sigmoid = not self.clipped
        self.ceiling = float(ceiling)
        self.dt = float(dt)
        if self.sigmoid:
            params = sigmoid_form(params, n_s)
        params["head_t"] = params.pop("head").transpose(1, 2)  # (E, S, W): the output product runs transposed
        for name, value in params.items():
            self.register_buffer(name, value.to(dtype).contiguous())

    def _activation_(self, h: torch.Tensor) -> torch.Tensor:
        if self.clipped:
            return h.clamp_(0.0, self.ceiling)
        return h.sigmoid_()  # sigmoid_form: the tanh's shift and scale are in the weights

    def _heading_features_(self, columns: torch.Tensor) -> None:
        """In place, as DnnRollout._psi_features_ on a view of the T heading columns (E, B, T)."""
        if self.trig_mode == 2:
            columns.sin_()
        elif self.trig_mode == 1:
            columns.remainder_(2.0 * math.pi)

    def forward(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
        if state.dim() != 2 or state.size(1) != 4:
            raise ValueError("state must be (B, 4) [u, v, r, psi]")
        if controls.dim() != 3 or controls.size(2) != self.n_controls or controls.size(0) != state.size(0):
            raise ValueError("controls must be (B, H, C) in the model's control_layout, with the B of state")
        e = self.ensemble_size
        b = state.size(0)
        horizon = controls.size(1)
        n_s = 4 + self.n_trig
        z0 = state.to(self.m_s.dtype).unsqueeze(0).expand(e, b, 4)  # (E, B, 4)
        s = torch.cat([z0, z0[:, :, 3:4] + self.phase], dim=2)  # (E, B, S)
        self._psi_features_(s)
        ctrl = controls.to(self.m_s.dtype).reshape(1, b * horizon, self.n_controls)
        # the controls' share of every step's first layer, before the loop: H x (E, B, S + W)
        per_step = (torch.matmul(ctrl, self.w_c).reshape(e, b, horizon, -1) + self.bias.unsqueeze(2)).unbind(2)
        hidden_w = self.hidden_w.unbind(1)  # one (E, W, W) per hidden layer
        hidden_b = self.hidden_b.unbind(1)
        # every tensor the loop writes is allocated here and every view it reads is taken here: a step is its three
        # products and its activations only (no allocation, no slicing op). The steps are kept transposed, (E, S, B):
        # the output product is then head^T h^T, which BLAS runs ~4x faster than h head for the candidates' B = 64
        # (an N of S = 6 columns is its slow case; benchmarks/bench_node.py)
        dtype = self.m_s.dtype
        steps = torch.empty(horizon, e, n_s, b, dtype=dtype)  # (H, E, S, B): step k written in place
        outs = steps.unbind(0)  # H x (E, S, B)
        states = steps.transpose(2, 3).unbind(0)  # H x (E, B, S): the same memory, the next step's input
        heading_columns = steps.narrow(2, 4, self.n_trig).unbind(0)  # H x (E, T, B): the psi-feature arguments
        y = torch.empty(e, b, n_s + self.width, dtype=dtype)  # (E, B, S + W): [s_lin | pre-activation]
        s_lin_t = y.narrow(2, 0, n_s).transpose(1, 2)  # (E, S, B)
        pre = y.narrow(2, n_s, self.width)  # (E, B, W)
        n_hidden = self.n_hidden  # a constant: TorchScript unrolls the layer loop
        last = torch.empty(e, b, self.width, dtype=dtype) if n_hidden > 0 else pre  # (E, B, W): the last layer's
        last_t = last.transpose(1, 2)  # (E, W, B)
        for k in range(horizon):
            torch.baddbmm(per_step[k], s, self.m_s, out=y)
            h = self._activation_(pre)  # (E, B, W)
            for i in range(n_hidden):
                if i == n_hidden - 1:
                    h = self._activation_(torch.baddbmm(hidden_b[i], h, hidden_w[i], out=last))
                else:
                    h = self._activation_(torch.baddbmm(hidden_b[i], h, hidden_w[i]))  # (E, B, W)
            torch.baddbmm(s_lin_t, self.head_t, last_t, out=outs[k])  # (E, S, B): [u, v, r, psi, args] at k+1
            self._heading_features_(heading_columns[k])
            s = states[k]
        path = steps.permute(1, 3, 0, 2)[..., 0:4]  # (E, B, H, 4)
        full = torch.cat([z0.unsqueeze(2), path], dim=2)  # (E, B, H+1, 4)
        cos_psi = torch.cos(full[..., 3])
        sin_psi = torch.sin(full[..., 3])
        v_north = full[..., 0] * cos_psi - full[..., 1] * sin_psi  # (E, B, H+1)
        v_east = full[..., 0] * sin_psi + full[..., 1] * cos_psi
        velocity = torch.stack([v_north, v_east], dim=-1)  # (E, B, H+1, 2)
        position = torch.cumsum(0.5 * self.dt * (velocity[:, :, 1:] + velocity[:, :, :-1]), dim=2)  # (E, B, H, 2)
        return torch.cat([path[..., 0:3], position, path[..., 3:4]], dim=-1)  # (E, B, H, 6)


def _probe(metadata: Mapping[str, Any], batch: int = 4) -> tuple[torch.Tensor, torch.Tensor]:
    """Realistic inputs of a model for checking a fused rollout against the file's own: states and held controls
    at the training data's mean and +-1 std (normalisation.feature_mean / feature_std), headings round the circle.
    float64 (B, 4), (B, H, C) with H the model's horizon_steps."""
    names = list(metadata["feature_names"])
    norm = metadata["normalisation"]
    mean = np.asarray(norm["feature_mean"], dtype=np.float64)
    std = np.asarray(norm["feature_std"], dtype=np.float64)
    offsets = np.linspace(-1.0, 1.0, batch)[:, None]  # (B, 1) in std
    state = np.zeros((batch, 4))
    for j, name in enumerate(("u", "v", "r")):
        state[:, j] = mean[names.index(name)] + offsets[:, 0] * std[names.index(name)]
    state[:, 3] = np.linspace(-3.0, 3.0, batch)  # rad
    columns = [names.index(c) for c in metadata["control_layout"]]
    controls = mean[columns] - offsets * std[columns]  # (B, C): the opposite side of the state's offset
    horizon = int(metadata["horizon_steps"])
    return torch.from_numpy(state), torch.from_numpy(np.repeat(controls[:, None], horizon, axis=1))


def fused_rollout(artifact: ModelArtifact, members: int | None = None, freeze: bool = True) -> torch.jit.ScriptModule:
    """The artifact's DNN rollout fused for inference (FusedDnnRollout), scripted and frozen (torch.jit.freeze:
    the buffers become constants of the graph), checked against the file's own module on _probe's inputs.

    ModelError when the file's module is not a DnnRollout's network (another model family, a DnnRollout of other
    buffers) or when the fused rollout differs from it by more than FUSED_CHECK_RTOL of each output column's scale
    (the caller then keeps the file's module: old or unknown artifacts always run, models/loading.py)."""
    metadata = artifact.metadata
    if str(metadata.get("model_type")) != "dnn":
        raise ModelError(f"model {artifact.path}: model_type {metadata.get('model_type')!r}, not a plain dnn")
    buffers = dict(artifact.module.named_buffers())
    try:
        arch = metadata["architecture"]
        module = FusedDnnRollout(buffers, feature_set=str(metadata["feature_set"]), activation=str(arch["activation"]),
                                 ceiling=float(arch["ceiling"]), dt=float(metadata["dt"]), members=members)
        state, controls = _probe(metadata)
    except (KeyError, TypeError, ValueError, IndexError, ConfigError) as err:
        raise ModelError(f"model {artifact.path}: its network cannot be fused ({type(err).__name__}: {err})") from err
    dtype = buffers["m_s"].dtype
    try:  # TorchScript compiles FusedDnnRollout from its source file now: a failure keeps the file's module
        with quiet_jit():
            scripted = torch.jit.script(module.eval())
            if freeze:
                scripted = torch.jit.freeze(scripted)
        with torch.inference_mode():
            # (E, B, H, 6)
            expected = artifact.module(state.to(dtype), controls.to(dtype))[: module.ensemble_size].double()
            got = scripted(state.to(dtype), controls.to(dtype)).double()
    except MODEL_RUN_ERRORS as err:
        raise ModelError(f"model {artifact.path}: the fused rollout cannot be built or run: "
                         f"{failure_reason(err)}") from err
    scale = 1.0 + expected.abs().amax(dim=(0, 1, 2))  # (6,)
    error = (((got - expected).abs().amax(dim=(0, 1, 2)) / scale).max().item() if got.shape == expected.shape
             else math.inf)
    if not error <= FUSED_CHECK_RTOL:
        raise ModelError(f"model {artifact.path}: the fused rollout differs from the file's by {error:.3g} of the "
                         f"output's scale (limit {FUSED_CHECK_RTOL:g}): not a DnnRollout of this version?")
    return scripted


# ----------------------------------------------------------------------------- the node's numpy rollout

BIAS_UNIT_PRE = 30.0  # pre-activation of the bias unit: tanh(30) == 1 exactly in float32 and float64
NUMPY_FORM = "fused (models/dnn.NumpyDnnRollout, numpy)"  # inference_note of a model running NumpyDnnRollout


class NumpyDnnRollout:
    """The rollout the node and `replay evaluate` run for a DNN artifact: the artifact's folded network (its DnnRollout
    buffers, the TorchScript file stays the source of the weights) stepped with numpy, in the artifact's dtype. Same
    function as DnnRollout within float rounding (test_dnn_fused.py); callable like the TorchScript module
    (forward: (B, 4), (B, H, C) tensors -> (E, B, H, 6) tensor), and `rollout` takes and returns numpy arrays.

    One step, for all members at once (E the stacked dimension of numpy's matmul, the candidates' batch B its rows):

        [s_lin | pre | 1] = [s | c_k | 1] F          F = [[M_s], [W_c], [b]] and the bias unit (E, S + C + 1, S + W + 1)
        g = act([pre | 1])                           tanh (or clippedReLU); the bias unit stays 1 exactly
        h = act(g [[W_i], [b_i]]) ...                hidden layers, their bias a row of the stacked weights
        s' = s_lin + h head;  heading columns of s' -> sin (NTF) / remainder 2 pi (NAF)

    i.e. three matrix products, two activations, one add and one sin per step, written in place into buffers made
    before the loop (the states of all steps are one (H + 1, E, S + C + 1, B) array, transposed: _rollout_batch;
    the controls already in place).
    The bias unit is a unit of the first and hidden layers whose pre-activation is BIAS_UNIT_PRE (1 for clippedReLU),
    so that act() gives exactly 1 and the next layer's bias rides in its product (numpy's matmul has no bias term).
    Why numpy: at these sizes a step is dispatch-bound (one state: ~1 us per numpy op against 1.4-2.9 us per
    TorchScript op) or bound by the hidden product (64 candidates: numpy's OpenBLAS, with the AVX2 kernels this
    machine's OPENBLAS_CORETYPE pins, ~1.2x faster than torch's MKL; its AVX-512 kernels ~2x faster again), and
    numpy's tanh is a fast kernel (torch's float tanh was the reason for FusedDnnRollout's sigmoids).
    benchmarks/bench_node.py measures it against FusedDnnRollout and the file's rollout.
    Positions are integrated after the loop in float64 (trapezoidal, as DnnRollout). Buffers are allocated per call:
    one instance serves any caller and batch size.
    """

    def __init__(self, buffers: Mapping[str, torch.Tensor], *, feature_set: str, activation: str, ceiling: float,
                 dt: float, members: int | None = None) -> None:
        self.trig_mode, self.n_trig, self.ensemble_size, members_f64 = _members_of(buffers, feature_set, activation,
                                                                                 members)
        self.dtype = {torch.float32: np.float32, torch.float64: np.float64}.get(buffers["m_s"].dtype)
        if self.dtype is None:
            raise ModelError(f"network dtype {buffers['m_s'].dtype}; expected float32 or float64")
        p = {k: v.numpy() for k, v in members_f64.items()}
        n_s = 4 + self.n_trig
        self.clipped = activation == "clipped_relu"
        self.ceiling = float(ceiling)
        self.dt = float(dt)
        self.n_state = n_s
        self.n_controls = int(p["w_c"].shape[1])
        width = int(p["m_s"].shape[2]) - n_s
        n_hidden = int(p["hidden_w"].shape[1])
        unit = 1.0 if self.clipped else BIAS_UNIT_PRE
        if self._act(np.array([unit], dtype=self.dtype))[0] != 1.0:
            raise ModelError(f"{activation} with ceiling {ceiling:g} has no exact bias unit (act({unit:g}) != 1)")
        e, c = self.ensemble_size, self.n_controls
        first = np.zeros((e, n_s + c + 1, n_s + width + (n_hidden > 0)))  # (E, S + C + 1, S + W [+ 1])
        first[:, :n_s, : n_s + width] = p["m_s"]
        first[:, n_s: n_s + c, : n_s + width] = p["w_c"]
        first[:, n_s + c, : n_s + width] = p["bias"][:, 0]
        hidden = []
        for i in range(n_hidden):  # (E, W + 1, W [+ 1]): the last hidden layer feeds the head, no bias unit
            more = i < n_hidden - 1
            w = np.zeros((e, width + 1, width + more))
            w[:, :width, :width] = p["hidden_w"][:, i]
            w[:, width, :width] = p["hidden_b"][:, i, 0]
            if more:
                w[:, width, width] = unit
            hidden.append(np.ascontiguousarray(w, dtype=self.dtype))
        if n_hidden:
            first[:, n_s + c, n_s + width] = unit
        self.first = np.ascontiguousarray(first, dtype=self.dtype)
        self.hidden = tuple(hidden)
        self.head = np.ascontiguousarray(p["head"], dtype=self.dtype)  # (E, W, S)
        # the batch form's transposes (_rollout_batch): (E, S + W [+ 1], S + C + 1), (E, W [+ 1], W + 1), (E, S, W)
        self.first_t = np.ascontiguousarray(self.first.transpose(0, 2, 1))
        self.hidden_t = tuple(np.ascontiguousarray(w.transpose(0, 2, 1)) for w in self.hidden)
        self.head_t = np.ascontiguousarray(self.head.transpose(0, 2, 1))
        self.phase = p["phase"][:, 0].astype(self.dtype)  # (E, T)
        self.width = width
        self._vector_weights(p, unit)

    def _column(self, member: int, j: int) -> int:
        """Column of member e's state column j in the one-state form's state vector [q (E x 4) | t (E x T)]."""
        return member * 4 + j if j < 4 else self.ensemble_size * 4 + member * self.n_trig + (j - 4)

    def _vector_weights(self, p: Mapping[str, np.ndarray], unit: float) -> None:
        """The first and output layers of the one-state form (_rollout_one) as block-diagonal matrices over the
        members: a step of one state is then two 2-D products and one stacked (the hidden layer), every activation on
        one contiguous vector. Per step a row r_k = [h (E W) | s_k (E S) | c_k (C) | 1]."""
        e, n_s, c, width = self.ensemble_size, self.n_state, self.n_controls, self.width
        unit_column = 1 if self.hidden else 0
        block = width + unit_column
        first = np.zeros((e * n_s + c + 1, e * block))  # [s | c | 1] -> E x [pre | unit]
        out = np.zeros((e * width + e * n_s + c + 1, e * n_s))  # r_k -> s_{k+1}
        for m in range(e):
            pre = slice(m * block, m * block + width)
            for j in range(n_s):
                first[self._column(m, j), pre] = p["m_s"][m, j, n_s:]
                out[m * width:(m + 1) * width, self._column(m, j)] = p["head"][m, :, j]
                for i in range(n_s):
                    out[e * width + self._column(m, i), self._column(m, j)] = p["m_s"][m, i, j]
                out[e * width + e * n_s: e * width + e * n_s + c, self._column(m, j)] = p["w_c"][m, :, j]
                out[-1, self._column(m, j)] = p["bias"][m, 0, j]
            first[e * n_s: e * n_s + c, pre] = p["w_c"][m, :, n_s:]
            first[-1, pre] = p["bias"][m, 0, n_s:]
            if unit_column:
                first[-1, m * block + width] = unit
        self.first_one = np.ascontiguousarray(first, dtype=self.dtype)
        self.out_one = np.ascontiguousarray(out, dtype=self.dtype)

    def _act(self, h: np.ndarray) -> np.ndarray:
        """In place."""
        if self.clipped:
            np.maximum(h, 0.0, out=h)
            return np.minimum(h, self.ceiling, out=h)
        return np.tanh(h, out=h)

    def _heading(self, columns: np.ndarray) -> None:
        """In place, the heading columns [psi + phase] (..., T) become the psi features (DnnRollout._psi_features_)."""
        if self.trig_mode == 2:
            np.sin(columns, out=columns)
        elif self.trig_mode == 1:
            np.remainder(columns, 2.0 * math.pi, out=columns)

    def rollout(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """(E, B, H, 6) [u, v, r, x_n, y_e, psi] float64 from state (B, 4) [u, v, r, psi] and controls (B, H, C)."""
        state = np.asarray(state, dtype=np.float64)
        controls = np.asarray(controls, dtype=np.float64)
        if state.ndim != 2 or state.shape[1] != 4:
            raise ValueError("state must be (B, 4) [u, v, r, psi]")
        if controls.ndim != 3 or controls.shape[2] != self.n_controls or controls.shape[0] != state.shape[0]:
            raise ValueError("controls must be (B, H, C) in the model's control_layout, with the B of state")
        return self._rollout_one(state, controls) if state.shape[0] == 1 else self._rollout_batch(state, controls)

    def _rollout_batch(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """rollout() of B states: the members stacked (E the stacked dimension of matmul), the B states the columns.

        Transposed (column vectors, x_k (S + C + 1, B) per member) so that every activation runs on memory that is
        contiguous per member ([s_lin | pre | unit] are rows: pre's rows are one block), where the row form's
        [s_lin | pre | unit] columns made the first tanh a strided walk of E B rows (11 us against 6 us for
        64 candidates), and the output product is head^T h^T, an N of B columns, not BLAS's slow case of N = S."""
        e, b, horizon = self.ensemble_size, state.shape[0], controls.shape[1]
        n_s, c = self.n_state, self.n_controls
        # x (H + 1, E, S + C + 1, B): [s_k; c_k; 1] of every step; s_k written by step k - 1's add
        x = np.empty((horizon + 1, e, n_s + c + 1, b), dtype=self.dtype)
        x[0, :, :4] = state.T
        x[0, :, 4:n_s] = state[None, :, 3] + self.phase[:, :, None]  # (E, T, B)
        self._heading(x[0, :, 4:n_s])
        x[:horizon, :, n_s: n_s + c] = controls.transpose(1, 2, 0)[:, None]  # (H, 1, C, B)
        x[horizon, :, n_s: n_s + c] = 0.0
        x[:, :, n_s + c] = 1.0
        first = self.first_t
        y = np.empty((e, first.shape[1], b), dtype=self.dtype)  # (E, S + W [+ 1], B): [s_lin; pre; unit]
        s_lin, g = y[:, :n_s], y[:, n_s:]
        layers = [(w, np.empty((e, w.shape[1], b), dtype=self.dtype)) for w in self.hidden_t]
        last = layers[-1][1] if layers else g  # (E, W, B)
        t = np.empty((e, n_s, b), dtype=self.dtype)  # (E, S, B): head^T h^T
        matmul, add, head = np.matmul, np.add, self.head_t
        heading = None if self.trig_mode == 0 else (np.sin if self.trig_mode == 2 else self._heading)
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model gives inf / NaN: the caller refuses it
            if not self.clipped and len(layers) == 1 and heading is np.sin:  # the usual network (NTF, tanh, depth 2)
                tanh, sin, (w, z) = np.tanh, np.sin, layers[0]
                for x_k, s_next, columns in zip(x[:-1], x[1:, :, :n_s], x[1:, :, 4:n_s]):
                    matmul(first, x_k, out=y)
                    tanh(g, out=g)
                    matmul(w, g, out=z)
                    tanh(z, out=z)
                    matmul(head, z, out=t)
                    add(t, s_lin, out=s_next)
                    sin(columns, out=columns)
            else:  # the same step for any depth, activation and heading columns
                for x_k, s_next, columns in zip(x[:-1], x[1:, :, :n_s], x[1:, :, 4:n_s]):
                    matmul(first, x_k, out=y)
                    h = self._act(g)
                    for w, z in layers:
                        matmul(w, h, out=z)
                        h = self._act(z)
                    matmul(head, last, out=t)
                    add(t, s_lin, out=s_next)
                    if heading is not None:
                        self._heading(columns)
        return self._kinematics(state, x[1:, :, :4].transpose(1, 3, 0, 2))  # (E, B, H, 4)

    def _rollout_one(self, state: np.ndarray, controls: np.ndarray) -> np.ndarray:
        """rollout() of one state (the node's cycle): the members side by side in one vector per step (the
        block-diagonal first_one / out_one, _vector_weights), so that a step is six numpy calls on contiguous
        memory: [pre | unit] = [s | c | 1] F, act, hidden products (stacked over the members), act, s' = r O, sin."""
        e, horizon, n_s, c, width = self.ensemble_size, controls.shape[1], self.n_state, self.n_controls, self.width
        hw, hs = e * width, e * n_s  # where s_k starts in a row, and its length
        rows = np.empty((horizon + 1, hw + hs + c + 1), dtype=self.dtype)  # r_k = [h (E W) | s_k (E S) | c_k | 1]
        rows[0, hw: hw + 4 * e] = np.tile(state[0], e)  # q = E x [u, v, r, psi]
        heading = rows[0, hw + 4 * e: hw + hs]
        heading[...] = (state[0, 3] + self.phase).reshape(-1)  # E x [psi + phase]
        self._heading(heading)
        rows[:horizon, hw + hs: hw + hs + c] = controls[0]
        rows[horizon, hw + hs: hw + hs + c] = 0.0
        rows[:, -1] = 1.0
        first, out_one = self.first_one, self.out_one
        y = np.empty(first.shape[1], dtype=self.dtype)  # E x [pre | unit] (or the last h, without hidden layers)
        stacked = y.reshape(e, 1, -1)
        layers = [(w, np.empty((e, 1, w.shape[2]), dtype=self.dtype)) for w in self.hidden[:-1]]
        dot, matmul, last = np.dot, np.matmul, self.hidden[-1] if self.hidden else None
        steps = zip(rows[:-1], rows[:-1, hw:], rows[:-1, :hw], rows[:-1, :hw].reshape(horizon, e, 1, width),
                    rows[1:, hw: hw + hs], rows[1:, hw + 4 * e: hw + hs])
        with np.errstate(over="ignore", invalid="ignore"):
            # the usual network: NTF, tanh, depth 2
            if not self.clipped and len(self.hidden) == 1 and self.trig_mode == 2:
                tanh, sin = np.tanh, np.sin
                for row, inputs, h, h_stacked, s_next, columns in steps:
                    dot(inputs, first, out=y)
                    tanh(y, out=y)
                    matmul(stacked, last, out=h_stacked)
                    tanh(h, out=h)
                    dot(row, out_one, out=s_next)
                    sin(columns, out=columns)
            else:  # the same step for any depth, activation and heading columns
                for row, inputs, h, h_stacked, s_next, columns in steps:
                    if last is None:  # no hidden layers: the first layer's units are the last ones
                        dot(inputs, first, out=h)
                        self._act(h)
                    else:
                        dot(inputs, first, out=y)
                        g = self._act(stacked)
                        for w, z in layers:
                            matmul(g, w, out=z)
                            g = self._act(z)
                        matmul(g, last, out=h_stacked)
                        self._act(h)
                    dot(row, out_one, out=s_next)
                    self._heading(columns)
        path = rows[1:, hw: hw + 4 * e].reshape(horizon, e, 4).transpose(1, 0, 2)[:, None]  # (E, 1, H, 4)
        return self._kinematics(state, path)

    def _kinematics(self, state: np.ndarray, path: np.ndarray) -> np.ndarray:
        """(E, B, H, 6) [u, v, r, x_n, y_e, psi] float64 from the start state (B, 4) and the steps' [u, v, r, psi]
        (E, B, H, 4): positions by the trapezoidal rule over R(psi) [u, v] (DnnRollout's kinematics).

        Computed step-major, each quantity one (H + 1, E, B) array (the batch form's memory order: B contiguous),
        the same operations in the same order as the member-major form before, so the same numbers; only the six
        columns of the result are written strided."""
        e, b, horizon = path.shape[:3]
        q = np.empty((4, horizon + 1, e, b))  # [u, v, r, psi] float64 of the start and every step
        q[:, 0] = state.T[:, None, :]
        q[:, 1:] = path.transpose(3, 2, 0, 1)  # (4, H, E, B)
        u, v, psi = q[0], q[1], q[3]
        cos_psi, sin_psi = np.cos(psi), np.sin(psi)  # (H + 1, E, B)
        north, east = u * cos_psi - v * sin_psi, u * sin_psi + v * cos_psi
        out = np.empty((e, b, horizon, 6))
        steps = out.transpose(2, 0, 1, 3)  # (H, E, B, 6) view
        for j in range(3):
            steps[..., j] = q[j, 1:]
        np.cumsum(0.5 * self.dt * (north[1:] + north[:-1]), axis=0, out=steps[..., 3])
        np.cumsum(0.5 * self.dt * (east[1:] + east[:-1]), axis=0, out=steps[..., 4])
        steps[..., 5] = psi[1:]
        return out

    def __call__(self, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
        """As the TorchScript module: (B, 4), (B, H, C) tensors -> (E, B, H, 6) float64 tensor."""
        return torch.from_numpy(self.rollout(state.detach().cpu().double().numpy(),
                                             controls.detach().cpu().double().numpy()))


def _differs_from_file(artifact: ModelArtifact, runner: Any, members: int) -> float:
    """The largest difference of `runner` from the file's own module on _probe's inputs, relative to each output
    column's scale (inf when the shapes differ)."""
    state, controls = _probe(artifact.metadata)
    dtype = artifact.module.m_s.dtype
    with torch.inference_mode():
        expected = artifact.module(state.to(dtype), controls.to(dtype))[:members].double()  # (E, B, H, 6)
        got = runner(state.to(dtype), controls.to(dtype)).double()
    if got.shape != expected.shape:
        return math.inf
    scale = 1.0 + expected.abs().amax(dim=(0, 1, 2))  # (6,)
    return float(((got - expected).abs().amax(dim=(0, 1, 2)) / scale).max().item())


def numpy_rollout(artifact: ModelArtifact, members: int | None = None) -> NumpyDnnRollout:
    """The artifact's DNN rollout as NumpyDnnRollout, checked against the file's own module on _probe's inputs.

    ModelError when the file's module is not a DnnRollout's network or the numpy rollout differs from it by more than
    FUSED_CHECK_RTOL of each output column's scale (the caller then tries FusedDnnRollout, then the file's module:
    models/loading.py)."""
    metadata = artifact.metadata
    if str(metadata.get("model_type")) != "dnn":
        raise ModelError(f"model {artifact.path}: model_type {metadata.get('model_type')!r}, not a plain dnn")
    try:
        arch = metadata["architecture"]
        runner = NumpyDnnRollout(dict(artifact.module.named_buffers()), feature_set=str(metadata["feature_set"]),
                                 activation=str(arch["activation"]), ceiling=float(arch["ceiling"]),
                                 dt=float(metadata["dt"]), members=members)
    except (KeyError, TypeError, ValueError, IndexError, AttributeError, ConfigError) as err:
        raise ModelError(f"model {artifact.path}: its network cannot be stepped with numpy "
                         f"({type(err).__name__}: {err})") from err
    try:
        error = _differs_from_file(artifact, runner, runner.ensemble_size)
    except MODEL_RUN_ERRORS as err:
        raise ModelError(f"model {artifact.path}: the numpy rollout cannot be run: {failure_reason(err)}") from err
    if not error <= FUSED_CHECK_RTOL:
        raise ModelError(f"model {artifact.path}: the numpy rollout differs from the file's by {error:.3g} of the "
                         f"output's scale (limit {FUSED_CHECK_RTOL:g}): not a DnnRollout of this version?")
    return runner

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
"""
from __future__ import annotations

import copy
import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

from usv_predictor.errors import ConfigError
from usv_predictor.features import FEATURE_SETS

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

    def __post_init__(self) -> None:
        if self.feature_set not in FEATURE_SETS:
            raise ConfigError(f"DnnConfig.feature_set={self.feature_set!r}; known: {sorted(FEATURE_SETS)}")
        if self.n_features != len(FEATURE_SETS[self.feature_set]):
            raise ConfigError(f"DnnConfig.n_features={self.n_features} but feature set {self.feature_set} has "
                              f"{len(FEATURE_SETS[self.feature_set])} features")
        if self.activation not in ACTIVATIONS:
            raise ConfigError(f"DnnConfig.activation={self.activation!r}; expected one of {list(ACTIVATIONS)}")
        if not (1 <= self.width <= 4096 and 1 <= self.depth <= 16):
            raise ConfigError(f"DnnConfig width={self.width} / depth={self.depth}: expected 1..4096 / 1..16")
        if not (self.ceiling > 0.0 and math.isfinite(self.ceiling)):
            raise ConfigError(f"DnnConfig.ceiling={self.ceiling}: expected a finite value > 0")

    @classmethod
    def for_features(cls, feature_set: str, **kwargs: Any) -> "DnnConfig":
        if feature_set not in FEATURE_SETS:
            raise ConfigError(f"feature set {feature_set!r}; known: {sorted(FEATURE_SETS)}")
        return cls(feature_set=feature_set, n_features=len(FEATURE_SETS[feature_set]), **kwargs)

    @property
    def feature_names(self) -> tuple[str, ...]:
        return FEATURE_SETS[self.feature_set]

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


def wrap_angle_torch(angle: torch.Tensor) -> torch.Tensor:
    """frames.wrap_angle in torch: [-pi, pi), the same floor-modulo operations."""
    return torch.remainder(angle + math.pi, 2.0 * math.pi) - math.pi


def features_torch(feature_set: str, state: torch.Tensor, controls: torch.Tensor) -> torch.Tensor:
    """features.features in torch (differentiable): state (..., 4), controls (..., 2) -> (..., F)."""
    columns = [state[..., 0:3], controls]  # u, v, r, delta, rpm
    psi = state[..., 3:4]
    if feature_set == "NAF":
        columns.append(wrap_angle_torch(psi))
    elif feature_set == "NTF":
        columns += [torch.sin(psi), torch.cos(psi)]
    elif feature_set != "F0":
        raise ConfigError(f"unknown feature set {feature_set!r}; known: {sorted(FEATURE_SETS)}")
    return torch.cat(columns, dim=-1)

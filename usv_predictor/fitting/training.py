"""Training of the seed 000 network (sec. 2.2, Table 5), reproducible and fast on a small CPU.

Recipe (TrainingConfig defaults = seed 000 Table 5):
    loss          MSE (eq. 5) on the normalised target (each of u, v, r divided by its training std,
                  so the surge speed in m/s does not drown the yaw rate in rad/s)
    L2            1e-4 on the Linear weights, as Adam weight_decay (grad += lambda w: the gradient of
                  lambda/2 |w|^2, the toolbox's L2Regularization); biases and batch norm are not decayed
    optimiser     Adam, initial learning rate 0.005, decayed stepwise: x`lr_drop` every `lr_step_epochs`
                  (the toolbox's 'piecewise' schedule; the paper says only "it will decrease accordingly")
    batches       128, reshuffled every epoch, an incomplete last batch dropped (as the toolbox does;
                  batch norm needs > 1 sample); all data held as tensors, no DataLoader
    epochs        at most 500; early stopping when the validation loss has not improved for
                  `patience` epochs, and the weights of the best validation epoch are restored

One-step training (the paper, eq. 7): features X (N, F) -> next [u, v, r] Y (N, 3).
Multi-step training (extension, `multi_step=k > 1`): windows of k steps are rolled out closed loop
as in Fig. 3 (teacher forcing off): the predicted [u, v, r] is fed back, psi is integrated from r by
the trapezoidal rule, features are recomputed in torch (data.features.features takes tensors), and the loss is
the mean normalised MSE over the k predicted [u, v, r].
Ensembles (`ensemble=E`): E members trained alike from seeds seed, seed+1, ... (different
initialisation and batch order); their spread is the prediction uncertainty.

Reproducibility: the torch RNG is forked (the caller's global state is untouched) and seeded per
member, batch order comes from a seeded Generator, intra-op threads are fixed (`threads`, default 1:
on these tiny matrices threads cost more than they give) and restored afterwards, and deterministic
algorithms are enforced while training.
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import asdict, dataclass
from typing import Callable, Iterator, Sequence

import numpy as np
import torch
from torch import nn

from usv_predictor.data.features import feature_names, features
from usv_predictor.data.recording import Recording, recording_layout
from usv_predictor.errors import ConfigError, DatasetError
from usv_predictor.models.dnn import DnnConfig, DnnModel, Normalisation, fit_normalisation

LR_SCHEDULES = ("step", "cosine", "constant")


@dataclass(frozen=True)
class TrainingConfig:
    epochs: int = 500  # maximum epochs (seed 000 Table 5)
    batch_size: int = 128  # (seed 000 Table 5)
    learning_rate: float = 0.005  # initial (seed 000 Table 5)
    lr_schedule: str = "step"  # "step" (x lr_drop every lr_step_epochs) | "cosine" (to 1 % at `epochs`) | "constant"
    lr_step_epochs: int = 100
    lr_drop: float = 0.5
    weight_decay: float = 1e-4  # L2 regularisation (seed 000 Table 5)
    patience: int | None = 50  # epochs without validation improvement before stopping; None: never stop
    multi_step: int = 1  # k > 1: closed-loop rollout training over k steps
    ensemble: int = 1  # members, seeds seed .. seed+E-1
    seed: int = 0
    threads: int = 1  # intra-op threads while training

    def __post_init__(self) -> None:
        checks = {
            "epochs": 1 <= self.epochs <= 100_000,
            "batch_size": self.batch_size >= 2,
            "learning_rate": 0.0 < self.learning_rate < 1.0,
            "lr_schedule": self.lr_schedule in LR_SCHEDULES,
            "lr_step_epochs": self.lr_step_epochs >= 1,
            "lr_drop": 0.0 < self.lr_drop <= 1.0,
            "weight_decay": 0.0 <= self.weight_decay <= 1.0,  # an L2 weight beyond 1 overflows Adam's float32
            "patience": self.patience is None or self.patience >= 1,
            "multi_step": 1 <= self.multi_step <= 1000,
            "ensemble": 1 <= self.ensemble <= 64,
            "threads": self.threads >= 1,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            raise ConfigError(f"TrainingConfig: invalid {', '.join(f'{n}={getattr(self, n)!r}' for n in bad)}")

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class Samples:
    """One-step samples: features x (N, F) and next states y (N, 3) [u, v, r]."""

    x: np.ndarray
    y: np.ndarray

    def __len__(self) -> int:
        return len(self.x)


@dataclass(frozen=True)
class Windows:
    """k-step rollout windows: start state (N, 4) [u, v, r, psi], controls (N, k, 2), targets (N, k, 3)."""

    state0: np.ndarray
    controls: np.ndarray
    targets: np.ndarray
    dt: float

    def __len__(self) -> int:
        return len(self.state0)


@dataclass(frozen=True)
class MemberResult:
    seed: int
    best_epoch: int  # 1-based; the restored weights
    epochs_run: int
    train_loss: float  # at the best epoch
    val_loss: float | None  # at the best epoch (None without validation data: there is no such loss)
    history: tuple[tuple[float, float | None], ...]  # (train, val or None) per epoch


@dataclass(frozen=True)
class TrainingResult:
    models: tuple[DnnModel, ...]  # eval mode, best weights, batch norm not folded
    config: DnnConfig
    recipe: TrainingConfig
    normalisation: Normalisation
    members: tuple[MemberResult, ...]
    time_s: float
    monitor: str  # "val" or "train" (no validation data: the training loss picks the best epoch)
    n_train: int
    n_val: int

    @property
    def best_epoch(self) -> int:
        return self.members[0].best_epoch

    @property
    def val_loss(self) -> float | None:
        """Mean validation loss at the best epochs; None without validation data."""
        losses = [m.val_loss for m in self.members if m.val_loss is not None]
        return float(np.mean(losses)) if losses else None

    @property
    def train_loss(self) -> float:
        return float(np.mean([m.train_loss for m in self.members]))

    def summary(self) -> dict:
        """Recipe, best epochs and losses: what the artifact keeps under `training`."""
        return {
            "recipe": self.recipe.to_dict(),
            "loss": "mse_normalised_target"
                + (f"_rollout_{self.recipe.multi_step}" if self.recipe.multi_step > 1 else ""),
            "monitor": self.monitor,
            "best_epoch": [m.best_epoch for m in self.members],
            "epochs_run": [m.epochs_run for m in self.members],
            "train_loss": [m.train_loss for m in self.members],
            "val_loss": [m.val_loss for m in self.members],
            "n_train": self.n_train,
            "n_val": self.n_val,
            "time_s": self.time_s,
        }


Progress = Callable[[int, int, float, "float | None"], None]  # (member, epoch, train loss, val loss or None)


# ----------------------------------------------------------------------------- data

def samples_from_recordings(recordings: Sequence[Recording], feature_set: str) -> Samples:
    """One-step samples (features at t, [u, v, r] at t+1) of each recording, skipping non-finite rows."""
    xs, ys = [], []
    layout = recording_layout(recordings)
    for rec in recordings:
        x = features(feature_set, rec.state()[:-1], rec.controls[:-1], layout)  # (T-1, F)
        y = rec.nu[1:]  # (T-1, 3)
        ok = np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1)
        xs.append(x[ok])
        ys.append(y[ok])
    width = len(feature_names(feature_set, layout))
    return Samples(np.concatenate(xs) if xs else np.zeros((0, width)), np.concatenate(ys) if ys else np.zeros((0, 3)))


def windows_from_recordings(recordings: Sequence[Recording], k: int, stride: int = 1) -> Windows:
    """Every k-step window (start every `stride` samples) lying in one recording with finite values."""
    if k < 1:
        raise ConfigError(f"rollout windows need k >= 1 steps, got {k}")
    dts = {round(rec.dt, 9) for rec in recordings}
    if len(dts) > 1:
        raise DatasetError(f"recordings have different steps {sorted(dts)} s; windows need one dt")
    starts, ctrls, targets = [], [], []
    for rec in recordings:
        state = rec.state()  # (T, 4)
        finite = np.isfinite(state).all(axis=1) & np.isfinite(rec.controls).all(axis=1)
        for s in range(0, len(rec) - k, stride):
            if finite[s:s + k + 1].all():
                starts.append(state[s])
                ctrls.append(rec.controls[s:s + k])
                targets.append(rec.nu[s + 1:s + k + 1])
    dt = float(recordings[0].dt) if recordings else float("nan")
    if not starts:
        width = len(recording_layout(recordings).controls)
        return Windows(np.zeros((0, 4)), np.zeros((0, k, width)), np.zeros((0, k, 3)), dt)
    return Windows(np.stack(starts), np.stack(ctrls), np.stack(targets), dt)


# ----------------------------------------------------------------------------- training

@contextlib.contextmanager
def reproducible(seed: int, threads: int) -> Iterator[None]:
    """Seeded, deterministic, fixed-thread torch inside; the caller's RNG, threads and flags restored."""
    old_threads = torch.get_num_threads()
    old_deterministic = torch.are_deterministic_algorithms_enabled()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(True)
        try:
            yield
        finally:
            torch.use_deterministic_algorithms(old_deterministic)
            torch.set_num_threads(old_threads)


def rollout_nu(model: DnnModel, feature_set: str, state0: torch.Tensor, controls: torch.Tensor,
               dt: float) -> torch.Tensor:
    """Closed-loop k-step prediction (seed 000 Fig. 3), differentiable: returns nu (N, k, 3).

    state0 (N, 4) [u, v, r, psi]; controls (N, k, C) in the model's layout; psi_{j+1} = psi_j + dt/2 (r_j + r_{j+1}).
    """
    nu, psi = state0[:, :3], state0[:, 3:4]  # (N, 3), (N, 1)
    layout = model.config.actuator_layout
    out = []
    for j in range(controls.shape[1]):
        x = features(feature_set, torch.cat([nu, psi], dim=1), controls[:, j], layout)  # (N, F)
        nxt = model(x)  # (N, 3)
        psi = psi + 0.5 * dt * (nu[:, 2:3] + nxt[:, 2:3])
        nu = nxt
        out.append(nu)
    return torch.stack(out, dim=1)  # (N, k, 3)


def _learning_rate(recipe: TrainingConfig, epoch: int) -> float:
    """Learning rate of epoch (0-based)."""
    if recipe.lr_schedule == "step":
        return recipe.learning_rate * recipe.lr_drop ** (epoch // recipe.lr_step_epochs)
    if recipe.lr_schedule == "cosine":  # from lr to 1 % of lr at the last epoch
        floor = 0.01 * recipe.learning_rate
        return floor + 0.5 * (recipe.learning_rate - floor) * (1.0
                                                               + math.cos(math.pi * epoch / max(recipe.epochs - 1, 1)))
    return recipe.learning_rate


def _optimizer(model: DnnModel, recipe: TrainingConfig) -> torch.optim.Adam:
    decayed = [m.weight for m in model.modules() if isinstance(m, nn.Linear)]
    ids = {id(p) for p in decayed}
    others = [p for p in model.parameters() if id(p) not in ids]
    return torch.optim.Adam([{"params": decayed, "weight_decay": recipe.weight_decay},
                             {"params": others, "weight_decay": 0.0}], lr=recipe.learning_rate)


class _Objective:
    """Tensors of one split and the loss of a model on a batch of them (one-step or rollout)."""

    def __init__(self, config: DnnConfig, recipe: TrainingConfig, samples: Samples | None, windows: Windows | None):
        self.feature_set = config.feature_set
        self.multi = recipe.multi_step > 1
        if self.multi:
            assert windows is not None
            arrays = (windows.state0, windows.controls, windows.targets)
            self.tensors = [torch.as_tensor(a, dtype=torch.float32) for a in arrays]
            self.dt = windows.dt
        else:
            assert samples is not None
            self.tensors = [torch.as_tensor(a, dtype=torch.float32) for a in (samples.x, samples.y)]
            self.dt = float("nan")
        self.n = len(self.tensors[0])

    def loss(self, model: DnnModel, index: torch.Tensor | None = None) -> torch.Tensor:
        batch = self.tensors if index is None else [t.index_select(0, index) for t in self.tensors]
        if not self.multi:
            x, y = batch  # (B, F), (B, 3)
            return torch.mean((model.forward_normalised(x) - model.normalised_target(x, y)) ** 2)
        state0, controls, targets = batch  # (B, 4), (B, k, 2), (B, k, 3)
        pred = rollout_nu(model, self.feature_set, state0, controls, self.dt)  # (B, k, 3)
        return torch.mean(((pred - targets) / model.y_std) ** 2)


def _train_member(config: DnnConfig, recipe: TrainingConfig, norm: Normalisation, train: _Objective,
                  val: _Objective | None, seed: int, member: int,
                  progress: Progress | None) -> tuple[DnnModel, MemberResult]:
    with reproducible(seed, recipe.threads):
        model = DnnModel(config, norm)
        optimizer = _optimizer(model, recipe)
        order = torch.Generator().manual_seed(seed)
        batch = min(recipe.batch_size, train.n)
        n_batches = max(train.n // batch, 1)
        best: tuple[float, int, float, float | None] = (math.inf, 0, math.nan, None)  # (monitored, epoch, train, val)
        best_state = {k: v.clone() for k, v in model.state_dict().items()}
        history: list[tuple[float, float | None]] = []
        for epoch in range(recipe.epochs):
            for group in optimizer.param_groups:
                group["lr"] = _learning_rate(recipe, epoch)
            model.train()
            perm = torch.randperm(train.n, generator=order)
            total = 0.0
            for b in range(n_batches):
                loss = train.loss(model, perm[b * batch:(b + 1) * batch])
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                total += loss.item()
            train_loss = total / n_batches
            model.eval()
            with torch.no_grad():
                val_loss = float(val.loss(model)) if val is not None else None
            history.append((train_loss, val_loss))
            monitored = val_loss if val_loss is not None else train_loss
            if not math.isfinite(monitored):
                raise ConfigError(f"training diverged: the {'validation' if val_loss is not None else 'training'} loss "
                                  f"is {monitored} at epoch {epoch + 1} of member {member}; lower the learning rate "
                                  f"(now {recipe.learning_rate:g})")
            if monitored < best[0]:
                best = (monitored, epoch + 1, train_loss, val_loss)
                best_state = {k: v.clone() for k, v in model.state_dict().items()}
            if progress is not None:
                progress(member, epoch + 1, train_loss, val_loss)
            if recipe.patience is not None and epoch + 1 - best[1] >= recipe.patience:
                break
        model.load_state_dict(best_state)
        model.eval()
    return model, MemberResult(seed, best[1], len(history), best[2], best[3], tuple(history))


def train_dnn(config: DnnConfig, train: Samples, val: Samples | None = None, recipe: TrainingConfig = TrainingConfig(),
              *,
              train_windows: Windows | None = None, val_windows: Windows | None = None,
              progress: Progress | None = None) -> TrainingResult:
    """Train recipe.ensemble members on `train`, early-stopping on `val`; see the module docstring.

    The normalisation always comes from the one-step training samples. Multi-step training
    (recipe.multi_step = k > 1) needs `train_windows` (and `val_windows` for early stopping) of k steps.
    """
    if len(train) == 0:
        raise DatasetError("the training split holds no samples: nothing to train on")
    if train.x.shape[1] != config.n_features:
        raise ConfigError(f"training features have {train.x.shape[1]} columns, the {config.feature_set} "
                          f"network expects {config.n_features}")
    if recipe.multi_step > 1:
        if train_windows is None or len(train_windows) == 0:
            raise DatasetError(f"multi-step training needs {recipe.multi_step}-step windows from the training "
                               f"recordings; none given (recordings shorter than {recipe.multi_step + 1} samples?)")
        for name, w in (("train", train_windows), ("val", val_windows)):
            if w is not None and w.controls.shape[1] != recipe.multi_step:
                raise ConfigError(f"{name} windows have {w.controls.shape[1]} steps, multi_step is {recipe.multi_step}")
    norm = fit_normalisation(train.x, train.y, config.predict_increment)
    train_obj = _Objective(config, recipe, train, train_windows)
    val_data = val_windows if recipe.multi_step > 1 else val  # validation uses the training objective
    val_obj = _Objective(config, recipe, val, val_windows) if val_data is not None and len(val_data) else None
    started = time.perf_counter()
    models, members = [], []
    for m in range(recipe.ensemble):
        model, result = _train_member(config, recipe, norm, train_obj, val_obj, recipe.seed + m, m, progress)
        models.append(model)
        members.append(result)
    return TrainingResult(models=tuple(models), config=config, recipe=recipe, normalisation=norm,
                          members=tuple(members), time_s=time.perf_counter() - started,
                          monitor="val" if val_obj is not None else "train", n_train=train_obj.n,
                          n_val=val_obj.n if val_obj is not None else 0)

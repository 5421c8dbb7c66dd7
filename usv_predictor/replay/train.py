"""A dataset -> the seed 000 network as one TorchScript artifact: what `replay train` does, from a typed TrainRequest.

Trains on the dataset's `train` split (usv_predictor.fitting.training.train_dnn), early-stops on its `val` split
(without one, the training loss picks the best epoch) and exports the ensemble with its metadata and the vessel's
whole description (usv_predictor.models.dnn.export). The recipe defaults are seed 000 Table 5.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from usv_predictor.fitting.training import Progress, TrainingConfig
    from usv_predictor.physics.vessel import Vessel


@dataclass(frozen=True)
class Architecture:
    """The network's shape (models/dnn.DnnConfig.for_features; seed 000 eq. 1-2); its inputs are the feature set's."""

    width: int = 100  # hidden units per layer
    depth: int = 2  # hidden layers
    activation: str = "tanh"  # "tanh" (seed 000 eq. 2) or "clipped_relu" (eq. 1)
    ceiling: float = 10.0  # (-) clippedReLU ceiling
    batch_norm: bool = True  # batch normalisation after each hidden layer
    predict_increment: bool = True  # predict the change of [u, v, r] over a step, not its next value


@dataclass(frozen=True)
class TrainRequest:
    """Which dataset `replay train` trains on, how, and what it writes."""

    dataset: Path  # a dataset of `replay dataset` (.npz)
    output: Path  # the model artifact written
    vessel: Vessel  # the bags' vessel, resolved once by the command, embedded in the model: its layout the dataset's
    recipe: TrainingConfig  # epochs, batches, learning rate, L2, multi-step loss, ensemble, seed, threads
    architecture: Architecture = Architecture()
    features: str | None = None  # feature set (F0, NAF, NTF); None: the dataset's (another: recomputed from it)
    horizon_steps: int | None = None  # default prediction horizon recorded in the model; None: the config's
    dtype: str = "float32"  # arithmetic of the exported rollout: "float32" or "float64"


def train(request: TrainRequest, progress: Progress | None = None,
          log: Callable[[str], None] = lambda _: None) -> dict[str, Any]:
    """Train and export the request's model; the summary (losses, best epochs, time, model_id, architecture, recipe).
    progress: per member and epoch (fitting.training.train_dnn); log: the line saying what is trained. DatasetError
    for a dataset without training samples, ConfigError for a vessel of another layout than its bags'."""
    from usv_predictor.config import load_predictor_config
    from usv_predictor.data.dataset import load_dataset
    from usv_predictor.errors import ConfigError, DatasetError
    from usv_predictor.fitting import training
    from usv_predictor.models.dnn import DnnConfig, export
    from usv_predictor.physics.actuators import actuator_layout

    dataset = load_dataset(request.dataset)
    feature_set = request.features or dataset.feature_set
    train_split, val_split = dataset.split("train"), dataset.split("val")
    if len(train_split.X) == 0:
        raise DatasetError(f"{request.dataset}: the train split has no samples "
                           f"(splits: {dataset.split_sizes()}); build the dataset with training manoeuvres")
    if feature_set == dataset.feature_set:
        samples = training.Samples(train_split.X, train_split.Y)
        held = training.Samples(val_split.X, val_split.Y)
    else:  # the recordings are in the file: recompute the features of the other set
        samples = training.samples_from_recordings(train_split.recordings(), feature_set)
        held = training.samples_from_recordings(val_split.recordings(), feature_set)
    vessel, recipe, shape = request.vessel, request.recipe, request.architecture
    layout = actuator_layout(dataset.control_layout)  # the bags' layout, stored by `replay dataset`
    if vessel.actuator_layout.name != layout.name:
        raise ConfigError(f"{request.dataset}: the dataset's control layout is {layout.name} "
                          f"{list(layout.control_names)} but vessel {vessel.name} is {vessel.actuator_layout.name}: "
                          "give --vessel of the vessel the bags were recorded on")
    config = DnnConfig.for_features(feature_set, layout, width=shape.width, depth=shape.depth,
                                    activation=shape.activation, ceiling=shape.ceiling, batch_norm=shape.batch_norm,
                                    predict_increment=shape.predict_increment)
    windows = {}
    if recipe.multi_step > 1:
        windows = {"train_windows": training.windows_from_recordings(train_split.recordings(), recipe.multi_step),
                   "val_windows": training.windows_from_recordings(val_split.recordings(), recipe.multi_step)}
    log(f"training {config.feature_set} {config.activation} {config.depth}x{config.width} on {len(samples)} samples "
        f"(val {len(held)}), {recipe.epochs} epochs max, ensemble {recipe.ensemble}")
    result = training.train_dnn(config, samples, held if len(held) else None, recipe, progress=progress, **windows)
    horizon_steps = request.horizon_steps or round(load_predictor_config().horizon_s / dataset.dt)
    artifact = export(request.output, result.models, config, dt=dataset.dt, vessel=vessel,
                      training_data_sha256=dataset.digest(),
                      training={**result.summary(), "dataset": str(request.dataset)},
                      horizon_steps=horizon_steps, dtype=request.dtype)
    return {
        "model": str(request.output), "model_id": artifact.model_id, "feature_set": feature_set,
        "dt": dataset.dt, "ensemble_size": recipe.ensemble, "time_s": result.time_s,
        "best_epoch": [m.best_epoch for m in result.members], "epochs_run": [m.epochs_run for m in result.members],
        "train_loss": result.train_loss, "val_loss": result.val_loss, "monitor": result.monitor,
        "n_train": result.n_train, "n_val": result.n_val, "architecture": config.to_dict(), "recipe": recipe.to_dict(),
    }
